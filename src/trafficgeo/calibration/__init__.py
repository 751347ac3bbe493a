"""GCP tables, hierarchical calibration, validation (see :mod:`.pipeline` for the stages)."""

from trafficgeo.calibration.gcp_checks import validate_gcps
from trafficgeo.calibration.gcp_read import read_gcps
from trafficgeo.calibration.gcp_table import GCPTable
from trafficgeo.calibration.pipeline import Calibration, CalibrationOptions, Finding, calibrate
from trafficgeo.calibration.report import CalibrationReport, read_calibration_report
from trafficgeo.calibration.run import CalibrationRun, run_calibration
from trafficgeo.calibration.validation import build_report

__all__ = [
    "Calibration",
    "CalibrationOptions",
    "CalibrationReport",
    "CalibrationRun",
    "Finding",
    "GCPTable",
    "build_report",
    "calibrate",
    "read_calibration_report",
    "read_gcps",
    "run_calibration",
    "validate_gcps",
]
