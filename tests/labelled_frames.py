"""Hand-labelled real frames as detector truth: a loader for the ``tests/data/*-labels/`` folders and a scorer
(precision, recall and F1 at an IoU threshold, one-to-one matching).

A folder holds the frames (JPEG or PNG) and ``boxes.csv`` with columns ``image, x1, y1, x2, y2, class, truncated,
occluded``. Boxes are full-frame pixels in the pixel-centre convention (pixel (0, 0) is the centre of the top-left
pixel, so a box around pixel columns i..j has x1 = i - 0.5, x2 = j + 0.5); ``truncated`` = 1 where the frame edge
cuts the vehicle, ``occluded`` = 1 where something in front of it hides part of it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from trafficgeo.video.detections import box_iou

DATA = Path(__file__).parent / "data"
NGSIM_LABELS = DATA / "ngsim-us101-labels"
INTEL_LABELS = DATA / "intel-car-detection-labels"
COLUMNS = ["image", "x1", "y1", "x2", "y2", "class", "truncated", "occluded"]


class LabelledFrame(NamedTuple):
    """One frame: ``image`` (H, W, 3) uint8 BGR, ``boxes`` (N, 4) float px, ``classes`` (N,) str, ``flags`` (N, 2)
    bool = (truncated, occluded)."""

    image: np.ndarray
    boxes: np.ndarray
    classes: np.ndarray
    flags: np.ndarray


def read_boxes(folder: Path | str) -> pd.DataFrame:
    """``boxes.csv`` of a label folder as a table with the columns of :data:`COLUMNS`."""
    table = pd.read_csv(Path(folder) / "boxes.csv", dtype={"image": str, "class": str})
    missing = [c for c in COLUMNS if c not in table.columns]
    if missing:
        raise ValueError(f"{folder}/boxes.csv: missing columns {missing}")
    return table[COLUMNS]


def load_labels(folder: Path | str) -> dict[str, LabelledFrame]:
    """Every labelled frame of ``folder``: image file name -> :class:`LabelledFrame`."""
    folder = Path(folder)
    table = read_boxes(folder)
    out: dict[str, LabelledFrame] = {}
    for name, rows in table.groupby("image", sort=True):
        image = cv2.imread(str(folder / name), cv2.IMREAD_COLOR)
        if image is None:
            raise FileNotFoundError(f"{folder / name}: listed in boxes.csv but not readable")
        out[str(name)] = LabelledFrame(
            image=image,
            boxes=rows[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64),
            classes=rows["class"].to_numpy(dtype=str),
            flags=rows[["truncated", "occluded"]].to_numpy(dtype=np.int64).astype(bool),
        )
    return out


def match_pairs(iou: np.ndarray, iou_min: float = 0.5, method: str = "greedy") -> list[tuple[int, int]]:
    """One-to-one matches (row, column) of an IoU matrix (detections x truth) with IoU >= ``iou_min``.
    ``greedy``: best IoU first; ``hungarian``: the most matches, then the largest IoU sum among those."""
    iou = np.asarray(iou, dtype=np.float64)
    if iou.size == 0:
        return []
    ok = iou >= iou_min
    if method == "greedy":
        rows, cols = np.nonzero(ok)
        order = np.argsort(-iou[rows, cols], kind="stable")
        used_r, used_c, pairs = set(), set(), []
        for k in order:
            r, c = int(rows[k]), int(cols[k])
            if r not in used_r and c not in used_c:
                used_r.add(r)
                used_c.add(c)
                pairs.append((r, c))
        return pairs
    if method == "hungarian":
        # Each valid pair is worth 1 (more matches first) plus its IoU / (n+1) (then the best overlap).
        cost = np.where(ok, -(1.0 + iou / (min(iou.shape) + 1.0)), 0.0)
        rows, cols = linear_sum_assignment(cost)
        return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if ok[r, c]]
    raise ValueError(f"unknown matching method {method!r}; use 'greedy' or 'hungarian'")


@dataclass(frozen=True)
class Score:
    """Counts of a detection score: ``tp`` found vehicles, ``fp`` false detections, ``fn`` missed vehicles;
    ``ignored`` truth boxes that need not be found and detections dropped because they matched only those."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    ignored_truth: int = 0
    ignored_detections: int = 0

    @property
    def precision(self) -> float:
        return self.tp / max(self.tp + self.fp, 1)

    @property
    def recall(self) -> float:
        return self.tp / max(self.tp + self.fn, 1)

    @property
    def f1(self) -> float:
        p, r = self.precision, self.recall
        return 2 * p * r / (p + r) if p + r > 0 else 0.0

    def __add__(self, other: Score) -> Score:
        return Score(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn,
                     self.ignored_truth + other.ignored_truth, self.ignored_detections + other.ignored_detections)


def ignored_truth(boxes: np.ndarray, flags: np.ndarray | None = None, *, min_side_px: float = 0.0,
                  ignore_truncated: bool = False, ignore_occluded: bool = False) -> np.ndarray:
    """(N,) bool: truth boxes a detector need not find: shorter side < ``min_side_px`` px, or flagged truncated /
    occluded when asked."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    out = np.minimum(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]) < min_side_px
    if flags is not None and len(boxes):
        flags = np.asarray(flags, dtype=bool).reshape(-1, 2)
        out |= (flags[:, 0] & ignore_truncated) | (flags[:, 1] & ignore_occluded)
    return out


def score_frame(detections: np.ndarray, truth: np.ndarray, ignore: np.ndarray | None = None, *,
                iou_min: float = 0.5, method: str = "greedy") -> Score:
    """Score detection boxes (M, 4) against truth boxes (N, 4) of one frame. Detections are matched one-to-one
    to the required truth first; a detection left over that reaches ``iou_min`` with an ignored truth box is
    dropped (neither right nor wrong), every other one is a false positive."""
    det = np.asarray(detections, dtype=np.float64).reshape(-1, 4)
    tru = np.asarray(truth, dtype=np.float64).reshape(-1, 4)
    ign = np.zeros(len(tru), dtype=bool) if ignore is None else np.asarray(ignore, dtype=bool).reshape(-1)
    if ign.shape != (len(tru),):
        raise ValueError(f"ignore has {ign.size} entries for {len(tru)} truth boxes")
    need = tru[~ign]
    iou = box_iou(det[:, None], need[None]) if len(det) and len(need) else np.zeros((len(det), len(need)))
    pairs = match_pairs(iou, iou_min, method)
    matched = np.zeros(len(det), dtype=bool)
    matched[[r for r, _ in pairs]] = True
    dropped = 0
    if ign.any() and (~matched).any():
        rest = box_iou(det[~matched][:, None], tru[ign][None])
        dropped = int(np.sum(rest.max(axis=1) >= iou_min))
    return Score(tp=len(pairs), fp=int(np.sum(~matched)) - dropped, fn=len(need) - len(pairs),
                 ignored_truth=int(ign.sum()), ignored_detections=dropped)


def score_labels(labels: Mapping[str, LabelledFrame], detect: Callable[[np.ndarray], np.ndarray], *,
                 iou_min: float = 0.5, method: str = "greedy", min_side_px: float = 0.0,
                 ignore_truncated: bool = False, ignore_occluded: bool = False) -> tuple[Score, dict[str, Score]]:
    """Run ``detect(image) -> boxes (M, 4)`` on every labelled frame; the summed score and the score per frame."""
    per: dict[str, Score] = {}
    for name, frame in labels.items():
        ign = ignored_truth(frame.boxes, frame.flags, min_side_px=min_side_px, ignore_truncated=ignore_truncated,
                            ignore_occluded=ignore_occluded)
        per[name] = score_frame(detect(frame.image), frame.boxes, ign, iou_min=iou_min, method=method)
    return sum(per.values(), Score()), per
