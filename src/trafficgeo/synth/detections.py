"""Simulated tracker output from the demo world's truth boxes: what a real detector + tracker would hand to
``analyze``, with its typical faults and with the truth kept alongside.

From ``truth_tracks.csv`` (:mod:`trafficgeo.synth.world`), :func:`noisy_tracks`:

* drops vehicles hidden by nearer ones (``visible_fraction`` below ``min_visible``) and boxes entirely outside
  the frame;
* misses each remaining detection with probability ``miss_rate``;
* jitters every box edge by ``jitter_px + jitter_rel * box size`` (1-sigma, pixels; detectors are worse on big
  boxes in absolute terms), except edges on the frame's border, where the vehicle is cut off;
* fragments tracks: with probability ``fragment_rate`` a vehicle's track continues under a new id from a random
  frame on (a lost and re-found track);
* swaps identities: where two vehicles' boxes overlap (IoU > ``swap_iou``), with probability ``swap_rate`` the
  tracker swaps their ids from that frame on (the classic ID switch).

The result has the columns ``analyze`` reads (``frame, track_id, class, x1, y1, x2, y2``) plus ``vehicle`` (the
true vehicle of each row) so that every output can be scored against the truth.

:func:`ideal_detections` is the other end: a detector that finds every vehicle it can see, exactly, and nothing
else, frame by frame for a real tracker. What the tracker and ``analyze`` then lose is lost to occlusion and
tracking, not to detection.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.video.detections import Detections, box_iou


@dataclass(frozen=True)
class DetectionNoise:
    """Faults of the simulated detector and tracker (see the module docstring)."""

    jitter_px: float = 1.5
    jitter_rel: float = 0.02
    miss_rate: float = 0.1
    min_visible: float = 0.5
    fragment_rate: float = 0.1
    swap_rate: float = 0.5
    swap_iou: float = 0.3

    def __post_init__(self) -> None:
        for name in ("jitter_px", "jitter_rel", "miss_rate", "min_visible", "fragment_rate", "swap_rate", "swap_iou"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0) or (name != "jitter_px" and value > 1):
                raise InputError(f"DetectionNoise.{name} = {value!r} is out of range (>= 0; rates and fractions <= 1)")


def _swap_ids(df: pd.DataFrame, noise: DetectionNoise, rng: np.random.Generator) -> pd.DataFrame:
    """Swap the ids of overlapping vehicles from the first frame they overlap (each pair at most once)."""
    ids = df["track_id"].to_numpy().copy()
    done: set[tuple[str, str]] = set()
    for _frame, g in df.groupby("frame", sort=True):
        if len(g) < 2:
            continue
        box = g[["x1", "y1", "x2", "y2"]].to_numpy()
        iou = np.triu(box_iou(box[:, None], box[None, :]), k=1)
        for i, j in zip(*np.nonzero(iou > noise.swap_iou), strict=True):
            a, b = g["vehicle"].iloc[i], g["vehicle"].iloc[j]
            key = (min(a, b), max(a, b))
            if key in done:
                continue
            done.add(key)
            if rng.random() < noise.swap_rate:
                later = df["frame"].to_numpy() >= _frame
                ta, tb = ids[g.index[i]], ids[g.index[j]]
                sel_a, sel_b = later & (ids == ta), later & (ids == tb)
                ids[sel_a], ids[sel_b] = tb, ta
    out = df.copy()
    out["track_id"] = ids
    return out


def noisy_tracks(truth: pd.DataFrame, image_size: tuple[int, int], noise: DetectionNoise | None = None,
                 seed: int = 0) -> pd.DataFrame:
    """Simulated tracker output (module docstring) from a ``truth_tracks.csv`` table with boxes."""
    noise = noise or DetectionNoise()
    need = {"frame", "vehicle", "class", "x1", "y1", "x2", "y2", "visible_fraction"}
    if not need <= set(truth.columns):
        raise InputError(f"truth tracks need columns {', '.join(sorted(need))}; build the world with its video")
    rng = np.random.default_rng(seed)
    w, h = image_size
    df = truth[list(need | {"time"} & set(truth.columns))].copy()
    box = df[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    seen = np.all(np.isfinite(box), axis=1) & (df["visible_fraction"].to_numpy() >= noise.min_visible)
    seen &= rng.random(len(df)) >= noise.miss_rate
    df = df[seen].reset_index(drop=True)
    box = df[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    size = np.column_stack([box[:, 2] - box[:, 0], box[:, 3] - box[:, 1]])
    sigma = noise.jitter_px + noise.jitter_rel * np.column_stack([size, size])
    # edges the frame cuts stay on the frame's border (detectors clip there); the others jitter
    border = (box <= 1.0) | (box >= np.array([w, h, w, h]) - 2.0)
    box = np.where(border, box, box + rng.normal(0.0, 1.0, box.shape) * sigma)
    box[:, [0, 2]] = np.sort(np.clip(box[:, [0, 2]], 0, w - 1), axis=1)
    box[:, [1, 3]] = np.sort(np.clip(box[:, [1, 3]], 0, h - 1), axis=1)
    df[["x1", "y1", "x2", "y2"]] = box
    df = df[(box[:, 2] - box[:, 0] >= 2) & (box[:, 3] - box[:, 1] >= 2)].reset_index(drop=True)
    df["track_id"] = df["vehicle"].astype(str)
    # fragmentation: the rest of a vehicle's track under a new id
    for k, vid in enumerate(pd.unique(df["vehicle"])):
        if rng.random() < noise.fragment_rate:
            rows = np.flatnonzero(df["vehicle"].to_numpy() == vid)
            if rows.size >= 4:
                cut = rows[rng.integers(1, rows.size - 1)]
                frames = df["frame"].to_numpy()
                df.loc[rows[frames[rows] >= frames[cut]], "track_id"] = f"{vid}-f{k}"
    df = _swap_ids(df.sort_values(["frame", "vehicle"]).reset_index(drop=True), noise, rng)
    return df[["frame", "track_id", "class", "x1", "y1", "x2", "y2", "vehicle"]].sort_values(
        ["track_id", "frame"], kind="stable").reset_index(drop=True)


def ideal_detections(truth: pd.DataFrame, image_size: tuple[int, int], *, min_visible: float = 0.5,
                     min_size_px: float = 4.0) -> Iterator[tuple[int, float, Detections]]:
    """``(frame, time_s, detections)`` for each frame of a ``truth_tracks.csv`` table, in time order: the true
    boxes (pixels, clipped to the ``(width, height)`` image) of the vehicles at least ``min_visible`` visible and at
    least ``min_size_px`` wide and tall once clipped, with score 1 and their true class (see the module docstring).
    A frame where no vehicle is seen yields empty detections."""
    need = {"frame", "time", "class", "x1", "y1", "x2", "y2", "visible_fraction"}
    if not need <= set(truth.columns):
        raise InputError(f"truth tracks need columns {', '.join(sorted(need))}; build the world with its video")
    if not 0.0 <= min_visible <= 1.0:
        raise InputError(f"min_visible = {min_visible!r} must be a fraction in [0, 1]")
    w, h = image_size
    box = truth[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64, copy=True)
    box[:, [0, 2]] = np.clip(box[:, [0, 2]], 0.0, w - 1.0)
    box[:, [1, 3]] = np.clip(box[:, [1, 3]], 0.0, h - 1.0)
    keep = (np.all(np.isfinite(box), axis=1) & (truth["visible_fraction"].to_numpy() >= min_visible)
            & (box[:, 2] - box[:, 0] >= min_size_px) & (box[:, 3] - box[:, 1] >= min_size_px))
    frames, times = truth["frame"].to_numpy(), truth["time"].to_numpy(dtype=np.float64)
    classes = truth["class"].astype(str).to_numpy(dtype=object)
    order = np.argsort(frames, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(frames[order]) != 0])
    for group in np.split(order, starts[1:]):
        rows = group[keep[group]]
        yield int(frames[group[0]]), float(times[group[0]]), Detections(box[rows], np.ones(rows.size), classes[rows])
