"""What a ``process`` run will cost, said before it starts: the detector passes per detection frame (the full frame
and the tiles of :mod:`trafficgeo.video.detectors.tiling`), how often (``every``), the time per pass measured by the
backend probe (:mod:`trafficgeo.video.detectors.backends`) and the whole run's estimated wall-clock time.

A pass at an input other than the probe's (the bands of ``tiling="bands"``) is counted in proportion to its input
pixels. The probe times the network alone; the rest of a detection (cropping, letterboxing, decoding the outputs,
merging the tiles, the size classes) and decoding the video are measured at the start of the run (one detection on
the first frame, a few frames decoded); the tracker's allowance is :data:`TRACK_MS_PER_FRAME`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from trafficgeo.video.detectors.backends import BackendChoice
    from trafficgeo.video.detectors.tile_plan import TilePlan

# Tracking and the rest of the per-frame work (ms per detection frame): ByteTrack on the learned detector's
# detections of NGSIM seq2 (24 a frame, 2 x 2 tiles) took 1.6 ms a frame on average, 6.1 ms at the 95th percentile
# (bench_backends, 2026-12-04, 2 threads).
TRACK_MS_PER_FRAME = 3.0

# How far a run's wall clock strayed from this estimate: repeated runs of one command on a shared 2-core machine
# took 0.65x to 1.6x of it (65 s once, 23 s the next; issue 42). The estimate says this range; the progress bar's
# time left follows the pace measured as the run goes.
SPREAD = (0.65, 1.6)


@dataclass(frozen=True)
class RunCost:
    """The estimate: ``passes`` per detection frame (``pass_units``: the same counted in probe-input pixels), one
    detection frame in ``every``, ``ms_per_pass`` of ``backend``; per detection frame ``other_ms`` (the detector's
    work besides the network), ``decode_ms`` and ``track_ms``; ``detection_frames`` over ``video_s`` s of video ->
    ``seconds`` of wall clock, ``realtime_factor`` (video s per wall-clock s)."""

    passes: int
    pass_units: float
    every: int
    backend: str
    ms_per_pass: float
    other_ms: float
    decode_ms: float
    track_ms: float
    detection_frames: int
    video_s: float
    seconds: float
    realtime_factor: float
    scheduled_passes: float | None = None  # passes per detection frame expected under a tile schedule
    probe_ms_per_pass: float | None = None  # the backend probe's time per pass (``ms_per_pass`` is what was used)

    def to_dict(self) -> dict[str, object]:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}

    def summary(self) -> str:
        """One line for the terminal."""
        often = "every frame" if self.every == 1 else f"every {_ordinal(self.every)} frame"
        units = f" ({self.pass_units:.2f} probe-size passes)" if abs(self.pass_units - self.passes) > 0.01 else ""
        if self.scheduled_passes is not None:
            units = (f", about {self.scheduled_passes:.1f} with the tile schedule ({self.pass_units:.2f} probe-size "
                     "passes)")
        lo, hi = (duration_text(self.seconds * k) for k in SPREAD)
        return (f"detector: {self.passes} pass{'es' if self.passes != 1 else ''} per detection frame{units}, {often}, "
                f"{self.ms_per_pass:.0f} ms per pass ({self.backend}) -> about {duration_text(self.seconds)} for "
                f"{duration_text(self.video_s)} of video ({self.realtime_factor:.2f}x real time; {lo} to {hi} as "
                "the machine's load goes, the progress bar follows the measured pace)")


def _ordinal(n: int) -> str:
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def duration_text(seconds: float) -> str:
    """``seconds`` in words: "45 s", "2 min 10 s", "3 h 5 min"."""
    s = round(max(0.0, seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s" if s % 60 else f"{s // 60} min"
    return f"{s // 3600} h {(s % 3600) // 60} min"


def plan_passes(plan: TilePlan | None, probe_input_hw: tuple[int, int], tile_share: ArrayLike = None
                ) -> tuple[int, float]:
    """Detector passes per detection frame of a tile ``plan`` (None: the full frame only) and the same in passes of
    the probe's input size (``probe_input_hw``, (h, w) px), counted by input pixels; ``tile_share`` (K,): the share
    of detection frames each tile runs on (a tile schedule; None: all)."""
    probe_px = float(probe_input_hw[0] * probe_input_hw[1])
    if plan is None or not probe_px > 0:
        return 1, 1.0
    passes = 1 + len(plan.tiles)
    share = np.ones(len(plan.tiles)) if tile_share is None else np.asarray(tile_share, dtype=np.float64)
    tile_px = np.prod(plan.tile_inputs_hw, axis=1).astype(np.float64)
    return passes, (plan.full_input_pixels + float(share @ tile_px)) / probe_px


def estimate_cost(choice: BackendChoice, plan: TilePlan | None, *, every: int, video_s: float, fps: float,
                  decode_ms: float, track_ms: float = TRACK_MS_PER_FRAME, detect_ms: float | None = None,
                  tile_share: ArrayLike = None) -> RunCost:
    """The run's cost: detection frames = ceil(``video_s`` x ``fps`` / ``every``), each costing the plan's passes
    (:func:`plan_passes`, each tile weighted by its ``tile_share`` under a tile schedule) x the time per pass, plus
    the rest of the detection (``detect_ms``, a whole detection's measured time with every tile, minus those passes;
    0 when not given or less; it is work per pass, so a tile schedule runs less of it), ``decode_ms`` (decoding the
    frame and skipping the ``every`` - 1 before it) and ``track_ms``. The time per pass is the probe's, or less
    where the run's own detection (``detect_ms``) took less than the probe's time for its passes: the probe is
    timed once per machine and model (the backend cache), on whatever else the machine was doing then; the 13
    junction runs of ``bench_junction`` took 0.24-0.58 of an estimate from a probe timed on a busy machine
    (``benchmarks/bench_cost.py``)."""
    passes, all_units = plan_passes(plan, choice.probe_input_hw)
    _, units = plan_passes(plan, choice.probe_input_hw, tile_share)
    frames = max(1, math.ceil(video_s * fps / every - 1e-9))
    pass_ms = choice.ms_per_pass
    if detect_ms is not None and all_units > 0:
        # the run's own detection says more than the probe, which was timed once per machine and model (and may
        # have been timed while the machine was busy): its network cannot have taken longer than all of it
        pass_ms = min(pass_ms, float(detect_ms) / all_units)
    network_ms = units * pass_ms
    # the rest of a detection (crops, letterboxing, decoding each pass's outputs, merging) is work per pass too:
    # under a tile schedule it shrinks with the passes run
    other_ms = max(0.0, float(detect_ms) - all_units * pass_ms) * units / all_units \
        if detect_ms is not None and all_units > 0 else 0.0
    seconds = frames * (network_ms + other_ms + decode_ms + track_ms) / 1e3
    scheduled = None if tile_share is None else 1.0 + float(np.sum(tile_share))
    return RunCost(passes, units, int(every), choice.backend, pass_ms, other_ms, float(decode_ms),
                   float(track_ms), frames, float(video_s), seconds, video_s / seconds if seconds > 0 else math.inf,
                   scheduled, probe_ms_per_pass=choice.ms_per_pass)
