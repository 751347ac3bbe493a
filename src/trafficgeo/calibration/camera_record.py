"""A calibration as the camera JSON records it: the camera, the GCPs with their residuals, the fit statistics, the
model, the uncertainty and the covariance of every parameter (:class:`~trafficgeo.camera.calibrated.CalibratedCamera`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from trafficgeo.calibration.params import ParameterModel
from trafficgeo.calibration.refine import fit_camera
from trafficgeo.calibration.report import CalibrationReport
from trafficgeo.calibration.validation import build_report
from trafficgeo.camera.calibrated import (
    CalibratedCamera,
    CameraCovariance,
    FitModel,
    FitStats,
    PoseUncertainty,
)

if TYPE_CHECKING:
    from trafficgeo.calibration.pipeline import Calibration


def camera_covariance(cal: Calibration) -> CameraCovariance:
    """Covariance of the full OpenCV parameter vector about the local origin (for :mod:`trafficgeo.geo.uncertainty`).

    Fixed parameters have zero rows and columns, so a covariance of the selected model says nothing about the
    radial distortion it chose not to estimate - yet an unestimated k1 of 0.01 moves points 60 m away by decimetres.
    When k1/k2 were left out and the focal length is free, the covariance is therefore taken from a fit that also
    frees k1 and k2 on the same inliers (values unchanged): the uncertainty then covers the lens the data could not
    pin down. Scaled by the a-posteriori variance factor, like the report.
    """
    M = cal.fit.model.matrix()
    cov = M @ cal.fit.covariance() @ M.T
    model = cal.fit.model
    basis = "selected model: " + ", ".join(model.names)
    radial = {"k1", "k2"}
    if model.focal != "fixed" and not radial <= set(model.free_dist):
        ext = ParameterModel(focal=model.focal, principal_point_free=model.principal_point_free,
                             free_dist=tuple(set(model.free_dist) | radial))
        use = cal.inlier
        if 2 * int(use.sum()) - ext.n_free >= 3:
            fit = fit_camera(cal.gcps.world[use] - cal.origin, cal.gcps.pixels[use], cal.sigma_eff_px[use],
                             cal.fit.full, ext, focal_bounds=cal.fit.focal_bounds)
            if fit.success and np.all(np.isfinite(fit.covariance())):
                Me = ext.matrix()
                cov = Me @ fit.covariance() @ Me.T
                basis = "selected model plus k1, k2 (not estimated, but not known either): " + ", ".join(ext.names)
    return CameraCovariance(origin=np.array(cal.origin, dtype=np.float64), values=np.array(cal.fit.full),
                            matrix=np.asarray(cov, dtype=np.float64), basis=basis)


def calibrated_camera(cal: Calibration, report: CalibrationReport | None = None) -> CalibratedCamera:
    """The calibrated camera as the camera JSON stores it: the camera, the GCPs with their residuals, the fit
    statistics, model and uncertainty of ``report`` (built from ``cal`` when not given) and the covariance."""
    report = report or build_report(cal)
    unc, s, o = report.uncertainty, report.stats, report.uncertainty.orientation_std_deg
    return CalibratedCamera(
        cal.camera, gcps=report.gcps,
        stats=FitStats(s.n_control, s.n_inliers, s.mean_px, s.rmse_px, s.loo_rmse_px),
        model=FitModel(tuple(report.model.free_parameters), tuple(report.model.reasons)),
        uncertainty=PoseUncertainty(tuple(unc.position_std_m), (o.heading, o.tilt, o.roll), unc.focal_std_px),
        covariance=camera_covariance(cal))


__all__ = ["calibrated_camera", "camera_covariance"]
