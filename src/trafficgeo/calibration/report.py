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
import types
import typing
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

from trafficgeo.camera.orientation import Orientation
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import to_json_safe
from trafficgeo.io.json_text import loads_json

REPORT_FORMAT = "trafficgeo.calibration-report/1"
NAN = float("nan")


class _Malformed(Exception):
    """A key of the document is missing or has the wrong type (the message names it)."""


def _plain(value: Any) -> Any:
    """``value`` as JSON-ready data: records and orientations as dicts, tuples as lists, mappings as dicts."""
    if isinstance(value, _Record | Orientation):
        return value.to_dict()
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _convert(tp: Any, value: Any, key: str) -> Any:
    """``value`` read from JSON as the type ``tp`` (a field's annotation); raises :class:`_Malformed`."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (types.UnionType, typing.Union):
        if value is None and type(None) in args:
            return None
        return _convert(next(a for a in args if a is not type(None)), value, key)
    if tp is float:
        if value is None:  # NaN is written as null
            return NAN
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        raise _Malformed(f"'{key}' is not a number")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise _Malformed(f"'{key}' is not an integer")
    if tp in (bool, str):
        if isinstance(value, tp):
            return value
        raise _Malformed(f"'{key}' is not {'true or false' if tp is bool else 'text'}")
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise _Malformed(f"'{key}' is not a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{key}[{k}]") for k, v in enumerate(value))
        if len(value) != len(args):
            raise _Malformed(f"'{key}' has {len(value)} values, expected {len(args)}")
        return tuple(_convert(a, v, f"{key}[{k}]") for k, (a, v) in enumerate(zip(args, value, strict=True)))
    if origin is Mapping:
        if not isinstance(value, Mapping):
            raise _Malformed(f"'{key}' is not an object")
        return types.MappingProxyType({k: _convert(args[1], v, f"{key}.{k}") for k, v in value.items()})
    if isinstance(tp, type) and is_dataclass(tp):
        return _read_fields(tp, value, key)
    raise TypeError(f"no reader for {tp!r} ({key})")  # a programming error: a field of an unsupported type


def _read_fields(cls: type[Any], doc: Any, where: str) -> Any:
    """An instance of the dataclass ``cls`` from the JSON object ``doc``; fields with defaults may be absent."""
    if not isinstance(doc, Mapping):
        raise _Malformed(f"'{where}' is not an object" if where else "the document is not a JSON object")
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in fields(cls):
        key = f"{where}.{f.name}" if where else f.name
        if f.name not in doc:
            if f.default is MISSING and f.default_factory is MISSING:
                raise _Malformed(f"key '{key}' is missing")
            continue
        kwargs[f.name] = _convert(hints[f.name], doc[f.name], key)
    return cls(**kwargs)


class _Record:
    """Base of the report's dataclasses: ``to_dict`` in field order; equal when they write the same JSON (so NaN,
    "not available", equals NaN)."""

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready record (keys = field names, in order)."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}  # type: ignore[arg-type]

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return to_json_safe(self.to_dict()) == to_json_safe(other.to_dict())  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]  (equal by JSON value, which a hash of the fields would not follow)


@dataclass(frozen=True, eq=False)
class GCPResidual(_Record):
    """One GCP of the report: its survey point (x, y, z; CRS units), clicked pixel (u, v) and projection
    (u_proj, v_proj; px), the residual du, dv = projected - clicked (px), the fit and leave-one-out errors in the
    image (px) and on the ground (m), its sigmas (px), ``status`` inlier / outlier / check and the outlier's
    ``reason`` ("" otherwise)."""

    id: str
    role: str
    x: float
    y: float
    z: float
    u: float
    v: float
    u_proj: float
    v_proj: float
    du: float
    dv: float
    error_px: float
    inlier: bool
    loo_error_px: float
    ground_error_m: float
    loo_ground_error_m: float
    sigma_px: float
    sigma_eff_px: float
    status: str
    reason: str


@dataclass(frozen=True, eq=False)
class FitStats(_Record):
    """Fit statistics over the inlier control points: residuals (px), leave-one-out errors (px, and m on the
    ground), redundancy (observations - parameters) and sigma0 (1 = residuals match the stated noise)."""

    n_control: int
    n_check: int
    n_inliers: int
    n_outliers: int
    mean_px: float
    rmse_px: float
    max_px: float
    std_px: float
    loo_rmse_px: float
    loo_ground_rmse_m: float
    loo_ground_median_m: float
    ground_rmse_m: float
    redundancy: int
    n_parameters: int
    sigma0: float


@dataclass(frozen=True, eq=False)
class CheckStats(_Record):
    """Errors at the check points (never used in the fit), px and m; NaN (and only ``n`` in the file) without any."""

    n: int
    rmse_px: float = NAN
    mean_px: float = NAN
    max_px: float = NAN
    ground_rmse_m: float = NAN
    ground_max_m: float = NAN

    def to_dict(self) -> dict[str, Any]:
        return super().to_dict() if self.n else {"n": self.n}


@dataclass(frozen=True, eq=False)
class PairError(_Record):
    """The distance ratio error of one pair of GCPs (percent)."""

    a: str
    b: str
    error_pct: float


@dataclass(frozen=True, eq=False)
class DistanceRatios(_Record):
    """Paper eq. 15 over all pairs of points: |d_world - d_image| / d_world (percent), and the 5 worst pairs;
    NaN (and only ``n_pairs`` in the file) without any pair."""

    n_pairs: int
    mean_pct: float = NAN
    median_pct: float = NAN
    max_pct: float = NAN
    worst_pairs: tuple[PairError, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return super().to_dict() if self.n_pairs else {"n_pairs": self.n_pairs}


@dataclass(frozen=True, eq=False)
class CameraSummary(_Record):
    """The calibrated camera: focal length(s) and principal point (px), distortion (OpenCV k1, k2, p1, p2, k3),
    field of view (deg, horizontal and vertical), position (CRS units) and orientation."""

    focal_px: float
    fx: float
    fy: float
    principal_point: tuple[float, float]
    dist: tuple[float, ...]
    fov_deg: tuple[float, float]
    position: tuple[float, float, float]
    orientation: Orientation


@dataclass(frozen=True, eq=False)
class FitStart(_Record):
    """One start of the robust fit: how it was found, the focal length it converged to (px) and its robust cost."""

    method: str
    focal_px: float
    robust_cost: float


@dataclass(frozen=True, eq=False)
class ModelSummary(_Record):
    """The parameter model the fit chose (its free parameters, in words, and why), the robust loss, the routes
    to a starting camera and the starts tried, the planarity of the GCPs (singular value ratio) and where the
    consensus came from (None where the calibration did not note it)."""

    free_parameters: tuple[str, ...]
    description: str
    reasons: tuple[str, ...]
    loss: str | None
    initialization: tuple[str, ...] | None
    starts: tuple[FitStart, ...] | None
    planarity_ratio: float | None
    consensus: str | None


@dataclass(frozen=True, eq=False)
class ParameterStd(_Record):
    """A free parameter's value and 1-sigma (rotation vector rad; translation CRS units; focal px)."""

    value: float
    std: float


@dataclass(frozen=True, eq=False)
class Correlation(_Record):
    """Two parameters the GCPs cannot separate, and their correlation coefficient."""

    a: str
    b: str
    correlation: float


@dataclass(frozen=True, eq=False)
class AnglesDeg(_Record):
    """Heading, tilt and roll (deg)."""

    heading: float
    tilt: float
    roll: float


@dataclass(frozen=True, eq=False)
class Uncertainty(_Record):
    """1-sigma of the free parameters and of position (m), angles (deg) and focal length (px), from the fit
    covariance (scaled by sigma0^2), and the pairs of parameters correlated above 0.98."""

    scaled_by_variance_factor: bool
    parameters: Mapping[str, ParameterStd]
    position_std_m: tuple[float, float, float]
    orientation_std_deg: AnglesDeg
    focal_std_px: float
    high_correlations: tuple[Correlation, ...]


@dataclass(frozen=True, eq=False)
class PoseConsistency(_Record):
    """Jackknife spread of the camera over the leave-one-out refits: position (m), angles (deg), focal (px), the
    largest shift (m) and the point whose removal causes it; NaN and empty (only ``method``, ``n_fits`` and
    ``available`` in the file) with fewer than 3 refits."""

    method: str
    n_fits: int
    available: bool
    position_spread_m: tuple[float, ...] = ()
    max_position_deviation_m: float = NAN
    most_influential_gcp: str = ""
    angle_spread_deg: AnglesDeg = field(default_factory=lambda: AnglesDeg(NAN, NAN, NAN))
    focal_spread_px: float = NAN

    def to_dict(self) -> dict[str, Any]:
        if self.available:
            return super().to_dict()
        return {"method": self.method, "n_fits": self.n_fits, "available": self.available}


@dataclass(frozen=True, eq=False)
class Outlier(_Record):
    """A control point left out of the fit, and why in plain words."""

    id: str
    reason: str


@dataclass(frozen=True, eq=False)
class CalibrationReport(_Record):
    """How far a calibration can be trusted (see :mod:`trafficgeo.calibration.validation` for how each number is
    computed): the summary line, the camera, the model, fit and check-point statistics, per-GCP residuals, distance
    ratios, parameter uncertainty, pose consistency, outliers, warnings and recommendations.

    ``crs`` is the camera's CRS as text (None: local coordinates); ``metres_per_crs_unit`` converts its units to
    metres; ``image_size`` is (width, height) px. Two reports are equal when they write the same JSON.
    """

    summary: str
    image_size: tuple[int, int]
    crs: str | None
    metres_per_crs_unit: float
    camera: CameraSummary
    model: ModelSummary
    stats: FitStats
    check: CheckStats
    gcps: tuple[GCPResidual, ...]
    distance_ratios: DistanceRatios
    distance_ratios_check: DistanceRatios
    uncertainty: Uncertainty
    pose_consistency: PoseConsistency
    outliers: tuple[Outlier, ...]
    warnings: tuple[str, ...]
    recommendations: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        """The report.json document (format :data:`REPORT_FORMAT`; NaN where the file has null)."""
        return {"format": REPORT_FORMAT, **super().to_dict()}

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
            return _read_fields(cls, doc, "")
        except _Malformed as exc:
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
