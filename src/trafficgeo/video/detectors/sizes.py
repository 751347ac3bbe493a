"""Vehicle sizes on the ground, for the background detector's size filter and both detectors' size-based classes:
plausible sizes per class (:class:`SizeRules`), a box's ground size through a calibrated camera
(:func:`blob_ground_size` -> :class:`BlobSizes`, metres) and the class it fits (:func:`classify_sizes`). Pixels
follow :mod:`trafficgeo.video.detections`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from trafficgeo.errors import InputError
from trafficgeo.geo.surface import OK

if TYPE_CHECKING:
    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.mapping import Surface


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

    def length(self, height_m: ArrayLike) -> np.ndarray:
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


def broadside_heavy(sizes: BlobSizes, rules: SizeRules) -> np.ndarray:
    """(N,) bool: the blob's bottom edge is wider on the ground than the longest light vehicle of ``rules`` (the
    upper length of every class but "truck") and no longer than ``max_length_m``. Seen broadside, as at a junction,
    a vehicle's side is its box's bottom edge, so its width is its length: such a box is a truck or a bus, which
    :func:`classify_sizes` (judging the size along the line of sight) finds implausible. For a learned detector's
    boxes, which are one vehicle each; a background blob this wide may be vehicles merged side by side."""
    light = [spec[1] for name, spec in rules.classes.items() if name != "truck"]
    if not light:
        return np.zeros(sizes.width_m.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        return (sizes.width_m > max(light)) & (sizes.width_m <= rules.max_length_m)
