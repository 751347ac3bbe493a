"""Hierarchical calibration from GCPs: starts -> robust fit -> outliers -> model choice -> final fit.

1. Starting cameras (:mod:`.initial`): DLT + RQ when the points are spread in 3D, a focal sweep with SQPnP always.
2. Robust fit of pose + focal from the best starts (soft-L1 by default), keeping the lowest robust cost.
3. Consensus: points within a threshold of the robust fit, or of a RANSAC pose (OpenCV ``solvePnPRansac`` on
   minimal sets, intrinsics from the robust fit), whichever explains more points.
4. Model choice on the consensus (unless the user fixed it): each distortion term the GCP count and image coverage
   can support is tried (started from the linear stage-3 estimate) and kept only if it lowers the leave-one-out
   RMSE by 5 %, is significant (> 2 sigma) and keeps the radial distortion monotonic over the frame.
5. Data snooping: the point with the largest externally studentized leave-one-out residual is removed while it
   fails an F(2, dof) test at 99.9 %; excluded points that fit the final camera are re-admitted.
6. Final plain least-squares (maximum-likelihood) fit on the inliers, exact leave-one-out and the report.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from scipy import stats

from trafficgeo.calibration.gcp_checks import validate_gcps
from trafficgeo.calibration.gcp_table import GCPTable
from trafficgeo.calibration.initial import initial_cameras
from trafficgeo.calibration.params import ParameterModel, focal_bounds, project_full
from trafficgeo.calibration.refine import (
    LOSSES,
    Fit,
    exact_loo_stats,
    fit_camera,
    leave_one_out,
    studentized_loo,
)
from trafficgeo.camera.calibrated import CalibratedCamera
from trafficgeo.camera.distortion import max_monotonic_radius
from trafficgeo.camera.model import Camera
from trafficgeo.camera.parameters import DIST_NAMES, full_to_camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import CalibrationError, InputError

EXACT_LOO_MAX_POINTS = 14
"""Up to this many points, outlier tests use exact leave-one-out refits (~1 ms each): with few points a blunder on a
high-leverage point pulls the fit onto itself and the linearized statistics cannot see it."""

RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))
"""Median of the length of a 2-D standard normal vector: turns a median pixel error into a per-axis sigma."""


@dataclass(frozen=True)
class CalibrationOptions:
    """What the calibration may estimate and how.

    Attributes:
        focal: "auto" (= "single"), "single" (square pixels), "separate" (fx, fy) or "fixed" (needs intrinsics).
        principal_point: "auto" (fixed at the image centre unless the data can separate it), "fixed" or "free".
        distortion: "auto" (chosen from the data), "none", or a tuple of terms to estimate, e.g. ("k1", "k2").
        focal_px: hold the focal length at this value (px), e.g. from the phone's specifications; the principal
            point stays at the image centre; distortion as ``distortion`` says.
        intrinsics: (K, dist) to start from; with ``fix_intrinsics`` they are held fixed (pre-calibrated phone).
        fix_intrinsics: hold ``intrinsics`` fixed and estimate only the pose.
        loss: robust loss of the outlier stage: "soft_l1", "huber", "cauchy" or "linear".
        loss_scale: the robust loss's scale in units of sigma_px.
        survey_sigma_m: standard deviation of the GCPs' world coordinates (orthophoto X, Y and point-cloud Z), in
            metres. Each point is weighted by its effective pixel sigma ``sqrt(sigma_px^2 + (f sigma_w / depth)^2)``:
            a few centimetres are a pixel or more on a point near the camera.
        confidence: confidence of the outlier tests (0.999: one inlier in a thousand is wrongly flagged).
        seed: RANSAC seed (results are deterministic).
    """

    focal: str = "auto"
    principal_point: str = "auto"
    distortion: str | tuple[str, ...] = "auto"
    focal_px: float | None = None
    intrinsics: tuple[np.ndarray, np.ndarray] | None = None
    fix_intrinsics: bool = False
    loss: str = "soft_l1"
    loss_scale: float = 3.0
    survey_sigma_m: float = 0.03
    confidence: float = 0.999
    ransac_iterations: int = 500
    seed: int = 0

    def __post_init__(self) -> None:
        if self.focal not in ("auto", "single", "separate", "fixed"):
            raise InputError(f"focal option '{self.focal}' is unknown; use auto, single, separate or fixed")
        if self.principal_point not in ("auto", "fixed", "free"):
            raise InputError(f"principal point option '{self.principal_point}' is unknown; use auto, fixed or free")
        if isinstance(self.distortion, str):
            if self.distortion not in ("auto", "none"):
                raise InputError(f"distortion option '{self.distortion}' is unknown; use auto, none or terms "
                                 "such as k1,k2")
        elif set(self.distortion) - set(DIST_NAMES):
            raise InputError(f"unknown distortion terms {sorted(set(self.distortion) - set(DIST_NAMES))}; "
                             "use any of k1,k2,p1,p2,k3")
        if self.loss not in LOSSES:
            raise InputError(f"loss '{self.loss}' is unknown; use one of {', '.join(LOSSES)}")
        if (self.fix_intrinsics or self.focal == "fixed") and self.intrinsics is None:
            raise InputError("fixed intrinsics need `intrinsics` (OpenCV YAML or a trafficgeo camera JSON)",
                             parameters=("intrinsics",))
        if self.focal_px is not None and not (np.isfinite(self.focal_px) and self.focal_px > 0):
            raise InputError(f"focal length {self.focal_px} px is not a positive number")
        if self.focal_px is not None and self.intrinsics is not None:
            raise InputError("give either focal_px or `intrinsics`, not both", parameters=("focal_px", "intrinsics"))
        if not (np.isfinite(self.survey_sigma_m) and self.survey_sigma_m >= 0):
            raise InputError(f"survey sigma {self.survey_sigma_m} m must be a number >= 0 (e.g. 0.03)")
        if not 0.5 < self.confidence < 1.0:
            raise InputError("confidence must lie between 0.5 and 1 (e.g. 0.999)")


@dataclass(frozen=True)
class Finding:
    """A GCP excluded from the fit, with the reason in words."""

    index: int
    id: str
    reason: str
    stage: str


@dataclass(frozen=True)
class Calibration:
    """The calibrated camera with everything needed to judge it.

    ``inlier`` marks the control points used in the final fit (check points and outliers are False);
    ``fit`` is the final least-squares fit on them about ``origin`` (local coordinates).
    """

    camera: Camera
    gcps: GCPTable
    inlier: np.ndarray
    fit: Fit
    origin: np.ndarray
    findings: tuple[Finding, ...]
    notes: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    loo_residuals_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    loo_fulls: np.ndarray = field(default_factory=lambda: np.zeros((0, 15)))
    sigma_eff_px: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def model(self) -> ParameterModel:
        return self.fit.model

    def calibrated_camera(self) -> CalibratedCamera:
        """The camera with what this calibration knows (GCPs and their residuals, statistics, covariance), as
        ``trafficgeo calibrate`` writes it to the camera JSON: a :class:`~trafficgeo.site.Site` built from it has
        the ``"plane"`` surface and calibration-aware speeds without a file."""
        from trafficgeo.calibration.camera_record import calibrated_camera

        return calibrated_camera(self)


# ------------------------------------------------------------------------------------------------ helpers


def _known_intrinsics(options: CalibrationOptions, image_size: tuple[int, int]
                      ) -> tuple[np.ndarray, np.ndarray] | None:
    if options.intrinsics is not None:
        K, dist = options.intrinsics
        return np.asarray(K, dtype=np.float64), np.asarray(dist, dtype=np.float64)
    if options.focal_px is not None:
        w, h = image_size
        f = float(options.focal_px)
        return np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]]), np.zeros(5)
    return None


def _base_model(options: CalibrationOptions) -> ParameterModel:
    if options.fix_intrinsics:
        return ParameterModel("fixed", False, ())
    if options.focal == "fixed" or options.focal_px is not None:
        return ParameterModel("fixed", options.principal_point == "free", ())
    focal = "single" if options.focal == "auto" else options.focal
    return ParameterModel(focal, options.principal_point == "free", ())


def effective_sigma(full: np.ndarray, loc: np.ndarray, sigma_px: np.ndarray, sigma_world: float) -> np.ndarray:
    """Pixel sigma (N,) including the survey error ``sigma_world`` (CRS units) seen at each point's depth."""
    R, _ = cv2.Rodrigues(full[0:3])
    depth = np.maximum(loc @ R[2] + full[5], 1e-9)
    f = 0.5 * (full[6] + full[7])
    return np.sqrt(sigma_px ** 2 + (f * sigma_world / depth) ** 2)


def _soft_l1_cost(resid_norm: np.ndarray, scale: float) -> float:
    z = np.sum(resid_norm ** 2, axis=1) / scale ** 2
    return float(np.sum(2.0 * (np.sqrt(1.0 + z) - 1.0)))


def _normalized(fit_full: np.ndarray, loc: np.ndarray, pix: np.ndarray, sig: np.ndarray) -> np.ndarray:
    uv, _ = project_full(fit_full, loc, jacobian=False)
    return (uv - pix) / sig[:, None]


def linear_distortion(full: np.ndarray, loc: np.ndarray, pix: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """Stage 3: distortion terms ``names`` by linear least squares, K and pose held (the model is linear in them)."""
    out = full.copy()
    if not names:
        return out
    R, _ = cv2.Rodrigues(full[0:3])
    xc = loc @ R.T + full[3:6]
    x = xc[:, 0] / xc[:, 2]
    y = xc[:, 1] / xc[:, 2]
    r2 = x * x + y * y
    fx, fy, cx, cy = full[6:10]
    xd = (pix[:, 0] - cx) / fx
    yd = (pix[:, 1] - cy) / fy
    cols = {"k1": (x * r2, y * r2), "k2": (x * r2 ** 2, y * r2 ** 2), "k3": (x * r2 ** 3, y * r2 ** 3),
            "p1": (2 * x * y, r2 + 2 * y * y), "p2": (r2 + 2 * x * x, 2 * x * y)}
    A = np.vstack([np.concatenate(cols[n]) for n in names]).T
    b = np.concatenate([xd - x, yd - y])
    coef = np.linalg.lstsq(A, b, rcond=None)[0]
    for n, c in zip(names, coef, strict=True):
        out[10 + DIST_NAMES.index(n)] = c
    return out


def _linear_loo_rmse(fit: Fit, sigma: np.ndarray) -> float:
    """Leave-one-out RMSE (px) from the hat matrix (exact for linear models, close near a converged fit)."""
    J = fit.jacobian
    JtJ_inv = np.linalg.pinv(J.T @ J)
    r = fit.residuals_px / sigma[:, None]
    out = []
    for i in range(r.shape[0]):
        Ji = J[2 * i:2 * i + 2]
        A = np.eye(2) - Ji @ JtJ_inv @ Ji.T
        try:
            out.append(np.linalg.solve(A, r[i]) * sigma[i])
        except np.linalg.LinAlgError:
            return float("inf")
    e = np.linalg.norm(np.array(out), axis=1)
    return float(np.sqrt(np.mean(e ** 2)))


def _max_image_radius(full: np.ndarray, image_size: tuple[int, int]) -> float:
    """Normalized radius of the frame corner farthest from the principal point."""
    w, h = image_size
    fx, fy, cx, cy = full[6:10]
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
    return float(np.max(np.hypot((corners[:, 0] - cx) / fx, (corners[:, 1] - cy) / fy)))


def _coverage_radius(full: np.ndarray, pix: np.ndarray, image_size: tuple[int, int]) -> float:
    """How far out the GCPs reach, as a fraction of the corner radius (distortion is observable only there)."""
    fx, fy, cx, cy = full[6:10]
    r = np.hypot((pix[:, 0] - cx) / fx, (pix[:, 1] - cy) / fy)
    return float(np.percentile(r, 90) / _max_image_radius(full, image_size))


@functools.lru_cache(maxsize=256)
def _f_critical(confidence: float, dof: int) -> float:
    return float(stats.f.ppf(confidence, 2, max(dof, 1)))


@functools.lru_cache(maxsize=256)
def _chi2_quantile(q: float, dof: int) -> float:
    return float(stats.chi2.ppf(q, dof))


# ------------------------------------------------------------------------------------------------ stages
def _robust_start(loc: np.ndarray, pix: np.ndarray, sig: np.ndarray, image_size: tuple[int, int],
                  options: CalibrationOptions, model: ParameterModel) -> tuple[Fit, dict[str, Any]]:
    known = _known_intrinsics(options, image_size)
    known_K, known_dist = known if known is not None else (None, None)
    starts, notes = initial_cameras(loc, pix, image_size, scale_px=options.loss_scale * float(np.median(sig)),
                                    known_K=known_K, known_dist=known_dist)
    if not starts:
        raise CalibrationError("no starting camera puts all GCPs in front of it: check that pixel and world "
                               "coordinates belong to the same points and the image size is right")
    best: Fit | None = None
    best_cost = np.inf
    tried = []
    distinct: list = []
    for start in starts:
        # Starts that agree on the focal length (1 %) and the camera centre converge to the same camera.
        if all(abs(start.full[6] - d.full[6]) > 0.01 * d.full[6] for d in distinct):
            distinct.append(start)
    for start in distinct[:3]:
        fit = fit_camera(loc, pix, sig, start.full, model, loss=options.loss, f_scale=options.loss_scale,
                         focal_bounds=focal_bounds(image_size))
        cost = _soft_l1_cost(fit.residuals_px / sig[:, None], options.loss_scale) if fit.success else np.inf
        tried.append({"method": start.method, "focal_px": float(fit.full[6]), "robust_cost": cost})
        if cost < best_cost:
            best, best_cost = fit, cost
    notes["starts"] = tried
    if best is None or not np.isfinite(best_cost):
        raise CalibrationError("the robust fit did not converge from any start: the GCPs may be mismatched "
                               "(check ids, pixel order u,v and the image size)")
    return best, notes


def _consensus(fit: Fit, loc: np.ndarray, pix: np.ndarray, sig: np.ndarray, options: CalibrationOptions
               ) -> tuple[np.ndarray, float, str]:
    """Inlier mask of the larger consensus (robust fit vs RANSAC), its threshold (sigmas) and its source."""
    e = np.linalg.norm(fit.residuals_px / sig[:, None], axis=1)
    n = len(e)
    scale = max(float(np.median(e)) / RAYLEIGH_MEDIAN, 1.0)
    thr = float(np.sqrt(stats.chi2.ppf(options.confidence, 2))) * scale
    robust_mask = e < thr
    best_mask, source = robust_mask, "robust fit"
    if n >= 6:
        K = np.array([[fit.full[6], 0, fit.full[8]], [0, fit.full[7], fit.full[9]], [0, 0, 1.0]])
        dist = fit.full[10:15]
        cv2.setRNGSeed(options.seed)
        try:
            ok, rvec, tvec, idx = cv2.solvePnPRansac(
                loc.reshape(-1, 1, 3), pix.reshape(-1, 1, 2), K, dist,
                iterationsCount=options.ransac_iterations, reprojectionError=thr * float(np.median(sig)),
                confidence=0.999, flags=cv2.SOLVEPNP_SQPNP)
        except cv2.error:
            ok, idx = False, None
        if ok and idx is not None and len(idx) >= 4:
            ransac_mask = np.zeros(n, dtype=bool)
            ransac_mask[idx.ravel()] = True
            # Refit pose and intrinsics on the RANSAC inliers, then score every point against that camera.
            full = fit.full.copy()
            full[0:3], full[3:6] = rvec.ravel(), tvec.ravel()
            sub = fit_camera(loc[ransac_mask], pix[ransac_mask], sig[ransac_mask], full, fit.model,
                             focal_bounds=fit.focal_bounds)
            e_r = np.linalg.norm(_normalized(sub.full, loc, pix, sig), axis=1)
            ransac_mask = e_r < thr
            if ransac_mask.sum() > best_mask.sum():
                best_mask, source = ransac_mask, "RANSAC (SQPnP minimal sets)"
    # Tighten: refit on the consensus, re-estimate the noise from it, rescore every point; until stable.
    chi_thr = float(np.sqrt(stats.chi2.ppf(options.confidence, 2)))
    full = fit.full
    for _ in range(5):
        if best_mask.sum() < 4:
            break
        sub = fit_camera(loc[best_mask], pix[best_mask], sig[best_mask], full, fit.model,
                         focal_bounds=fit.focal_bounds)
        full = sub.full
        e_all = np.linalg.norm(_normalized(full, loc, pix, sig), axis=1)
        scale_in = max(float(np.sqrt(sub.variance_factor())), 1.0)
        thr = chi_thr * scale_in
        new_mask = e_all < thr
        if new_mask.sum() < 4 or np.array_equal(new_mask, best_mask):
            break
        best_mask = new_mask
    return best_mask, thr, source


def _choose_model(base: ParameterModel, fit: Fit, loc: np.ndarray, pix: np.ndarray, sig: np.ndarray,
                  image_size: tuple[int, int], options: CalibrationOptions,
                  n_control: int | None = None) -> tuple[Fit, ParameterModel]:
    """Pick the distortion terms (and principal point) the data support; returns the fit and its model.

    ``loc``/``pix``/``sig`` are the control points the consensus kept, chosen before data snooping and the
    readmission of excluded points, so their number can differ from the final fit's; ``n_control`` (all control
    points) lets the reasons say which count they mean.
    """
    n = loc.shape[0]
    n_control = n if n_control is None else n_control
    reasons: list[str] = []
    if options.fix_intrinsics:
        reasons.append("intrinsics fixed from the given file; only the pose is estimated")
        return fit, ParameterModel(base.focal, False, (), tuple(reasons))
    pp_free = base.principal_point_free
    if options.principal_point == "auto":
        reasons.append("principal point fixed at the image centre (phone and traffic cameras have it within a few "
                       "% of the centre; road GCPs cannot separate it from the camera's rotation)")
    elif options.principal_point == "fixed":
        reasons.append("principal point fixed at the image centre (option)")
    else:
        reasons.append("principal point estimated (option)")
    reasons.append({"single": "square pixels, zero skew", "separate": "fx and fy estimated (option)",
                    "fixed": f"focal length fixed at {fit.full[6]:.1f} px (option)"}[base.focal])

    if isinstance(options.distortion, tuple):
        model = ParameterModel(base.focal, pp_free, options.distortion)
        start = linear_distortion(fit.full, loc, pix, model.free_dist)
        fitted = fit_camera(loc, pix, sig, start, model, focal_bounds=fit.focal_bounds)
        reasons.append(f"distortion terms {', '.join(model.free_dist)} estimated (option)")
        return fitted, ParameterModel(model.focal, pp_free, model.free_dist, tuple(reasons))
    if options.distortion == "none":
        reasons.append("no distortion estimated (option)")
        return fit, ParameterModel(base.focal, pp_free, (), tuple(reasons))

    coverage = _coverage_radius(fit.full, pix, image_size)
    ladder = [("k1", 8, 0.45), ("k2", 14, 0.6)]
    current, current_loo = fit, _linear_loo_rmse(fit, sig)
    for term, min_points, min_cov in ladder:
        if n < min_points or coverage < min_cov:
            why = _too_few_points(n, n_control, min_points) if n < min_points else (
                f"GCPs reach {coverage:.0%} of the corner radius (needs {min_cov:.0%})")
            reasons.append(f"{term} not estimated: {why}")
            break
        terms = (*current.model.free_dist, term)
        model = ParameterModel(base.focal, pp_free, terms)
        cand = fit_camera(loc, pix, sig, linear_distortion(current.full, loc, pix, terms), model,
                          focal_bounds=fit.focal_bounds)
        if not cand.success:
            reasons.append(f"{term} not estimated: the fit with it did not converge")
            break
        cand_loo = _linear_loo_rmse(cand, sig)
        cov = cand.covariance()
        k = cand.full[10 + DIST_NAMES.index(term)]
        k_std = float(np.sqrt(max(cov[-1, -1], 0.0)))
        monotonic = max_monotonic_radius(cand.full[10:15]) >= _max_image_radius(cand.full, image_size)
        if cand_loo < 0.95 * current_loo and abs(k) > 2 * k_std and monotonic:
            reasons.append(f"{term} = {k:.4g} +/- {k_std:.2g} estimated: leave-one-out RMSE "
                           f"{current_loo:.2f} -> {cand_loo:.2f} px")
            current, current_loo = cand, cand_loo
        else:
            why = ("the radial distortion would fold back inside the frame" if not monotonic else
                   f"not significant ({k:.3g} +/- {k_std:.2g})" if abs(k) <= 2 * k_std else
                   f"leave-one-out RMSE {current_loo:.2f} -> {cand_loo:.2f} px is no real gain")
            reasons.append(f"{term} not estimated: {why}")
            break
    reasons.append("tangential terms p1, p2 and k3 not estimated (rarely supported by GCPs; use --distortion)")
    final_model = ParameterModel(current.model.focal, pp_free, current.model.free_dist, tuple(reasons))
    return current, final_model


def _too_few_points(n: int, n_control: int, min_points: int) -> str:
    """Why a distortion term was not tried: the count of control points the lens model was chosen on."""
    if n == n_control:
        return f"{n} control points (needs {min_points})"
    return (f"only {n} of the {n_control} control points agreed on one camera when the lens model was chosen "
            f"(needs {min_points}); points readmitted after that count in the final fit, not here")


def outlier_test(d2: float, s2: float, dof: int, confidence: float) -> tuple[float, float]:
    """(statistic, critical value) of the test on a squared normalized 2-D residual ``d2``.

    The stated sigmas are trusted (chi2(2) test, Baarda's data snooping) unless the remaining points show
    significantly more noise (variance factor ``s2`` above the 99 % quantile of chi2(dof) / dof): then the noise is
    estimated from them and the test is F(2, dof) (Pope's tau test).
    """
    if dof <= 0 or s2 <= _chi2_quantile(0.99, dof) / dof:
        return d2 / 2.0, _chi2_quantile(confidence, 2) / 2.0
    return d2 / 2.0 / s2, _f_critical(confidence, dof)


def _snoop(fit: Fit, loc: np.ndarray, pix: np.ndarray, sig: np.ndarray, mask: np.ndarray,
           options: CalibrationOptions) -> tuple[Fit, np.ndarray, list[tuple[int, float, float]]]:
    """Remove, one at a time, the worst point while it fails the leave-one-out test. Returns fit, mask, removals."""
    removed: list[tuple[int, float, float]] = []
    # Keep at least 4 points and a redundancy of 2 after the removal (the test needs dof > 0).
    while int(mask.sum()) - 1 >= 4 and 2 * (int(mask.sum()) - 1) - fit.model.n_free >= 2:
        idx = np.nonzero(mask)[0]
        if idx.size <= EXACT_LOO_MAX_POINTS:
            d2, s2_ext, dof = exact_loo_stats(loc[idx], pix[idx], sig[idx], fit)
        else:
            d2, s2_ext, dof = studentized_loo(fit, sig[idx])
        tests = [outlier_test(d2[k], s2_ext[k], dof, options.confidence) if np.isfinite(d2[k]) else (0.0, 1.0)
                 for k in range(idx.size)]
        ratio = np.array([t / c for t, c in tests])
        j = int(np.argmax(ratio))
        if ratio[j] <= 1.0:
            break
        removed.append((int(idx[j]), tests[j][0], tests[j][1]))
        mask = mask.copy()
        mask[idx[j]] = False
        fit = fit_camera(loc[mask], pix[mask], sig[mask], fit.full, fit.model, focal_bounds=fit.focal_bounds)
    return fit, mask, removed


def _readmit(fit: Fit, loc: np.ndarray, pix: np.ndarray, sig: np.ndarray, mask: np.ndarray,
             options: CalibrationOptions) -> np.ndarray:
    """Excluded points whose prediction residual passes the F test against the current fit come back."""
    out = np.nonzero(~mask)[0]
    if out.size == 0 or fit.redundancy <= 0:
        return mask
    uv, J = project_full(fit.full, loc[out])
    M = fit.model.matrix()
    cov_unit = np.linalg.pinv(fit.jacobian.T @ fit.jacobian)
    s2 = fit.variance_factor()
    new = mask.copy()
    for k, i in enumerate(out):
        r = (uv[k] - pix[i]) / sig[i]
        Ji = (J[2 * k:2 * k + 2] @ M) / sig[i]
        S = np.eye(2) + Ji @ cov_unit @ Ji.T
        stat, crit = outlier_test(float(r @ np.linalg.solve(S, r)), s2, fit.redundancy + 2, options.confidence)
        if stat <= crit:
            new[i] = True
    return new


# ------------------------------------------------------------------------------------------------ main entry
def required_points(options: CalibrationOptions) -> int:
    """Fewest control points for the chosen model: enough observations (2 per point) for its parameters."""
    model = _base_model(options)
    n_dist = len(options.distortion) if isinstance(options.distortion, tuple) else 0
    return max(4, int(np.ceil((model.n_free + n_dist) / 2.0)))


def calibrate(gcps: GCPTable, image_size: tuple[int, int], options: CalibrationOptions | None = None) -> Calibration:
    """Calibrate a camera (intrinsics, distortion, pose) from GCPs; see the module docstring for the stages.

    Raises:
        InputError: the GCPs cannot support a calibration (too few, degenerate, outside the image).
        CalibrationError: no convergent, physically valid camera was found.
    """
    options = options or CalibrationOptions()
    warnings = list(validate_gcps(gcps, image_size, min_control=required_points(options)))
    ctrl = np.nonzero(gcps.is_control)[0]
    origin = gcps.world[ctrl].mean(axis=0)
    loc_all = gcps.world - origin
    loc, pix, sig = loc_all[ctrl], gcps.pixels[ctrl], gcps.sigma_px[ctrl]
    base = _base_model(options)

    robust, notes = _robust_start(loc, pix, sig, image_size, options, base)
    m_per_unit = metres_per_unit(gcps.crs) if gcps.crs is not None else 1.0
    sig = effective_sigma(robust.full, loc, sig, options.survey_sigma_m / m_per_unit)
    robust = fit_camera(loc, pix, sig, robust.full, base, loss=options.loss, f_scale=options.loss_scale,
                        focal_bounds=robust.focal_bounds)
    sigma_eff = np.full(gcps.n, np.nan)
    sigma_eff[ctrl] = sig
    mask, thr, source = _consensus(robust, loc, pix, sig, options)
    notes.update({"consensus": source, "consensus_threshold_sigma": thr, "loss": options.loss})
    findings: list[Finding] = []
    for i in np.nonzero(~mask)[0]:
        findings.append(Finding(int(ctrl[i]), gcps.ids[ctrl[i]], "", "consensus"))
    if mask.sum() < required_points(options):
        raise CalibrationError(f"only {int(mask.sum())} of {len(ctrl)} control points agree on one camera (need "
                               f"{required_points(options)}): re-check the GCP pairs, most do not fit together")

    fit = fit_camera(loc[mask], pix[mask], sig[mask], robust.full, base, focal_bounds=robust.focal_bounds)
    fit, model = _choose_model(base, fit, loc[mask], pix[mask], sig[mask], image_size, options, len(ctrl))
    fit = dataclasses.replace(fit, model=model)

    fit, mask, removed = _snoop(fit, loc, pix, sig, mask, options)
    for i, stat, crit in removed:
        findings.append(Finding(int(ctrl[i]), gcps.ids[ctrl[i]], f"studentized leave-one-out test {stat:.1f} > "
                                f"{crit:.1f} (F(2, dof) at {options.confidence:.1%})", "data snooping"))
    readmitted = _readmit(fit, loc, pix, sig, mask, options)
    if readmitted.sum() > mask.sum():
        back = np.nonzero(readmitted & ~mask)[0]
        findings = [f for f in findings if f.index not in set(ctrl[back].tolist())]
        mask = readmitted
        notes["readmitted"] = [gcps.ids[ctrl[i]] for i in back]
    fit = fit_camera(loc[mask], pix[mask], sig[mask], fit.full, fit.model, focal_bounds=fit.focal_bounds)
    fit = dataclasses.replace(fit, model=model)

    rmse = float(np.sqrt(np.mean(np.sum(fit.residuals_px ** 2, axis=1))))
    diag = float(np.hypot(*image_size))
    if not fit.success or not np.isfinite(rmse) or rmse > 0.05 * diag or fit.full[6] <= 0:
        raise CalibrationError(f"the final fit did not converge to a usable camera (RMSE {rmse:.1f} px on a "
                               f"{diag:.0f} px diagonal): the GCPs do not describe one pinhole camera; check for "
                               "swapped ids or a wrong image size")
    loo_r, loo_fulls = leave_one_out(loc[mask], pix[mask], sig[mask], fit)
    camera = full_to_camera(fit.full, origin, image_size, _crs_text(gcps))
    inlier = np.zeros(gcps.n, dtype=bool)
    inlier[ctrl[mask]] = True
    return Calibration(camera=camera, gcps=gcps, inlier=inlier, fit=fit, origin=origin, findings=tuple(findings),
                       notes=notes, warnings=tuple(warnings), loo_residuals_px=loo_r, loo_fulls=loo_fulls,
                       sigma_eff_px=sigma_eff)


def _crs_text(gcps: GCPTable) -> str | None:
    crs = gcps.crs
    if crs is None:
        return None
    auth = crs.to_authority()
    return f"{auth[0]}:{auth[1]}" if auth else crs.to_wkt()
