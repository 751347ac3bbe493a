"""When each tile of a :class:`~trafficgeo.video.detectors.tile_plan.TilePlan` runs: a :class:`TileSchedule`.

The full frame runs on every detection frame; tile ``k`` runs when one of these holds:

* **due**: ``period[k]`` detection frames have passed since it last ran. The period comes from the road the tile
  serves (:func:`tile_periods`): a vehicle at ``design_speed_kmh`` crossing the tile's part of a lane must be
  detected there at least ``looks`` times, and no tile waits longer than ``max_gap_s`` (the tracker's prediction
  of a vehicle seen less often drifts). Far tiles, which serve long stretches of road, run least often. Tiles of
  one period run on the same frames: taking turns instead (to spread the passes evenly) cost the high camera of
  ``bench_video`` 2.8 points of per-lane counts, as a vehicle in the overlap of two tiles got its box from each
  on alternate frames.
* **forced**: a new track (seen once, not yet confirmed: the tracker needs it on two detection frames in a row) has
  its box in the tile; the tile runs on the next detection frame so that the vehicle's track starts.

A due tile whose pixels did not change since it last ran (a grey thumbnail at 1/4 scale: fewer than
``still_pixels`` of its pixels moved by more than ``still_grey`` grey levels) is **still**: it is not run, and its
last detections are given again (a parked or queued vehicle keeps its track). A forced tile runs whether or not
its pixels changed.

Frames follow :mod:`trafficgeo.video.detections` (boxes in full-frame px; a tile ``(x0, y0, x1, y1)`` is the crop
``image[y0:y1, x0:x1]``). The schedule's state (last run, thumbnails) lives in the object: one per video run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.video.detectors.tile_plan import tiles_holding

if TYPE_CHECKING:
    from trafficgeo.camera.model import Camera
    from trafficgeo.video.detectors.tile_plan import TilePlan

__all__ = ["SCHEDULES", "ScheduleOptions", "TileSchedule", "tile_dwell_m", "tile_periods"]

SCHEDULES = ("auto", "sparse", "all")  # "sparse": TileSchedule; "all": every tile on every detection frame;
# "auto": "all" where the run's cost estimate keeps real time, else "sparse" (video.pipeline)
THUMB_SCALE = 4  # the motion test's thumbnails: 1 / THUMB_SCALE of the frame's width and height


@dataclass(frozen=True)
class ScheduleOptions:
    """Settings of a :class:`TileSchedule` (see the module docstring)."""

    looks: int = 4  # detections of a vehicle per tile, at least, while it crosses the tile's road
    design_speed_kmh: float = 100.0  # the fastest vehicle the periods are planned for
    max_gap_s: float = 0.5  # the longest time a tile waits between runs
    still_grey: int = 20  # grey levels a thumbnail pixel must change by to count as moved
    still_pixels: int = 4  # a tile with fewer moved thumbnail pixels than this is still

    def __post_init__(self) -> None:
        ok = (self.looks >= 1 and np.isfinite(self.design_speed_kmh) and self.design_speed_kmh > 0
              and np.isfinite(self.max_gap_s) and self.max_gap_s > 0 and 0 <= self.still_grey <= 255
              and self.still_pixels >= 0)
        if not ok:
            raise InputError(f"tile schedule options out of range: {self}; looks >= 1, speeds and times > 0")


def tile_dwell_m(plan: TilePlan, camera: Camera) -> np.ndarray:
    """(K,) metres of lane each tile serves (inf: none): over the plan's road samples that need a tile (the
    reference car is below the minimum size in the full frame) and that the tile holds whole at a zoom bringing the
    car to the minimum size, the extent along the direction of travel per lane (or ROI / line band), the median
    over the lanes it serves."""
    from trafficgeo.video.detectors.tiling import vehicle_boxes

    k = len(plan.tiles)
    out = np.full(k, np.inf)
    s = plan.samples
    if s is None or k == 0:
        return out
    seen = np.isfinite(plan.size_px)
    need = seen & (plan.size_px * plan.full_scale < plan.min_size_px)
    if not need.any():
        return out
    idx = np.flatnonzero(need)
    boxes = vehicle_boxes(camera, s.xyz[idx], s.heading_deg[idx], plan.vehicle_m)
    held = tiles_holding(plan.tiles, boxes, plan.frame_shape, plan.cut_margin_px)  # (K, N)
    held &= (plan.size_px[idx][None, :] * plan.tile_scales[:, None]) >= plan.min_size_px
    xy = s.xyz[idx, :2] * plan.unit_m
    for t in range(k):
        extents = []
        for name in dict.fromkeys(s.region[idx][held[t]].tolist()):
            mine = held[t] & (s.region[idx] == name)
            if mine.sum() < 2:
                continue
            extents.append(_extent_along_m(xy[mine], s.heading_deg[idx][mine]))
        if extents:
            out[t] = float(np.median(extents))
    return out


def _extent_along_m(xy: np.ndarray, heading_deg: np.ndarray) -> float:
    """Extent (m) of points (N, 2) (m) along their mean direction (deg from north, modulo 180); the principal axis
    when no direction is known."""
    h = heading_deg[np.isfinite(heading_deg)]
    if h.size:
        a = np.radians(2.0 * h)  # axial mean: angles modulo 180
        mean = 0.5 * np.arctan2(np.sin(a).mean(), np.cos(a).mean())
        axis = np.array([np.sin(mean), np.cos(mean)])
    else:
        centred = xy - xy.mean(axis=0)
        axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    along = xy @ axis
    return float(along.max() - along.min())


def tile_periods(dwell_m: np.ndarray, frame_step_s: float, options: ScheduleOptions = ScheduleOptions()
                 ) -> np.ndarray:
    """(K,) int >= 1: detection frames between two runs of each tile, for tiles serving ``dwell_m`` metres of lane
    and ``frame_step_s`` seconds between detection frames (see the module docstring)."""
    if not (np.isfinite(frame_step_s) and frame_step_s > 0):
        raise InputError(f"tile schedule: the time between detection frames {frame_step_s!r} s must be positive")
    longest = max(1, int(np.floor(options.max_gap_s / frame_step_s + 1e-9)))
    step_m = options.design_speed_kmh / 3.6 * frame_step_s * options.looks
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.floor(np.asarray(dwell_m, dtype=np.float64) / step_m + 1e-9)
    return np.clip(np.nan_to_num(p, nan=1.0, posinf=float(longest)), 1, longest).astype(np.int64)


class TileSchedule:
    """Which tiles of ``plan`` run on each detection frame (see the module docstring). ``periods`` (K,) int >= 1.

    Call :meth:`choose` once per detection frame (before the detector runs), then :meth:`ran` with what each tile
    found, and :meth:`observe_tracks` with the tracker's boxes after the tracker's update."""

    def __init__(self, plan: TilePlan, periods: np.ndarray, options: ScheduleOptions = ScheduleOptions()) -> None:
        self.plan, self.options = plan, options
        self.periods = np.asarray(periods, dtype=np.int64).reshape(-1)
        if self.periods.shape[0] != len(plan.tiles) or (self.periods < 1).any():
            raise InputError(f"tile schedule: {self.periods.shape[0]} periods for {len(plan.tiles)} tiles; give one "
                             "whole number >= 1 per tile")
        k = len(plan.tiles)
        self.frame = -1
        self.last_run = -self.periods.copy()  # all due on the first frame
        self.forced = np.zeros(k, dtype=bool)
        self._thumbs: list[np.ndarray | None] = [None] * k
        t = plan.tiles // THUMB_SCALE
        self._thumb_tiles = np.column_stack([t[:, 0], t[:, 1], np.maximum(t[:, 2], t[:, 0] + 1),
                                             np.maximum(t[:, 3], t[:, 1] + 1)])
        self.runs = np.zeros(k, dtype=np.int64)  # counters, for the run's report
        self.reused = np.zeros(k, dtype=np.int64)
        self.forced_runs = np.zeros(k, dtype=np.int64)

    def choose(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(run, reuse): (K,) bool each, for this detection frame's ``image`` ((H, W, 3) uint8 BGR): the tiles to run
        and the still tiles whose last detections stand."""
        self.frame += 1
        due = self.frame - self.last_run >= self.periods
        run = due | self.forced
        reuse = np.zeros_like(run)
        thumb = self._thumbnail(image) if run.any() else None
        if thumb is not None:
            for k in np.flatnonzero(due & ~self.forced):
                if self._still(k, thumb):
                    run[k], reuse[k] = False, True
        for k in np.flatnonzero(run):
            self._thumbs[k] = self._crop(thumb, k).copy()
        self.runs += run
        self.reused += reuse
        self.forced_runs += run & self.forced & ~due
        self.last_run[run | reuse] = self.frame
        self.forced[:] = False
        return run, reuse

    def observe_tracks(self, boxes: np.ndarray, young: np.ndarray) -> None:
        """The tracker's boxes (N, 4) (full-frame px) after this frame's update, ``young`` (N,) bool for tracks not
        yet confirmed: each young track forces its home tile (the one holding it whole at the largest zoom, else
        those holding its centre) on the next detection frame."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)[np.asarray(young, dtype=bool)]
        if not len(b) or not len(self.plan.tiles):
            return
        tiles = self.plan.tiles
        whole = tiles_holding(tiles, b, self.plan.frame_shape, self.plan.cut_margin_px)  # (K, N)
        scale = np.where(whole, self.plan.tile_scales[:, None], -np.inf)
        has = whole.any(axis=0)
        self.forced[np.argmax(scale[:, has], axis=0)] = True
        if (~has).any():
            cx = 0.5 * (b[~has, 0] + b[~has, 2])
            cy = 0.5 * (b[~has, 1] + b[~has, 3])
            inside = ((tiles[:, 0, None] <= cx) & (cx < tiles[:, 2, None])
                      & (tiles[:, 1, None] <= cy) & (cy < tiles[:, 3, None]))
            self.forced |= inside.any(axis=1)

    def state(self) -> dict[str, np.ndarray]:
        """What the schedule remembers (frame counter, last runs, forced tiles, counters and each tile's last
        thumbnail) as arrays of numbers, for a checkpoint; :meth:`restore` puts it back."""
        k = len(self.periods)
        shapes = np.array([t.shape if t is not None else (-1, -1) for t in self._thumbs], dtype=np.int64)
        pixels = [t.ravel() for t in self._thumbs if t is not None]
        return {"frame": np.array([self.frame], dtype=np.int64), "last_run": self.last_run.copy(),
                "forced": self.forced.copy(), "runs": self.runs.copy(), "reused": self.reused.copy(),
                "forced_runs": self.forced_runs.copy(), "thumb_shape": shapes.reshape(k, 2),
                "thumb_pixels": np.concatenate(pixels).astype(np.uint8) if pixels else np.zeros(0, np.uint8)}

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        """Put back a :meth:`state` (of a schedule of the same tiles); :class:`ValueError` if it is not one."""
        k = len(self.periods)
        try:
            shapes = np.asarray(arrays["thumb_shape"], dtype=np.int64).reshape(k, 2)
            sizes = np.where(shapes[:, 0] >= 0, shapes[:, 0] * shapes[:, 1], 0)
            pixels = np.asarray(arrays["thumb_pixels"])
            counters = {n: np.asarray(arrays[n]) for n in ("last_run", "runs", "reused", "forced_runs")}
            forced = np.asarray(arrays["forced"])
            frame = int(np.asarray(arrays["frame"]).reshape(-1)[0])
        except (KeyError, ValueError, IndexError, TypeError) as exc:
            raise ValueError(f"the tile schedule's state is damaged ({exc})") from None
        if (pixels.dtype != np.uint8 or pixels.size != sizes.sum() or forced.shape != (k,) or forced.dtype != bool
                or any(c.shape != (k,) or c.dtype.kind != "i" for c in counters.values())):
            raise ValueError("the tile schedule's state is not one of these tiles")
        bounds = np.concatenate([[0], np.cumsum(sizes)])
        self._thumbs = [pixels[bounds[j]:bounds[j + 1]].reshape(shapes[j]).copy() if shapes[j, 0] >= 0 else None
                        for j in range(k)]
        self.frame, self.forced = frame, forced.copy()
        self.last_run, self.runs = counters["last_run"].astype(np.int64), counters["runs"].astype(np.int64)
        self.reused, self.forced_runs = counters["reused"].astype(np.int64), counters["forced_runs"].astype(np.int64)

    def summary(self, frame_step_s: float) -> str:
        """The schedule in one line for the terminal (``frame_step_s``: seconds between detection frames)."""
        p = self.periods
        per = 1.0 + float(np.sum(1.0 / p))
        lo, hi = int(p.min()), int(p.max())
        every = (f"{lo} detection frame{'s' if lo > 1 else ''} ({frame_step_s * lo:.2f} s" if lo == hi else
                 f"{lo}-{hi} detection frames ({frame_step_s * lo:.2f}-{frame_step_s * hi:.2f} s")
        return (f"tile schedule: each tile runs every {every}; each vehicle seen >= "
                f"{self.options.looks} times per tile at "
                f"{self.options.design_speed_kmh:g} km/h), and on the next frame after a new vehicle appears in it; "
                f"tiles whose pixels did not change are skipped: about {per:.1f} passes per detection frame instead "
                f"of {len(p) + 1} (tile_schedule='all' runs every tile every frame)")

    def to_dict(self) -> dict[str, object]:
        """The schedule and what it did, for ``process.json``: periods, runs, reuses and forced runs per tile, and
        the mean tile passes per detection frame."""
        n = max(1, self.frame + 1)
        return {"periods": self.periods.tolist(), "looks": self.options.looks,
                "design_speed_kmh": self.options.design_speed_kmh, "max_gap_s": self.options.max_gap_s,
                "detection_frames": self.frame + 1, "tile_runs": self.runs.tolist(),
                "still_reused": self.reused.tolist(), "forced_runs": self.forced_runs.tolist(),
                "tile_passes_per_frame": round(float(self.runs.sum()) / n, 3),
                "planned_passes_per_frame": round(float(np.sum(1.0 / self.periods)), 3)}

    def _thumbnail(self, image: np.ndarray) -> np.ndarray:
        h, w = image.shape[:2]
        small = cv2.resize(image, (max(1, w // THUMB_SCALE), max(1, h // THUMB_SCALE)), interpolation=cv2.INTER_AREA)
        return cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)

    def _crop(self, thumb: np.ndarray, k: int) -> np.ndarray:
        x0, y0, x1, y1 = self._thumb_tiles[k]
        return thumb[y0:y1, x0:x1]

    def _still(self, k: int, thumb: np.ndarray) -> bool:
        before = self._thumbs[k]
        if before is None:
            return False
        now = self._crop(thumb, k)
        moved = int(np.count_nonzero(cv2.absdiff(now, before) > self.options.still_grey))
        return moved < self.options.still_pixels
