"""Read back the refinement report (format ``trafficgeo-refine/1``, written by
:func:`trafficgeo.registration.run.refine_camera_files`) as a typed, checked record.

Nothing in the file is trusted: every key the readers use is checked, and a damaged file gives one
:class:`~trafficgeo.errors.InputError` line naming the file and the key. Units: ground errors in metres, image
positions and distances in pixels (pixel-centre convention of :mod:`trafficgeo.camera.model`), world positions in
the camera CRS's units.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.io.json_text import loads_json
from trafficgeo.registration.refine import Pass
from trafficgeo.registration.run import MATCH_COLUMNS, REFINE_FORMAT

FIX = "write it again with 'trafficgeo refine --report'"


@dataclass(frozen=True)
class PointError:
    """One user's point: its ``id``, ``role`` ("control" or "check"), held-out ground error (m) and pixel error
    (px); NaN where the file has none."""

    id: str
    role: str
    ground_error_m: float
    pixel_error_px: float


@dataclass(frozen=True)
class HeldOutSummary:
    """Held-out errors of one camera at the user's points (as :meth:`HeldOutErrors.to_dict` wrote them): RMS over
    all points, over the check points and leave-one-out over the control points, on the ground (m) and in the
    image (px; the verdict's statistic); NaN when not known."""

    rmse_m: float
    check_rmse_m: float
    loo_rmse_m: float
    points: tuple[PointError, ...]
    rmse_px: float = float("nan")
    check_rmse_px: float = float("nan")
    loo_rmse_px: float = float("nan")

    def point(self, point_id: str) -> PointError | None:
        """The point with this id, or None."""
        return next((p for p in self.points if p.id == point_id), None)


@dataclass(frozen=True)
class CameraSummary:
    """What the report shows of a camera: image size (W, H px), focal lengths and principal point (px), the five
    distortion coefficients, position (CRS units) and heading / tilt / roll (degrees)."""

    image_size: tuple[int, int]
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    dist: tuple[float, ...]
    position: tuple[float, float, float]
    heading_deg: float
    tilt_deg: float
    roll_deg: float


@dataclass(frozen=True)
class RefineRecord:
    """A refinement report read back.

    Attributes:
        path: the file read.
        accepted, reason: the verdict and why, in words.
        matches_kept: automatic correspondences the last re-fit kept.
        before, after: the user's points' held-out errors with the original and the refined camera (``after`` None
            when no re-fit was possible).
        passes: the passes run.
        model: the refined model's free parameters (names as in a camera JSON), or None without a re-fit.
        original, refined: the original and the refined camera (``refined`` None without a re-fit).
        pixels, predicted: (N, 2) px: where each automatic correspondence of the last pass was found in the frame,
            and where the camera of the pass before predicted it.
        kept: (N,) bool: the correspondences the last re-fit kept.
        ncc: (N,) normalised cross-correlation of each match.
        frame: the frame image beside the file (``<stem>_frame.jpg`` as its ``frame`` key names it), or None when
            the key is absent; the file itself may be missing.
    """

    path: Path
    accepted: bool
    reason: str
    matches_kept: int
    before: HeldOutSummary
    after: HeldOutSummary | None
    passes: tuple[Pass, ...]
    model: tuple[str, ...] | None
    original: CameraSummary
    refined: CameraSummary | None
    pixels: np.ndarray
    predicted: np.ndarray
    kept: np.ndarray
    ncc: np.ndarray
    frame: Path | None

    @property
    def matches_found(self) -> int:
        """Automatic correspondences found on the last pass."""
        return len(self.kept)


class _Doc:
    """Checked access to the keys of one file's JSON document; each failure is one InputError line."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def bad(self, key: str, what: str) -> InputError:
        return InputError(f"{self.path}: key '{key}' {what}; {FIX}", parameters=("refine_report",))

    def get(self, obj: Any, key: str, name: str) -> Any:
        if not isinstance(obj, dict) or key not in obj:
            return self.missing(name)
        return obj[key]

    def missing(self, name: str) -> Any:
        raise self.bad(name, "is missing")

    def number(self, value: Any, name: str, *, allow_null: bool = True) -> float:
        if value is None and allow_null:
            return float("nan")
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(float(value)):
            raise self.bad(name, f"is not a number (found {_short(value)})")
        return float(value)

    def count(self, value: Any, name: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self.bad(name, f"is not a count (found {_short(value)})")
        return int(value)

    def text(self, value: Any, name: str) -> str:
        if not isinstance(value, str):
            raise self.bad(name, f"is not text (found {_short(value)})")
        return value

    def items(self, value: Any, name: str) -> list[Any]:
        if not isinstance(value, list):
            raise self.bad(name, f"is not a list (found {_short(value)})")
        return value


def _short(value: Any) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _held_out(d: _Doc, obj: Any, name: str) -> HeldOutSummary:
    points = []
    for k, p in enumerate(d.items(d.get(obj, "points", f"{name}.points"), f"{name}.points")):
        at = f"{name}.points[{k}]"
        role = d.text(d.get(p, "role", f"{at}.role"), f"{at}.role")
        if role not in ("control", "check"):
            raise d.bad(f"{at}.role", f"is neither 'control' nor 'check' (found {_short(role)})")
        points.append(PointError(id=str(d.get(p, "id", f"{at}.id")), role=role,
                                 ground_error_m=d.number(d.get(p, "ground_error_m", f"{at}.ground_error_m"),
                                                         f"{at}.ground_error_m"),
                                 pixel_error_px=d.number(d.get(p, "pixel_error_px", f"{at}.pixel_error_px"),
                                                         f"{at}.pixel_error_px")))
    keys = ("rmse_m", "check_rmse_m", "loo_rmse_m", "rmse_px", "check_rmse_px", "loo_rmse_px")
    values = {key: d.number(d.get(obj, key, f"{name}.{key}"), f"{name}.{key}") for key in keys}
    return HeldOutSummary(points=tuple(points), **values)


def _camera(d: _Doc, obj: Any, name: str) -> CameraSummary:
    def vector(key: str, n: int) -> list[float]:
        v = d.get(obj, key, f"{name}.{key}")
        if not isinstance(v, list) or len(v) != n:
            raise d.bad(f"{name}.{key}", f"is not a list of {n} numbers")
        return [d.number(x, f"{name}.{key}", allow_null=False) for x in v]

    size = vector("image_size", 2)
    if any(s <= 0 or s != round(s) for s in size):
        raise d.bad(f"{name}.image_size", "is not two positive whole numbers [W, H]")
    K = d.get(obj, "K", f"{name}.K")
    if not isinstance(K, list) or len(K) != 3 or not all(isinstance(r, list) and len(r) == 3 for r in K):
        raise d.bad(f"{name}.K", "is not a 3x3 matrix")
    k = [[d.number(x, f"{name}.K", allow_null=False) for x in r] for r in K]
    dist = vector("dist", 5) if isinstance(obj, dict) and "dist" in obj else [0.0] * 5
    position = vector("position", 3)
    ori = d.get(obj, "orientation", f"{name}.orientation")
    angles = [d.number(d.get(ori, a, f"{name}.orientation.{a}"), f"{name}.orientation.{a}", allow_null=False)
              for a in ("heading_deg", "tilt_deg", "roll_deg")]
    return CameraSummary(image_size=(int(size[0]), int(size[1])), fx_px=k[0][0], fy_px=k[1][1], cx_px=k[0][2],
                         cy_px=k[1][2], dist=tuple(dist), position=(position[0], position[1], position[2]),
                         heading_deg=angles[0], tilt_deg=angles[1], roll_deg=angles[2])


def _matches(d: _Doc, obj: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    columns = d.items(d.get(obj, "columns", "matches.columns"), "matches.columns")
    need = ("u", "v", "u_predicted", "v_predicted", "ncc", "kept")
    for c in need:
        if c not in columns:
            raise d.bad("matches.columns", f"lacks '{c}' (format {REFINE_FORMAT} lists {', '.join(MATCH_COLUMNS)})")
    at = {c: columns.index(c) for c in need}
    rows = d.items(d.get(obj, "rows", "matches.rows"), "matches.rows")
    values = np.full((len(rows), 5), np.nan)
    kept = np.zeros(len(rows), dtype=bool)
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != len(columns):
            raise d.bad(f"matches.rows[{i}]", f"is not a row of {len(columns)} values")
        for j, c in enumerate(need[:5]):
            values[i, j] = d.number(row[at[c]], f"matches.rows[{i}].{c}", allow_null=False)
        if not isinstance(row[at["kept"]], bool):
            raise d.bad(f"matches.rows[{i}].kept", f"is not true or false (found {_short(row[at['kept']])})")
        kept[i] = row[at["kept"]]
    return values[:, 0:2], values[:, 2:4], kept, values[:, 4]


def read_refine_record(path: str | Path) -> RefineRecord:
    """The refinement report at ``path`` (see the module docstring).

    Raises:
        InputError: the file cannot be read, is not a refinement report, or a key is missing or damaged.
    """
    p = Path(path)
    try:
        doc = loads_json(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{p}: not readable JSON ({' '.join(str(exc).split())}); {FIX}",
                         parameters=("refine_report",)) from None
    d = _Doc(p)
    if not isinstance(doc, dict) or doc.get("format") != REFINE_FORMAT:
        found = _short(doc.get("format")) if isinstance(doc, dict) else "not a JSON object"
        raise d.bad("format", f"is not '{REFINE_FORMAT}' (found {found}): not a refinement report")
    accepted = d.get(doc, "accepted", "accepted")
    if not isinstance(accepted, bool):
        raise d.bad("accepted", f"is not true or false (found {_short(accepted)})")
    after = d.get(doc, "after", "after")
    passes = []
    for k, q in enumerate(d.items(d.get(doc, "passes", "passes"), "passes")):
        at = f"passes[{k}]"
        passes.append(Pass(
            search_px=d.number(d.get(q, "search_px", f"{at}.search_px"), f"{at}.search_px", allow_null=False),
            tried=d.count(d.get(q, "tried", f"{at}.tried"), f"{at}.tried"),
            matched=d.count(d.get(q, "matched", f"{at}.matched"), f"{at}.matched"),
            kept=d.count(d.get(q, "kept", f"{at}.kept"), f"{at}.kept"),
            rmse_px=d.number(d.get(q, "rmse_px", f"{at}.rmse_px"), f"{at}.rmse_px"),
            moved_px=d.number(d.get(q, "moved_px", f"{at}.moved_px"), f"{at}.moved_px")))
    model = d.get(doc, "model", "model")
    if model is not None and not (isinstance(model, list) and all(isinstance(m, str) for m in model)):
        raise d.bad("model", f"is not a list of parameter names (found {_short(model)})")
    refined = d.get(doc, "refined_camera", "refined_camera")
    pixels, predicted, kept, ncc = _matches(d, d.get(doc, "matches", "matches"))
    frame = doc.get("frame")
    if frame is not None and (not isinstance(frame, str) or not frame or Path(frame).name != frame):
        raise d.bad("frame", f"is not the name of an image beside the file (found {_short(frame)})")
    record = RefineRecord(
        path=p, accepted=accepted, reason=d.text(d.get(doc, "reason", "reason"), "reason"),
        matches_kept=d.count(d.get(doc, "matches_kept", "matches_kept"), "matches_kept"),
        before=_held_out(d, d.get(doc, "before", "before"), "before"),
        after=None if after is None else _held_out(d, after, "after"), passes=tuple(passes),
        model=None if model is None else tuple(model),
        original=_camera(d, d.get(doc, "original_camera", "original_camera"), "original_camera"),
        refined=None if refined is None else _camera(d, refined, "refined_camera"),
        pixels=pixels, predicted=predicted, kept=kept, ncc=ncc, frame=None if frame is None else p.parent / frame)
    if record.matches_kept != int(kept.sum()):
        raise d.bad("matches_kept", f"is {record.matches_kept} but {int(kept.sum())} rows of matches.rows are kept")
    return record
