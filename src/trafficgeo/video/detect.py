"""Vehicle detectors behind one interface: ``detect(image, time_s) -> Detections``.

Images are (H, W, 3) uint8 **BGR** frames (OpenCV order). Boxes are ``x1, y1, x2, y2`` in full-frame pixels in the
OpenCV pixel-centre convention (pixel (0, 0) is the *centre* of the top-left pixel, so a blob covering pixel columns
``i..j`` spans ``x1 = i - 0.5`` to ``x2 = j + 0.5``); scores are in [0, 1]; classes are the names used downstream
(``car, van, truck, bus, motorcycle, bicycle``; ``""`` = unknown).

* :class:`BackgroundDetector` (the default, no weights needed) for a **fixed** camera: background subtraction
  (OpenCV MOG2 or KNN with shadow detection) on a downscaled frame, then morphology, connected components, an
  optional region of interest, the merging of a vehicle's parts and the splitting of blobs of touching vehicles,
  and, given a calibrated camera and a road surface, a size filter and a size-based class in metres on the ground
  (rules in the class docstring). It finds what moves: vehicles that touch in the image often stay one blob.
* :class:`OnnxDetector` runs a YOLOv8/YOLO11-style ONNX export with onnxruntime on the CPU. trafficgeo never
  downloads weights: bring your own ``.onnx`` file.
* :func:`make_detector` builds either from a short spec (a name of
  :data:`trafficgeo.video.detector_names.DETECTOR_NAMES` or the path of an ``.onnx`` file).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import cv2
import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.geo.surface import OK
from trafficgeo.video.detector_names import DETECTOR_NAMES, ONNX_HINT, detector_kind  # noqa: F401 (re-exported)

if TYPE_CHECKING:
    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.mapping import Surface

# COCO class ids (0-based, as YOLO exports number them) of the road vehicles, and their trafficgeo names.
COCO_VEHICLES: dict[int, str] = {1: "bicycle", 2: "car", 3: "motorcycle", 5: "bus", 7: "truck"}
WARMUP_FRAMES = 20  # warm-up frames kept for the initial background (their per-pixel mode)
# s of video the background detector learns on before it reports anything; below the 4 s that `process` primes
# it on (pipeline.PRIME_S). On the demo world's bench 3 s counted 90.0 % per lane, 2 s 77.3 %, 1.67 s 84.5 %.
WARMUP_S = 3.0
GAIN_STEP = 8  # grid step (detection-scale px) of the pixels that measure a frame's brightness


# ---------------------------------------------------------------------------------------------------- Detections
@dataclass(frozen=True, eq=False)
class Detections:
    """Detections in one frame.

    Attributes:
        boxes: (N, 4) float64 ``x1, y1, x2, y2`` in full-frame pixels (pixel-centre convention).
        scores: (N,) float64 confidence in [0, 1].
        classes: (N,) object array of class names (``""`` = unknown).
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray

    def __post_init__(self) -> None:
        boxes = np.asarray(self.boxes, dtype=np.float64).reshape(-1, 4)
        scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        classes = np.asarray(self.classes, dtype=object).reshape(-1)
        if not (boxes.shape[0] == scores.shape[0] == classes.shape[0]):
            raise ValueError(f"Detections: {boxes.shape[0]} boxes, {scores.shape[0]} scores and "
                             f"{classes.shape[0]} classes; give one of each per detection")
        object.__setattr__(self, "boxes", boxes)
        object.__setattr__(self, "scores", scores)
        object.__setattr__(self, "classes", classes)

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
        return cls(np.concatenate([p.boxes for p in parts]), np.concatenate([p.scores for p in parts]),
                   np.concatenate([p.classes for p in parts]))

    def select(self, which: object) -> Detections:
        """The detections picked by a boolean mask (N,) or an index array."""
        idx = np.asarray(which)
        return Detections(self.boxes[idx], self.scores[idx], self.classes[idx])

    @property
    def bottom_centres(self) -> np.ndarray:
        """(N, 2) bottom-centre pixels ``((x1 + x2) / 2, y2)``: where a vehicle's nearest edge meets the road."""
        return np.column_stack([0.5 * (self.boxes[:, 0] + self.boxes[:, 2]), self.boxes[:, 3]])


def box_iou(a: object, b: object) -> np.ndarray:
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


# ---------------------------------------------------------------------------------------------------- sizes
@dataclass(frozen=True)
class SizeRules:
    """Plausible vehicle sizes on the ground (metres) for :class:`BackgroundDetector`'s size filter and classes.

    Attributes:
        classes: per class name, ``(min_length, max_length, min_height, max_height)`` in metres. "truck" stands
            for trucks and buses (a blob cannot tell them apart: both are long and high).
        min_length_m, max_length_m: accepted range of the length estimate (at the best class's height).
        min_width_m, max_width_m: accepted range of the ground width of the blob's bottom edge. Seen obliquely, a
            vehicle's side adds to it (a 2.55 m wide truck measures up to ~5.5 m), hence the wide default range.
        max_log_mismatch: a blob is kept only if some class explains it within this factor
            (``|ln(length / nearest length of the class)|``; 0.5 = a factor of 1.65).
        lane_width_m: lane width; a blob wider on the ground than ``split_lanes`` lane widths may also be split at
            a valley of its column density (:func:`split_mask`).
        split_lanes: see ``lane_width_m``.
        defect_ratio: a notch (convexity defect) of the outline at least this deep, relative to the blob's smaller
            side, marks two merged vehicles (:func:`split_mask`).
        valley_ratio: a column is a valley when its foreground density is below this fraction of the densest
            column on each side of it.
        motorcycle_max_length_m, motorcycle_max_width_m: a "car" shorter and narrower than these is a "motorcycle".
        truck_min_fill: a blob of the "truck" class whose foreground fills less than this fraction of its box is
            of unknown class (``""``): more likely vehicles merged into one blob than one truck.
    """

    classes: Mapping[str, tuple[float, float, float, float]] = field(default_factory=lambda: {
        "car": (3.0, 5.3, 1.2, 1.8), "van": (4.6, 7.5, 1.8, 2.9), "truck": (7.5, 25.0, 2.6, 4.3)})
    min_length_m: float = 1.2
    max_length_m: float = 25.0
    min_width_m: float = 0.5
    max_width_m: float = 6.0
    max_log_mismatch: float = 0.5
    lane_width_m: float = 3.5
    split_lanes: float = 1.6
    defect_ratio: float = 0.15
    valley_ratio: float = 0.6
    motorcycle_max_length_m: float = 3.0
    motorcycle_max_width_m: float = 1.4
    truck_min_fill: float = 0.5

    def __post_init__(self) -> None:
        for name in ("min_length_m", "max_length_m", "min_width_m", "max_width_m", "lane_width_m", "split_lanes",
                     "defect_ratio", "valley_ratio", "max_log_mismatch", "truck_min_fill"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"SizeRules.{name} = {value!r} must be a positive number")
        if self.min_length_m >= self.max_length_m or self.min_width_m >= self.max_width_m:
            raise InputError("SizeRules: the minimum length/width must be below the maximum")
        if not self.classes:
            raise InputError("SizeRules.classes is empty; give at least one class (min/max length, min/max height)")
        for name, r in self.classes.items():
            if len(r) != 4 or not (0 < r[0] < r[1] and 0 < r[2] <= r[3]):
                raise InputError(f"SizeRules.classes[{name!r}] = {r!r}: give (min_length, max_length, min_height, "
                                 "max_height) in metres with min < max")


@dataclass(frozen=True)
class BlobSizes:
    """Ground sizes of image blobs (metres; NaN where a ray misses the surface).

    The length of a blob depends on the height assumed for the vehicle: ``length(h) = a + b * h``.

    Attributes:
        width_m: (N,) ground distance between the bottom-left and bottom-right box corners.
        a_m, b: (N,) the intercept (m) and slope (m per m of height) of the length; ``b`` is negative for a camera
            above the vehicle (a higher roof ends nearer).
        distance_m: (N,) camera to the bottom-centre ground point.
    """

    width_m: np.ndarray
    a_m: np.ndarray
    b: np.ndarray
    distance_m: np.ndarray

    def length(self, height_m: object) -> np.ndarray:
        """Ground length (m) for vehicle heights (m) broadcast against the blobs."""
        return self.a_m + self.b * np.asarray(height_m, dtype=np.float64)


def blob_ground_size(camera: Camera, surface: Surface, boxes: np.ndarray, *,
                     metres_per_unit: float | None = None) -> BlobSizes:
    """Ground sizes of blobs with image boxes (N, 4) (full-frame px).

    The bottom edge of a vehicle's box is where its nearest bottom edge meets the road: its two corners mapped to
    the ground give the width, its centre the ground contact point ``G`` (on ``surface``). The top edge is the far
    top edge of the vehicle (for a camera above the vehicle): the top-centre's ray meets the horizontal plane
    ``h`` above ``G`` at ``T(h)``; the length for height ``h`` is the horizontal distance from ``G`` to ``T(h)``
    along the camera's horizontal viewing direction, linear in ``h``. With the right height this is the vehicle's
    length seen along the road (more when seen obliquely). It is very sensitive to the height far from the camera
    (several metres of length per metre of height), which is what makes the classes distinguishable.

    ``metres_per_unit``: of the camera's CRS (looked up when not given). Pixels outside the frame and rays missing
    the surface give NaN.
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    n = b.shape[0]
    if n == 0:
        return BlobSizes(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))
    if metres_per_unit is None:
        from trafficgeo.crs import metres_per_unit as crs_metres_per_unit
        from trafficgeo.geo.mapping import camera_crs

        crs = camera_crs(camera)
        metres_per_unit = crs_metres_per_unit(crs) if crs is not None else 1.0
    m = float(metres_per_unit)
    xc = 0.5 * (b[:, 0] + b[:, 2])
    # Bottom-left, bottom-right, bottom-centre and top-centre pixels; rays only inside the frame (lens model).
    uv = np.column_stack([np.concatenate([b[:, 0], b[:, 2], xc, xc]), np.concatenate([np.tile(b[:, 3], 3), b[:, 1]])])
    rays = np.full((4 * n, 3), np.nan)
    inside = camera.in_image(uv, margin=-0.5)
    if inside.any():
        rays[inside] = camera.rays(uv[inside])
    c = camera.position
    hits = surface.intersect(c, rays[:3 * n])
    xyz = np.where((hits.code == OK)[:, None], hits.points, np.nan).reshape(3, n, 3)
    width = np.hypot(*(xyz[1, :, :2] - xyz[0, :, :2]).T) * m
    ground = xyz[2]
    away = ground[:, :2] - c[:2]
    away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-12)
    r = rays[3 * n:]
    with np.errstate(invalid="ignore", divide="ignore"):
        # Ray C + t r meets z = z_G + h at t = (z_G + h - C_z) / r_z (h in CRS units = h_m / m).
        horiz = np.sum(r[:, :2] * away, axis=1)
        t0 = (ground[:, 2] - c[2]) / r[:, 2]
        a_m = (np.sum((c[:2] - ground[:, :2]) * away, axis=1) + t0 * horiz) * m
        slope = horiz / r[:, 2]  # CRS units of length per CRS unit of height = metres per metre
        ok = r[:, 2] < 0  # the top ray goes down: it meets the planes below the camera
    distance = np.where(hits.code[2 * n:] == OK, hits.distance[2 * n:] * m, np.nan)
    return BlobSizes(width_m=width, a_m=np.where(ok, a_m, np.nan), b=np.where(ok, slope, np.nan),
                     distance_m=distance)


def classify_sizes(sizes: BlobSizes, rules: SizeRules) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Class, length (m) and plausibility per blob from :func:`blob_ground_size`.

    Returns ``(classes (N,) object, length_m (N,), plausible (N,) bool)``. For each class the blob's length over
    the class's height range is an interval; its mismatch with the class's length range is 0 if they overlap, else
    the log-ratio of the gap (``|ln(length / nearest class length)|``). The class is the one of least mismatch
    (ties: the class whose length at its mid height is nearest, in log, to the middle of its length range); the
    length is the estimate at that class's height nearest to its mid height that fits its length range. "car"
    becomes "motorcycle" when shorter than ``motorcycle_max_length_m`` and narrower than
    ``motorcycle_max_width_m``. Plausible: a mismatch within ``max_log_mismatch``, the length within
    ``min/max_length_m`` and the width within ``min/max_width_m``.
    """
    names = list(rules.classes)
    spec = np.array([rules.classes[c] for c in names], dtype=np.float64)  # (K, 4)
    n = sizes.width_m.shape[0]
    if n == 0:
        return np.zeros(0, dtype=object), np.zeros(0), np.zeros(0, dtype=bool)
    eps = 1e-3
    with np.errstate(invalid="ignore", divide="ignore"):
        l_lo_h = sizes.a_m[:, None] + sizes.b[:, None] * spec[None, :, 2]
        l_hi_h = sizes.a_m[:, None] + sizes.b[:, None] * spec[None, :, 3]
        lo, hi = np.minimum(l_lo_h, l_hi_h), np.maximum(l_lo_h, l_hi_h)  # (N, K) length interval of the class
        below = np.log(spec[None, :, 0] / np.maximum(hi, eps))  # > 0: the blob is too short for the class
        above = np.log(np.maximum(lo, eps) / spec[None, :, 1])  # > 0: too long
        mismatch = np.maximum(np.maximum(below, above), 0.0)
        mismatch = np.where(np.isfinite(mismatch), mismatch, np.inf)
        mid_h = np.sqrt(spec[:, 2] * spec[:, 3])
        mid_l = np.sqrt(spec[:, 0] * spec[:, 1])
        l_mid = sizes.a_m[:, None] + sizes.b[:, None] * mid_h[None, :]
        # Tie-break: how far from the class's typical height the vehicle must be to have its typical length.
        h_star = (mid_l[None, :] - sizes.a_m[:, None]) / sizes.b[:, None]
        tie = np.abs(np.log(np.maximum(h_star, eps) / mid_h[None, :]))
        tie = np.where(np.isfinite(tie), tie, 1e3)
    best = np.argmin(mismatch + 1e-3 * np.minimum(tie, 1e3), axis=1)
    rows = np.arange(n)
    # Length: the estimate at the class's mid height, moved into the class's length range along its heights.
    length = np.clip(l_mid[rows, best], lo[rows, best], hi[rows, best])
    length = np.clip(length, spec[best, 0], spec[best, 1])
    length = np.where(np.isfinite(mismatch[rows, best]) & (mismatch[rows, best] > 0),
                      np.where(below[rows, best] > 0, hi[rows, best], lo[rows, best]), length)
    classes = np.asarray(names, dtype=object)[best]
    with np.errstate(invalid="ignore"):
        small = ((classes == "car") & (length < rules.motorcycle_max_length_m)
                 & (sizes.width_m < rules.motorcycle_max_width_m))
        classes[small] = "motorcycle"
        plausible = ((mismatch[rows, best] <= rules.max_log_mismatch)
                     & (length >= rules.min_length_m) & (length <= rules.max_length_m)
                     & (sizes.width_m >= rules.min_width_m) & (sizes.width_m <= rules.max_width_m))
    return classes, length, plausible


# ---------------------------------------------------------------------------------------------------- blobs
def _union_boxes(boxes: np.ndarray, groups: list[list[int]]) -> np.ndarray:
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


def group_pairs(n: int, pairs: np.ndarray) -> list[list[int]]:
    """Groups of ``range(n)`` joined by ``pairs`` (P, 2), transitively (union-find), in order of first member."""
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in np.asarray(pairs, dtype=np.int64).reshape(-1, 2):
        ri, rj = find(int(i)), find(int(j))
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    return list(groups.values())


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


def _tight_part(mask: np.ndarray, x0: int, y0: int) -> tuple[np.ndarray, float, np.ndarray]:
    """Inclusive pixel box (x1, y1, x2, y2) of a non-empty bool mask's foreground offset by (x0, y0), its pixel
    count and the mask cropped to the box."""
    cols = np.flatnonzero(mask.any(axis=0))
    rows = np.flatnonzero(mask.any(axis=1))
    box = np.array([x0 + cols[0], y0 + rows[0], x0 + cols[-1], y0 + rows[-1]], dtype=np.float64)
    crop = mask[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
    return box, float(crop.sum()), crop


@dataclass
class _Blobs:
    """Blobs in the small (detection-scale) image: inclusive integer pixel boxes, pixel counts, label ids."""

    boxes: np.ndarray  # (N, 4) x1, y1, x2, y2 inclusive, small-image px
    areas: np.ndarray  # (N,) foreground pixels
    labels: list[list[int]]  # connected-component ids making up each blob


# ---------------------------------------------------------------------------------------------------- background
def temporal_mode(frames: Sequence[np.ndarray], tol: int = 10) -> np.ndarray:
    """The most frequent colour of each pixel over ``frames`` (K images (H, W, 3) uint8): per pixel, the frame
    whose colour is within ``tol`` grey levels (every channel) of the most other frames. In dense traffic the road
    is visible less than half of the time far from the camera, so a median shows vehicles; the passing vehicles'
    colours differ from each other, the road's does not. O(K^2) image comparisons, done once."""
    k = len(frames)
    if k < 3:
        return frames[-1].copy()
    support = np.zeros((k, *frames[0].shape[:2]), dtype=np.uint8)
    lo, hi = (0, 0, 0), (tol, tol, tol)
    for i in range(k):
        for j in range(i + 1, k):
            close = cv2.inRange(cv2.absdiff(frames[i], frames[j]), lo, hi) // 255
            support[i] += close
            support[j] += close
    best = np.argmax(support, axis=0)
    stack = np.stack(frames)
    return np.take_along_axis(stack, best[None, :, :, None], axis=0)[0]


class BackgroundDetector:
    """Moving-vehicle detector for a fixed camera by background subtraction; needs no weights.

    Per frame (``detect``):

    1. The frame is downscaled by ``scale`` (INTER_AREA; default 0.5 for speed). During the first ``warmup_s``
       seconds of video (frame times, whatever the frame rate) nothing is reported: up to 20 of their frames,
       evenly spaced in time, are kept, and their per-pixel temporal mode
       (:func:`temporal_mode`: the colour seen most often, which in traffic is the road's even where vehicles cover
       it more than half of the time) initialises OpenCV's MOG2 (or KNN) model (``detectShadows=True``). From
       then on every frame updates the model with ``learning_rate`` per frame, by default ``1 / history``, a fixed
       slow rate (OpenCV's automatic rate, ``1 / min(2 * frames, history)``, is fast for the first hundreds of
       frames and absorbs uniformly coloured vehicles into the background); with MOG2 a vehicle that stops becomes
       background after about ``0.1 / learning_rate`` frames (2 s at 25 fps by default), and so does a ghost left
       where a vehicle stood during the warm-up. Before the update, with ``compensate_gain``, the frame is scaled
       to the brightness of the initial background (the median brightness ratio over a sparse pixel grid): a slow
       learning rate cannot follow auto-exposure or clouds.
    2. Foreground = pixels marked 255; shadows (marked 127: darker than the background by a factor between
       ``shadow_threshold`` and 1 with the same colour) are dropped. Dark grey vehicle faces on a grey road can
       pass for shadows: their blobs lose those faces. The ROI mask (bool (H, W), full resolution), if any, is
       applied here: nothing outside it is foreground.
    3. Morphology: opening with an ``open_px`` ellipse removes speckle noise (and the flicker of edges of a
       shaking camera), closing with a ``close_px`` ellipse joins a vehicle's parts (sizes in full-frame pixels,
       odd and at least 3 px at detection scale; by default no closing, which joins vehicles close in the image).
    4. Connected components (8-connectivity) of at least ``min_area_px`` full-frame pixels become blobs.
    5. **Merging** (``merge=True``): two blobs whose column ranges overlap by at least half the narrower one's
       width and whose vertical gap is at most a quarter of the smaller one's height (:func:`merge_candidates`)
       may be one vehicle broken in two (a windshield and a body whose colour is close to the road's). With a
       camera they are merged when the union is a plausible vehicle and at least one part is not; without, when
       the smaller part has at most half the pixels of the larger (vehicles one behind the other in a lane are
       stacked the same way, and are similar in size).
    6. **Splitting** (``split=True``, single-component blobs not touching the left or right frame border, at most
       3 levels, :func:`split_mask`): vehicles that touch in the image (side by side, or one partly hiding
       another) make one blob whose outline has a notch, a vehicle's own outline is nearly convex. The blob is
       cut through its deepest notches (convexity defects) when they are deeper than ``rules.defect_ratio`` (0.15)
       times the blob's smaller side. With a camera only blobs that are not plausible as one vehicle or whose
       bottom edge is wider on the ground than ``rules.split_lanes`` lane widths (1.6 x 3.5 m) are cut; the
       latter also, without a notch, at the column of minimum foreground density if it is a valley (below
       ``rules.valley_ratio`` of the densest column on each side). Without a camera notches must be twice as
       deep. Vehicles exactly one behind the other in one lane stay one blob.
    7. With a ``camera`` and a road ``surface`` (both or neither), the **class and size filter**
       (:func:`blob_ground_size`, :func:`classify_sizes`): the blob's ground length follows from its box for an
       assumed vehicle height (the bottom edge is on the road, the top edge is the far end of the roof); the class
       is the one of ``rules.classes`` (car 3-5.3 m long and 1.2-1.8 m high, van 4.6-7.5 m / 1.8-2.9 m, truck 7.5-25
       m / 2.6-4.3 m) whose heights give lengths within its length range, or nearest to it. "truck" covers trucks
       and buses: both are long and high, a blob cannot tell them apart. A "car" shorter than 3 m and narrower than
       1.4 m is a "motorcycle". The blob is kept when its class fits within a factor 1.65, its length is within
       1.2-25 m and its bottom edge is 0.5-6 m wide on the ground, and, with ``keep_merged``, also when it is longer
       than a car (the shortest class) or wider than 6 m but could not be split (vehicles hiding each other:
       dropping the blob would lose them all, keeping it makes at least one track). Blobs too small for a vehicle
       are dropped. A blob cut by the frame border (its ground contact or its extent is not seen) is kept without
       the size check. A blob no single vehicle explains (kept by ``keep_merged``, or cut by the border and not
       plausible) and a "truck" whose foreground fills less than ``rules.truck_min_fill`` of its box (vehicles
       merged into one blob leave empty corners, a truck's body does not) have class ``""`` (unknown). Without a
       camera every blob is kept and its class is ``""``.
    8. Score: the blob's fill ratio, foreground pixels / box area (in (0, 1]): compact vehicles score high, sparse
       noise or merged clutter low.

    Not thread-safe (the background model is state); use one detector per video. ``detect`` needs the frames'
    times (s, increasing): the warm-up is counted in them.
    """

    def __init__(self, *, method: str = "mog2", scale: float = 0.5, warmup_s: float = WARMUP_S,
                 learning_rate: float | None = None, history: int = 500, threshold: float | None = None,
                 shadow_threshold: float = 0.5, camera: Camera | None = None,
                 surface: Surface | None = None, roi: np.ndarray | None = None, min_area_px: float | None = None,
                 open_px: float | None = None, close_px: float | None = None, merge: bool = True,
                 split: bool = True, rules: SizeRules | None = None, compensate_gain: bool = True,
                 keep_merged: bool = True) -> None:
        """Options (pixels are full-frame pixels):

        Args:
            method: "mog2" or "knn" (OpenCV background subtractors).
            scale: downscale factor of the frame the model runs on (0 < scale <= 1).
            warmup_s: seconds of video (from the first frame's time) whose frames' temporal mode initialises the
                background; nothing is reported for them (longer in dense traffic). The first frame at or after
                ``warmup_s`` is detected in. With 0 the first frame initialises it (nothing is reported for it).
            learning_rate: background learning rate per frame in [0, 1] (default ``1 / history``), or -1 for
                OpenCV's automatic rate.
            history: frames of history of the model.
            shadow_threshold: a pixel darker than the background by a factor in [shadow_threshold, 1] with the same
                colour is a shadow and ignored (OpenCV's ``tau``; raise it if dark grey vehicles go undetected,
                lower it if dark shadows are detected).
            threshold: MOG2 ``varThreshold`` (squared Mahalanobis distance, default 16) or KNN ``dist2Threshold``
                (squared distance, default 400).
            camera, surface: calibrated camera and road surface for the metric size filter, class and splitting.
            roi: bool (H, W) region of interest at full resolution (True = watched).
            min_area_px: smallest blob area (px^2); default 5e-5 of the frame area (104 px^2 at 1920x1080: a car
                about 15 px tall).
            open_px, close_px: sizes of the opening and closing ellipses; default frame width / 400 and 0 (no
                closing: it joins neighbouring vehicles into one blob; 0 disables either).
            merge, split: merge the parts of a vehicle; split blobs of several vehicles.
            rules: metric size rules (:class:`SizeRules`).
            compensate_gain: scale each frame to the brightness of the initial background (camera auto-exposure,
                passing clouds) before the model sees it.
            keep_merged: keep blobs too long or too wide for one vehicle that could not be split (step 7): fewer
                boxes match one vehicle, more vehicles are counted.
        """
        method = method.lower().strip()
        if method not in ("mog2", "knn"):
            raise InputError(f"BackgroundDetector: unknown method {method!r}; use 'mog2' or 'knn'")
        if not (np.isfinite(scale) and 0 < scale <= 1):
            raise InputError(f"BackgroundDetector: scale {scale!r} must be in (0, 1], e.g. 0.5")
        if not (np.isfinite(warmup_s) and warmup_s >= 0):
            raise InputError(f"BackgroundDetector: warmup_s {warmup_s!r} must be a number of seconds >= 0, e.g. 3")
        if learning_rate is None:
            learning_rate = 1.0 / history if history >= 1 else -1.0
        if not (learning_rate == -1 or (np.isfinite(learning_rate) and 0 <= learning_rate <= 1)):
            raise InputError(f"BackgroundDetector: learning_rate {learning_rate!r} must be in [0, 1] or -1 (auto)")
        if int(history) != history or history < 1:
            raise InputError(f"BackgroundDetector: history {history!r} must be a whole number of frames >= 1")
        if threshold is not None and not (np.isfinite(threshold) and threshold > 0):
            raise InputError(f"BackgroundDetector: threshold {threshold!r} must be positive")
        if not (np.isfinite(shadow_threshold) and 0 < shadow_threshold < 1):
            raise InputError(f"BackgroundDetector: shadow_threshold {shadow_threshold!r} must be in (0, 1), e.g. 0.5")
        if (camera is None) != (surface is None):
            raise InputError("BackgroundDetector: the metric size filter needs both a camera and a road surface; "
                             "give both or neither")
        for name, value in (("min_area_px", min_area_px), ("open_px", open_px), ("close_px", close_px)):
            if value is not None and not (np.isfinite(value) and value >= 0):
                raise InputError(f"BackgroundDetector: {name} {value!r} must be >= 0")
        self.method = method
        self.scale = float(scale)
        self.warmup_s = float(warmup_s)
        self.learning_rate = float(learning_rate)
        self.camera = camera
        self.surface = surface
        self.roi = None if roi is None else np.asarray(roi)
        self.min_area_px = min_area_px
        self.open_px = open_px
        self.close_px = close_px
        self.merge = merge
        self.split = split
        self.rules = rules or SizeRules()
        self.frames_seen = 0
        if method == "mog2":
            self._model = cv2.createBackgroundSubtractorMOG2(history=int(history), varThreshold=threshold or 16.0,
                                                             detectShadows=True)
        else:
            self._model = cv2.createBackgroundSubtractorKNN(history=int(history), dist2Threshold=threshold or 400.0,
                                                            detectShadows=True)
        self._model.setShadowThreshold(float(shadow_threshold))
        self._buffer: list[np.ndarray] = []
        self._t_first: float | None = None  # time (s) of the first frame
        self._t_kept = -np.inf  # time (s) of the last warm-up frame kept in the buffer
        self._ready = False  # the background model is initialised
        self._shape: tuple[int, int] | None = None
        self._memo: dict[tuple[float, ...], tuple[str, float, bool, float]] = {}
        self._m = 1.0
        if camera is not None:
            from trafficgeo.crs import metres_per_unit
            from trafficgeo.geo.mapping import camera_crs

            crs = camera_crs(camera)
            self._m = metres_per_unit(crs) if crs is not None else 1.0
        self._small: tuple[int, int] = (0, 0)
        self._roi_small: np.ndarray | None = None
        self._open: np.ndarray | None = None
        self._close: np.ndarray | None = None
        self._min_area = 0.0
        self.last_mask: np.ndarray | None = None  # the last cleaned foreground mask (small image), for inspection
        self.background: np.ndarray | None = None  # the initial background (small image) once warmed up
        self.compensate_gain = bool(compensate_gain)
        self.keep_merged = bool(keep_merged)
        self.gain = 1.0  # brightness of the last frame relative to the initial background
        self._ref: np.ndarray | None = None
        self._ref_ok: np.ndarray | None = None

    # ---------------------------------------------------------------- set-up on the first frame
    def _setup(self, shape: tuple[int, int]) -> None:
        h, w = shape
        if self.camera is not None and tuple(self.camera.image_size) != (w, h):
            cw, ch = self.camera.image_size
            raise InputError(f"BackgroundDetector: frames are {w}x{h} px but the camera is calibrated for {cw}x{ch}; "
                             "use the camera of this video (or rescale it)")
        sw, sh = max(1, round(w * self.scale)), max(1, round(h * self.scale))
        self._small = (sw, sh)
        self._sx, self._sy = w / sw, h / sh
        if self.roi is not None:
            roi = check_roi(self.roi, (h, w))
            small = cv2.resize(roi.astype(np.uint8) * 255, (sw, sh), interpolation=cv2.INTER_AREA)
            self._roi_small = np.where(small >= 128, 255, 0).astype(np.uint8)
        open_px = w / 400.0 if self.open_px is None else self.open_px
        # No closing by default: it joins vehicles that are close in the image (far away, or one behind the other)
        # into one blob far more often than it mends a vehicle (its parts are merged by step 5 instead).
        close_px = 0.0 if self.close_px is None else self.close_px
        # Odd sizes: an even kernel has no centre pixel and shifts the mask by a pixel.
        ko = max(3, 2 * round(0.5 * (open_px / self._sx - 1)) + 1) if open_px > 0 else 1
        kc = max(3, 2 * round(0.5 * (close_px / self._sx - 1)) + 1) if close_px > 0 else 1
        self._open = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (ko, ko)) if ko > 1 else None
        self._close = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (kc, kc)) if kc > 1 else None
        min_area = 5e-5 * w * h if self.min_area_px is None else self.min_area_px
        self._min_area = max(1.0, min_area / (self._sx * self._sy))
        self._shape = (h, w)

    def _in_warmup(self, time_s: float) -> bool:
        """Is a frame at ``time_s`` (s) a warm-up frame (the first frame always is)?"""
        if not np.isfinite(time_s):
            raise InputError(f"BackgroundDetector: frame time {time_s!r} is not a number of seconds")
        if self._ready:
            return False
        if self._t_first is None:
            return True
        return time_s - self._t_first < self.warmup_s - 1e-9

    # ---------------------------------------------------------------- per frame
    def foreground(self, image: np.ndarray, time_s: float) -> np.ndarray:
        """Update the model with ``image`` taken at ``time_s`` (s) and return the cleaned foreground mask (uint8
        0/255) at detection scale (steps 1-3 of the class docstring); all zero for warm-up frames."""
        image = check_image(image)
        time_s = float(time_s)
        if self._shape is None:
            self._setup(image.shape[:2])
        elif image.shape[:2] != self._shape:
            raise InputError(f"BackgroundDetector: frame size changed from {self._shape[1]}x{self._shape[0]} to "
                             f"{image.shape[1]}x{image.shape[0]} px; use one detector per video")
        small = image if self._small == (image.shape[1], image.shape[0]) else \
            cv2.resize(image, self._small, interpolation=cv2.INTER_AREA)
        self.frames_seen += 1
        if self._in_warmup(time_s):
            if self._t_first is None:
                self._t_first = time_s
            # Up to WARMUP_FRAMES frames evenly spaced in time over the warm-up, whatever the frame rate.
            if time_s - self._t_kept >= self.warmup_s / WARMUP_FRAMES - 1e-9 and len(self._buffer) < WARMUP_FRAMES:
                self._buffer.append(small.copy() if small is image else small)
                self._t_kept = time_s
            self.last_mask = np.zeros(small.shape[:2], dtype=np.uint8)
            return self.last_mask
        if not self._ready:
            self._initialise()
        if self.compensate_gain and self._ref is not None:
            small = self._compensate(small)
        fg = self._model.apply(small, learningRate=self.learning_rate)
        _, mask = cv2.threshold(fg, 200, 255, cv2.THRESH_BINARY)  # 255 = foreground, 127 = shadow, 0 = background
        if self._roi_small is not None:
            mask = cv2.bitwise_and(mask, self._roi_small)
        if self._open is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._open)
        if self._close is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._close)
        self.last_mask = mask
        return mask

    def _initialise(self) -> None:
        """Initialise the model with the per-pixel temporal mode of the buffered warm-up frames."""
        background = temporal_mode(self._buffer)
        self._buffer = []
        self._ready = True
        self._model.apply(background, learningRate=1.0)  # 1 = re-initialise the model from this image
        if self.method == "knn":  # KNN fills its sample memories only over several updates
            for _ in range(5):
                self._model.apply(background, learningRate=0.5)
        self.background = background
        ref = background[::GAIN_STEP, ::GAIN_STEP].mean(axis=2)
        self._ref_ok = (ref > 16) & (ref < 240)
        self._ref = ref[self._ref_ok]
        if self._ref.size < 16:
            self._ref = None

    def _compensate(self, small: np.ndarray) -> np.ndarray:
        """``small`` scaled to the brightness of the initial background (the median ratio over a sparse grid)."""
        cur = small[::GAIN_STEP, ::GAIN_STEP].mean(axis=2)[self._ref_ok]
        gain = float(np.median(cur / self._ref))
        self.gain = gain
        if gain > 0 and abs(gain - 1.0) > 0.005:
            return cv2.convertScaleAbs(small, alpha=1.0 / gain)
        return small

    @property
    def warming_up(self) -> bool:
        """True until the background model is initialised (by the first frame after the warm-up)."""
        return not self._ready

    def detect(self, image: np.ndarray, time_s: float) -> Detections:
        """Vehicles moving in ``image`` ((H, W, 3) uint8 BGR) taken at ``time_s`` (s); empty during the warm-up
        (the first ``warmup_s`` seconds)."""
        learning = self._in_warmup(float(time_s))
        mask = self.foreground(image, time_s)
        if learning:
            return Detections.empty()
        self._memo.clear()
        # BBDT: several times faster than the default algorithm on sparse masks in OpenCV 4.x/5.x.
        _, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_BBDT)
        keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= self._min_area) + 1
        if keep.size == 0:
            return Detections.empty()
        s = stats[keep]
        boxes = np.column_stack([s[:, 0], s[:, 1], s[:, 0] + s[:, 2] - 1, s[:, 1] + s[:, 3] - 1]).astype(np.float64)
        blobs = _Blobs(boxes, s[:, cv2.CC_STAT_AREA].astype(np.float64), [[int(k)] for k in keep])
        if self.merge and len(keep) > 1:
            blobs = self._merge(blobs)
        if self.split:
            blobs = self._split(blobs, labels)
        classes = np.full(len(blobs.areas), "", dtype=object)
        if self.camera is not None and self.surface is not None and len(blobs.areas):
            blobs, classes = self._metric(blobs)
        full = self._to_full(blobs.boxes)
        box_area = (blobs.boxes[:, 2] - blobs.boxes[:, 0] + 1) * (blobs.boxes[:, 3] - blobs.boxes[:, 1] + 1)
        scores = np.clip(blobs.areas / np.maximum(box_area, 1.0), 0.0, 1.0)
        return Detections(full, scores, classes)

    def _to_full(self, boxes: np.ndarray) -> np.ndarray:
        """Inclusive small-image pixel boxes -> full-frame boxes (pixel-centre convention: the blob's outer edges)."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        out = np.empty_like(b)
        out[:, 0] = b[:, 0] * self._sx - 0.5
        out[:, 2] = (b[:, 2] + 1) * self._sx - 0.5
        out[:, 1] = b[:, 1] * self._sy - 0.5
        out[:, 3] = (b[:, 3] + 1) * self._sy - 0.5
        return out

    def _measure(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(classes, length_m, plausible, width_m) of small-image boxes (memoised within a frame)."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        keys = [tuple(row) for row in b.tolist()]
        new = [k for k in dict.fromkeys(keys) if k not in self._memo]
        if new:
            sizes = blob_ground_size(self.camera, self.surface, self._to_full(np.array(new)),
                                     metres_per_unit=self._m)
            classes, length, plausible = classify_sizes(sizes, self.rules)
            for k, row in enumerate(new):
                self._memo[row] = (classes[k], length[k], plausible[k], sizes.width_m[k])
        out = [self._memo[k] for k in keys]
        return (np.array([o[0] for o in out], dtype=object), np.array([o[1] for o in out], dtype=np.float64),
                np.array([o[2] for o in out], dtype=bool), np.array([o[3] for o in out], dtype=np.float64))

    def _merge(self, blobs: _Blobs) -> _Blobs:
        """Merge the parts of one vehicle (step 5 of the class docstring)."""
        pairs = merge_candidates(blobs.boxes)
        if pairs.size == 0:
            return blobs
        i, j = pairs[:, 0], pairs[:, 1]
        if self.camera is not None and self.surface is not None:
            single = self._measure(blobs.boxes)[2]
            union = np.column_stack([np.minimum(blobs.boxes[i, :2], blobs.boxes[j, :2]),
                                     np.maximum(blobs.boxes[i, 2:], blobs.boxes[j, 2:])])
            ok = self._measure(union)[2] & ~(single[i] & single[j])
        else:
            a, b = blobs.areas[i], blobs.areas[j]
            ok = np.minimum(a, b) <= 0.5 * np.maximum(a, b)
        groups = group_pairs(len(blobs.areas), pairs[ok])
        if len(groups) == len(blobs.areas):
            return blobs
        return _Blobs(_union_boxes(blobs.boxes, groups), np.array([blobs.areas[g].sum() for g in groups]),
                      [[lab for k in g for lab in blobs.labels[k]] for g in groups])

    def _split(self, blobs: _Blobs, labels: np.ndarray) -> _Blobs:
        """Split blobs of merged vehicles (:func:`split_mask`, at most 3 levels): any single-component blob with a
        deep notch; with a camera, also at a density valley when wider on the ground than ``rules.split_lanes``
        lanes. Blobs touching the left or right frame border and blobs made by merging are left whole."""
        rules = self.rules
        sw, _sh = self._small
        metric = self.camera is not None and self.surface is not None
        boxes, areas, ids = list(blobs.boxes), list(blobs.areas), list(blobs.labels)
        masks: list[np.ndarray | None] = [None] * len(boxes)  # the crop of a part made by a split
        todo = [i for i in range(len(boxes)) if len(ids[i]) == 1]
        for _level in range(3):
            if not todo:
                break
            wide = np.zeros(len(todo), dtype=bool)
            suspect = np.ones(len(todo), dtype=bool)
            if metric:
                _cls, _len, plausible, width = self._measure(np.array([boxes[i] for i in todo]))
                with np.errstate(invalid="ignore"):
                    wide = width > rules.split_lanes * rules.lane_width_m
                suspect = wide | ~plausible
            ratio = rules.defect_ratio if metric else 2.0 * rules.defect_ratio
            nxt = []
            for i, is_wide, is_suspect in zip(todo, wide, suspect, strict=True):
                x1, y1, x2, y2 = (int(v) for v in boxes[i])
                if not is_suspect or x1 <= 0 or x2 >= sw - 1:
                    continue
                crop = masks[i] if masks[i] is not None else labels[y1:y2 + 1, x1:x2 + 1] == ids[i][0]
                parts = split_mask(crop, defect_ratio=ratio, valley_ratio=rules.valley_ratio if is_wide else None)
                if parts is None:
                    continue
                new = [_tight_part(p, x1, y1) for p in parts]
                boxes[i], areas[i], masks[i] = new[0]
                boxes.append(new[1][0])
                areas.append(new[1][1])
                masks.append(new[1][2])
                ids.append(ids[i])
                nxt += [i, len(boxes) - 1]
            todo = nxt
        keep = [i for i in range(len(boxes)) if areas[i] >= self._min_area]
        return _Blobs(np.array([boxes[i] for i in keep], dtype=np.float64).reshape(-1, 4),
                      np.array([areas[i] for i in keep], dtype=np.float64), [ids[i] for i in keep])

    def _metric(self, blobs: _Blobs) -> tuple[_Blobs, np.ndarray]:
        """The size filter and the classes (step 6 of the class docstring)."""
        sw, sh = self._small
        classes, length, single, width = self._measure(blobs.boxes)
        classes = classes.copy()
        b = blobs.boxes
        # keep_merged: longer than the shortest class allows (a car), or too wide, yet not split: vehicles that hide
        # each other (seen along the road from a low camera). Dropped, all of them would be lost.
        shortest = min(spec[1] for spec in self.rules.classes.values())
        with np.errstate(invalid="ignore"):
            merged = self.keep_merged & ~single & ((length > shortest) | (width > self.rules.max_width_m))
        # Cut by the frame border, a blob's ground size is not measurable: it is kept without the size check.
        cut = (b[:, 0] <= 0) | (b[:, 1] <= 0) | (b[:, 2] >= sw - 1) | (b[:, 3] >= sh - 1)
        # A blob that no single vehicle explains (vehicles merged into one blob) has no class: "" (unknown). Nor
        # has a truck-sized blob that fills little of its box: a truck's box-shaped body fills it, vehicles one
        # behind the other or side by side leave empty corners.
        box_area = (b[:, 2] - b[:, 0] + 1) * (b[:, 3] - b[:, 1] + 1)
        sparse = (classes == "truck") & (blobs.areas < self.rules.truck_min_fill * box_area)
        classes[~single | sparse] = ""
        keep = np.flatnonzero(single | merged | cut)
        return _Blobs(blobs.boxes[keep], blobs.areas[keep], [blobs.labels[i] for i in keep]), classes[keep]


# ---------------------------------------------------------------------------------------------------- ONNX
def letterbox(image: np.ndarray, size: int, pad_value: int = 114) -> tuple[np.ndarray, float, tuple[int, int]]:
    """Resize ``image`` to fit a ``size`` x ``size`` square keeping its aspect, centred on a ``pad_value`` border
    (the ultralytics letterbox). Returns the square image, the scale and the (left, top) padding in pixels."""
    h, w = image.shape[:2]
    r = min(size / h, size / w)
    nw, nh = round(w * r), round(h * r)
    left = round((size - nw) / 2 - 0.1)
    top = round((size - nh) / 2 - 0.1)
    resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR) if (nw, nh) != (w, h) else image
    out = cv2.copyMakeBorder(resized, top, size - nh - top, left, size - nw - left, cv2.BORDER_CONSTANT,
                             value=(pad_value, pad_value, pad_value))
    return out, r, (left, top)


ONNX_SHAPES = ("supported: [1, 4 + classes, anchors] with 3 or 4 strides' anchors (a YOLOv8/YOLO11 detection "
               "export without NMS, e.g. [1, 84, 8400] at 640 px); not exports with NMS ([1, 300, 6]), transposed "
               "outputs ([1, 8400, 84]) or outputs with an objectness score ([1, 25200, 85])")


def yolo_anchor_counts(input_size: int) -> tuple[int, int]:
    """Anchors of a YOLOv8/YOLO11 head on a square input of ``input_size`` px: strides 8, 16, 32 (P5 models) and
    8 to 64 (P6 models)."""
    p5 = sum(math.ceil(input_size / st) ** 2 for st in (8, 16, 32))
    return p5, p5 + math.ceil(input_size / 64) ** 2


def check_output_shape(path: str | Path, shape: Sequence[object], input_size: int) -> None:
    """InputError unless an ONNX output shape (dimensions: ints, or names/None where dynamic) is one
    :class:`OnnxDetector` decodes: ``[1, 4 + classes, anchors]``, the anchors those of its head at
    ``input_size`` px (:func:`yolo_anchor_counts`) and more than the values per anchor."""
    dims = list(shape)
    fixed = [d if isinstance(d, int) and not isinstance(d, bool) and d > 0 else None for d in dims]
    ok = len(dims) == 3 and fixed[0] in (1, None)
    if ok and fixed[1] is not None and fixed[1] < 5:
        ok = False
    if ok and fixed[2] is not None:
        ok = fixed[2] in yolo_anchor_counts(input_size) and (fixed[1] is None or fixed[2] > fixed[1])
    if not ok:
        found = "[" + ", ".join(str(d) if f is not None else "?" for d, f in zip(dims, fixed, strict=True)) + "]"
        raise InputError(f"{path}: the model's output has shape {found} (input {input_size} px), which trafficgeo "
                         f"cannot decode; {ONNX_SHAPES}; {ONNX_HINT}")


class OnnxDetector:
    """A YOLOv8/YOLO11-style ONNX detector run with onnxruntime on the CPU (2 intra-op threads).

    The model takes a ``[1, 3, S, S]`` float32 RGB image scaled to 0..1 and letterboxed (aspect kept, grey 114
    border) and returns ``[1, 4 + nc, A]``: per anchor the box centre and size ``cx, cy, w, h`` in letterboxed
    input pixels, then one score per class (no objectness; the ultralytics export without NMS). Only classes in
    ``class_map`` (model class id -> trafficgeo name; default the COCO vehicles) are kept; boxes scoring at least
    ``conf`` go through non-maximum suppression at IoU ``iou`` (across classes with ``agnostic=True``, so that one
    vehicle is not reported as both a car and a truck), then back to full-frame pixels. The model's pixel
    coordinates have their origin at the top-left *corner* of the image; 0.5 px is subtracted for the pixel-centre
    convention. A model with a fixed input size uses it (``input_size`` is for dynamic inputs).
    """

    def __init__(self, model_path: str | Path, *, input_size: int = 640, conf: float = 0.3, iou: float = 0.5,
                 class_map: Mapping[int, str] | None = None, agnostic: bool = True, roi: np.ndarray | None = None,
                 threads: int = 2) -> None:
        p = Path(model_path)
        if not p.is_file():
            raise InputError(f"{p}: ONNX model not found; put the .onnx file there or pass its path with "
                             f"--detector PATH.onnx ({ONNX_HINT})")
        if int(input_size) != input_size or input_size < 32:
            raise InputError(f"OnnxDetector: input_size {input_size!r} must be a whole number of pixels >= 32")
        for name, value in (("conf", conf), ("iou", iou)):
            if not (np.isfinite(value) and 0 <= value <= 1):
                raise InputError(f"OnnxDetector: {name} {value!r} must be in [0, 1]")
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        try:
            self._session = ort.InferenceSession(str(p), sess_options=opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            msg = " ".join(str(exc).split())[:200]
            raise InputError(f"{p}: not a usable ONNX model ({msg}); {ONNX_HINT}") from None
        inputs, outputs = self._session.get_inputs(), self._session.get_outputs()
        in_shape = inputs[0].shape if len(inputs) == 1 else []
        if len(in_shape) != 4 or (isinstance(in_shape[1], int) and in_shape[1] != 3):
            shapes = [i.shape for i in inputs]
            raise InputError(f"{p}: expected one input of shape [1, 3, S, S] (a YOLOv8/YOLO11 detection export), "
                             f"found {shapes}; {ONNX_HINT}")
        if not outputs:
            raise InputError(f"{p}: the model has no output; {ONNX_SHAPES}; {ONNX_HINT}")
        if inputs[0].type != "tensor(float)":
            raise InputError(f"{p}: the model's input is {inputs[0].type}, not float32; export it without half "
                             f"precision; {ONNX_HINT}")
        shape = inputs[0].shape
        fixed = [d for d in shape[2:] if isinstance(d, int) and d > 0]
        if len(fixed) == 2 and fixed[0] != fixed[1]:
            raise InputError(f"{p}: input {shape} is not square; export with a square imgsz (e.g. imgsz=640)")
        self.input_size = int(fixed[0]) if fixed else int(input_size)
        check_output_shape(p, outputs[0].shape, self.input_size)
        self._input_name = inputs[0].name
        self._output_name = outputs[0].name
        cmap = dict(COCO_VEHICLES if class_map is None else class_map)
        if not cmap:
            raise InputError("OnnxDetector: class_map is empty; map at least one model class id to a vehicle name")
        self.class_map = {int(k): str(v) for k, v in cmap.items()}
        nc_out = outputs[0].shape[1]
        if isinstance(nc_out, int) and nc_out - 4 <= max(self.class_map):
            raise InputError(f"{p}: the model has {nc_out - 4} classes but class_map uses class id "
                             f"{max(self.class_map)}; give a class_map for this model")
        self.conf, self.iou, self.agnostic = float(conf), float(iou), bool(agnostic)
        self.roi = None if roi is None else np.asarray(roi)
        self.path = p

    def detect(self, image: np.ndarray, time_s: float = 0.0) -> Detections:
        """Vehicles in ``image`` ((H, W, 3) uint8 BGR); ``time_s`` is not used."""
        image = check_image(image)
        h, w = image.shape[:2]
        lb, r, (left, top) = letterbox(image, self.input_size)
        blob = cv2.dnn.blobFromImage(lb, scalefactor=1.0 / 255.0, swapRB=True)  # (1, 3, S, S) float32 RGB
        try:
            out = np.asarray(self._session.run([self._output_name], {self._input_name: blob})[0])
        except Exception as exc:  # onnxruntime's own exception types (shape mismatch inside the graph, ...)
            msg = " ".join(str(exc).split())[:200]
            raise InputError(f"{self.path}: the model failed on a {w}x{h} frame letterboxed to {self.input_size} px "
                             f"({msg}); {ONNX_HINT}") from None
        check_output_shape(self.path, list(out.shape), self.input_size)
        if out.shape[1] - 4 <= max(self.class_map):
            raise InputError(f"{self.path}: output of shape {list(out.shape)} has {out.shape[1] - 4} classes but "
                             f"class_map uses class id {max(self.class_map)}; give a class_map for this model")
        pred = out[0]
        ids = np.array(sorted(self.class_map), dtype=np.int64)
        cls_scores = pred[4 + ids, :]  # (K, A)
        best = np.argmax(cls_scores, axis=0)
        score = cls_scores[best, np.arange(pred.shape[1])]
        keep = np.flatnonzero(score >= self.conf)
        if keep.size == 0:
            return Detections.empty()
        cx, cy, bw, bh = pred[0, keep], pred[1, keep], pred[2, keep], pred[3, keep]
        x1 = (cx - 0.5 * bw - left) / r - 0.5
        y1 = (cy - 0.5 * bh - top) / r - 0.5
        x2 = (cx + 0.5 * bw - left) / r - 0.5
        y2 = (cy + 0.5 * bh - top) / r - 0.5
        boxes = np.column_stack([x1, y1, x2, y2]).astype(np.float64)
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], -0.5, w - 0.5)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], -0.5, h - 0.5)
        score = score[keep].astype(np.float64)
        cls_id = ids[best[keep]]
        xywh = np.column_stack([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]])
        if self.agnostic:
            picked = cv2.dnn.NMSBoxes(xywh.tolist(), score.tolist(), self.conf, self.iou)
        else:
            picked = cv2.dnn.NMSBoxesBatched(xywh.tolist(), score.tolist(), cls_id.tolist(), self.conf, self.iou)
        picked = np.asarray(picked, dtype=np.int64).reshape(-1)
        picked = picked[np.argsort(-score[picked], kind="stable")]
        names = np.array([self.class_map[int(c)] for c in cls_id[picked]], dtype=object)
        det = Detections(boxes[picked], np.clip(score[picked], 0.0, 1.0), names)
        if self.roi is not None and len(det):
            det = det.select(in_roi(self.roi, det.bottom_centres, (h, w)))
        return det


def in_roi(roi: np.ndarray, points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Whether pixels (N, 2) fall inside the bool ROI mask (H, W) of frames of ``shape``."""
    mask = check_roi(roi, shape)
    uv = np.rint(np.asarray(points, dtype=np.float64)).astype(np.int64)
    u = np.clip(uv[:, 0], 0, shape[1] - 1)
    v = np.clip(uv[:, 1], 0, shape[0] - 1)
    return mask[v, u]


# ---------------------------------------------------------------------------------------------------- factory
def check_detector(spec: str) -> str:
    """:func:`detector_kind` of ``spec``, having opened an ONNX model to check that it can be used (an InputError
    if not): a run checks its detector before it writes anything."""
    kind = detector_kind(spec)
    if kind == "onnx":
        OnnxDetector(str(spec).strip(), threads=1)
    return kind


def make_detector(spec: str = "background", *, camera: Camera | None = None, surface: Surface | None = None,
                  roi: np.ndarray | None = None, scale: float = 0.5, warmup_s: float = WARMUP_S,
                  learning_rate: float | None = None, rules: SizeRules | None = None, conf: float = 0.3,
                  iou: float = 0.5, input_size: int = 640, class_map: Mapping[int, str] | None = None) -> Detector:
    """A detector from a short spec (:func:`detector_kind`): a background subtraction name
    (:class:`BackgroundDetector` with MOG2 for "background", "bg" or "mog2", with KNN for "knn") or the path of a
    ``.onnx`` model (:class:`OnnxDetector`; ``camera`` and ``surface`` are not used, ``roi`` keeps detections
    whose bottom centre lies inside it). ``warmup_s``: the background detector's warm-up (s of video)."""
    kind = detector_kind(spec)
    if kind == "onnx":
        return OnnxDetector(str(spec).strip(), input_size=input_size, conf=conf, iou=iou, class_map=class_map,
                            roi=roi)
    return BackgroundDetector(method=kind, scale=scale, warmup_s=warmup_s, learning_rate=learning_rate,
                              camera=camera, surface=surface, roi=roi, rules=rules)
