"""Blob geometry for the background detector: the merging of a vehicle's parts and the splitting of touching
vehicles (in image pixels; sizes on the ground are :mod:`trafficgeo.video.detectors.sizes`). Pixels follow
:mod:`trafficgeo.video.detections`."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


# ---------------------------------------------------------------------------------------------------- blobs
def union_boxes(boxes: np.ndarray, groups: list[list[int]]) -> np.ndarray:
    return np.array([[boxes[g, 0].min(), boxes[g, 1].min(), boxes[g, 2].max(), boxes[g, 3].max()] for g in groups],
                    dtype=np.float64).reshape(-1, 4)


def merge_candidates(boxes: np.ndarray, *, min_overlap: float = 0.5, max_gap: float = 0.25) -> np.ndarray:
    """Pairs (P, 2) ``i < j`` of boxes (N, 4) that may be parts of one object: their column ranges overlap by at
    least ``min_overlap`` of the narrower box's width and the rows between them (the vertical gap; 0 when they
    overlap) are at most ``max_gap`` times the smaller box's height. Boxes are inclusive integer pixel ranges
    ``x1, y1, x2, y2`` (the last column/row included)."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    if b.shape[0] < 2:
        return np.zeros((0, 2), dtype=np.int64)
    w = b[:, 2] - b[:, 0] + 1
    h = b[:, 3] - b[:, 1] + 1
    overlap = np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0]) + 1
    gap = np.maximum(b[:, None, 1], b[None, :, 1]) - np.minimum(b[:, None, 3], b[None, :, 3]) - 1
    join = ((overlap >= min_overlap * np.minimum(w[:, None], w[None, :]))
            & (gap <= max_gap * np.minimum(h[:, None], h[None, :])))
    return np.argwhere(np.triu(join, k=1)).astype(np.int64).reshape(-1, 2)


def split_mask(mask: np.ndarray, *, defect_ratio: float = 0.15, valley_ratio: float | None = 0.6,
               min_part: float = 0.2) -> tuple[np.ndarray, np.ndarray] | None:
    """Cut a blob's bool mask (h, w) holding two merged vehicles into two masks, or None.

    A vehicle's silhouette is nearly convex; two vehicles side by side (at slightly different distances, so at
    different heights in the image) make a notch in the union's outline. The convexity defects of the largest
    outer contour deeper than ``defect_ratio`` times the blob's smaller side (in pixels) are the notches: with two
    or more, the cut is the line through the far points of the two deepest; with one, the line through its far
    point perpendicular to the hull edge bridging it. Without a notch, the column of minimum foreground density
    (smoothed over 3 columns, searched in the middle 60 % of the width) cuts vertically if it is a valley (below
    ``valley_ratio`` times the densest column on each side). A cut leaving either side with less than
    ``min_part`` of the pixels is refused.
    """
    h, w = mask.shape
    if h < 4 or w < 4:
        return None
    m8 = mask.astype(np.uint8)
    total = int(m8.sum())
    if total == 0:
        return None
    cut = _notch_cut(m8, defect_ratio * min(h, w))
    if cut is not None:
        (x0, y0), (dx, dy) = cut
        yy, xx = np.mgrid[0:h, 0:w]
        side = (xx - x0) * dy - (yy - y0) * dx > 0
    elif valley_ratio is not None:
        density = m8.mean(axis=0)
        density = np.convolve(np.pad(density, 1, mode="edge"), np.ones(3) / 3.0, mode="valid")
        lo, hi = max(1, int(np.floor(0.2 * w))), min(w - 1, int(np.ceil(0.8 * w)))
        if hi <= lo:
            return None
        c = lo + int(np.argmin(density[lo:hi]))
        if not density[c] < valley_ratio * min(density[:c].max(), density[c + 1:].max()):
            return None
        side = np.broadcast_to(np.arange(w) >= c, (h, w))
    else:
        return None
    a, b = mask & ~side, mask & side
    na = int(a.sum())
    if min(na, total - na) < min_part * total:
        return None
    return a, b


def _notch_cut(mask: np.ndarray, min_depth: float) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """A point and a direction of the cut through the notches of a uint8 mask (see :func:`split_mask`)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    contour = max(contours, key=len)
    if len(contour) < 5:
        return None
    hull = cv2.convexHull(contour, returnPoints=False)
    try:
        defects = cv2.convexityDefects(contour, np.sort(hull, axis=0))
    except cv2.error:  # a self-intersecting contour (rare on thin blobs): no notch
        return None
    if defects is None:
        return None
    d = defects.reshape(-1, 4)
    depth = d[:, 3] / 256.0
    order = np.argsort(-depth)
    order = order[depth[order] >= max(min_depth, 3.0)]
    if order.size == 0:
        return None
    pts = contour[:, 0, :].astype(np.float64)
    f1 = pts[d[order[0], 2]]
    if order.size >= 2:
        f2 = pts[d[order[1], 2]]
        if np.hypot(*(f2 - f1)) >= 1.0:
            return (float(f1[0]), float(f1[1])), (float(f2[0] - f1[0]), float(f2[1] - f1[1]))
    edge = pts[d[order[0], 1]] - pts[d[order[0], 0]]
    return (float(f1[0]), float(f1[1])), (float(-edge[1]), float(edge[0]))


def tight_part(mask: np.ndarray, x0: int, y0: int) -> tuple[np.ndarray, float, np.ndarray]:
    """Inclusive pixel box (x1, y1, x2, y2) of a non-empty bool mask's foreground offset by (x0, y0), its pixel
    count and the mask cropped to the box."""
    cols = np.flatnonzero(mask.any(axis=0))
    rows = np.flatnonzero(mask.any(axis=1))
    box = np.array([x0 + cols[0], y0 + rows[0], x0 + cols[-1], y0 + rows[-1]], dtype=np.float64)
    crop = mask[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
    return box, float(crop.sum()), crop


@dataclass
class Blobs:
    """Blobs in the small (detection-scale) image: inclusive integer pixel boxes, pixel counts, label ids."""

    boxes: np.ndarray  # (N, 4) x1, y1, x2, y2 inclusive, small-image px
    areas: np.ndarray  # (N,) foreground pixels
    labels: list[list[int]]  # connected-component ids making up each blob


