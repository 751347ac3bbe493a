"""``process``: video -> detections -> tracks -> traffic data, streaming, with checkpoints to resume from.

Frames are decoded one at a time (:func:`trafficgeo.video.reader.iter_frames`, real timestamps), detected
(:mod:`trafficgeo.video.detectors`) and tracked (:mod:`trafficgeo.video.track`). The time range is cut into segments of
``checkpoint_s`` seconds of video; at the end of each, its frame times, detections and track boxes go to
``OUT/.checkpoint/`` (plain data, :mod:`trafficgeo.video.checkpoint`), so memory stays bounded during detection and
an interrupted run (Ctrl-C, a crash, a reboot, a full disk) resumes at the segment it was in.

A resumed run gives exactly the outputs of an uninterrupted one, by construction:

* The background detector (OpenCV MOG2/KNN) has a state that cannot be saved, so **every** run starts a fresh
  background model at each segment start, learnt on the ``PRIME_S`` seconds of video before it (on the first
  ``PRIME_S`` seconds of the video if the segment starts earlier than that; longer if its warm-up needs more frames
  than that holds); detections are a function of the video,
  the options and the segment layout, never of where a run was interrupted. An uninterrupted run learns the next
  segment's model on frames it decodes anyway (a second model runs through the last ``PRIME_S`` seconds of each
  segment); a resumed run decodes them again.
* The tracker (ByteTrack) is restored by feeding it again every stored detection of the earlier segments, at the
  same frame times; its tracks must come out equal to the stored ones, or the checkpoint is not used.

At the end the parts become ``detections.csv`` and ``tracks.csv``. A checkpoint whose detection is complete (the run
was stopped during the analysis or while writing) goes straight to that. The caller runs ``analyze`` on the tracks
(:mod:`trafficgeo.traffic.analyze`) and then removes the checkpoint (:func:`finish_run`). Every output is written
atomically; the output folder is locked for the run (:func:`~trafficgeo.io.folder_lock.hold_folder`), and
temporary files left by a killed run are removed when the next one starts.

Time chunks: ``start_s``/``end_s`` process one part of a video into its own folder;
:func:`trafficgeo.video.stitch.stitch_tracks` joins the tracks of chunks that overlap by a few seconds.
"""

from __future__ import annotations

import itertools
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, is_dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface
from trafficgeo.io.atomic import remove_stale_temporaries
from trafficgeo.io.folder_lock import hold_folder
from trafficgeo.run.folder import RunFolder
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.site.lanes import Lanes
from trafficgeo.site.lines import CountLine
from trafficgeo.video.checkpoint import (
    CHECKPOINT_DIR,
    Checkpoint,
    PartBuffer,
    joined_parts,
    load_checkpoint,
    read_part,
    run_key,
    save_checkpoint,
    write_part,
)
from trafficgeo.video.detections import DetectionFrames, Detections
from trafficgeo.video.detectors.factory import check_detector
from trafficgeo.video.track import TrackerOptions, VehicleTracker

if TYPE_CHECKING:
    from trafficgeo.video.detectors.schedule import TileSchedule

__all__ = ["CHECKPOINT_DIR", "PRIME_S", "ProcessOptions", "detect_and_track", "finish_run", "hold_folder",
           ]

DETECTION_COLUMNS = ["frame", "time", "x1", "y1", "x2", "y2", "score", "class"]
PRIME_S = 10.0  # s of video a background model learns on before a segment (see the module docstring)
LEARNED_DETECT_HZ = 10.0  # detections a second of a learned detector when --every is auto (see bench_video)
REALTIME_FOR_ALL_TILES = 1.0  # tile_schedule="auto": every tile when the estimate is at least this x real time
LEARNED_TRACKER = TrackerOptions(lost_track_s=3.0, activation_score=0.3, high_score=0.4)  # see settled_options
JUNCTION_TRACKER = replace(LEARNED_TRACKER, min_iou=0.3)  # the same where the site has gates (settled_options)


@dataclass(frozen=True)
class ProcessOptions:
    """What ``process`` does with a video (times in seconds of video)."""

    # a name of detectors.names.DETECTOR_NAMES, the path of an ONNX model, or a detector object: anything with
    # ``detect(image, time_s) -> Detections`` (BGR image, s), run on every detection frame of the whole video; its
    # ``name`` (else its class's) is what the run records and resumes by, ``learns_background`` (default False)
    # whether it learns from every frame (then every frame is a detection frame), ``fresh()`` (optional) an untrained
    # copy of itself for each segment to learn anew (as background subtraction does), ``warmup_s`` (optional) the
    # seconds of video it learns before it detects
    detector: str | object = "nanodet"
    detector_format: str = "auto"  # an ONNX model's layout (onnx_formats.LAYOUTS), or "auto": from the model
    start_s: float = 0.0
    end_s: float | None = None
    every: int | None = None  # detect on every n-th frame; None: auto (settled_options)
    tiles: bool = True  # the built-in learned detector: camera-aware tiles over the far road (video.tiling)
    tiling: str = "squares"  # how they are planned: "squares" or "bands" (video.learned.TILINGS)
    checkpoint_s: float = 30.0
    tracker: TrackerOptions | None = None  # None: the detector's (settled_options)
    backend: str = "auto"  # what runs a learned detector's network (video.detectors.backends.BACKENDS)
    tile_schedule: str = "auto"  # "all": every tile, every frame; "sparse": each tile as often as its road needs;
    # "auto": "all" where the estimate keeps real time, else "sparse" (_announce_cost)
    restart: bool = False  # start over, ignoring the run folder's checkpoint (not part of the run's key)

    def __post_init__(self) -> None:
        from trafficgeo.video.detectors.backends import check_backend
        from trafficgeo.video.detectors.names import is_background

        if not isinstance(self.detector, str):
            if not callable(getattr(self.detector, "detect", None)):
                raise InputError(f"detector {type(self.detector).__name__}: not a detector; give a name (nanodet, "
                                 "background), the path of an ONNX model, or an object with detect(image, time_s)",
                                 parameters=("detector",))
        else:
            check_detector(self.detector, self.detector_format)  # a bad name or model fails here, before writing
            if not is_background(self.detector):
                check_backend(self.backend)  # openvino asked but not installed: fails here, before writing
        if not (self.start_s >= 0 and (self.end_s is None or self.end_s > self.start_s)):
            raise InputError(f"start_s {self.start_s} / end_s {self.end_s}: need 0 <= start_s < end_s (seconds)",
                             parameters=("start_s", "end_s"))
        if not (self.every is None or (isinstance(self.every, int) and self.every >= 1)):
            raise InputError(f"every {self.every}: must be a whole number >= 1", parameters=("every",))
        from trafficgeo.video.detectors.learned import TILINGS

        if self.tiling not in TILINGS:
            raise InputError(f"tiling {self.tiling}: use one of {', '.join(TILINGS)}", parameters=("tiling",))
        from trafficgeo.video.detectors.schedule import SCHEDULES

        if self.tile_schedule not in SCHEDULES:
            raise InputError(f"tile_schedule {self.tile_schedule}: use one of {', '.join(SCHEDULES)}",
                             parameters=("tile_schedule",))
        if not self.checkpoint_s > 0:
            raise InputError(f"checkpoint_s {self.checkpoint_s}: must be a positive number of seconds",
                             parameters=("checkpoint_s",))


def options_record(options: ProcessOptions) -> dict:
    """``options`` as plain data (a run's key, its record): a detector object by its name
    (:func:`~trafficgeo.video.detectors.names.detector_name`)."""
    from trafficgeo.video.detectors.names import detector_name

    doc = {f.name: getattr(options, f.name) for f in fields(options)}
    doc = {k: asdict(v) if is_dataclass(v) else v for k, v in doc.items()}
    doc.pop("restart", None)  # how to start, not what is run: a restarted run resumes as any other
    return {**doc, "detector": detector_name(options.detector)}


def settled_options(options: ProcessOptions, fps: float, *, junction: bool = False) -> ProcessOptions:
    """``options`` with what is left to the detector settled for a video of ``fps`` frames/s:

    * ``every`` (None): every frame for background subtraction (it learns from every frame), else the frame step
      that detects about :data:`LEARNED_DETECT_HZ` times a second (the tracker bridges the frames between);
    * ``tracker`` (None): :class:`TrackerOptions` for background subtraction; for a learned detector
      :data:`LEARNED_TRACKER`, whose lower score thresholds fit the IoU-quality scores such models give (NanoDet's
      median on the demo world is 0.52; 40 % are below 0.5) and whose longer memory bridges the wider gaps between
      detections (demo world, every 3rd frame: per-lane counts 93.6 -> 96.4 %, speed at the lines 1.52 -> 1.40
      km/h; every 5th: 90.9 -> 96.4 %; every frame: 92.7 -> 94.5 %; bench_video).
      At a ``junction`` (a site with gates) :data:`JUNCTION_TRACKER`: a track takes a detection only where its
      predicted box overlaps it by IoU 0.3, not 0.1, so an identity passes less often to the next car in a queue
      or across a turn, where slow vehicles' boxes touch (37 generated junction worlds, their detections
      tracked again: tracks holding two true vehicles 265 -> 229, turning-movement count errors 78 -> 69 of 880
      vehicles; IoU 0.2 / 0.25 / 0.35 / 0.4 / 0.5 gave 73 / 74 / 66 / 78 / 79). Not on roads: a fast vehicle in a
      tile the sparse schedule runs rarely moves further than its length between looks, and only the loose gate
      keeps its identity (tests/test_tile_schedule.py).
    """
    if options.every is not None and options.tracker is not None:
        return options  # settled already (replace() would check the detector, e.g. open an ONNX model, again)
    from trafficgeo.video.detectors.names import is_background

    background = is_background(options.detector)
    every = options.every
    if every is None:
        every = 1 if background or not fps > 0 else max(1, round(fps / LEARNED_DETECT_HZ))
    learned = JUNCTION_TRACKER if junction else LEARNED_TRACKER
    tracker = options.tracker or (TrackerOptions() if background else learned)
    return replace(options, every=every, tracker=tracker)


def _prime_seconds(detector: object) -> float:
    """How long (s of video) a fresh background model learns: ``PRIME_S``, or more if the detector's own warm-up
    (``warmup_s``, s of video) is longer."""
    warmup_s = getattr(detector, "warmup_s", 0.0)
    return max(PRIME_S, 1.5 * float(warmup_s))


def _prime_window(boundary_s: float, end_s: float, prime_s: float) -> tuple[float, float]:
    """The video (s, ``[lo, hi)``) a fresh background model learns on before the segment starting at
    ``boundary_s``."""
    return (boundary_s - prime_s, boundary_s) if boundary_s >= prime_s else (0.0, min(prime_s, end_s))


def _resume_schedule(folder: Path, state: Checkpoint, sparse: TileSchedule | None,
                     detector: object) -> TileSchedule | None:
    """The tile schedule of the interrupted run ``state`` (None: every tile), with its memory and the tiled
    detector's last detections put back as they were at its last checkpoint; :class:`ValueError` if that cannot be
    done (then the run starts again)."""
    from trafficgeo.video.checkpoint import read_schedule_state
    from trafficgeo.video.detectors.learned import tiled_detector

    entry = state.schedule
    if sparse is None or entry is None:
        if (sparse is None) != (entry is None):
            raise ValueError("its tile schedule is not this run's")
        return None
    if entry["used"] == "all":
        return None
    if "sha256" in entry:
        arrays = read_schedule_state(folder, entry)
        sparse.restore(arrays)
        tiled_detector(detector).restore_last(arrays)
    return sparse


def _save_schedule(folder: Path, state: Checkpoint, schedule: TileSchedule | None, detector: object) -> None:
    """Keep the tile schedule's memory and the tiled detector's last detections with the checkpoint."""
    from trafficgeo.video.checkpoint import write_schedule_state
    from trafficgeo.video.detectors.learned import tiled_detector

    if schedule is not None:
        state.schedule = write_schedule_state(folder, {**schedule.state(), **tiled_detector(detector).last_state()})


def _replay(folder: Path, state: Checkpoint, tracker: VehicleTracker, variable_rate: bool) -> None:
    """Feed the stored detections of ``state``'s parts to a fresh ``tracker``; :class:`ValueError` if the tracks do
    not come out as stored."""
    for entry in state.parts:
        part = read_part(folder, entry)
        a = part.arrays
        ds, ts = part.frame_slices("det"), part.frame_slices("trk")
        for j in range(part.n_frames):
            d, t = slice(ds[j], ds[j + 1]), slice(ts[j], ts[j + 1])
            time_s = float(a["frame_time"][j])
            out = tracker.update(Detections(a["det_box"][d], a["det_score"][d], a["det_class"][d].astype(object)),
                                 time_s if variable_rate else None)
            if not (np.array_equal(out.track_ids, a["trk_id"][t]) and np.array_equal(out.boxes, a["trk_box"][t])):
                raise ValueError(f"its tracks at {time_s:.2f} s differ from those its detections give now")


def _write_tables(folder: Path, state: Checkpoint, out: Path) -> tuple[DetectionFrames, ImageTracks]:
    """``detections.csv`` and ``tracks.csv`` from the parts, each checked against its schema
    (:meth:`~trafficgeo.run.folder.RunFolder.write_table`); returns the detections over time (full precision) and the
    tracks as ``tracks.csv`` holds them (:meth:`~trafficgeo.run.tracks.ImageTracks.as_written`), so that ``analyze``
    on the file repeats the run's analysis. Times are the video's to the microsecond before they are written."""
    frames, tracks = joined_parts([read_part(folder, e) for e in state.parts])
    tracks = replace(tracks, time=np.round(tracks.time, 6)).as_written()
    run = RunFolder(out)
    run.write_table("detections.csv", _detection_table(frames), float_format="%.3f")
    run.write_table("tracks.csv", tracks.to_table(), float_format="%.3f")
    return frames, tracks


def _detection_table(frames: DetectionFrames) -> pd.DataFrame:
    """The ``detections.csv`` table of ``frames`` (:data:`DETECTION_COLUMNS`), times to the microsecond."""
    table = frames.to_table()
    return table.assign(time=np.round(table["time"].to_numpy(), 6))[DETECTION_COLUMNS]


def detect_and_track(video: str | Path, camera: Camera | None, surface: Surface | None, out_dir: str | Path,
                     options: ProcessOptions | None = None, *, roi: np.ndarray | None = None,
                     restart: bool = False, lanes: Lanes | None = None, lines: list[CountLine] | None = None,
                     progress: Callable[[int, int, float], None] | None = None,
                     notice: Callable[[str], None] | None = None,
                     detector_info: Callable[[dict], None] | None = None) -> tuple[DetectionFrames, ImageTracks]:
    """Decode, detect and track (with checkpoints); returns the detections over time and the tracks (also written as
    ``detections.csv`` and ``tracks.csv`` in ``out_dir``; the tracks as written there). ``progress(frames_done,
    frames_total, video_time_s)`` is called per frame; ``notice(text)`` with one line when a checkpoint is resumed
    ("resuming from 8.0 s") or ignored (and why), with the built-in learned detector's tile plan
    (:mod:`trafficgeo.video.detectors.tiling`: the tiles over the counted road, ``lanes`` else ``roi`` else a band
    around each of the counting ``lines``, the road too far for it, and the counting lines where vehicles stay too small
    for it), and with a learned detector's backend and the run's estimated cost (:mod:`trafficgeo.video.cost`);
    ``detector_info(doc)`` once with the plan (``tiling``), the backend choice (``backend``) and the estimate
    (``estimate``) as plain data (for ``process.json``). Without a ``camera`` (and ``surface``) the detector has no size
    filter or class in metres and no tiles. Holds the lock on ``out_dir`` while it runs (:class:`InputError` if another
    process holds it)."""
    from trafficgeo.video.detectors.factory import make_detector
    from trafficgeo.video.detectors.learned import detector_plan, tiled_detector
    from trafficgeo.video.reader import video_info

    tell = notice or (lambda text: None)
    video = Path(video)
    info = video_info(video)
    opts = settled_options(options or ProcessOptions(), info.fps)
    if camera is not None and (info.width, info.height) != tuple(camera.image_size):
        raise InputError(f"{video}: frames are {info.width}x{info.height} but the camera was calibrated for "
                         f"{camera.image_size[0]}x{camera.image_size[1]}; calibrate on a frame of this video "
                         "(trafficgeo frame)")
    end_s = min(opts.end_s, info.duration_s) if opts.end_s is not None else info.duration_s
    if opts.start_s >= end_s:
        raise InputError(f"start_s {opts.start_s:g} s is past the end of {video} ({info.duration_s:.2f} s)",
                         parameters=("start_s",))
    cam = camera if surface is not None else None

    # before anything is written: a bad --detector leaves nothing behind; a detector object is the caller's, one for
    # the whole run
    detector = opts.detector if not isinstance(opts.detector, str) else make_detector(
        opts.detector, camera=cam, surface=surface, roi=roi, detector_format=opts.detector_format, road=lanes,
        tiles=opts.tiles, tiling=opts.tiling, lines=lines, backend=opts.backend)
    # a detector that learns the scene and can give an untrained copy of itself (``fresh()``: background
    # subtraction) learns anew for each segment (the module docstring); any other runs as one for the whole run
    fresh = getattr(detector, "fresh", None)
    learns = callable(fresh)
    plan = detector_plan(detector)
    if plan is not None:
        for line in plan.summary_lines():
            tell(line)
    sparse = _tile_schedule(detector, cam, plan, opts, info.fps)
    cost, schedule, used = _announce_cost(detector, plan, video, info.fps, opts, end_s, tell, sparse)
    if detector_info is not None:
        detector_info({"tiling": plan.to_dict() if plan is not None else None,
                       **({"backend": cost[0].to_dict(), "estimate": cost[1].to_dict()} if cost else {}),
                       **({"tile_schedule": used} if used else {})})
    model = Path(opts.detector) if isinstance(opts.detector, str) and not learns and Path(opts.detector).is_file() \
        else None
    tiles = plan.tiles.tolist() if plan is not None else None  # the lanes enter the detections through the tiles
    # not what tile_schedule="auto" chose: a resumed run may choose otherwise (the machine's load changed) and keeps
    # the segments already detected, which are the same video's detections either way
    # the runtime the probe chose (the built-in model's INT8 or float version, OpenVINO) is part of the run: a run
    # resumed where the probe chooses another starts again rather than mixing two models' detections
    runtime = cost[0].backend if cost else None
    key = run_key(video, camera=camera, surface=surface, roi=roi,
                  options={**options_record(opts), "prime_s": PRIME_S, "tile_boxes": tiles, "runtime": runtime},
                  detector_file=model)
    out = Path(out_dir)
    ck = out / CHECKPOINT_DIR
    fps = info.fps / opts.every
    with hold_folder(out):
        remove_stale_temporaries(ck)  # the output folder's own: hold_folder removed them
        state, tracker = None, VehicleTracker(fps, opts.tracker)
        if ck.exists() and not restart:
            try:
                state = load_checkpoint(ck, key)
                if state.complete:
                    tables = _write_tables(ck, state, out)
                    tell(f"resuming from {state.next_time_s:.1f} s: detection and tracking had finished")
                    return tables
                resumed = _resume_schedule(ck, state, sparse, detector)
                _replay(ck, state, tracker, info.variable_frame_rate)
                if resumed != schedule:
                    schedule = resumed
                    tell(f"tile schedule: {'sparse' if schedule is not None else 'every tile'}, as the interrupted "
                         "run chose")
                    if detector_info is not None and used:
                        detector_info({"tile_schedule": {**used, "used": "sparse" if schedule else "all"}})
            except ValueError as exc:
                tell(f"ignoring the checkpoint in {ck}: {exc}; starting again")
                state, tracker = None, VehicleTracker(fps, opts.tracker)
                if sparse is not None:  # as new: what the failed restore may have put back is forgotten
                    sparse = _tile_schedule(detector, cam, plan, opts, info.fps)
                    schedule = sparse if schedule is not None else None
        if state is None:
            if ck.exists():
                shutil.rmtree(ck)
            ck.mkdir(parents=True)
            state = Checkpoint(key, segment=0, next_time_s=opts.start_s,
                               schedule={"used": "sparse" if schedule is not None else "all"} if sparse else None)
            save_checkpoint(ck, state)
        elif state.parts:
            tell(f"resuming from {state.next_time_s:.1f} s")
        if sparse is not None:
            tiled_detector(detector).schedule = schedule  # after the cost's trial detection
        _run_segments(video, info, end_s, opts, ck, state, tracker, detector if not learns else None,
                      fresh, _prime_seconds(detector), progress, schedule)
        if schedule is not None and detector_info is not None:
            detector_info({"schedule": schedule.to_dict()})
        return _write_tables(ck, state, out)


def _decode_ms(video: Path, start_s: float, end_s: float, every: int, frames: int = 4) -> tuple[float, object]:
    """Wall-clock ms to decode one frame in ``every`` (and skip the others) at ``start_s``: the mean over up to
    ``frames`` - 1 frames after the first (which pays for the seek); and the first frame (None if none)."""
    import time

    from trafficgeo.video.reader import iter_frames

    stamps, first = [], None
    for frame in itertools.islice(iter_frames(video, start_s=start_s, end_s=end_s, every=every), frames):
        stamps.append(time.perf_counter())
        first = first or frame
    if len(stamps) < 2:
        return 0.0, first
    return 1e3 * (stamps[-1] - stamps[0]) / (len(stamps) - 1), first


def _detect_ms(detector: object, frame, repeats: int = 3) -> float | None:
    """Wall-clock ms of one detection on ``frame``: the median of ``repeats`` calls after one that warms the runtime
    up for the plan's input sizes (one call alone strayed by 2x on a busy machine), or None without a frame. The
    learned detectors keep no state between frames."""
    import time

    if frame is None:
        return None
    detector.detect(frame.image, frame.time_s)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        detector.detect(frame.image, frame.time_s)
        times.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(times))


def _announce_cost(detector: object, plan, video: Path, fps: float, opts: ProcessOptions, end_s: float,
                   tell: Callable[[str], None], schedule: TileSchedule | None = None):
    """Tell the detector's backend choice, when its tiles run and the run's estimated cost
    (:mod:`trafficgeo.video.cost`). Returns ((choice, cost) or None for a detector without a backend choice, the
    schedule to run or None for every tile, and what ``tile_schedule`` chose: ``{"asked", "used",
    "all_tiles_realtime_factor"}``, or {} without a schedule to choose).

    ``tile_schedule="auto"`` runs every tile on every detection frame when the estimate says that keeps real time
    (:data:`REALTIME_FOR_ALL_TILES`), else the sparse schedule: on the demo world the sparse schedule counted 0.9-6.1
    points fewer per lane than every tile (3 seeds, ``bench_video``), so it is spent only where every tile cannot
    keep up with the video."""
    from trafficgeo.video.cost import estimate_cost
    from trafficgeo.video.detectors.learned import detector_backend

    choice = detector_backend(detector)
    if choice is None:
        if schedule is not None:
            tell(schedule.summary(opts.every / fps))
        return None, schedule, ({"asked": opts.tile_schedule, "used": "sparse"} if schedule is not None else {})
    decode_ms, first = _decode_ms(video, opts.start_s, end_s, opts.every)
    common = {"every": opts.every, "video_s": end_s - opts.start_s, "fps": fps, "decode_ms": decode_ms,
              "detect_ms": _detect_ms(detector, first)}
    cost = estimate_cost(choice, plan, **common)
    used: dict[str, object] = {}
    if schedule is not None:
        used = {"asked": opts.tile_schedule, "used": "sparse",
                "all_tiles_realtime_factor": round(cost.realtime_factor, 3)}
        if opts.tile_schedule == "auto" and cost.realtime_factor >= REALTIME_FOR_ALL_TILES:
            used["used"], schedule = "all", None
            tell(f"tile schedule: every tile on every detection frame, as that keeps real time (about "
                 f"{cost.realtime_factor:.2f}x; tile_schedule='sparse' runs fewer tiles, faster but counting fewer)")
        else:
            tell(schedule.summary(opts.every / fps))
            cost = estimate_cost(choice, plan, tile_share=1.0 / schedule.periods, **common)
    tell(choice.summary())
    tell(cost.summary())
    return (choice, cost), schedule, used


def _run_segments(video: Path, info, end_s: float, opts: ProcessOptions, ck: Path, state: Checkpoint,
                  tracker: VehicleTracker, fixed_detector, new_detector, prime_s: float, progress,
                  schedule: TileSchedule | None = None) -> None:
    """Detect and track from ``state`` to ``end_s``, writing a part and the state at each segment's end; with no
    ``fixed_detector``, each segment gets a fresh background model learnt on ``prime_s`` seconds of video before
    it. A tile ``schedule`` (the fixed detector's) sees the tracker's boxes after each frame."""
    from trafficgeo.video.reader import iter_frames

    def boundary(k: int) -> float:
        return opts.start_s + k * opts.checkpoint_s

    def primed(k: int, anchor: int):
        """A fresh model learnt on segment k's window: the frames of the run's phase (index = anchor mod every)."""
        detector = new_detector()
        lo, hi = _prime_window(boundary(k), end_s, prime_s)
        pad = 1.0 / info.fps
        for f in iter_frames(video, start_s=max(0.0, lo - pad), end_s=hi + pad):
            if lo <= f.time_s < hi and (f.index - anchor) % opts.every == 0:
                detector.detect(f.image, f.time_s)
        return detector

    total = max(1, round((end_s - opts.start_s) * info.fps / opts.every))
    done = state.frames_done
    buffer = PartBuffer()
    frames = iter_frames(video, start_s=state.next_time_s, end_s=end_s, every=opts.every) \
        if state.next_time_s < end_s else iter([])
    first = next(frames, None)
    if first is not None:
        seg = state.segment
        while boundary(seg + 1) <= first.time_s:
            seg += 1
        state.segment, state.next_time_s, state.next_frame = seg, first.time_s, first.index
        loop_start = boundary(seg)  # windows from here on are decoded by this run
        detector = fixed_detector if fixed_detector is not None else primed(seg, first.index)
        pending: dict[int, object] = {}  # segment -> the model learning on its window during this run
        for frame in itertools.chain([first], frames):
            t = frame.time_s
            if t >= boundary(seg + 1):
                seg += 1
                while boundary(seg + 1) <= t:
                    seg += 1
                state.parts.append(write_part(ck, len(state.parts), buffer.to_part()))
                buffer = PartBuffer()
                state.segment, state.next_time_s, state.next_frame, state.frames_done = seg, t, frame.index, done
                _save_schedule(ck, state, schedule, fixed_detector)
                save_checkpoint(ck, state)
                if fixed_detector is None:
                    learnt = pending.pop(seg, None)
                    detector = learnt if learnt is not None else primed(seg, frame.index)
                    pending = {k: d for k, d in pending.items() if k > seg}
            if fixed_detector is None:
                k = seg + 1
                while boundary(k) - prime_s <= t and boundary(k) < end_s:
                    if t < boundary(k) and boundary(k) - prime_s >= loop_start:
                        if k not in pending:
                            pending[k] = new_detector()
                        pending[k].detect(frame.image, t)
                    k += 1
            dets = detector.detect(frame.image, t)
            tracked = tracker.update(dets, t if info.variable_frame_rate else None)
            if schedule is not None:
                schedule.observe_tracks(*tracker.live_boxes())
            buffer.add(frame.index, t, dets, tracked)
            done += 1
            if progress is not None:
                progress(done, total, t)
    state.parts.append(write_part(ck, len(state.parts), buffer.to_part()))
    state.next_time_s, state.frames_done, state.complete = end_s, done, True
    save_checkpoint(ck, state)


def _tile_schedule(detector: object, camera: Camera | None, plan, opts: ProcessOptions, fps: float
                   ) -> TileSchedule | None:
    """The tile schedule for a tiled learned detector, or None (no tiles, ``tile_schedule="all"``)."""
    from trafficgeo.video.detectors.learned import tiled_detector
    from trafficgeo.video.detectors.schedule import TileSchedule, tile_dwell_m, tile_periods

    tiled = tiled_detector(detector)
    if tiled is None or plan is None or camera is None or not len(plan.tiles) or opts.tile_schedule == "all":
        return None
    step_s = opts.every / fps if fps > 0 else 0.1
    return TileSchedule(plan, tile_periods(tile_dwell_m(plan, camera), step_s))


def finish_run(out_dir: str | Path) -> None:
    """Remove the checkpoint of a completed run."""
    ck = Path(out_dir) / CHECKPOINT_DIR
    if ck.exists():
        shutil.rmtree(ck)
