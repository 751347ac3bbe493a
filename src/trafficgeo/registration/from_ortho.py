"""Calibrate a camera from the orthophoto alone: no clicks, only a map position of the camera's pole.

The search (:func:`calibrate_from_ortho`):

1. **Ground views.** For each candidate focal length and tilt (heading 0, roll 0, height :data:`VIEW_HEIGHT_M`),
   the frame is warped onto the ground plane: a bird's-eye view at ``resolution_m`` whose pixels hold what the frame
   shows of the ground (where a frame pixel covers at most a few view pixels). With the right focal and tilt the
   view *is* a map of the ground, up to a similarity: its rotation is the heading, its scale the height over
   :data:`VIEW_HEIGHT_M`, its shift the camera's position.
2. **Matching.** SIFT keypoints of each view are matched (Lowe's ratio test) to those of the orthophoto within
   ``radius_m`` of the given position (both contrast-equalised: an orthophoto flown at another time or season has
   another brightness), and the similarity is fitted by RANSAC among the hypotheses that put the camera within
   ``max_offset_m`` of the given position at a plausible height (the prior is tested before any inlier is counted,
   so a loose ratio test can be afforded). The candidates with the most agreeing matches go on, best first.
3. **Start.** The agreeing matches are correspondences (frame pixel; orthophoto X, Y with Z from the surface); the
   calibration pipeline (:func:`trafficgeo.calibration.calibrate`: robust start, consensus) fits a camera to them,
   no distortion yet.
4. **Registration.** From that camera the orthophoto is matched patch by patch to the frame and the camera re-fitted
   until it stops moving (:func:`trafficgeo.registration.refine.register`, as ``trafficgeo refine`` does); the
   re-fit chooses the distortion model from the hundreds of correspondences.
5. **Verdict.** The camera is refused (:class:`OrthoCalibration` ``accepted`` False, the reason in words) when no
   candidate had ``min_view_matches`` agreeing matches (no texture, another place, another season), when the camera
   found stands farther than ``max_offset_m`` from the given position, or when the registration does not end in
   one camera. Check points, never fitted, measure the ground error of an accepted camera.

Frame pixels follow the camera model ((0, 0) = centre of the top-left pixel); OpenCV's keypoint and warp
coordinates use the same convention, so no half-pixel shifts appear between the views and the frame.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from trafficgeo.calibration.gcp_table import ROLE_CONTROL, GCPTable
from trafficgeo.calibration.pipeline import Calibration, CalibrationOptions, calibrate
from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import CalibrationError, InputError
from trafficgeo.geo.mapping import Surface
from trafficgeo.geo.raster import GeoRaster
from trafficgeo.registration.matching import Matches, OrthoPyramid, gray
from trafficgeo.registration.refine import Pass, RefineOptions, register

VIEW_HEIGHT_M = 10.0
"""Height (m) of the candidate cameras the ground views are made with; the match's scale gives the true height."""

MIN_HEIGHT_M, MAX_HEIGHT_M = 1.5, 300.0
"""Heights (m) of a camera above the ground a ground view's match may imply."""

SIFT_FEATURES = 30000  # at most this many keypoints per image
RATIO = 0.85  # Lowe's ratio test, loose: the position prior and RANSAC sort the rest

FOCAL_WIDTHS = (0.45, 0.57, 0.72, 0.9, 1.13, 1.42)
"""Candidate focal lengths as a multiple of the image width: horizontal fields of view of about 96 to 39 degrees."""


@dataclass(frozen=True)
class OrthoPoseOptions:
    """How the camera is searched for (metres, degrees, pixels).

    Attributes:
        max_offset_m: the camera may stand at most this far (horizontally) from the given position.
        radius_m: the orthophoto is searched within this distance of the given position.
        resolutions_m: ground samplings of the ground views and of the orthophoto they are matched to; every one
            is swept (a low camera's grazing view keeps its texture only at the coarser one: a 6 m camera was
            found at 0.3 m and not at 0.15 m).
        view_distance_m: the ground views reach this far from a candidate camera at :data:`VIEW_HEIGHT_M`.
        tilts_deg: candidate tilts (below the horizon).
        focal_px: the focal length when known (px); otherwise :data:`FOCAL_WIDTHS` x the image width are tried.
        min_view_matches: fewer agreeing matches than this in the best ground view refuse the calibration.
        candidates: this many best ground views are tried in turn.
        max_rmse_px: a camera is accepted only when its registration converged and the correspondences it kept
            miss it by at most this (RMS, px): with no user's points to judge it, the correspondences must agree
            (on development worlds right cameras ended at 0.3-0.9 px, 1.5-1.6 px under the harshest lighting; a
            wrong start the passes dragged along ended unconverged at 2.3 px).
    """

    max_offset_m: float = 20.0
    radius_m: float = 150.0
    resolutions_m: tuple[float, ...] = (0.15, 0.3)
    view_distance_m: float = 90.0
    tilts_deg: tuple[float, ...] = tuple(float(t) for t in range(3, 61, 3))
    focal_px: float | None = None
    min_view_matches: int = 8
    candidates: int = 4
    max_rmse_px: float = 2.0
    refine: RefineOptions = field(default_factory=lambda: RefineOptions(search_px=40.0, max_iterations=6))

    def __post_init__(self) -> None:
        for name in ("max_offset_m", "radius_m", "view_distance_m", "max_rmse_px"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"{name} = {value} must be a positive number", parameters=(name,))
        if not self.resolutions_m or not all(np.isfinite(r) and 0 < r <= 5.0 for r in self.resolutions_m):
            raise InputError("resolutions_m must list ground samplings between 0 and 5 m",
                             parameters=("resolutions_m",))
        if self.focal_px is not None and not (np.isfinite(self.focal_px) and self.focal_px > 0):
            raise InputError(f"focal_px = {self.focal_px} must be a positive number of pixels",
                             parameters=("focal_px",))
        if not self.tilts_deg or not all(0.0 < t < 90.0 for t in self.tilts_deg):
            raise InputError("tilts_deg must list tilts between 0 and 90 degrees", parameters=("tilts_deg",))
        if self.min_view_matches < 6 or self.candidates < 1:
            raise InputError("min_view_matches must be at least 6 and candidates at least 1",
                             parameters=("min_view_matches", "candidates"))


@dataclass(frozen=True)
class ViewMatch:
    """One candidate ground view: its focal length (px), tilt (deg) and ground sampling (m), keypoints found in it,
    matches passing the ratio test, matches agreeing on one similarity, and the similarity's height (m) and camera
    position (X, Y)."""

    focal_px: float
    tilt_deg: float
    resolution_m: float
    keypoints: int
    matched: int
    agreeing: int
    height_m: float
    position: tuple[float, float]
    frame_pixels: np.ndarray = field(repr=False)  # (K, 2) the agreeing matches in the frame
    map_xy: np.ndarray = field(repr=False)  # (K, 2) and on the map


@dataclass(frozen=True)
class OrthoCalibration:
    """The outcome of :func:`calibrate_from_ortho`.

    Attributes:
        accepted: whether a camera was found that passed every test.
        reason: why, in words.
        calibration: the final fit on the automatic correspondences (None when refused before one existed).
        matches: the automatic correspondences of the last registration pass; ``kept`` (len(matches),) bool
            marks those the final fit kept.
        views: the ground views tried, most agreeing matches first.
        passes: the registration passes of the chosen candidate.
        offset_m: horizontal distance of the camera found from the given position (m; NaN without one).
        check_errors_m: (C,) ground errors at the check points (m), NaN where a ray misses; empty without checks.
    """

    accepted: bool
    reason: str
    calibration: Calibration | None
    matches: Matches
    kept: np.ndarray
    views: tuple[ViewMatch, ...]
    passes: tuple[Pass, ...]
    offset_m: float
    check_errors_m: np.ndarray

    @property
    def camera(self) -> Camera | None:
        """The camera found (None when refused)."""
        return self.calibration.camera if self.accepted and self.calibration is not None else None


# ------------------------------------------------------------------------------------------------ ground views
def _equalised(g: np.ndarray) -> np.ndarray:
    return cv2.createCLAHE(clipLimit=4.0, tileGridSize=(8, 8)).apply(np.clip(g, 0, 255).astype(np.uint8))


class _OrthoFeatures:
    """SIFT keypoints of the orthophoto within ``radius`` (CRS units) of ``centre``, resampled to ``res`` (CRS
    units per pixel), with a FLANN index over their descriptors."""

    def __init__(self, ortho: GeoRaster, centre: np.ndarray, radius: float, res: float, sift: cv2.SIFT,
                 max_offset: float) -> None:
        n = math.ceil(2.0 * radius / res)
        self.centre_px = np.array([radius / res - 0.5, radius / res - 0.5])  # ``centre`` in view pixels
        self.max_offset_px = max_offset / res
        self.left, self.top, self.res = float(centre[0] - radius), float(centre[1] + radius), res
        # view pixel (i, j) centre -> map (left + (j + 0.5) res, top - (i + 0.5) res) -> ortho pixel (corner conv.)
        c0, r0 = ortho.map_to_pixel(self.left + 0.5 * res, self.top - 0.5 * res)
        c1, r1 = ortho.map_to_pixel(self.left + 1.5 * res, self.top - 0.5 * res)
        c2, r2 = ortho.map_to_pixel(self.left + 0.5 * res, self.top - 1.5 * res)
        A = np.array([[c1 - c0, c2 - c0, c0 - 0.5], [r1 - r0, r2 - r0, r0 - 0.5]], dtype=np.float64)
        data = ortho.data
        g = gray(data[:3].transpose(1, 2, 0), bgr=False) if data.shape[0] >= 3 else data[0].astype(np.float32)
        valid = np.isfinite(g)
        if ortho.nodata is not None and np.isfinite(ortho.nodata):
            valid &= ~np.any(data == ortho.nodata, axis=0)
        g = np.where(valid, g, 0.0).astype(np.float32)
        scale = res / max(ortho.resolution)
        if scale > 1.5:  # a fine orthophoto: blur to the view's sampling first (no aliasing)
            g = cv2.GaussianBlur(g, (0, 0), 0.5 * scale)
        view = cv2.warpAffine(g, A, (n, n), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=0.0)
        mask = cv2.warpAffine(valid.astype(np.uint8) * 255, A, (n, n), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                              borderValue=0)
        mask = cv2.erode(mask, np.ones((9, 9), np.uint8))
        self.keypoints, self.descriptors = sift.detectAndCompute(_equalised(view), mask)
        self.matcher = None
        if self.descriptors is not None and len(self.keypoints) >= 8:
            self.matcher = cv2.FlannBasedMatcher(dict(algorithm=1, trees=4), dict(checks=64))
            self.matcher.add([self.descriptors])
            self.matcher.train()

    def to_map(self, pts: np.ndarray) -> np.ndarray:
        """(N, 2) view pixels (centre convention) -> map X, Y."""
        return np.column_stack([self.left + (pts[:, 0] + 0.5) * self.res, self.top - (pts[:, 1] + 0.5) * self.res])


def _ground_view(frame_gray: np.ndarray, focal_px: float, tilt_deg: float, res_m: float, reach_m: float,
                 image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frame warped onto the ground of a camera at (0, 0, VIEW_HEIGHT_M) looking north: (view, mask, Hb) where
    ``Hb`` maps view pixels (x, y, 1) to frame pixels; view pixel (j, i) is ground (-reach + j res, reach - i res)."""
    c = Camera.from_orientation(image_size, focal_px, (0.0, 0.0, VIEW_HEIGHT_M), 0.0, tilt_deg)
    ground_to_frame = c.K @ np.column_stack([c.R[:, 0], c.R[:, 1], -c.R @ c.position])
    n = math.ceil(2.0 * reach_m / res_m)
    view_to_ground = np.array([[res_m, 0.0, -reach_m], [0.0, -res_m, reach_m], [0.0, 0.0, 1.0]])
    Hb = ground_to_frame @ view_to_ground
    view = cv2.warpPerspective(frame_gray, Hb, (n, n), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    step = 4  # the mask on a coarse grid, then resized
    jj, ii = np.meshgrid(np.arange(0, n, step, dtype=np.float64), np.arange(0, n, step, dtype=np.float64))
    p = Hb @ np.stack([jj.ravel(), ii.ravel(), np.ones(jj.size)])
    w, h = image_size
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = p[0] / p[2], p[1] / p[2]
    x, y = -reach_m + res_m * jj.ravel(), reach_m - res_m * ii.ravel()
    d = np.hypot(x, y)
    # a frame pixel covers about d^2 / (f h) metres along the view: keep where that is at most 4 view pixels
    ok = (p[2] > 0) & (u >= 2) & (u <= w - 3) & (v >= 2) & (v <= h - 3) & (d * d / (focal_px * VIEW_HEIGHT_M)
                                                                            <= 4.0 * res_m)
    mask = cv2.resize(ok.reshape(jj.shape).astype(np.uint8) * 255, (n, n), interpolation=cv2.INTER_NEAREST)
    mask = cv2.erode(mask, np.ones((9, 9), np.uint8))
    return view, mask, Hb


def _similarity_ransac(src: np.ndarray, dst: np.ndarray, foot_src: np.ndarray, centre_dst: np.ndarray,
                       max_offset_px: float, threshold_px: float, hypotheses: int = 4000
                       ) -> tuple[complex, complex, np.ndarray] | None:
    """The similarity ``dst = a src + b`` (complex: rotation and scale in ``a``, shift in ``b``) that most matches
    agree with (within ``threshold_px``), among those that put the camera's foot ``foot_src`` within
    ``max_offset_px`` of ``centre_dst`` and imply a height in [MIN_HEIGHT_M, MAX_HEIGHT_M]: hypotheses from random
    pairs of matches (seeded: deterministic), the prior tested before any inlier is counted, the best refined by
    least squares on its inliers. None when no hypothesis has 6 inliers."""
    n = len(src)
    if n < 6:
        return None
    zs = src[:, 0] + 1j * src[:, 1]
    zd = dst[:, 0] + 1j * dst[:, 1]
    rng = np.random.default_rng(0)
    i, j = rng.integers(0, n, hypotheses), rng.integers(0, n, hypotheses)
    i, j = i[i != j], j[i != j]
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (zd[j] - zd[i]) / (zs[j] - zs[i])
    b = zd[i] - a * zs[i]
    foot = a * complex(*foot_src) + b
    ok = (np.isfinite(a) & (np.abs(a) * VIEW_HEIGHT_M >= MIN_HEIGHT_M) & (np.abs(a) * VIEW_HEIGHT_M <= MAX_HEIGHT_M)
          & (np.abs(foot - complex(*centre_dst)) <= max_offset_px))
    a, b = a[ok], b[ok]
    if a.size == 0:
        return None
    best_count, best = 0, None
    for k in range(0, a.size, 512):  # (hypotheses, matches) in blocks
        r = np.abs(a[k:k + 512, None] * zs[None, :] + b[k:k + 512, None] - zd[None, :]) < threshold_px
        counts = r.sum(axis=1)
        m = int(np.argmax(counts))
        if counts[m] > best_count:
            best_count, best = int(counts[m]), (a[k + m], b[k + m])
    if best is None or best_count < 6:
        return None
    inl = np.abs(best[0] * zs + best[1] - zd) < threshold_px
    for _ in range(2):  # least squares on the inliers, then their new set
        A = np.column_stack([zs[inl], np.ones(int(inl.sum()))])
        (a1, b1), *_ = np.linalg.lstsq(A, zd[inl], rcond=None)
        new = np.abs(a1 * zs + b1 - zd) < threshold_px
        if new.sum() < 6:
            break
        best, inl = (complex(a1), complex(b1)), new
    return best[0], best[1], inl


def _match_view(frame_gray: np.ndarray, focal_px: float, tilt_deg: float, res_m: float, ortho: _OrthoFeatures,
                sift: cv2.SIFT, options: OrthoPoseOptions, image_size: tuple[int, int],
                lock: threading.Lock) -> ViewMatch | None:
    view, mask, Hb = _ground_view(frame_gray, focal_px, tilt_deg, res_m, options.view_distance_m, image_size)
    if not mask.any():
        return None
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1  # SIFT on the ground's bounding box only
    kp, desc = sift.detectAndCompute(_equalised(view[r0:r1, c0:c1]), mask[r0:r1, c0:c1])
    if desc is None or len(kp) < 8 or ortho.matcher is None:
        return None
    with lock:
        pairs = ortho.matcher.knnMatch(desc, k=2)
    good = sorted((p[0] for p in pairs if len(p) == 2 and p[0].distance < RATIO * p[1].distance),
                  key=lambda m: m.distance)
    if len(good) < 6:
        return None
    src = np.float64([kp[m.queryIdx].pt for m in good]) + [c0, r0]
    dst = np.float64([ortho.keypoints[m.trainIdx].pt for m in good])
    # SIFT gives one keypoint per orientation at a spot, and two spots may match one: the closest match per spot
    keep = np.ones(len(src), dtype=bool)
    for pts in (src, dst):
        _, first = np.unique(np.round(pts / 0.5), axis=0, return_index=True)
        once = np.zeros(len(pts), dtype=bool)
        once[first] = True
        keep &= once
    src, dst = src[keep], dst[keep]
    n = view.shape[0]
    found = _similarity_ransac(src, dst, np.array([(n - 1) / 2.0, (n - 1) / 2.0]), ortho.centre_px,
                               ortho.max_offset_px, 3.0)
    if found is None:
        return None
    a, b, agree = found
    scale = abs(a)  # ortho view pixels per ground-view pixel
    foot = a * complex((n - 1) / 2.0, (n - 1) / 2.0) + b  # the candidate camera's foot, in the ortho view
    position = ortho.to_map(np.array([[foot.real, foot.imag]]))[0]
    fp = Hb @ np.column_stack([src[agree], np.ones(int(agree.sum()))]).T
    return ViewMatch(focal_px=focal_px, tilt_deg=tilt_deg, resolution_m=res_m, keypoints=len(kp), matched=len(src),
                     agreeing=int(agree.sum()), height_m=VIEW_HEIGHT_M * scale,
                     position=(float(position[0]), float(position[1])), frame_pixels=(fp[:2] / fp[2]).T,
                     map_xy=ortho.to_map(dst[agree]))


def search_views(frame_gray: np.ndarray, ortho: GeoRaster, near_xy: np.ndarray, image_size: tuple[int, int],
                 options: OrthoPoseOptions, m_per_unit: float = 1.0,
                 progress: Callable[[str], None] | None = None) -> list[ViewMatch]:
    """Every candidate ground view matched to the orthophoto around ``near_xy`` (steps 1-2 of the module
    docstring), most agreeing matches first."""
    w = image_size[0]
    focals = (options.focal_px,) if options.focal_px is not None else tuple(f * w for f in FOCAL_WIDTHS)
    views: list[ViewMatch] = []
    # OpenCV releases the GIL in SIFT: one view per core (each thread its own detector; the FLANN index is shared
    # read-only, its knnMatch is guarded by a lock as its thread safety is not documented)
    lock = threading.Lock()
    local = threading.local()
    for res_m in options.resolutions_m:
        features = _OrthoFeatures(ortho, np.asarray(near_xy, dtype=np.float64), options.radius_m / m_per_unit,
                                  res_m / m_per_unit, cv2.SIFT_create(nfeatures=SIFT_FEATURES),
                                  (options.max_offset_m + 5.0) / m_per_unit)
        if features.matcher is None:
            continue

        def one(f: float, t: float, res_m: float = res_m, features: _OrthoFeatures = features) -> ViewMatch | None:
            if not hasattr(local, "sift"):
                local.sift = cv2.SIFT_create(nfeatures=SIFT_FEATURES)
            return _match_view(frame_gray, f, t, res_m, features, local.sift, options, image_size, lock)

        with ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1))) as pool:
            for k, f in enumerate(focals):
                found = pool.map(lambda t, f=f: one(float(f), float(t)), options.tilts_deg)
                views.extend(v for v in found if v is not None)
                if progress is not None:
                    best = max((v.agreeing for v in views), default=0)
                    progress(f"ground views at {res_m:g} m: focal {k + 1} of {len(focals)} done, best {best} "
                             "agreeing matches")
    return sorted(views, key=lambda v: (-v.agreeing, v.resolution_m, v.focal_px, v.tilt_deg))


# ------------------------------------------------------------------------------------------------ the search
def _empty_gcps(crs: object) -> GCPTable:
    return GCPTable(ids=(), world=np.zeros((0, 3)), pixels=np.zeros((0, 2)), roles=(), sigma_px=np.zeros(0),
                    crs=crs, source="calibrate-ortho", lines=())


def _start(view: ViewMatch, surface: Surface, image_size: tuple[int, int], crs: object, focal_px: float | None
           ) -> Calibration:
    """A camera fitted to a ground view's agreeing matches (step 3)."""
    xy = view.map_xy
    z = np.asarray(surface.elevation(xy[:, 0], xy[:, 1]), dtype=np.float64)
    ok = np.isfinite(z)
    n = int(ok.sum())
    if n < 6:
        raise CalibrationError(f"only {n} of the view's matches lie on the surface")
    gcps = GCPTable(ids=tuple(f"view{k + 1:04d}" for k in range(n)), world=np.column_stack([xy[ok], z[ok]]),
                    pixels=view.frame_pixels[ok], roles=(ROLE_CONTROL,) * n, sigma_px=np.full(n, 2.0), crs=crs,
                    source="ground view matches", lines=(0,) * n)
    return calibrate(gcps, image_size, CalibrationOptions(distortion="none", focal_px=focal_px))


def _check_errors(camera: Camera, checks: GCPTable | None) -> np.ndarray:
    if checks is None or checks.n == 0:
        return np.zeros(0)
    m = metres_per_unit(checks.crs) if checks.crs is not None else 1.0
    g = camera.intersect_horizontal_plane(checks.pixels, checks.world[:, 2])
    return np.hypot(g[:, 0] - checks.world[:, 0], g[:, 1] - checks.world[:, 1]) * m


def calibrate_from_ortho(frame: np.ndarray, ortho: GeoRaster, surface: Surface, near_xy: tuple[float, float], *,
                         crs: object = None, checks: GCPTable | None = None,
                         options: OrthoPoseOptions | None = None,
                         progress: Callable[[str], None] | None = None) -> OrthoCalibration:
    """Find the camera that filmed ``frame`` from the orthophoto and the surface alone (see the module docstring).

    Args:
        frame: (H, W, 3) BGR uint8 or (H, W) grey: a frame without traffic (the temporal mode of a stretch of video).
        ortho: the orthophoto, in ``crs``.
        surface: the ground the orthophoto lies on (DEM, point cloud or plane), in ``crs``.
        near_xy: the camera's pole on the map (X, Y in ``crs``), within ``options.max_offset_m`` of the truth.
        crs: the working CRS (the orthophoto's when None).
        checks: GCPs used only as check points (never fitted): their ground error is measured.
        options: the search's ranges and thresholds; see :class:`OrthoPoseOptions`.
        progress: called with a line of text as the search goes on.
    """
    options = options or OrthoPoseOptions()
    a = np.asarray(frame)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)) or min(a.shape[:2]) < 64:
        raise InputError(f"frame of shape {a.shape} is not an image (H, W) or (H, W, 3) of at least 64 px",
                         parameters=("frame",))
    crs = crs if crs is not None else ortho.crs
    m = metres_per_unit(crs) if crs is not None else 1.0
    near = np.asarray(near_xy, dtype=np.float64).reshape(2)
    if not np.all(np.isfinite(near)):
        raise InputError(f"the camera position {tuple(near)} is not a pair of numbers", parameters=("near",))
    left, bottom, right, top = ortho.bounds
    r = options.radius_m / m
    if not (left - r < near[0] < right + r and bottom - r < near[1] < top + r):
        raise InputError(f"the camera position ({near[0]:.2f}, {near[1]:.2f}) is more than {options.radius_m:g} m "
                         f"from the orthophoto ({left:.1f}..{right:.1f}, {bottom:.1f}..{top:.1f}); give it in the "
                         "orthophoto's CRS", parameters=("near",))
    h, w = a.shape[:2]
    image_size = (w, h)
    fg = gray(a, bgr=True)
    views = search_views(fg, ortho, near, image_size, options, m, progress)
    none = Matches.empty()

    def refused(reason: str, cal: Calibration | None = None, passes: tuple[Pass, ...] = (),
                offset_m: float = math.nan, matches: Matches = none, kept: np.ndarray | None = None
                ) -> OrthoCalibration:
        return OrthoCalibration(False, reason, cal, matches, np.zeros(len(matches), bool) if kept is None else kept,
                                tuple(views), passes, offset_m, np.zeros(0))

    if not views or views[0].agreeing < options.min_view_matches:
        best = views[0].agreeing if views else 0
        return refused(f"the frame's ground matches the orthophoto in too few places ({best} agreeing matches in "
                       f"the best ground view, need {options.min_view_matches}): the orthophoto may show another "
                       "place or season, the frame too little ground texture, or the position is not the camera's")
    reasons = []
    pyramid: OrthoPyramid | None = None
    tried = [v for v in views if v.agreeing >= options.min_view_matches][:options.candidates]
    for k, view in enumerate(tried):
        label = (f"ground view {k + 1} (focal {view.focal_px:.0f} px, tilt {view.tilt_deg:g} deg, "
                 f"{view.resolution_m:g} m)")
        off = float(np.hypot(*(np.asarray(view.position) - near)) * m)
        if off > options.max_offset_m:
            reasons.append(f"{label} puts the camera {off:.0f} m from the given position")
            continue
        try:
            start = _start(view, surface, image_size, crs, options.focal_px)
        except (CalibrationError, InputError) as exc:
            reasons.append(f"{label}: no camera fits its {view.agreeing} matches ({exc})")
            continue
        if pyramid is None:
            pyramid = OrthoPyramid(_crop(ortho, near, options.radius_m / m + options.max_offset_m / m))
        ropts = options.refine
        if options.focal_px is not None:
            ropts = replace(ropts, calibration=CalibrationOptions(focal_px=options.focal_px))
        reg = register(start.camera, _empty_gcps(crs), np.zeros(0, bool), fg, pyramid, surface, ropts,
                       progress=progress)
        if reg.calibration is None:
            reasons.append(f"{label}: {reg.reason}")
            continue
        cam = reg.calibration.camera
        off = float(np.hypot(*(cam.position[:2] - near)) * m)
        if off > options.max_offset_m:
            return refused(f"the camera found stands {off:.1f} m from the given position (at most "
                           f"{options.max_offset_m:g} m allowed): the position may be wrong, or the orthophoto "
                           "matched another place", reg.calibration, reg.passes, off, reg.matches, reg.kept)
        kept = int(reg.kept.sum())
        last = reg.passes[-1]
        if reg.reason or not last.rmse_px <= options.max_rmse_px:
            why = reg.reason or f"RMSE {last.rmse_px:.2f} px"
            reasons.append(f"{label}: the registration did not settle on one camera ({why}; at most "
                           f"{options.max_rmse_px:g} px RMS after converging expected)")
            continue
        reason = (f"{kept} orthophoto matches agree on one camera (RMSE {last.rmse_px:.2f} px) from {label} with "
                  f"{view.agreeing} agreeing matches; camera {off:.1f} m from the given position, "
                  f"{cam.position[2] - float(surface.elevation([cam.position[0]], [cam.position[1]])[0]):.1f} "
                  f"units above the ground")
        return OrthoCalibration(True, reason, reg.calibration, reg.matches, reg.kept, tuple(views), reg.passes, off,
                                _check_errors(cam, checks))
    return refused("no ground view led to a camera: " + "; ".join(reasons))


def review_gcps(result: OrthoCalibration, n: int = 40) -> GCPTable:
    """``n`` of the correspondences the final fit kept, spread over the frame (farthest-point sampling from the
    strongest), as a GCP table (ids ``auto01``...; control points with their pixel sigma): a set a person can review
    in ``trafficgeo gcp-ui`` (drop or move a pair, see the camera change) without wading through hundreds."""
    from trafficgeo.registration.refine import match_sigma_px

    m = result.matches.select(result.kept) if len(result.kept) else result.matches
    if len(m) == 0:
        raise InputError("there are no automatic correspondences to review", parameters=("gcps_out",))
    chosen = [int(np.argmax(m.ncc))]
    d2 = np.full(len(m), np.inf)
    while len(chosen) < min(n, len(m)):
        d2 = np.minimum(d2, np.sum((m.pixels - m.pixels[chosen[-1]]) ** 2, axis=1))
        chosen.append(int(np.argmax(d2)))
    idx = np.asarray(chosen)
    crs = result.calibration.camera.crs if result.calibration is not None else None
    return GCPTable(ids=tuple(f"auto{k + 1:02d}" for k in range(len(idx))), world=m.world[idx], pixels=m.pixels[idx],
                    roles=(ROLE_CONTROL,) * len(idx), sigma_px=match_sigma_px(m, RefineOptions().match_sigma_px)[idx],
                    crs=crs, source="calibrate-ortho", lines=(0,) * len(idx))


def _crop(ortho: GeoRaster, centre: np.ndarray, radius: float) -> GeoRaster:
    left, bottom, right, top = ortho.bounds
    box = (max(left, centre[0] - radius), max(bottom, centre[1] - radius), min(right, centre[0] + radius),
           min(top, centre[1] + radius))
    return ortho.crop(box)


__all__ = ["FOCAL_WIDTHS", "VIEW_HEIGHT_M", "OrthoCalibration", "OrthoPoseOptions", "ViewMatch",
           "calibrate_from_ortho", "review_gcps", "search_views"]
