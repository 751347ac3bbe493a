"""The user's own points judge a camera: held-out ground errors at the GCPs, before and after a refinement.

A control point's error is its *leave-one-out* error: the camera refitted without it (same parameter model, warm
started from the camera, plain least squares, with any extra correspondences the camera was fitted to), then its
clicked pixel's ray meets the horizontal plane at its Z, and the distance to its surveyed X, Y is the error (metres,
whatever the CRS unit); the pixel error is the distance between the clicked pixel and the point's projection. A
check point was never fitted: its errors come from the camera itself. Both measure what a camera does at a point
it has not seen, so a camera from 8 clicks and one from 8 clicks plus 500 orthophoto matches are compared on equal
terms.

The errors include the clicks' own noise, and on the ground that noise is magnified where the camera looks along
the road: a click 7 px off on a pole top 83 m away is 22 m off on the ground. Ground errors of a handful of clicked
points are therefore dominated by their farthest clicks, whatever the camera; in pixels every click's noise weighs
the same. :attr:`HeldOutErrors.rmse_px` is the statistic a refinement is judged by, the ground errors are reported
beside it (measured on generated scenes: with 3 px clicks, a refined camera 50x closer to the truth on the ground
had a *larger* RMS ground error at the clicks, 7.2 m against 4.7 m, and a smaller pixel error, 4.4 px against 6.0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trafficgeo.calibration.gcp_table import GCPTable
from trafficgeo.calibration.params import ParameterModel
from trafficgeo.calibration.pipeline import effective_sigma
from trafficgeo.calibration.refine import fit_camera
from trafficgeo.camera.model import Camera
from trafficgeo.camera.parameters import camera_to_full, full_to_camera
from trafficgeo.crs import metres_per_unit


@dataclass(frozen=True)
class HeldOutErrors:
    """Per user point: ``ids``, ``roles`` ("control" or "check"), ``ground_error_m`` (N,) and ``pixel_error_px`` (N,),
    leave-one-out for control points, direct for check points (NaN where the ray misses the plane)."""

    ids: tuple[str, ...]
    roles: tuple[str, ...]
    ground_error_m: np.ndarray
    pixel_error_px: np.ndarray

    def _rms(self, values: np.ndarray, role: str | None) -> float:
        sel = np.array([role is None or r == role for r in self.roles], dtype=bool)
        e = values[sel]
        e = e[np.isfinite(e)]
        return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")

    @property
    def rmse_px(self) -> float:
        """RMS pixel error over all judged points (px): the statistic a refinement is judged by."""
        return self._rms(self.pixel_error_px, None)

    @property
    def rmse_m(self) -> float:
        """RMS ground error over all judged points (m)."""
        return self._rms(self.ground_error_m, None)

    @property
    def median_m(self) -> float:
        """Median ground error over all judged points (m)."""
        e = self.ground_error_m[np.isfinite(self.ground_error_m)]
        return float(np.median(e)) if e.size else float("nan")

    @property
    def check_rmse_m(self) -> float:
        """RMS ground error at the check points (m); NaN without check points."""
        return self._rms(self.ground_error_m, "check")

    @property
    def loo_rmse_m(self) -> float:
        """RMS leave-one-out ground error at the control points (m)."""
        return self._rms(self.ground_error_m, "control")

    @property
    def check_rmse_px(self) -> float:
        """RMS pixel error at the check points (px); NaN without check points."""
        return self._rms(self.pixel_error_px, "check")

    @property
    def loo_rmse_px(self) -> float:
        """RMS leave-one-out pixel error at the control points (px)."""
        return self._rms(self.pixel_error_px, "control")

    def to_dict(self) -> dict[str, object]:
        def num(v: float) -> float | None:
            return round(float(v), 4) if np.isfinite(v) else None

        return {"rmse_px": num(self.rmse_px), "check_rmse_px": num(self.check_rmse_px),
                "loo_rmse_px": num(self.loo_rmse_px), "rmse_m": num(self.rmse_m), "median_m": num(self.median_m),
                "check_rmse_m": num(self.check_rmse_m), "loo_rmse_m": num(self.loo_rmse_m),
                "points": [{"id": i, "role": r, "ground_error_m": num(g), "pixel_error_px": num(p)}
                           for i, r, g, p in zip(self.ids, self.roles, self.ground_error_m, self.pixel_error_px,
                                                 strict=True)]}


def worse_p_value(before: HeldOutErrors, after: HeldOutErrors) -> float:
    """One-sided p-value that ``after`` misses the user's points by more than ``before`` does: the Wilcoxon
    signed-rank test of the per-point differences of squared pixel errors (points judged in both; NaN with fewer
    than 5). Small: the second camera is worse at the clicks beyond what their noise explains."""
    from scipy.stats import wilcoxon

    b = dict(zip(before.ids, before.pixel_error_px, strict=True))
    d = np.array([a ** 2 - b[i] ** 2 for i, a in zip(after.ids, after.pixel_error_px, strict=True)
                  if i in b and np.isfinite(a) and np.isfinite(b[i])])
    if d.size < 5 or not np.any(d != 0):
        return float("nan")
    return float(wilcoxon(d, alternative="greater").pvalue)


def model_from_names(names: object) -> ParameterModel:
    """The parameter model whose free parameters are ``names`` (as a camera JSON's ``model.free_parameters``)."""
    free = {str(n) for n in (names or ())}
    focal = "separate" if {"fx", "fy"} & free else "single" if "f" in free else "fixed"
    return ParameterModel(focal=focal, principal_point_free=bool({"cx", "cy"} & free),
                          free_dist=tuple(n for n in ("k1", "k2", "p1", "p2", "k3") if n in free))


def _ground_error(camera: Camera, pixel: np.ndarray, world: np.ndarray, m_per_unit: float) -> tuple[float, float]:
    g = camera.intersect_horizontal_plane(pixel[None, :], world[2])[0]
    ground = float(np.hypot(*(g[:2] - world[:2])) * m_per_unit) if np.all(np.isfinite(g)) else float("nan")
    px = camera.project(world[None, :])[0]
    return ground, float(np.linalg.norm(px - pixel))


def held_out_errors(camera: Camera, gcps: GCPTable, model: ParameterModel, *, use: np.ndarray | None = None,
                    extra_world: np.ndarray | None = None, extra_pixels: np.ndarray | None = None,
                    extra_sigma_px: np.ndarray | None = None, survey_sigma_m: float = 0.03) -> HeldOutErrors:
    """Held-out ground errors of ``camera`` at the GCPs (see the module docstring).

    ``use`` (N,) bool marks the control points the camera was fitted to (default: all control points); only they
    are judged by leave-one-out and used in the refits, with the ``extra_*`` correspondences (world (M, 3), pixels
    (M, 2), sigma (M,)) the camera was also fitted to. The GCPs are weighted as the calibration weighs them: their
    pixel sigma with the survey error ``survey_sigma_m`` seen at their depth
    (:func:`trafficgeo.calibration.pipeline.effective_sigma`).
    """
    m = metres_per_unit(gcps.crs) if gcps.crs is not None else 1.0
    control = np.asarray(gcps.is_control, dtype=bool)
    use = control.copy() if use is None else (np.asarray(use, dtype=bool) & control)
    origin = gcps.world[use].mean(axis=0) if use.any() else camera.position.copy()
    start = camera_to_full(camera, origin)
    gcp_sigma = effective_sigma(start, gcps.world - origin, gcps.sigma_px, survey_sigma_m / m)
    ew = np.zeros((0, 3)) if extra_world is None else np.asarray(extra_world, dtype=np.float64)
    ep = np.zeros((0, 2)) if extra_pixels is None else np.asarray(extra_pixels, dtype=np.float64)
    es = np.ones(len(ew)) if extra_sigma_px is None else np.asarray(extra_sigma_px, dtype=np.float64)
    judged = np.flatnonzero(use | ~control)
    ground = np.full(len(judged), np.nan)
    pixel = np.full(len(judged), np.nan)
    for k, i in enumerate(judged):
        cam = camera
        if use[i]:
            rest = use.copy()
            rest[i] = False
            world = np.vstack([gcps.world[rest], ew]) - origin
            pix = np.vstack([gcps.pixels[rest], ep])
            sig = np.concatenate([gcp_sigma[rest], es])
            if 2 * len(world) - model.n_free < 1:
                continue
            fit = fit_camera(world, pix, sig, start, model)
            if not fit.success:
                continue
            cam = full_to_camera(fit.full, origin, camera.image_size, camera.crs)
        ground[k], pixel[k] = _ground_error(cam, gcps.pixels[i], gcps.world[i], m)
    return HeldOutErrors(ids=tuple(gcps.ids[i] for i in judged), roles=tuple(gcps.roles[i] for i in judged),
                         ground_error_m=ground, pixel_error_px=pixel)
