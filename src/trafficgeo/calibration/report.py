"""The calibration report as typed data (:class:`CalibrationReport`), and its JSON file (``report.json``).

:func:`trafficgeo.calibration.validation.build_report` makes it; :meth:`CalibrationReport.to_dict` gives the JSON
document ``trafficgeo calibrate --report`` writes (format :data:`REPORT_FORMAT`, the keys in the order of the fields
below, units in the names); :func:`read_calibration_report` reads such a file back. Units as in the names: pixels
(``_px``), metres on the ground (``_m``), degrees (``_deg``), percent (``_pct``); positions and ``x, y, z`` in the
CRS's units (``metres_per_crs_unit`` converts). A number that is not available (a leave-one-out error without enough
points to refit) is NaN in memory and ``null`` in the file.

Blocks that only hold numbers when there is something to report (:class:`CheckStats` without check points,
:class:`DistanceRatios` with no pairs, :class:`PoseConsistency` without enough refits) keep NaN and empty defaults
then, and write only their count (and ``available``) to the file, as the format has always done.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from trafficgeo.camera.calibrated import CameraGCP
from trafficgeo.camera.orientation import Orientation
from trafficgeo.errors import InputError
from trafficgeo.io.json_text import loads_json
from trafficgeo.io.records import NAN, Flag, Int, MaybeNum, Num, Record, RecordError, Text, read_record

REPORT_FORMAT = "trafficgeo.calibration-report/1"


GCP_KEYS = ("id", "role", "x", "y", "z", "u", "v", "u_proj", "v_proj", "du", "dv", "error_px", "inlier",
            "loo_error_px", "ground_error_m", "loo_ground_error_m", "sigma_px", "sigma_eff_px", "status", "reason")


def gcp_row(gcp: CameraGCP) -> dict[str, Any]:
    """One GCP of the report as report.json writes it (:data:`GCP_KEYS`: the residual ``du, dv`` = projected -
    clicked, px, and the ``status`` check / inlier / outlier with them; NaN where the file has null)."""
    return {k: getattr(gcp, k) for k in GCP_KEYS}


@dataclass(frozen=True, eq=False)
class FitStats(Record):
    """Fit statistics over the inlier control points: residuals (px), leave-one-out errors (px, and m on the
    ground), redundancy (observations - parameters) and sigma0 (1 = residuals match the stated noise)."""

    n_control: Int
    n_check: Int
    n_inliers: Int
    n_outliers: Int
    mean_px: Num
    rmse_px: Num
    max_px: Num
    std_px: Num
    loo_rmse_px: Num
    loo_ground_rmse_m: Num
    loo_ground_median_m: Num
    ground_rmse_m: Num
    redundancy: Int
    n_parameters: Int
    sigma0: Num


@dataclass(frozen=True, eq=False)
class CheckStats(Record):
    """Errors at the check points (never used in the fit), px and m; NaN (and only ``n`` in the file) without any."""

    n: Int
    rmse_px: Num = NAN
    mean_px: Num = NAN
    max_px: Num = NAN
    ground_rmse_m: Num = NAN
    ground_max_m: Num = NAN

    def to_dict(self) -> dict[str, Any]:
        return super().to_dict() if self.n else {"n": self.n}


@dataclass(frozen=True, eq=False)
class PairError(Record):
    """The distance ratio error of one pair of GCPs (percent)."""

    a: Text
    b: Text
    error_pct: Num


@dataclass(frozen=True, eq=False)
class DistanceRatios(Record):
    """Paper eq. 15 over all pairs of points: |d_world - d_image| / d_world (percent), and the 5 worst pairs;
    NaN (and only ``n_pairs`` in the file) without any pair."""

    n_pairs: Int
    mean_pct: Num = NAN
    median_pct: Num = NAN
    max_pct: Num = NAN
    worst_pairs: tuple[PairError, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return super().to_dict() if self.n_pairs else {"n_pairs": self.n_pairs}


@dataclass(frozen=True, eq=False)
class CameraSummary(Record):
    """The calibrated camera: focal length(s) and principal point (px), distortion (OpenCV k1, k2, p1, p2, k3),
    field of view (deg, horizontal and vertical), position (CRS units) and orientation."""

    focal_px: Num
    fx: Num
    fy: Num
    principal_point: tuple[Num, Num]
    dist: tuple[Num, ...]
    fov_deg: tuple[Num, Num]
    position: tuple[Num, Num, Num]
    orientation: Orientation


@dataclass(frozen=True, eq=False)
class FitStart(Record):
    """One start of the robust fit: how it was found, the focal length it converged to (px) and its robust cost."""

    method: Text
    focal_px: Num
    robust_cost: Num


@dataclass(frozen=True, eq=False)
class ModelSummary(Record):
    """The parameter model the fit chose (its free parameters, in words, and why), the robust loss, the routes
    to a starting camera and the starts tried, the planarity of the GCPs (singular value ratio) and where the
    consensus came from (None where the calibration did not note it)."""

    free_parameters: tuple[Text, ...]
    description: Text
    reasons: tuple[Text, ...]
    loss: Text | None
    initialization: tuple[Text, ...] | None
    starts: tuple[FitStart, ...] | None
    planarity_ratio: MaybeNum
    consensus: Text | None


@dataclass(frozen=True, eq=False)
class ParameterStd(Record):
    """A free parameter's value and 1-sigma (rotation vector rad; translation CRS units; focal px)."""

    value: Num
    std: Num


@dataclass(frozen=True, eq=False)
class Correlation(Record):
    """Two parameters the GCPs cannot separate, and their correlation coefficient."""

    a: Text
    b: Text
    correlation: Num


@dataclass(frozen=True, eq=False)
class AnglesDeg(Record):
    """Heading, tilt and roll (deg)."""

    heading: Num
    tilt: Num
    roll: Num


@dataclass(frozen=True, eq=False)
class Uncertainty(Record):
    """1-sigma of the free parameters and of position (m), angles (deg) and focal length (px), from the fit
    covariance (scaled by sigma0^2), and the pairs of parameters correlated above 0.98."""

    scaled_by_variance_factor: Flag
    parameters: Mapping[str, ParameterStd]
    position_std_m: tuple[Num, Num, Num]
    orientation_std_deg: AnglesDeg
    focal_std_px: Num
    high_correlations: tuple[Correlation, ...]


@dataclass(frozen=True, eq=False)
class PoseConsistency(Record):
    """Jackknife spread of the camera over the leave-one-out refits: position (m), angles (deg), focal (px), the
    largest shift (m) and the point whose removal causes it; NaN and empty (only ``method``, ``n_fits`` and
    ``available`` in the file) with fewer than 3 refits."""

    method: Text
    n_fits: Int
    available: Flag
    position_spread_m: tuple[Num, ...] = ()
    max_position_deviation_m: Num = NAN
    most_influential_gcp: Text = ""
    angle_spread_deg: AnglesDeg = field(default_factory=lambda: AnglesDeg(NAN, NAN, NAN))
    focal_spread_px: Num = NAN

    def to_dict(self) -> dict[str, Any]:
        if self.available:
            return super().to_dict()
        return {"method": self.method, "n_fits": self.n_fits, "available": self.available}


@dataclass(frozen=True, eq=False)
class Outlier(Record):
    """A control point left out of the fit, and why in plain words."""

    id: Text
    reason: Text


@dataclass(frozen=True, eq=False)
class CalibrationReport(Record):
    """How far a calibration can be trusted (see :mod:`trafficgeo.calibration.validation` for how each number is
    computed): the summary line, the camera, the model, fit and check-point statistics, per-GCP residuals, distance
    ratios, parameter uncertainty, pose consistency, outliers, warnings and recommendations.

    ``crs`` is the camera's CRS as text (None: local coordinates); ``metres_per_crs_unit`` converts its units to
    metres; ``image_size`` is (width, height) px. Two reports are equal when they write the same JSON.
    """

    summary: Text
    image_size: tuple[Int, Int]
    crs: Text | None
    metres_per_crs_unit: Num
    camera: CameraSummary
    model: ModelSummary
    stats: FitStats
    check: CheckStats
    gcps: tuple[CameraGCP, ...]
    distance_ratios: DistanceRatios
    distance_ratios_check: DistanceRatios
    uncertainty: Uncertainty
    pose_consistency: PoseConsistency
    outliers: tuple[Outlier, ...]
    warnings: tuple[Text, ...]
    recommendations: tuple[Text, ...]

    def to_dict(self) -> dict[str, Any]:
        """The report.json document (format :data:`REPORT_FORMAT`; NaN where the file has null)."""
        return {"format": REPORT_FORMAT, **super().to_dict(), "gcps": [gcp_row(g) for g in self.gcps]}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "calibration report") -> CalibrationReport:
        """The report of a report.json document (as :meth:`to_dict` gives it); ``where`` names it in errors.

        Raises:
            InputError: ``doc`` is not a calibration report (another format, a missing key or a wrong type).
        """
        fmt = doc.get("format") if isinstance(doc, Mapping) else None
        if fmt != REPORT_FORMAT:
            got = f"format {fmt!r}" if isinstance(fmt, str) else "no 'format' key"
            raise InputError(f"{where}: not a calibration report ({got}, expected {REPORT_FORMAT}); give the "
                             "--report JSON of 'trafficgeo calibrate'")
        try:
            return read_record(cls, doc)
        except RecordError as exc:
            raise InputError(f"{where}: not a complete calibration report ({exc}); write it again with "
                             "'trafficgeo calibrate --report'") from None


def read_calibration_report(path: str | Path, what: str | None = None) -> CalibrationReport:
    """The calibration report in the JSON file ``path`` (written by ``trafficgeo calibrate --report``); ``what``
    (the parameter that named the file) starts the error message.

    Raises:
        InputError: the file cannot be read, is not JSON, or is not a calibration report.
    """
    p = Path(path)
    where = f"{what} {p}" if what else str(p)
    named = (what,) if what else ()
    try:
        doc = loads_json(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{where}: file not found; give the --report JSON of 'trafficgeo calibrate'",
                         parameters=named) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{where}: not readable JSON ({' '.join(str(exc).split())}); write it again with "
                         "'trafficgeo calibrate --report'", parameters=named) from None
    try:
        return CalibrationReport.from_dict(doc, where)
    except InputError as exc:
        raise InputError(str(exc), parameters=named) from None
