"""Refine a rough GCP calibration by registering the orthophoto to a video frame.

The loop (:func:`refine_camera`):

1. Match the orthophoto, seen through the current camera, to the frame (:mod:`.matching`): hundreds of automatic
   correspondences (world point on the surface, frame pixel), sub-pixel where the texture allows.
2. Re-fit the camera with the calibration pipeline (:func:`trafficgeo.calibration.calibrate`: robust start, consensus,
   model choice, data snooping) on the automatic correspondences plus the user's control points; vehicles, shadows,
   parked cars and repeated dashes that matched the wrong place fall out as outliers there.
3. Repeat with a search radius a quarter of the last (down to ``final_search_px``) until, at the smallest radius,
   the camera moves the matched points by less than ``converged_px``.

The user's own points then judge (:mod:`.judge`): the held-out error at their check points and the leave-one-out
error at their control points, before and after, in pixels (where every click's noise weighs the same) and on
the ground. The refined camera is kept only when it has at least ``min_matches`` consistent correspondences and
lowers the pixel error, or leaves it the same within the clicks' noise (:func:`_verdict` says why that is
needed); otherwise the original camera is kept and the reason given.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np
from scipy.spatial import cKDTree

from trafficgeo.calibration.gcp_table import ROLE_CHECK, ROLE_CONTROL, GCPTable
from trafficgeo.calibration.params import ParameterModel
from trafficgeo.calibration.pipeline import Calibration, CalibrationOptions, calibrate
from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import CalibrationError, InputError
from trafficgeo.geo.mapping import Surface, pixels_to_world
from trafficgeo.geo.raster import GeoRaster
from trafficgeo.registration.judge import HeldOutErrors, held_out_errors, worse_p_value
from trafficgeo.registration.matching import Matches, MatchSettings, OrthoPyramid, gray, match_orthophoto

AUTO_PREFIX = "ortho"  # ids of the automatic correspondences in the refit: ortho0001, ...


@dataclass(frozen=True)
class RefineOptions:
    """How far to search and when to stop.

    Attributes:
        search_px: search radius of the first pass (full-resolution pixels): how far the rough camera may be off.
        final_search_px: the smallest search radius of later passes.
        max_iterations: passes of match + re-fit at most.
        converged_px: stop when a re-fit moves the matched points by less than this (RMS, px).
        min_matches: fewer consistent automatic correspondences than this refuse the refinement.
        match_sigma_px: pixel standard deviation given to an automatic correspondence in the re-fit.
        patch_px, cell_px, min_ncc: see :class:`~trafficgeo.registration.matching.MatchSettings`; ``cell_px`` None
            is 40 px per 1920 px of frame width (about 700 spots on a 1080p road scene, as many at 4K).
        max_distance_m: the orthophoto is matched up to this distance from the camera (m on the ground).
        max_rmse_px: a re-fit at the final search radius whose kept matches miss it by more than this (RMS, px)
            means the matches do not describe one camera: refused.
        calibration: options of the re-fit (default: the pipeline's, model chosen from the data).
    """

    search_px: float = 60.0
    final_search_px: float = 4.0
    max_iterations: int = 5
    converged_px: float = 0.25
    min_matches: int = 30
    match_sigma_px: float = 0.5
    patch_px: int = 25
    cell_px: int | None = None
    min_ncc: float = 0.55
    max_distance_m: float = 300.0
    max_rmse_px: float = 3.0
    calibration: CalibrationOptions = field(default_factory=CalibrationOptions)

    def __post_init__(self) -> None:
        for name in ("search_px", "final_search_px", "converged_px", "match_sigma_px", "max_distance_m",
                     "max_rmse_px"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"{name} = {value} must be a positive number", parameters=(name,))
        for name, low in (("max_iterations", 1), ("min_matches", 6), ("cell_px", 8)):
            if getattr(self, name) is not None and int(getattr(self, name)) < low:
                raise InputError(f"{name} = {getattr(self, name)} must be at least {low}", parameters=(name,))
        if self.patch_px < 7 or self.patch_px % 2 == 0:
            raise InputError(f"patch_px = {self.patch_px} must be an odd number >= 7", parameters=("patch_px",))
        if not 0.0 < self.min_ncc < 1.0:
            raise InputError(f"min_ncc = {self.min_ncc} must lie between 0 and 1", parameters=("min_ncc",))


@dataclass(frozen=True)
class Pass:
    """One match + re-fit pass: the search radius (px), spots searched, matches found, matches the re-fit kept,
    their RMS reprojection error (px), and how far the re-fit moved the matched points (RMS px)."""

    search_px: float
    tried: int
    matched: int
    kept: int
    rmse_px: float
    moved_px: float


@dataclass(frozen=True)
class OrthoRefinement:
    """The outcome of :func:`refine_camera`.

    Attributes:
        camera: the camera to use: the refined one when ``accepted``, else the original.
        accepted: whether the refinement passed the user's points.
        reason: why, in words.
        original: the camera given.
        refined: the re-fitted camera (also when refused), or None when no re-fit was possible.
        calibration: the last re-fit (automatic correspondences first, then the user's points), or None.
        matches: the automatic correspondences of the last pass.
        kept: (len(matches),) bool, the correspondences the last re-fit kept.
        before, after: held-out ground errors at the user's points of the original and the refined camera.
        passes: the passes run.
    """

    camera: Camera
    accepted: bool
    reason: str
    original: Camera
    refined: Camera | None
    calibration: Calibration | None
    matches: Matches
    kept: np.ndarray
    before: HeldOutErrors
    after: HeldOutErrors | None
    passes: tuple[Pass, ...]

    @property
    def n_kept(self) -> int:
        """Automatic correspondences kept by the last re-fit."""
        return int(np.count_nonzero(self.kept))


def _dedupe(m: Matches, user_pixels: np.ndarray) -> Matches:
    """Drop automatic matches closer than 1 px to another (the weaker) or to a user's GCP pixel."""
    if len(m) == 0:
        return m
    order = np.argsort(-m.ncc, kind="stable")
    keep = np.ones(len(m), dtype=bool)
    tree = cKDTree(m.pixels)
    for i in order:
        if not keep[i]:
            continue
        for j in tree.query_ball_point(m.pixels[i], 1.0):
            if j != i:
                keep[j] = False
    if len(user_pixels):
        d, _ = cKDTree(user_pixels).query(m.pixels)
        keep &= d > 1.0
    return m.select(keep)


def match_sigma_px(m: Matches, sigma_px: float) -> np.ndarray:
    """Pixel sigma of each automatic correspondence: ``sigma_px`` for a round peak (roundness >= 0.25), up to 3.5 x
    for an edge-like one, whose position along the edge is loose (measured on generated scenes: the error along
    the weak direction grows about as 1 / sqrt(roundness))."""
    return sigma_px / np.sqrt(np.clip(m.roundness / 0.25, 0.08, 1.0))


def _combined(gcps: GCPTable, m: Matches, use: np.ndarray, sigma_px: float) -> GCPTable:
    """The automatic correspondences (control) followed by the user's points: control points the original fit used
    stay control, check points stay check; control points it rejected are left out."""
    keep_user = use | ~np.asarray(gcps.is_control, dtype=bool)
    n = len(m)
    ids = tuple(f"{AUTO_PREFIX}{k + 1:04d}" for k in range(n)) + tuple(np.asarray(gcps.ids, dtype=object)[keep_user])
    roles = (ROLE_CONTROL,) * n + tuple(ROLE_CHECK if r == ROLE_CHECK else ROLE_CONTROL
                                        for r in np.asarray(gcps.roles, dtype=object)[keep_user])
    return GCPTable(ids=ids, world=np.vstack([m.world, gcps.world[keep_user]]),
                    pixels=np.vstack([m.pixels, gcps.pixels[keep_user]]), roles=roles,
                    sigma_px=np.concatenate([match_sigma_px(m, sigma_px), gcps.sigma_px[keep_user]]), crs=gcps.crs,
                    source="automatic orthophoto correspondences and the user's GCPs", lines=(0,) * len(ids))


def _moved_px(a: Camera, b: Camera, world: np.ndarray) -> float:
    if len(world) == 0:
        return float("inf")
    d = np.linalg.norm(a.project(world) - b.project(world), axis=1)
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d ** 2))) if d.size else float("inf")


def _seen_part(ortho: GeoRaster, camera: Camera, surface: Surface, search_px: float, max_distance_m: float
               ) -> GeoRaster:
    """The part of the orthophoto the camera can see within ``max_distance_m`` (with room for the camera being
    ``search_px`` off): orthophotos cover whole districts, the matching needs a few hectares of them."""
    w, h = camera.image_size
    u, v = np.meshgrid(np.linspace(0, w - 1, 64), np.linspace(0, h - 1, 36))
    g = pixels_to_world(camera, np.column_stack([u.ravel(), v.ravel()]), surface, min_incidence_deg=0.0,
                        with_lonlat=False)
    xy = g.xyz[:, :2]
    m = metres_per_unit(camera.crs) if camera.crs is not None else 1.0
    near = np.all(np.isfinite(xy), axis=1) & (np.hypot(*(xy - camera.position[:2]).T) * m <= max_distance_m)
    if not near.any():
        raise InputError(f"the camera sees no ground within {max_distance_m:g} m: check that the surface is in the "
                         "camera's CRS", parameters=("surface",))
    lo, hi = xy[near].min(axis=0), xy[near].max(axis=0)
    pad = (hi - lo).max() * (search_px / max(w, h)) + 20.0 / m
    try:
        return ortho.crop((lo[0] - pad, lo[1] - pad, hi[0] + pad, hi[1] + pad))
    except InputError:
        raise InputError("the orthophoto does not cover what the camera sees; give the orthophoto of this camera's "
                         "site, in its CRS", parameters=("ortho",)) from None


def _check_frame(frame: np.ndarray, camera: Camera) -> np.ndarray:
    a = np.asarray(frame)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (1, 3, 4)):
        raise InputError(f"frame of shape {a.shape} is not an image (H, W) or (H, W, 3)", parameters=("frame",))
    h, w = a.shape[:2]
    if (w, h) != tuple(camera.image_size):
        raise InputError(f"frame is {w}x{h} px but the camera is calibrated for {camera.width}x{camera.height}; "
                         "use a frame of the calibrated video", parameters=("frame",))
    return a


def _not_converged(passes: list[Pass], converged_px: float) -> str:
    """Why the passes did not settle: how far each moved the camera, and whether it was still creeping towards a
    camera (each pass moving it less: more passes may settle it) or swinging (the matches pull two ways)."""
    moved = [p.moved_px for p in passes]
    steps = ", ".join(f"{m:.2f}" for m in moved)
    tail = moved[-3:]
    creeping = all(b < a for a, b in pairwise(tail))
    why = ("each pass moved it less: it was still creeping towards a camera, more passes may settle it"
           if creeping else "it swung between passes: the matches pull two ways (repeated texture, or a shadow, a "
           "vehicle or a building that differs between the orthophoto and the video)")
    return (f"not converged after {len(passes)} passes: they moved the camera by {steps} px (converged below "
            f"{converged_px:g}); {why}")


@dataclass(frozen=True)
class Registration:
    """The outcome of :func:`register`: the last re-fit that passed (None when none did), the automatic
    correspondences of the last pass and which of them the re-fit kept, the passes run, and why it stopped early
    or failed ("" when it converged)."""

    calibration: Calibration | None
    matches: Matches
    kept: np.ndarray
    passes: tuple[Pass, ...]
    reason: str


def register(camera: Camera, gcps: GCPTable, use: np.ndarray, frame_gray: np.ndarray, pyramid: OrthoPyramid,
             surface: Surface, options: RefineOptions, *, progress: Callable[[str], None] | None = None
             ) -> Registration:
    """The passes of match + re-fit from ``camera`` (see the module docstring), with the control points of
    ``gcps`` marked in ``use`` fitted beside the automatic correspondences (``gcps`` may be empty)."""
    control = np.asarray(gcps.is_control, dtype=bool)
    passes: list[Pass] = []
    current, cal, matches = camera, None, Matches.empty()
    kept = np.zeros(0, dtype=bool)
    radius = options.search_px
    cell_px = options.cell_px or max(24, round(40 * camera.width / 1920))
    cal_rmse_px = float("nan")  # RMSE of the pass whose re-fit is ``cal``
    reason = ""
    for _ in range(options.max_iterations):
        settings = MatchSettings(scale=1.0, search_px=radius, patch_px=options.patch_px, cell_px=cell_px,
                                 min_ncc=options.min_ncc)
        found = _dedupe(match_orthophoto(current, surface, pyramid, frame_gray, settings), gcps.pixels[use | ~control])
        if len(found) < options.min_matches:
            reason = (f"only {len(found)} orthophoto patches matched the frame (need {options.min_matches}): the "
                      "orthophoto may show another place or season, or the camera is too far off")
            break
        try:
            fit = calibrate(_combined(gcps, found, use, options.match_sigma_px), camera.image_size,
                            options.calibration)
        except (CalibrationError, InputError) as exc:
            reason = f"the re-fit on {len(found)} orthophoto matches failed: {exc}"
            break
        n = len(found)
        fit_kept = fit.inlier[:n]
        res = np.linalg.norm(fit.camera.project(found.world[fit_kept]) - found.pixels[fit_kept], axis=1)
        moved = _moved_px(current, fit.camera, found.world)
        passes.append(Pass(search_px=radius, tried=found.tried, matched=n, kept=int(fit_kept.sum()),
                           rmse_px=float(np.sqrt(np.mean(res ** 2))) if res.size else float("nan"),
                           moved_px=moved))
        if progress is not None:
            p = passes[-1]
            progress(f"pass {len(passes)}: search {p.search_px:.0f} px, {p.matched} of {p.tried} patches matched, "
                     f"{p.kept} kept, RMSE {p.rmse_px:.2f} px, camera moved {p.moved_px:.2f} px")
        # A wide first search matches repeated texture to the wrong place; only a fine pass must agree.
        if radius <= options.final_search_px and not passes[-1].rmse_px <= options.max_rmse_px:
            reason = (f"the {passes[-1].kept} orthophoto matches kept do not agree on one camera (RMSE "
                      f"{passes[-1].rmse_px:.1f} px, at most {options.max_rmse_px:g} expected): the orthophoto may "
                      "show another place, or the camera is too far off")
            cal, matches, kept = None, found, fit_kept
            break
        current, cal, matches, kept, cal_rmse_px = fit.camera, fit, found, fit_kept, passes[-1].rmse_px
        if moved < options.converged_px and radius <= options.final_search_px:
            break
        if len(passes) == options.max_iterations:
            reason = _not_converged(passes, options.converged_px)
        radius = max(options.final_search_px, radius / 4.0)
    if cal is not None and not cal_rmse_px <= options.max_rmse_px:  # the loop ended before a fine pass
        reason = (f"the orthophoto matches of the last re-fit do not agree on one camera (RMSE {cal_rmse_px:.1f} "
                  f"px, at most {options.max_rmse_px:g} expected): the orthophoto may show another place, or the "
                  "camera is too far off")
        cal = None
    return Registration(calibration=cal, matches=matches, kept=kept, passes=tuple(passes), reason=reason)


def refine_camera(camera: Camera, gcps: GCPTable, frame: np.ndarray, ortho: GeoRaster, surface: Surface, *,
                  model: ParameterModel | None = None, use: np.ndarray | None = None,
                  options: RefineOptions | None = None,
                  progress: Callable[[str], None] | None = None) -> OrthoRefinement:
    """Refine ``camera`` (calibrated from ``gcps``) by registering ``ortho`` draped on ``surface`` to ``frame``.

    Args:
        camera: the rough camera, in the CRS of the orthophoto and the surface.
        gcps: the user's GCPs (control and check points) that calibrated it: the judges.
        frame: (H, W, 3) BGR uint8 (as OpenCV and :func:`trafficgeo.video.background_frame` give it) or (H, W)
            grey: a frame without traffic, e.g. the temporal mode of a stretch of video.
        ortho: the orthophoto (RGB or grey).
        surface: the ground the orthophoto lies on (DEM, point cloud or plane).
        model: the free parameters of the original calibration (for its leave-one-out errors); default one focal
            length, no distortion.
        use: (N,) bool, the control points the original calibration kept (default all).
        options: search radius, passes, thresholds; see :class:`RefineOptions`.
        progress: called with a line of text after each pass.
    """
    options = options or RefineOptions()
    frame = _check_frame(frame, camera)
    if gcps.crs is not None and camera.crs is not None and not gcps.crs.equals(camera.crs):
        raise InputError("the GCPs and the camera are in different CRSs; use the GCP file the camera was "
                         "calibrated from", parameters=("gcps",))
    model = model or ParameterModel()
    control = np.asarray(gcps.is_control, dtype=bool)
    use = control.copy() if use is None else np.asarray(use, dtype=bool) & control
    before = held_out_errors(camera, gcps, model, use=use)
    fg = gray(frame, bgr=True)
    pyramid = OrthoPyramid(_seen_part(ortho, camera, surface, options.search_px, options.max_distance_m))
    reg = register(camera, gcps, use, fg, pyramid, surface, options, progress=progress)
    cal, matches, kept, passes, reason = reg.calibration, reg.matches, reg.kept, reg.passes, reg.reason
    if cal is None:
        return OrthoRefinement(camera=camera, accepted=False, reason=reason or "no pass ran", original=camera,
                               refined=None, calibration=None, matches=matches, kept=kept, before=before,
                               after=None, passes=passes)
    after = held_out_errors(cal.camera, gcps, cal.fit.model, use=use, extra_world=matches.world[kept],
                            extra_pixels=matches.pixels[kept],
                            extra_sigma_px=match_sigma_px(matches, options.match_sigma_px)[kept])
    accepted, reason = _verdict(before, after, int(kept.sum()), options.min_matches, reason)
    return OrthoRefinement(camera=cal.camera if accepted else camera, accepted=accepted, reason=reason,
                           original=camera, refined=cal.camera, calibration=cal, matches=matches, kept=kept,
                           before=before, after=after, passes=tuple(passes))


WORSE_P = 0.05
"""A refined camera whose errors at the user's points are larger than the original's with a one-sided p-value
below this (:func:`~trafficgeo.registration.judge.worse_p_value`) is refused."""


def _verdict(before: HeldOutErrors, after: HeldOutErrors, kept: int, min_matches: int, why_stopped: str
             ) -> tuple[bool, str]:
    """Accept when enough correspondences survived and, at the user's points (held-out, in pixels: see
    :mod:`.judge`), the refined camera does better, or no worse than their clicks' noise can tell.

    A few clicks cannot always tell a good camera from a better one: where a rough camera is right at the clicks
    (its trouble is between and beyond them, e.g. 100 m down the road) both miss them by about the click noise.
    Requiring a strictly lower error there refused 2 of the first 9 worlds of ``benchmarks/bench_refine.py``
    whose refined camera was about 40x closer to the truth at 100 m (5.05 -> 5.06 px, 3.91 -> 4.00 px at the clicks).
    So the refined camera is refused when it is *significantly worse* at the clicks (:data:`WORSE_P`), and the
    reason says which case it is."""
    if kept < min_matches:
        return False, (f"only {kept} orthophoto matches agree on one camera (need {min_matches}): the orthophoto "
                       "may show another place, or too little texture is visible")
    b, a = before.rmse_px, after.rmse_px
    what = "check and leave-one-out" if np.isfinite(before.check_rmse_px) else "leave-one-out"
    if not np.isfinite(a):
        return False, "the refined camera cannot project the user's points"
    ground = f"; on the ground {before.rmse_m:.3f} m -> {after.rmse_m:.3f} m RMS"
    stopped = f" (stopped: {why_stopped})" if why_stopped else ""
    errors = f"{what} error at the user's points {b:.2f} px -> {a:.2f} px{ground}"
    if not np.isfinite(b) or a < b:
        return True, f"{kept} orthophoto matches; {errors}{stopped}"
    p = worse_p_value(before, after)
    if not np.isfinite(p) or p < WORSE_P:
        why = "fewer than 5 points to tell" if not np.isfinite(p) else f"worse beyond their noise, p = {p:.3f}"
        return False, (f"the refined camera does not improve the {errors} ({why}): the orthophoto does not agree "
                       "with the GCPs")
    return True, (f"{kept} orthophoto matches; {errors}: no worse within the clicks' noise (signed-rank p = "
                  f"{p:.2f} for worse), the user's points cannot tell the two cameras apart{stopped}")
