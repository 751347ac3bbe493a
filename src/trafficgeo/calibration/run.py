"""Calibrate, validate and write the results: the one call behind ``trafficgeo calibrate``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from trafficgeo.calibration.camera_record import calibrated_camera
from trafficgeo.calibration.gcp_table import GCPTable
from trafficgeo.calibration.pipeline import Calibration, CalibrationOptions, calibrate
from trafficgeo.calibration.report import CalibrationReport
from trafficgeo.calibration.validation import build_report
from trafficgeo.io.atomic import write_json_atomic


@dataclass(frozen=True)
class CalibrationRun:
    """A calibration and its validation report (see :func:`trafficgeo.calibration.validation.build_report`)."""

    calibration: Calibration
    report: CalibrationReport


def run_calibration(gcps: GCPTable, image_size: tuple[int, int], options: CalibrationOptions | None = None, *,
                    camera_path: str | Path | None = None, report_path: str | Path | None = None) -> CalibrationRun:
    """Calibrate, build the report and write the camera JSON and report JSON (atomically) if paths are given."""
    cal = calibrate(gcps, image_size, options)
    report = build_report(cal)
    if report_path is not None:
        write_json_atomic(report_path, report.to_dict())
    if camera_path is not None:
        calibrated_camera(cal, report).write(camera_path)
    return CalibrationRun(cal, report)
