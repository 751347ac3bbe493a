"""Calibrate, validate and write the results: the one call behind ``trafficgeo calibrate``."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from trafficgeo.calibration.gcps import GCPTable
from trafficgeo.calibration.pipeline import Calibration, CalibrationOptions, calibrate
from trafficgeo.calibration.validation import build_report, gcp_records, stats_record
from trafficgeo.camera.io import to_json_safe, write_camera_json
from trafficgeo.io.atomic import write_text_atomic


@dataclass(frozen=True)
class CalibrationRun:
    """A calibration and its validation report (see :func:`trafficgeo.calibration.validation.build_report`)."""

    calibration: Calibration
    report: dict[str, Any]


def camera_extras(report: dict[str, Any]) -> dict[str, Any]:
    """The calibration keys stored in the camera JSON beside the camera itself."""
    return {
        "gcps": gcp_records(report),
        "stats": stats_record(report),
        "model": {"free_parameters": report["model"]["free_parameters"], "reasons": report["model"]["reasons"]},
        "uncertainty": {k: report["uncertainty"][k] for k in ("position_std_m", "orientation_std_deg", "focal_std_px")},
    }


def run_calibration(gcps: GCPTable, image_size: tuple[int, int], options: CalibrationOptions | None = None, *,
                    camera_path: str | Path | None = None, report_path: str | Path | None = None) -> CalibrationRun:
    """Calibrate, build the report and write the camera JSON and report JSON (atomically) if paths are given."""
    cal = calibrate(gcps, image_size, options)
    report = build_report(cal)
    if report_path is not None:
        write_text_atomic(report_path, json.dumps(to_json_safe(report), indent=2, allow_nan=False) + "\n")
    if camera_path is not None:
        write_camera_json(camera_path, cal.camera, camera_extras(report))
    return CalibrationRun(cal, report)
