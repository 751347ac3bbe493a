"""Tracked boxes over time: :class:`ImageTracks`, the one type that goes from the tracker to the trajectories.

The tracker (:mod:`trafficgeo.video.track`) gives it, ``analyze`` (:mod:`trafficgeo.traffic.analyze`) reads it, and a
run writes it as ``tracks.csv`` (:meth:`ImageTracks.to_table`); files from other trackers are read into it by
:mod:`trafficgeo.traffic.tracks`. Pixels in the OpenCV pixel-centre convention (:mod:`trafficgeo.camera.model`),
``frame`` the frame's number in the video file, ``time`` seconds of video.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

TRACK_COLUMNS = ("frame", "time", "track_id", "x1", "y1", "x2", "y2", "score", "class")  # tracks.csv


def thousandths(values: ArrayLike) -> np.ndarray:
    """``values`` as a run's tables hold them, written to 3 decimals (``float_format="%.3f"``) and read back: the
    same text, so a run analysed in memory and its tables analysed again agree to the last bit."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return arr.copy()
    return np.char.mod("%.3f", arr).astype(np.float64)


def track_order(track_id: ArrayLike, time: ArrayLike) -> np.ndarray:
    """The (stable) order that sorts rows by track id, then time: ids in number order when they are all whole
    numbers (``2`` before ``10``, as a tracker numbers them; in text or not), else in text order."""
    ids = np.asarray(track_id).reshape(-1)
    t = np.asarray(time, dtype=np.float64).reshape(-1)
    text = ids.astype(str)
    if ids.dtype.kind in "iu":
        return np.lexsort((t, ids))
    if ids.dtype.kind == "f" and np.all(np.isfinite(ids)) and np.all(ids == np.round(ids)):
        return np.lexsort((t, ids))
    if text.size and pd.Series(text).str.fullmatch(r"[+-]?\d+").all():
        number = pd.to_numeric(pd.Series(text)).to_numpy(dtype=np.float64)
        return np.lexsort((t, text, number))  # "7" and "007" stay two tracks
    return np.lexsort((t, text))


@dataclass(frozen=True, eq=False)
class ImageTracks:
    """Track points, one row per (track, frame), sorted by track then time.

    Attributes:
        track_id: (N,) str; frame: (N,) int; time: (N,) s; u, v: (N,) ground contact point (px);
        box: (N, 4) x1, y1, x2, y2 (px; NaN when the input had only points); vclass: (N,) str ("" if unknown);
        score: (N,) detection score (NaN if unknown).
    """

    track_id: np.ndarray
    frame: np.ndarray
    time: np.ndarray
    u: np.ndarray
    v: np.ndarray
    box: np.ndarray
    vclass: np.ndarray
    score: np.ndarray

    def __len__(self) -> int:
        return int(self.frame.size)

    @property
    def track_ids(self) -> np.ndarray:
        """The distinct track ids, in order."""
        return np.unique(self.track_id)

    @classmethod
    def from_boxes(cls, *, track_id: ArrayLike, frame: ArrayLike, time: ArrayLike, boxes: ArrayLike,
                   scores: ArrayLike | None = None, classes: ArrayLike | None = None) -> ImageTracks:
        """Tracks from tracked boxes (N, 4) ``x1, y1, x2, y2`` px in any row order: the ground point is the box's
        bottom centre; rows are sorted by :func:`track_order`; ``scores`` default to NaN (unknown), ``classes``
        to ``""``."""
        ids = np.asarray(track_id).reshape(-1)
        box = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        n = box.shape[0]
        t = np.asarray(time, dtype=np.float64).reshape(-1)
        order = track_order(ids, t)
        score = np.full(n, np.nan) if scores is None else np.asarray(scores, dtype=np.float64).reshape(-1)
        vclass = np.full(n, "", dtype=object) if classes is None else \
            np.array(["" if c is None or c != c else str(c) for c in np.asarray(classes, dtype=object).reshape(-1)],
                     dtype=object)
        box = box[order]
        return cls(track_id=ids.astype(str).astype(object)[order],
                   frame=np.asarray(frame, dtype=np.int64).reshape(-1)[order], time=t[order],
                   u=0.5 * (box[:, 0] + box[:, 2]), v=box[:, 3], box=box, vclass=vclass[order], score=score[order])

    def as_written(self) -> ImageTracks:
        """These tracks with times, boxes and scores as ``tracks.csv`` holds them (:func:`thousandths`)."""
        box = thousandths(self.box)
        return ImageTracks(track_id=self.track_id, frame=self.frame, time=thousandths(self.time),
                           u=0.5 * (box[:, 0] + box[:, 2]), v=box[:, 3], box=box, vclass=self.vclass,
                           score=thousandths(self.score))

    def to_table(self) -> pd.DataFrame:
        """The ``tracks.csv`` table (:data:`TRACK_COLUMNS`), in time order (stably: by track within a frame)."""
        order = np.argsort(self.time, kind="stable")
        return pd.DataFrame({"frame": self.frame[order], "time": self.time[order],
                             "track_id": self.track_id[order],
                             **{c: self.box[order, k] for k, c in enumerate(("x1", "y1", "x2", "y2"))},
                             "score": self.score[order], "class": self.vclass[order]}, columns=list(TRACK_COLUMNS))
