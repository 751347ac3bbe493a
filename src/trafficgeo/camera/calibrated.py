"""A calibrated camera: the camera and what its calibration knows, read once from a camera JSON and written once.

``trafficgeo calibrate`` (and ``refine``, and the web app's save) store beside the camera (:mod:`.io`) the user's
GCPs with their residuals (``gcps``), the fit statistics (``stats``), the parameter model (``model``), 1-sigma pose
uncertainty (``uncertainty``), the covariance of the OpenCV parameter vector (``covariance``,
:mod:`.parameters`) and, after ``refine``, the verdict of the orthophoto refinement (``refinement``).
:class:`CalibratedCamera` holds them typed; any further key is kept as it was read and written back.

Units: world coordinates in the camera CRS's units, pixels with (0, 0) at the centre of the top-left pixel
(:mod:`.model`), ground errors in metres.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from trafficgeo.camera.io import FORMAT, camera_from_dict, camera_to_dict
from trafficgeo.camera.model import Camera
from trafficgeo.camera.parameters import FULL_NAMES, camera_to_full, full_to_camera
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import write_json_atomic
from trafficgeo.io.json_text import loads_json
from trafficgeo.io.records import Flag, Num, Text

CAMERA_KEYS = frozenset(("format", "image_size", "K", "dist", "R", "position", "crs", "orientation", "rvec", "tvec"))
TYPED_KEYS = ("gcps", "stats", "model", "uncertainty", "covariance", "refinement")
ROLES = ("control", "check")
COVARIANCE_CONVENTION = ("OpenCV rvec/tvec map (X_world - origin) to the camera frame; fx..cx in pixels; "
                         "origin, tvec in CRS units")


def _float(value: Any) -> float:
    """A JSON number, or NaN for null (TypeError / ValueError for anything else)."""
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"{value!r} is not a number")
    return float(value)


def _json_float(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


@dataclass(frozen=True)
class CameraGCP:
    """One GCP as the calibration used it, the one record of a GCP's outcome (the camera JSON's ``gcps`` and the
    calibration report's): world ``x, y, z`` (CRS units), clicked pixel ``u, v`` and its ``sigma_px``, its
    projection ``u_proj, v_proj`` and reprojection ``error_px`` under the camera, ``inlier`` (control points kept by
    the fit; None for check points when not stated), the leave-one-out error ``loo_error_px``; the report's ground
    errors ``ground_error_m``, ``loo_ground_error_m`` (m), the weight's ``sigma_eff_px`` and an outlier's ``reason``
    (NaN / "" where unknown, as in a camera JSON, which does not store them); ``source`` is "auto" for a
    correspondence found by matching the orthophoto (``trafficgeo calibrate-ortho``), "" for a user's point."""

    id: Text
    role: Text
    x: Num
    y: Num
    z: Num
    u: Num
    v: Num
    u_proj: Num = math.nan
    v_proj: Num = math.nan
    error_px: Num = math.nan
    inlier: Flag | None = True
    loo_error_px: Num = math.nan
    sigma_px: Num = math.nan
    source: Text = ""
    ground_error_m: Num = math.nan
    loo_ground_error_m: Num = math.nan
    sigma_eff_px: Num = math.nan
    reason: Text = ""

    @property
    def du(self) -> float:
        """Residual along the image columns, projected - clicked (px)."""
        return self.u_proj - self.u

    @property
    def dv(self) -> float:
        """Residual along the image rows, projected - clicked (px)."""
        return self.v_proj - self.v

    @property
    def status(self) -> str:
        """``check``, or for a control point ``inlier`` / ``outlier`` (kept by the fit or not; not stated: kept)."""
        return "check" if self.role == "check" else ("outlier" if self.inlier is False else "inlier")

    @classmethod
    def from_dict(cls, row: Any) -> CameraGCP:
        """From one row of the camera JSON's ``gcps`` list (TypeError / KeyError / ValueError when damaged)."""
        if not isinstance(row, Mapping):
            raise TypeError("a row is not a JSON object")
        role = str(row.get("role") or "control")
        if role not in ROLES:
            raise ValueError(f"role {role!r} is neither control nor check")
        inlier = row.get("inlier", True)
        if inlier is not None and not isinstance(inlier, bool):
            raise TypeError(f"inlier {inlier!r} is not true, false or null")
        xyz_uv = [_float(row[k]) for k in ("x", "y", "z", "u", "v")]
        if not all(math.isfinite(c) for c in xyz_uv):
            raise ValueError(f"GCP {row.get('id')!r} has no finite x, y, z, u, v")
        return cls(str(row.get("id", "")), role, *xyz_uv, *(_float(row.get(k)) for k in ("u_proj", "v_proj",
                   "error_px")), inlier, _float(row.get("loo_error_px")), _float(row.get("sigma_px")),
                   str(row.get("source") or ""))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"id": self.id, "role": self.role, "x": self.x, "y": self.y, "z": self.z,
                               "u": self.u, "v": self.v, "u_proj": _json_float(self.u_proj),
                               "v_proj": _json_float(self.v_proj), "error_px": _json_float(self.error_px),
                               "inlier": self.inlier, "loo_error_px": _json_float(self.loo_error_px)}
        if math.isfinite(self.sigma_px):
            out["sigma_px"] = self.sigma_px
        if self.source:
            out["source"] = self.source
        return out

    @property
    def used(self) -> bool:
        """A control point the calibration kept (its inliers): these describe where the camera is known."""
        return self.role == "control" and self.inlier is not False


@dataclass(frozen=True, eq=False)
class CameraCovariance:
    """Covariance of the OpenCV parameter vector ``[rvec, tvec, fx, fy, cx, cy, k1, k2, p1, p2, k3]`` of a camera
    about a local ``origin`` (world CRS units), as written by ``trafficgeo calibrate``; ``basis`` says which fit
    it comes from. ``matrix`` is kept as stored."""

    origin: np.ndarray
    values: np.ndarray
    matrix: np.ndarray
    basis: str = ""

    @classmethod
    def from_dict(cls, block: Any, camera: Camera, where: str = "camera JSON") -> CameraCovariance:
        """From the camera JSON's ``covariance`` block, checked to describe ``camera``."""
        try:
            names = tuple(block["parameters"])
            origin = np.asarray(block["origin"], dtype=np.float64).reshape(3)
            values = np.asarray(block["values"], dtype=np.float64).reshape(15)
            matrix = np.asarray(block["matrix"], dtype=np.float64).reshape(15, 15)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: malformed 'covariance' block ({exc}); re-run 'trafficgeo calibrate'") from None
        if names != FULL_NAMES:
            raise InputError(f"{where}: covariance parameters {names} are not {FULL_NAMES}; re-run calibrate")
        if not (np.all(np.isfinite(matrix)) and np.all(np.isfinite(values)) and np.all(np.isfinite(origin))):
            raise InputError(f"{where}: the covariance has non-finite entries; re-run 'trafficgeo calibrate'")
        # The stored values must describe this camera (a hand-edited JSON would silently mix two cameras).
        if not np.allclose(camera_to_full(camera, origin)[:10], values[:10], rtol=1e-6, atol=1e-6):
            raise InputError(f"{where}: the covariance block does not belong to this camera (its parameters differ); "
                             "remove the block or re-run 'trafficgeo calibrate'")
        return cls(origin=origin, values=values, matrix=matrix, basis=str(block.get("basis", "")))

    def to_dict(self) -> dict[str, Any]:
        return {"parameters": list(FULL_NAMES), "convention": COVARIANCE_CONVENTION, "basis": self.basis,
                "origin": self.origin.tolist(), "values": self.values.tolist(), "matrix": self.matrix.tolist()}

    def factor(self) -> np.ndarray:
        """Columns ``L`` (15, r) with ``L @ L.T`` the symmetric part of ``matrix`` (as stored, it is symmetric to
        rounding) over its non-negligible eigen-directions."""
        w, V = np.linalg.eigh(0.5 * (self.matrix + self.matrix.T))
        keep = w > max(float(w.max()), 0.0) * 1e-14
        return V[:, keep] * np.sqrt(w[keep])

    def camera(self, values: np.ndarray, like: Camera) -> Camera:
        """The camera of parameter vector ``values`` about this origin, with ``like``'s image size and CRS."""
        return full_to_camera(values, self.origin, like.image_size, like.crs)


def _present(cls: Any, block: Any, parse: Mapping[str, Any]) -> Any:
    """An instance of ``cls`` from the keys of ``block`` that are present (None for the absent ones)."""
    if not isinstance(block, Mapping):
        raise TypeError("not a JSON object")
    return cls(**{name: (convert(block[name]) if name in block else None) for name, convert in parse.items()})


def _written(record: Any, write: Mapping[str, Any]) -> dict[str, Any]:
    """The keys of ``record`` that are present (not None), converted for JSON."""
    return {name: convert(getattr(record, name)) for name, convert in write.items()
            if getattr(record, name) is not None}


def _floats(values: Any) -> tuple[float, ...]:
    return tuple(_float(v) for v in values)


def _json_floats(values: tuple[float, ...]) -> list[float | None]:
    return [_json_float(v) for v in values]


@dataclass(frozen=True)
class FitStats:
    """The calibration's fit: control points given and kept, mean and RMS reprojection error and the
    leave-one-out RMS (px; NaN where the calibration could not tell). None: not stated in the file."""

    n_control: int | None = None
    n_inliers: int | None = None
    mean_px: float | None = None
    rmse_px: float | None = None
    loo_rmse_px: float | None = None

    _PARSE: ClassVar[dict[str, Any]] = {
        "n_control": int, "n_inliers": int, "mean_px": _float, "rmse_px": _float, "loo_rmse_px": _float}
    _WRITE: ClassVar[dict[str, Any]] = {
        "n_control": int, "n_inliers": int, "mean_px": _json_float, "rmse_px": _json_float,
        "loo_rmse_px": _json_float}

    @classmethod
    def from_dict(cls, block: Any) -> FitStats:
        return _present(cls, block, cls._PARSE)

    def to_dict(self) -> dict[str, Any]:
        return _written(self, self._WRITE)


@dataclass(frozen=True)
class FitModel:
    """The parameters the calibration estimated (``free_parameters``, :mod:`.parameters` names), why, and a
    description when the file has one. None: not stated in the file."""

    free_parameters: tuple[str, ...] | None = None
    reasons: tuple[str, ...] | None = None
    description: str | None = None

    _PARSE: ClassVar[dict[str, Any]] = {
        "free_parameters": lambda v: tuple(map(str, v)), "reasons": lambda v: tuple(map(str, v)),
        "description": str}
    _WRITE: ClassVar[dict[str, Any]] = {
        "free_parameters": list, "reasons": list, "description": str}

    @classmethod
    def from_dict(cls, block: Any) -> FitModel:
        return _present(cls, block, cls._PARSE)

    def to_dict(self) -> dict[str, Any]:
        return _written(self, self._WRITE)


@dataclass(frozen=True)
class PoseUncertainty:
    """1-sigma of the camera position (m; east, north, up), of heading, tilt and roll (deg) and of the focal
    length (px). None: not stated in the file."""

    position_std_m: tuple[float, ...] | None = None
    orientation_std_deg: tuple[float, ...] | None = None
    focal_std_px: float | None = None

    _PARSE: ClassVar[dict[str, Any]] = {
        "position_std_m": _floats, "focal_std_px": _float,
        "orientation_std_deg": lambda v: tuple(_float(v.get(k)) for k in ("heading", "tilt", "roll"))}
    _WRITE: ClassVar[dict[str, Any]] = {
        "position_std_m": _json_floats, "focal_std_px": _json_float,
        "orientation_std_deg": lambda v: dict(zip(("heading", "tilt", "roll"), _json_floats(v), strict=True))}

    @classmethod
    def from_dict(cls, block: Any) -> PoseUncertainty:
        return _present(cls, block, cls._PARSE)

    def to_dict(self) -> dict[str, Any]:
        written = _written(self, self._WRITE)  # in the calibration's order: position, orientation, focal length
        return {k: written[k] for k in ("position_std_m", "orientation_std_deg", "focal_std_px") if k in written}


@dataclass(frozen=True)
class RefinementSummary:
    """The verdict of ``trafficgeo refine`` kept in the camera JSON: ``accepted`` (the camera is the refined one),
    why, matches kept, the user's points' held-out ground error RMS before / after (m) and the report's file name
    (beside the camera JSON; None when none was written)."""

    accepted: bool
    reason: str
    matches_kept: int
    before_rmse_m: float
    after_rmse_m: float = math.nan
    report: str | None = None

    @classmethod
    def from_dict(cls, block: Any) -> RefinementSummary:
        accepted = block["accepted"]
        if not isinstance(accepted, bool):
            raise TypeError(f"accepted {accepted!r} is not true or false")
        report = block.get("report")
        return cls(accepted, str(block.get("reason", "")), int(block.get("matches_kept", 0)),
                   _float(block.get("before_rmse_m")), _float(block.get("after_rmse_m")),
                   report if isinstance(report, str) and report else None)

    def to_dict(self) -> dict[str, Any]:
        return {"accepted": self.accepted, "reason": self.reason, "matches_kept": self.matches_kept,
                "before_rmse_m": _json_float(self.before_rmse_m), "after_rmse_m": _json_float(self.after_rmse_m),
                "report": self.report}


@dataclass(frozen=True, eq=False)
class CalibratedCamera:
    """A :class:`~trafficgeo.camera.model.Camera` and what its calibration knows (all optional: a camera made by
    hand has none; ``gcps`` is None when the file lists none). ``source`` is the file it was read from ("" when
    built in memory); ``extras`` any further keys of its JSON, kept as they were."""

    camera: Camera
    gcps: tuple[CameraGCP, ...] | None = None
    stats: FitStats | None = None
    model: FitModel | None = None
    uncertainty: PoseUncertainty | None = None
    covariance: CameraCovariance | None = None
    refinement: RefinementSummary | None = None
    extras: Mapping[str, Any] = field(default_factory=dict)
    source: str = ""

    @property
    def where(self) -> str:
        """How messages name this camera: its file, else "camera"."""
        return self.source or "camera"

    @classmethod
    def read(cls, path: str | Path) -> CalibratedCamera:
        """Read a camera JSON (``trafficgeo calibrate``'s, or any ``trafficgeo.camera/1`` file)."""
        p = Path(path)
        where = str(p)
        if not p.is_file():
            raise InputError(f"{where}: camera file not found; give the JSON written by 'trafficgeo calibrate'")
        try:
            doc = loads_json(p.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{where}: not valid JSON ({exc}); give the JSON written by 'trafficgeo calibrate'"
                             ) from None
        return cls.from_dict(doc, where)

    @classmethod
    def from_dict(cls, doc: Any, where: str = "") -> CalibratedCamera:
        """From a camera JSON document; ``where`` names it in messages (and becomes ``source``)."""
        said = where or "camera JSON"
        camera = camera_from_dict(doc, said)

        def block(key: str, parse: Any, fix: str) -> Any:
            value = doc.get(key)
            if value is None:
                return None
            try:
                return parse(value)
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                raise InputError(f"{said}: its '{key}' block is damaged ({exc}); {fix}") from None

        rows = doc.get("gcps")
        if rows is not None and not isinstance(rows, list):
            raise InputError(f"{said}: its gcps list is damaged (not a list); re-run 'trafficgeo calibrate'")
        gcps = []
        for k, row in enumerate(rows or ()):
            try:
                gcps.append(CameraGCP.from_dict(row))
            except (KeyError, TypeError, ValueError) as exc:
                raise InputError(f"{said}: its gcps list is damaged (row {k + 1}: {exc}); re-run "
                                 "'trafficgeo calibrate'") from None
        redo = "re-run 'trafficgeo calibrate'"
        cov = doc.get("covariance")
        return cls(camera, None if rows is None else tuple(gcps), block("stats", FitStats.from_dict, redo),
                   block("model", FitModel.from_dict, redo), block("uncertainty", PoseUncertainty.from_dict, redo),
                   None if cov is None else CameraCovariance.from_dict(cov, camera, said),
                   block("refinement", RefinementSummary.from_dict, "re-run 'trafficgeo refine'"),
                   {k: v for k, v in doc.items() if k not in CAMERA_KEYS and k not in TYPED_KEYS}, where)

    def to_dict(self) -> dict[str, Any]:
        """The camera JSON document: the camera's keys, then the calibration's blocks present, then ``extras``."""
        doc = camera_to_dict(self.camera)
        if self.gcps is not None:
            doc["gcps"] = [g.to_dict() for g in self.gcps]
        for key in TYPED_KEYS[1:]:
            value = getattr(self, key)
            if value is not None:
                doc[key] = value.to_dict()
        doc.update({k: v for k, v in self.extras.items() if k not in doc})
        return doc

    def write(self, path: str | Path) -> None:
        """Write the camera JSON to ``path`` atomically."""
        write_json_atomic(path, self.to_dict())

    def control_xyz(self) -> np.ndarray:
        """(K, 3) world positions (CRS units) of the control points the calibration kept."""
        return np.array([(g.x, g.y, g.z) for g in self.gcps or () if g.used], dtype=np.float64).reshape(-1, 3)


def load_calibrated_camera(camera: CalibratedCamera | Camera | str | Path | Any) -> CalibratedCamera:
    """A :class:`CalibratedCamera` as it is; a bare :class:`Camera` (knowing nothing of its calibration); or read
    from the camera JSON at the path ``camera``."""
    import os

    if isinstance(camera, CalibratedCamera):
        return camera
    if isinstance(camera, Camera):
        return CalibratedCamera(camera)
    if isinstance(camera, str | os.PathLike):
        return CalibratedCamera.read(camera)
    raise InputError(f"camera: {type(camera).__name__} is neither a Camera nor the path of a camera JSON",
                     parameters=("camera",))


def read_camera_json(path: str | Path) -> Camera:
    """The camera alone of a camera JSON (:meth:`CalibratedCamera.read` gives it with what its calibration
    knows)."""
    return CalibratedCamera.read(path).camera


def as_camera(camera: CalibratedCamera | Camera) -> Camera:
    """The :class:`Camera` of a :class:`CalibratedCamera`, or the camera as it is: for functions that need only the
    projection (a calibration's knowledge is kept by whoever holds the CalibratedCamera)."""
    return camera.camera if isinstance(camera, CalibratedCamera) else camera


__all__ = ["FORMAT", "CalibratedCamera", "CameraCovariance", "CameraGCP", "FitModel", "FitStats", "PoseUncertainty",
           "RefinementSummary", "as_camera", "load_calibrated_camera", "read_camera_json"]
