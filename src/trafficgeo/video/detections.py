"""What every detector returns: :class:`Detections` (boxes in full-frame pixels, scores, class names), the
:class:`Detector` protocol ``detect(image, time_s) -> Detections`` and the checks of images and ROI masks.

Images are (H, W, 3) uint8 **BGR** frames (OpenCV order). Boxes are ``x1, y1, x2, y2`` in full-frame pixels in the
OpenCV pixel-centre convention (pixel (0, 0) is the *centre* of the top-left pixel, so a blob covering pixel columns
``i..j`` spans ``x1 = i - 0.5`` to ``x2 = j + 0.5``); scores are in [0, 1]; classes are the names used downstream
(``car, van, truck, bus, motorcycle, bicycle``; ``""`` = unknown).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from trafficgeo.errors import InputError

# COCO class ids (0-based, as YOLO exports number them) of the road vehicles, and their trafficgeo names.
COCO_VEHICLES: dict[int, str] = {1: "bicycle", 2: "car", 3: "motorcycle", 5: "bus", 7: "truck"}


# ---------------------------------------------------------------------------------------------------- Detections
@dataclass(frozen=True, eq=False)
class Detections:
    """Detections in one frame; the tracker (:class:`~trafficgeo.video.track.VehicleTracker`) gives back the ones
    that belong to its tracks with their ``track_ids`` filled in.

    Attributes:
        boxes: (N, 4) float64 ``x1, y1, x2, y2`` in full-frame pixels (pixel-centre convention).
        scores: (N,) float64 confidence in [0, 1].
        classes: (N,) object array of class names (``""`` = unknown).
        track_ids: (N,) int64 track ids >= 0, or None before tracking.
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    track_ids: np.ndarray | None = None

    def __post_init__(self) -> None:
        boxes = np.asarray(self.boxes, dtype=np.float64).reshape(-1, 4)
        scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        classes = np.asarray(self.classes, dtype=object).reshape(-1)
        ids = None if self.track_ids is None else np.asarray(self.track_ids, dtype=np.int64).reshape(-1)
        if not (boxes.shape[0] == scores.shape[0] == classes.shape[0] == (boxes.shape[0] if ids is None
                                                                           else ids.shape[0])):
            raise ValueError(f"Detections: {boxes.shape[0]} boxes, {scores.shape[0]} scores, "
                             f"{classes.shape[0]} classes{'' if ids is None else f' and {ids.shape[0]} track ids'}; "
                             "give one of each per detection")
        object.__setattr__(self, "boxes", boxes)
        object.__setattr__(self, "scores", scores)
        object.__setattr__(self, "classes", classes)
        object.__setattr__(self, "track_ids", ids)

    def __len__(self) -> int:
        return int(self.scores.shape[0])

    @classmethod
    def empty(cls) -> Detections:
        """No detections."""
        return cls(np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype=object))

    @classmethod
    def concatenate(cls, parts: Iterable[Detections]) -> Detections:
        """All detections of ``parts``, in order."""
        parts = list(parts)
        if not parts:
            return cls.empty()
        tracked = [p.track_ids is not None for p in parts]
        if any(tracked) and not all(tracked):
            raise ValueError("Detections.concatenate: some parts have track ids and some do not")
        return cls(np.concatenate([p.boxes for p in parts]), np.concatenate([p.scores for p in parts]),
                   np.concatenate([p.classes for p in parts]),
                   np.concatenate([p.track_ids for p in parts]) if all(tracked) else None)

    def select(self, which: ArrayLike) -> Detections:
        """The detections picked by a boolean mask (N,) or an index array."""
        idx = np.asarray(which)
        return Detections(self.boxes[idx], self.scores[idx], self.classes[idx],
                          None if self.track_ids is None else self.track_ids[idx])

    @property
    def bottom_centres(self) -> np.ndarray:
        """(N, 2) bottom-centre pixels ``((x1 + x2) / 2, y2)``: where a vehicle's nearest edge meets the road."""
        return np.column_stack([0.5 * (self.boxes[:, 0] + self.boxes[:, 2]), self.boxes[:, 3]])


def box_iou(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """IoU of boxes ``x1, y1, x2, y2`` (px) in arrays (..., 4) that broadcast against each other: matching rows
    with ``box_iou(a, b)``, every pair with ``box_iou(a[:, None], b[None, :])`` -> (N, M)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    w = np.clip(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0, None)
    h = np.clip(np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1]), 0, None)
    inter = w * h
    area_a = (a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1])
    area_b = (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])
    return inter / np.maximum(area_a + area_b - inter, 1e-9)


@runtime_checkable
class Detector(Protocol):
    """Anything that finds vehicles in a frame."""

    def detect(self, image: np.ndarray, time_s: float) -> Detections:
        """Detections in ``image`` ((H, W, 3) uint8 BGR) taken at ``time_s`` seconds."""
        ...


def check_image(image: object, where: str = "frame") -> np.ndarray:
    """``image`` as an (H, W, 3) uint8 BGR array, or an InputError."""
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        desc = f"{image.dtype} array of shape {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise InputError(f"{where}: expected an (H, W, 3) uint8 BGR image, got a {desc}; decode frames as bgr24")
    if image.shape[0] < 2 or image.shape[1] < 2:
        raise InputError(f"{where}: image of {image.shape[1]}x{image.shape[0]} px is too small to detect anything")
    return image


def check_roi(roi: object, shape: tuple[int, int], where: str = "roi") -> np.ndarray:
    """``roi`` as a bool (H, W) mask for frames of ``shape`` (H, W), or an InputError."""
    mask = np.asarray(roi)
    if mask.shape != tuple(shape):
        raise InputError(f"{where}: mask of shape {mask.shape} does not match the frame ({shape[0]}, {shape[1]}); "
                         "give a bool (H, W) mask at the video's full resolution")
    return mask.astype(bool)




def in_roi(roi: np.ndarray, points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Whether pixels (N, 2) fall inside the bool ROI mask (H, W) of frames of ``shape``."""
    mask = check_roi(roi, shape)
    uv = np.rint(np.asarray(points, dtype=np.float64)).astype(np.int64)
    u = np.clip(uv[:, 0], 0, shape[1] - 1)
    v = np.clip(uv[:, 1], 0, shape[0] - 1)
    return mask[v, u]



@dataclass(frozen=True, eq=False)
class DetectionFrames:
    """Detections over time: every frame a run detected on, in order, and its detections (image px, pixel (0, 0) at
    the centre of the top-left pixel). ``frame_index`` (N,) frame numbers in the video file, ``time_s`` (N,) s of
    video (or of any clock, increasing); per detection ``row`` (M,) the position of its frame in ``frame_index``
    (non-decreasing), ``boxes`` (M, 4) x1, y1, x2, y2, ``scores`` (M,) and ``classes`` (M,) names."""

    frame_index: np.ndarray
    time_s: np.ndarray
    row: np.ndarray
    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray

    def __len__(self) -> int:
        return int(self.frame_index.size)

    def on_frame(self, j: int, bounds: np.ndarray | None = None) -> Detections:
        """The detections of frame position ``j`` (``bounds``: :meth:`frame_bounds`, computed once by a loop)."""
        b = self.frame_bounds() if bounds is None else bounds
        d = slice(int(b[j]), int(b[j + 1]))
        return Detections(self.boxes[d], self.scores[d], self.classes[d])

    def to_table(self) -> pd.DataFrame:
        """One row per detection: ``frame`` (the frame number), ``time`` (s), ``x1, y1, x2, y2`` (px), ``score``,
        ``class`` (the columns of ``detections.csv``)."""
        return pd.DataFrame({"frame": self.frame_index[self.row], "time": self.time_s[self.row],
                             **{c: self.boxes[:, k] for k, c in enumerate(("x1", "y1", "x2", "y2"))},
                             "score": self.scores, "class": self.classes})

    def frame_bounds(self) -> np.ndarray:
        """(N + 1,) bounds: frame j's detections are rows ``bounds[j]:bounds[j + 1]``."""
        return np.searchsorted(self.row, np.arange(len(self) + 1), side="left")
