"""Calibrate, validate and write the results: the one call behind ``trafficgeo calibrate``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from trafficgeo.calibration.gcps import GCPTable
from trafficgeo.calibration.params import FULL_NAMES, ParameterModel
from trafficgeo.calibration.pipeline import Calibration, CalibrationOptions, calibrate
from trafficgeo.calibration.refine import fit_camera
from trafficgeo.calibration.report import CalibrationReport
from trafficgeo.calibration.validation import build_report, gcp_records, stats_record
from trafficgeo.camera.io import write_camera_json
from trafficgeo.io.atomic import write_json_atomic


@dataclass(frozen=True)
class CalibrationRun:
    """A calibration and its validation report (see :func:`trafficgeo.calibration.validation.build_report`)."""

    calibration: Calibration
    report: CalibrationReport


def covariance_record(cal: Calibration) -> dict[str, Any]:
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
    return {
        "parameters": list(FULL_NAMES),
        "convention": "OpenCV rvec/tvec map (X_world - origin) to the camera frame; fx..cx in pixels; "
                      "origin, tvec in CRS units",
        "basis": basis,
        "origin": cal.origin.tolist(),
        "values": cal.fit.full.tolist(),
        "matrix": cov.tolist(),
    }


def camera_extras(report: CalibrationReport, cal: Calibration | None = None) -> dict[str, Any]:
    """The calibration keys stored in the camera JSON beside the camera itself."""
    unc = report.uncertainty
    extras = {
        "gcps": gcp_records(report),
        "stats": stats_record(report),
        "model": {"free_parameters": list(report.model.free_parameters), "reasons": list(report.model.reasons)},
        "uncertainty": {"position_std_m": list(unc.position_std_m),
                        "orientation_std_deg": unc.orientation_std_deg.to_dict(), "focal_std_px": unc.focal_std_px},
    }
    if cal is not None:
        extras["covariance"] = covariance_record(cal)
    return extras


def run_calibration(gcps: GCPTable, image_size: tuple[int, int], options: CalibrationOptions | None = None, *,
                    camera_path: str | Path | None = None, report_path: str | Path | None = None) -> CalibrationRun:
    """Calibrate, build the report and write the camera JSON and report JSON (atomically) if paths are given."""
    cal = calibrate(gcps, image_size, options)
    report = build_report(cal)
    if report_path is not None:
        write_json_atomic(report_path, report.to_dict())
    if camera_path is not None:
        write_camera_json(camera_path, cal.camera, camera_extras(report, cal))
    return CalibrationRun(cal, report)
