"""How far a calibration can be trusted: the validation report (paper section 2.4, and more).

Every number is computed from the saved camera (:attr:`Calibration.camera`), so re-projecting the GCPs through the
camera JSON gives exactly the reported residuals. Pixel errors are ``|projected - observed|``; ground errors are
horizontal distances, in metres, between a GCP's surveyed X, Y and the point where the ray of its observed pixel
meets the horizontal plane at its surveyed Z. Leave-one-out (LOO) errors come from refits without the point: they
are the honest error to expect for a new point. Check points are never used in the fit.
"""

from __future__ import annotations

from itertools import combinations
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np
from scipy import stats

from trafficgeo.calibration.params import focal_bounds
from trafficgeo.calibration.report import (
    REPORT_FORMAT,
    AnglesDeg,
    CalibrationReport,
    CameraSummary,
    CheckStats,
    Correlation,
    DistanceRatios,
    FitStart,
    FitStats,
    ModelSummary,
    Outlier,
    PairError,
    ParameterStd,
    PoseConsistency,
    Uncertainty,
)
from trafficgeo.camera.calibrated import CameraGCP
from trafficgeo.camera.model import Camera
from trafficgeo.camera.parameters import full_to_camera
from trafficgeo.crs import metres_per_unit

if TYPE_CHECKING:
    from trafficgeo.calibration.pipeline import Calibration

__all__ = ["REPORT_FORMAT", "build_report", "explain_outlier", "ground_points"]


def ground_points(camera: Camera, pixels: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Where the rays of ``pixels`` meet the horizontal planes at ``z`` (N, 3), NaN where they do not."""
    return camera.intersect_horizontal_plane(pixels, z)


def _angles(camera: Camera) -> np.ndarray:
    o = camera.orientation
    return np.array([o.heading_deg, o.tilt_deg, o.roll_deg])


def _wrap_deg(a: np.ndarray) -> np.ndarray:
    return (a + 180.0) % 360.0 - 180.0


def explain_outlier(camera: Camera, world: np.ndarray, pixel: np.ndarray, tol_px: float, m_per_unit: float) -> str:
    """A plain-words reason why one GCP does not fit ``camera``.

    If moving the point vertically makes it fit (to ``tol_px``), the elevation is blamed (a point-cloud Z from a
    tree, a vehicle or a kerb); otherwise the pixel residual is given with its size on the ground: from one
    observation a wrong click and a wrong orthophoto feature cannot be told apart.
    """
    proj = camera.project(world[None])[0]
    e = float(np.linalg.norm(proj - pixel))
    ray = camera.rays(pixel[None])[0]
    o = camera.position
    dxy = ray[:2]
    if np.all(np.isfinite(ray)) and dxy @ dxy > 1e-12:
        s = float((world[:2] - o[:2]) @ dxy / (dxy @ dxy))
        if s > 0:
            p = o + s * ray
            z_fit = p[2]
            e_z = float(np.linalg.norm(camera.project(np.array([[world[0], world[1], z_fit]]))[0] - pixel))
            dz_m = (world[2] - z_fit) * m_per_unit
            if e_z <= tol_px and abs(dz_m) >= 0.5:
                return (f"pixel residual {e:.0f} px; elevation inconsistent by {dz_m:+.1f} m (the pixel fits this "
                        f"X, Y at Z = {z_fit:.2f}: a point-cloud Z from a tree, vehicle or kerb?)")
    g = camera.intersect_horizontal_plane(pixel[None], world[2])[0]
    if np.all(np.isfinite(g)):
        d = float(np.hypot(*(g[:2] - world[:2]))) * m_per_unit
        return (f"pixel residual {e:.0f} px; on the ground the clicked pixel lies {d:.1f} m from the surveyed point "
                "(a wrong click in the frame or a wrong feature on the orthophoto)")
    return f"pixel residual {e:.0f} px; the clicked pixel's ray does not reach the point's elevation"


def _derived(full: np.ndarray, origin: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    cam = full_to_camera(full, origin, image_size, None)
    return np.concatenate([cam.position, _angles(cam), [cam.focal_px]])


def _uncertainty(cal: Calibration) -> Uncertainty:
    """Standard deviations of the free parameters and of position/orientation/focal, from the fit covariance."""
    fit = cal.fit
    cov = fit.covariance()
    names = fit.model.names
    M = fit.model.matrix()
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    size = cal.camera.image_size
    # Numeric Jacobian of position, angles and focal w.r.t. the free parameters.
    base = _derived(fit.full, cal.origin, size)
    G = np.zeros((base.size, len(names)))
    for k in range(len(names)):
        h = 1e-6 * max(1.0, abs(float(M[:, k] @ fit.full)))
        plus = _derived(fit.full + h * M[:, k], cal.origin, size)
        minus = _derived(fit.full - h * M[:, k], cal.origin, size)
        d = plus - minus
        d[3:6] = _wrap_deg(d[3:6])
        G[:, k] = d / (2 * h)
    cov_d = G @ cov @ G.T
    std_d = np.sqrt(np.clip(np.diag(cov_d), 0.0, None))
    corr = cov / np.outer(std, std).clip(1e-300)
    high = []
    for i, j in combinations(range(len(names)), 2):
        if abs(corr[i, j]) > 0.98 and (names[i] in ("f", "fx", "fy", "k1", "k2") or names[j] in ("f", "fx", "fy")):
            high.append(Correlation(names[i], names[j], float(corr[i, j])))
    m = metres_per_unit(cal.gcps.crs) if cal.gcps.crs is not None else 1.0
    params = {n: ParameterStd(float(M[:, k] @ fit.full) if n not in ("f",) else float(fit.full[6]), float(std[k]))
              for k, n in enumerate(names)}
    return Uncertainty(
        scaled_by_variance_factor=True,
        parameters=MappingProxyType(params),
        position_std_m=tuple((std_d[0:3] * m).tolist()),
        orientation_std_deg=AnglesDeg(float(std_d[3]), float(std_d[4]), float(std_d[5])),
        focal_std_px=float(std_d[6]),
        high_correlations=tuple(high),
    )


def _pose_consistency(cal: Calibration) -> PoseConsistency:
    """Jackknife spread of the camera position and angles over the leave-one-out refits."""
    fulls = cal.loo_fulls
    ok = np.all(np.isfinite(fulls), axis=1) if fulls.size else np.zeros(0, dtype=bool)
    if ok.sum() < 3:
        return PoseConsistency("leave-one-out refits", int(ok.sum()), False)
    size = cal.camera.image_size
    cams = [full_to_camera(f, cal.origin, size, None) for f in fulls[ok]]
    pos = np.array([c.position for c in cams])
    ang = np.array([_angles(c) for c in cams])
    ang_dev = _wrap_deg(ang - _angles(cal.camera))
    n = len(cams)
    m = metres_per_unit(cal.gcps.crs) if cal.gcps.crs is not None else 1.0
    jack_pos = np.sqrt((n - 1) / n * np.sum((pos - pos.mean(0)) ** 2, axis=0)) * m
    jack_ang = np.sqrt((n - 1) / n * np.sum((ang_dev - ang_dev.mean(0)) ** 2, axis=0))
    max_dev = np.linalg.norm(pos - cal.camera.position, axis=1) * m
    focal = np.array([c.focal_px for c in cams])
    return PoseConsistency(
        method="leave-one-out refits (jackknife)",
        n_fits=n,
        available=True,
        position_spread_m=tuple(jack_pos.tolist()),
        max_position_deviation_m=float(max_dev.max()),
        most_influential_gcp=cal.gcps.ids[int(np.nonzero(cal.inlier)[0][np.nonzero(ok)[0][int(max_dev.argmax())]])],
        angle_spread_deg=AnglesDeg(float(jack_ang[0]), float(jack_ang[1]), float(jack_ang[2])),
        focal_spread_px=float(np.sqrt((n - 1) / n * np.sum((focal - focal.mean()) ** 2))),
    )


def _distance_ratios(camera: Camera, world: np.ndarray, pixels: np.ndarray, ids: list[str]) -> DistanceRatios:
    """Paper eq. 15 over all pairs: |d_world - d_image| / d_world, with image points back-projected to their Z."""
    n = len(ids)
    if n < 2:
        return DistanceRatios(0)
    g = ground_points(camera, pixels, world[:, 2])
    i, j = np.triu_indices(n, 1)
    d_world = np.linalg.norm(world[i] - world[j], axis=1)
    d_image = np.linalg.norm(g[i] - g[j], axis=1)
    keep = (d_world > 1e-6) & np.isfinite(d_image)
    pct = np.abs(d_world[keep] - d_image[keep]) / d_world[keep] * 100.0
    if pct.size == 0:
        return DistanceRatios(0)
    order = np.argsort(pct)[::-1][:5]
    ii, jj = i[keep], j[keep]
    return DistanceRatios(
        n_pairs=int(pct.size),
        mean_pct=float(pct.mean()),
        median_pct=float(np.median(pct)),
        max_pct=float(pct.max()),
        worst_pairs=tuple(PairError(ids[ii[k]], ids[jj[k]], float(pct[k])) for k in order),
    )


def _grid_gaps(pixels: np.ndarray, image_size: tuple[int, int]) -> list[str]:
    """Names of the 3x3 image regions without any GCP."""
    w, h = image_size
    col = np.clip((pixels[:, 0] / w * 3).astype(int), 0, 2)
    row = np.clip((pixels[:, 1] / h * 3).astype(int), 0, 2)
    rows = ("top", "middle", "bottom")
    cols = ("left", "centre", "right")
    filled = {(r, c) for r, c in zip(row.tolist(), col.tolist(), strict=True)}
    return [f"{rows[r]}-{cols[c]}" if (r, c) != (1, 1) else "centre"
            for r in range(3) for c in range(3) if (r, c) not in filled]


def _rms(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a ** 2))) if a.size else float("nan")


def _max(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else float("nan")


def _median(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else float("nan")


def build_report(cal: Calibration) -> CalibrationReport:
    """The validation report of ``cal`` (:meth:`CalibrationReport.to_dict` gives the report.json document)."""
    cam = cal.camera
    g = cal.gcps
    m = metres_per_unit(g.crs) if g.crs is not None else 1.0
    proj = cam.project(g.world)
    resid = proj - g.pixels
    err = np.linalg.norm(resid, axis=1)
    ground = ground_points(cam, g.pixels, g.world[:, 2])
    ground_err = np.hypot(*(ground[:, :2] - g.world[:, :2]).T) * m
    inl = np.nonzero(cal.inlier)[0]
    loo_err = err.copy()  # points not in the fit: their residual already is a prediction error
    loo_ground = ground_err.copy()
    if cal.loo_residuals_px.shape[0] == inl.size and inl.size:
        loo_err[inl] = np.linalg.norm(cal.loo_residuals_px, axis=1)
        for k, i in enumerate(inl):
            if np.all(np.isfinite(cal.loo_fulls[k])):
                c_i = full_to_camera(cal.loo_fulls[k], cal.origin, cam.image_size, None)
                p = c_i.intersect_horizontal_plane(g.pixels[i:i + 1], g.world[i, 2])[0]
                loo_ground[i] = float(np.hypot(*(p[:2] - g.world[i, :2]))) * m
            else:
                loo_ground[i] = np.nan
    reasons: dict[int, str] = {}
    sigma = float(np.median(g.sigma_px))
    tol = max(3.0 * np.sqrt(max(cal.fit.variance_factor(), 1.0)) * sigma, 2.0)
    for f in cal.findings:
        reasons[f.index] = explain_outlier(cam, g.world[f.index], g.pixels[f.index], tol, m)
    check = np.nonzero(g.is_check)[0]
    ctrl_out = np.nonzero(g.is_control & ~cal.inlier)[0]

    rows = []
    for i in range(g.n):
        rows.append(CameraGCP(
            id=g.ids[i], role=g.roles[i], x=float(g.world[i, 0]), y=float(g.world[i, 1]), z=float(g.world[i, 2]),
            u=float(g.pixels[i, 0]), v=float(g.pixels[i, 1]), u_proj=float(proj[i, 0]), v_proj=float(proj[i, 1]),
            error_px=float(err[i]), inlier=bool(cal.inlier[i]), loo_error_px=float(loo_err[i]),
            sigma_px=float(g.sigma_px[i]), ground_error_m=float(ground_err[i]),
            loo_ground_error_m=float(loo_ground[i]),
            sigma_eff_px=float(cal.sigma_eff_px[i]) if cal.sigma_eff_px.size else float("nan"),
            reason=reasons.get(i, ""),
        ))

    e_in = err[inl]
    fit = cal.fit
    sigma0 = float(np.sqrt(fit.variance_factor()))
    fit_stats = FitStats(
        n_control=int(g.is_control.sum()), n_check=int(check.size), n_inliers=int(inl.size),
        n_outliers=int(ctrl_out.size),
        mean_px=float(e_in.mean()), rmse_px=float(np.sqrt(np.mean(e_in ** 2))), max_px=float(e_in.max()),
        std_px=float(e_in.std()),
        loo_rmse_px=_rms(loo_err[inl]),
        loo_ground_rmse_m=_rms(loo_ground[inl]),
        loo_ground_median_m=_median(loo_ground[inl]),
        ground_rmse_m=_rms(ground_err[inl]),
        redundancy=int(fit.redundancy), n_parameters=int(fit.model.n_free),
        sigma0=sigma0,
    )
    check_stats = CheckStats(int(check.size))
    if check.size:
        check_stats = CheckStats(
            n=int(check.size), rmse_px=float(np.sqrt(np.mean(err[check] ** 2))), mean_px=float(err[check].mean()),
            max_px=float(err[check].max()),
            ground_rmse_m=_rms(ground_err[check]),
            ground_max_m=_max(ground_err[check]),
        )

    unc = _uncertainty(cal)
    pose = _pose_consistency(cal)
    ids_in = [g.ids[i] for i in inl]
    ratios = _distance_ratios(cam, g.world[inl], g.pixels[inl], ids_in)
    if check.size >= 2:
        ratios_check = _distance_ratios(cam, g.world[check], g.pixels[check], [g.ids[i] for i in check])
    else:
        ratios_check = DistanceRatios(0)

    warnings = list(cal.warnings)
    recs: list[str] = []
    f = cam.focal_px
    lo, hi = focal_bounds(cam.image_size)
    f_rel = unc.focal_std_px / f if f > 0 else np.inf
    if fit.model.focal != "fixed" and (f_rel > 0.1 or f <= lo * 1.001 or f >= hi * 0.999):
        warnings.append(f"focal length poorly determined: {f:.0f} +/- {unc.focal_std_px:.0f} px "
                        f"({f_rel:.0%}): the GCPs cannot separate the focal length from the camera distance")
        recs.append("Fix the focal length (--focal-px from the camera's specifications, or --intrinsics from a "
                    "chessboard calibration), or add GCPs off the road plane (pole tops, building corners) and far "
                    "from the camera.")
    o = cam.orientation
    if abs(o.roll_deg) > 60 or o.tilt_deg < -30:
        warnings.append(f"implausible pose: roll {o.roll_deg:.0f} deg, tilt {o.tilt_deg:.0f} deg (an upright camera "
                        "looking at the road has roll near 0 and tilt above 0): the GCPs are likely inconsistent "
                        "(mismatched pairs, mirrored coordinates or wrong image size)")
    if fit.redundancy > 0:
        p_chi2 = float(stats.chi2.sf(fit.chi2, fit.redundancy))
        if sigma0 > 2.0 and p_chi2 < 0.001:
            warnings.append(f"residuals (RMSE {fit_stats.rmse_px:.1f} px) are {sigma0:.1f}x the expected noise "
                            f"(pixel sigma {sigma:.1f} px with the survey sigma): these GCPs do not fit one pinhole "
                            f"camera with {fit.model.describe()}")
            recs.append("Re-check the GCP pairs with the largest leave-one-out errors; if all are right, the stated "
                        "sigma_px is too small or the lens needs distortion terms (more GCPs near the frame edges).")
    if fit.redundancy < 4:
        warnings.append(f"little redundancy: {fit.redundancy} observations beyond the {fit.model.n_free} parameters; "
                        "errors cannot be detected reliably")
        recs.append(f"Add GCPs: with {int(np.ceil((8 - fit.redundancy) / 2))} more, single bad points become "
                    "detectable.")
    for hc in unc.high_correlations:
        warnings.append(f"parameters {hc.a} and {hc.b} are {abs(hc.correlation):.3f} correlated")
    for i in ctrl_out:
        recs.append(f"Re-measure GCP {g.ids[i]} (excluded): {reasons.get(int(i), '')}.")
    if inl.size >= 5 and np.isfinite(loo_err[inl]).sum() >= 5:
        med = _median(loo_err[inl])
        worst = inl[int(np.nanargmax(loo_err[inl]))]
        if loo_err[worst] > max(3 * med, 3 * sigma):
            recs.append(f"Verify GCP {g.ids[worst]}: its leave-one-out error {loo_err[worst]:.1f} px is "
                        f"{loo_err[worst] / med:.1f}x the median.")
    gaps = _grid_gaps(g.pixels[inl], cam.image_size)
    if gaps:
        recs.append("Add GCPs in the " + ", ".join(gaps) + " part(s) of the frame (if road is visible there): "
                    "positions there are extrapolated.")
    if not recs:
        recs.append("No action needed: the GCPs agree with one camera to the stated pixel noise.")
    if not np.isfinite(fit_stats.loo_rmse_px):
        summary = (f"Fit RMSE {fit_stats.rmse_px:.1f} px; leave-one-out errors are not available (too few points "
                   "to refit without each one), so the accuracy for a new point is unknown: add GCPs.")
    else:
        summary = (f"Expect about {fit_stats.loo_rmse_px:.1f} px for a new point (leave-one-out RMSE), typically "
                   f"{fit_stats.loo_ground_median_m:.2f} m on the ground within the GCPs' area (median "
                   "leave-one-out)")
    if check.size:
        summary = summary.rstrip(".") + f"; check points: {check_stats.ground_rmse_m:.2f} m RMS."
    elif not summary.endswith("."):
        summary += "."

    return CalibrationReport(
        summary=summary,
        image_size=(int(cam.image_size[0]), int(cam.image_size[1])),
        crs=cam.crs_text,
        metres_per_crs_unit=m,
        camera=CameraSummary(
            focal_px=f, fx=float(cam.K[0, 0]), fy=float(cam.K[1, 1]),
            principal_point=tuple(cam.principal_point), dist=tuple(cam.dist.tolist()),  # type: ignore[arg-type]
            fov_deg=tuple(cam.fov_deg()), position=tuple(cam.position.tolist()),  # type: ignore[arg-type]
            orientation=cam.orientation,
        ),
        model=_model_summary(cal),
        stats=fit_stats,
        check=check_stats,
        gcps=tuple(rows),
        distance_ratios=ratios,
        distance_ratios_check=ratios_check,
        uncertainty=unc,
        pose_consistency=pose,
        outliers=tuple(Outlier(g.ids[i], reasons.get(int(i), "")) for i in ctrl_out),
        warnings=tuple(warnings),
        recommendations=tuple(recs),
    )


def _model_summary(cal: Calibration) -> ModelSummary:
    """The model block of the report: the fit's model, and the notes the calibration made on the way."""
    model, notes = cal.fit.model, cal.notes
    routes, starts = notes.get("routes"), notes.get("starts")
    return ModelSummary(
        free_parameters=tuple(model.names), description=model.describe(), reasons=tuple(model.reasons),
        loss=notes.get("loss"), initialization=None if routes is None else tuple(routes),
        starts=None if starts is None else tuple(FitStart(s["method"], s["focal_px"], s["robust_cost"])
                                                 for s in starts),
        planarity_ratio=notes.get("planarity_ratio"), consensus=notes.get("consensus"),
    )
