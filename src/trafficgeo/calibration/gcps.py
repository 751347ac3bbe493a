"""Ground control points (GCPs): reading, writing and sanity checks before calibration.

A GCP pairs a world point with the pixel where it appears in the camera image.

Conventions
-----------
* **World** coordinates (X, Y, Z): a projected CRS with X east, Y north, Z up, in the CRS's own unit (metres
  or feet; see :func:`trafficgeo.crs.metres_per_unit`), float64. ``crs=None`` means local coordinates in an
  unknown CRS. Z is never transformed: it is whatever height the file gives.
* **Pixels** (u, v): (0, 0) is the *centre* of the top-left pixel, u grows to the right and v downwards.
  A pixel lies inside a W x H image when ``-0.5 <= u <= W - 0.5`` and ``-0.5 <= v <= H - 0.5``.
  OpenDroneMap/OpenSfM use the same convention for ``im_x im_y``.
* **Roles**: ``"control"`` points are used in the fit; ``"check"`` points are independent check points that
  are never used in the fit, only to measure its accuracy.
* ``sigma_px``: the standard deviation of a point's pixel position (default 1.0 px), used to weight it.

Input formats (detected from the first non-empty line)
------------------------------------------------------
* **CSV** with a header naming ``id,x,y,z,u,v`` in any order and any case; optional ``role`` and ``sigma_px``
  columns; other columns are ignored. The delimiter may be ``,``, ``;`` or a tab. Blank lines are skipped.
* **OpenDroneMap** ``gcp_list.txt``: the first line is the CRS of the points ("WGS84 UTM 10N", "EPSG:32610",
  a PROJ string, ...), then one observation per line, whitespace separated:
  ``geo_x geo_y geo_z im_x im_y image_name [gcp_name ...]``. Lines starting with ``#`` are comments.
  A GCP list usually covers many images; the rows of one image (``odm_image``) are taken.
  The id is ``gcp_name`` if present, else ``row<line number>``.

Every problem a user can fix raises :class:`~trafficgeo.errors.InputError` with a one-line message naming the
file, line and id, and the fix.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj
from numpy.typing import ArrayLike
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from trafficgeo.crs import (
    crs_label,
    is_geographic,
    looks_like_lonlat,
    metres_per_unit,
    parse_crs,
    transform_xy,
    utm_crs_for,
)
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_open

__all__ = [
    "CSV_COLUMNS",
    "OPTIONAL_COLUMNS",
    "REQUIRED_COLUMNS",
    "ROLES",
    "ROLE_CHECK",
    "ROLE_CONTROL",
    "GCPTable",
    "read_gcps",
    "validate_gcps",
]

ROLE_CONTROL = "control"
ROLE_CHECK = "check"
ROLES: tuple[str, ...] = (ROLE_CONTROL, ROLE_CHECK)
REQUIRED_COLUMNS: tuple[str, ...] = ("id", "x", "y", "z", "u", "v")
OPTIONAL_COLUMNS: tuple[str, ...] = ("role", "sigma_px")
#: Columns written by :meth:`GCPTable.to_csv`, in order.
CSV_COLUMNS: tuple[str, ...] = REQUIRED_COLUMNS + OPTIONAL_COLUMNS

_ODM_COLUMNS = ("geo_x", "geo_y", "geo_z", "im_x", "im_y")
_HINTS = {
    "x": "give world coordinates as numbers",
    "y": "give world coordinates as numbers",
    "z": "give world coordinates as numbers (use 0 for flat ground)",
    "u": "give pixel coordinates as numbers",
    "v": "give pixel coordinates as numbers",
    "sigma_px": "give the pixel standard deviation as a positive number, or leave it empty for 1.0",
}


def _q(text: str, limit: int = 40) -> str:
    """Quote user text for a one-line message (control characters escaped, long text shortened)."""
    text = str(text)
    if len(text) > limit:
        text = text[: limit - 3] + "..."
    return f'"{text}"' if text.isprintable() else repr(text)


def _fmt(value: float) -> str:
    return f"{value:.10g}"


@dataclass(frozen=True, eq=False)
class GCPTable:
    """An immutable table of N ground control points.

    Attributes:
        ids: unique point ids.
        world: (N, 3) float64 X east, Y north, Z up in the units of ``crs`` (see module docstring).
        pixels: (N, 2) float64 (u, v), (0, 0) = centre of the top-left pixel, u right, v down.
        roles: ``"control"`` (used in the fit) or ``"check"`` (independent check point, never fitted).
        sigma_px: (N,) float64 standard deviation of each pixel position [px], > 0.
        crs: working projected CRS of ``world``; ``None`` = unknown local coordinates.
        source: where the table came from (file name), for messages.
        lines: 1-based line number of each row in ``source`` (0 when the row has no line, e.g. built in code).

    Arrays are copied to read-only float64 arrays. Equality is identity (``eq=False``) because the fields are
    arrays; compare fields explicitly. Building a table with inconsistent shapes, non-finite values, unknown
    roles or non-positive sigma raises :class:`ValueError` (a programming error, not a user error: files go
    through :func:`read_gcps`, which reports such problems as :class:`~trafficgeo.errors.InputError`).
    """

    ids: tuple[str, ...]
    world: np.ndarray
    pixels: np.ndarray
    roles: tuple[str, ...]
    sigma_px: np.ndarray
    crs: pyproj.CRS | None
    source: str
    lines: tuple[int, ...]

    def __post_init__(self) -> None:
        ids = tuple(str(i) for i in self.ids)
        n = len(ids)
        world = np.array(self.world, dtype=np.float64, copy=True)
        pixels = np.array(self.pixels, dtype=np.float64, copy=True)
        sigma = np.array(self.sigma_px, dtype=np.float64, copy=True).reshape(-1)
        if n == 0:
            world, pixels = world.reshape(0, 3), pixels.reshape(0, 2)
        if world.ndim != 2 or world.shape[1] != 3 or pixels.ndim != 2 or pixels.shape[1] != 2:
            raise ValueError(
                f"GCPTable world must be (N, 3) and pixels (N, 2), got {world.shape}, {pixels.shape}"
            )
        roles = tuple(str(r) for r in self.roles)
        lines = tuple(int(i) for i in self.lines)
        sizes = {
            "ids": n,
            "world": world.shape[0],
            "pixels": pixels.shape[0],
            "roles": len(roles),
            "sigma_px": sigma.shape[0],
            "lines": len(lines),
        }
        if len(set(sizes.values())) != 1:
            raise ValueError(f"GCPTable fields have different lengths: {sizes}")
        if not (np.all(np.isfinite(world)) and np.all(np.isfinite(pixels)) and np.all(np.isfinite(sigma))):
            raise ValueError("GCPTable world, pixels and sigma_px must be finite")
        if np.any(sigma <= 0):
            raise ValueError("GCPTable sigma_px must be > 0")
        bad_roles = sorted(set(roles) - set(ROLES))
        if bad_roles:
            raise ValueError(f"GCPTable roles must be one of {ROLES}, got {bad_roles}")
        for arr in (world, pixels, sigma):
            arr.setflags(write=False)
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "world", world)
        object.__setattr__(self, "pixels", pixels)
        object.__setattr__(self, "sigma_px", sigma)
        object.__setattr__(self, "roles", roles)
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "source", str(self.source))

    @classmethod
    def from_arrays(
        cls,
        ids: Sequence[str],
        world: ArrayLike,
        pixels: ArrayLike,
        *,
        roles: Sequence[str] | None = None,
        sigma_px: ArrayLike | None = None,
        crs: pyproj.CRS | str | None = None,
        source: str = "<memory>",
        lines: Sequence[int] | None = None,
    ) -> GCPTable:
        """Build a table in code: roles default to all ``"control"``, sigma_px to 1.0, lines to 0."""
        n = len(ids)
        return cls(
            ids=tuple(ids),
            world=np.asarray(world, dtype=np.float64),
            pixels=np.asarray(pixels, dtype=np.float64),
            roles=tuple(roles) if roles is not None else (ROLE_CONTROL,) * n,
            sigma_px=np.asarray(sigma_px, dtype=np.float64) if sigma_px is not None else np.ones(n),
            crs=parse_crs(crs),
            source=source,
            lines=tuple(lines) if lines is not None else (0,) * n,
        )

    @property
    def n(self) -> int:
        """Number of points (control and check)."""
        return len(self.ids)

    @property
    def is_control(self) -> np.ndarray:
        """(N,) bool: rows used in the fit."""
        return np.array([r == ROLE_CONTROL for r in self.roles], dtype=bool)

    @property
    def is_check(self) -> np.ndarray:
        """(N,) bool: independent check points (never used in the fit)."""
        return np.array([r == ROLE_CHECK for r in self.roles], dtype=bool)

    def subset(self, mask_or_indices: ArrayLike) -> GCPTable:
        """A new table with the rows selected by a boolean mask of length N or by integer indices."""
        sel = np.asarray(mask_or_indices)
        if sel.dtype == bool:
            if sel.shape != (self.n,):
                raise ValueError(f"boolean mask has shape {sel.shape}, expected ({self.n},)")
            idx = np.flatnonzero(sel)
        elif sel.size == 0:
            idx = np.zeros(0, dtype=np.intp)
        elif np.issubdtype(sel.dtype, np.integer):
            idx = sel.reshape(-1).astype(np.intp)
        else:
            raise ValueError(f"subset needs a boolean mask or integer indices, got dtype {sel.dtype}")
        return GCPTable(
            ids=tuple(self.ids[i] for i in idx),
            world=self.world[idx],
            pixels=self.pixels[idx],
            roles=tuple(self.roles[i] for i in idx),
            sigma_px=self.sigma_px[idx],
            crs=self.crs,
            source=self.source,
            lines=tuple(self.lines[i] for i in idx),
        )

    def row_label(self, i: int) -> str:
        """Row ``i`` without the file name, e.g. ``line 5 (id "P4")`` (``row 5`` when it has no line)."""
        line = self.lines[i]
        place = f"line {line}" if line > 0 else f"row {i + 1}"
        return f"{place} (id {_q(self.ids[i])})"

    def where(self, i: int) -> str:
        """Row ``i`` for messages, e.g. ``gcps.csv line 5 (id "P4")``."""
        return f"{self.source} {self.row_label(i)}"

    def to_csv(self, path: str | os.PathLike[str]) -> None:
        """Write ``id,x,y,z,u,v,role,sigma_px`` with full float precision (``repr``), atomically.

        The file is written to a temporary file in the same folder and then moved over ``path``, so readers
        never see a half-written file. The CRS is not stored: pass it again to :func:`read_gcps`
        (``gcp_crs`` or ``crs``). ``read_gcps(path, crs=table.crs)`` gives back the same values exactly.
        """
        with atomic_open(path, "w", encoding="utf-8", newline="") as fh:
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(CSV_COLUMNS)
            for i in range(self.n):
                x, y, z = (repr(float(c)) for c in self.world[i])
                u, v = (repr(float(c)) for c in self.pixels[i])
                writer.writerow([self.ids[i], x, y, z, u, v, self.roles[i], repr(float(self.sigma_px[i]))])


# --------------------------------------------------------------------------------------------- reading


@dataclass
class _Rows:
    """Parsed rows of a GCP file before CRS handling."""

    ids: list[str]
    values: list[tuple[float, float, float, float, float]]
    roles: list[str]
    sigma: list[float]
    lines: list[int]
    images: list[str]


def _number(text: str, column: str, where: str, hint: str) -> float:
    raw = text.strip()
    if not raw:
        raise InputError(f'{where}: column "{column}" is empty; {hint}')
    try:
        value = float(raw)
    except ValueError:
        extra = "; use a dot as the decimal separator" if "," in raw else ""
        raise InputError(f'{where}: column "{column}" is {_q(raw)}, not a number; {hint}{extra}') from None
    if not math.isfinite(value):
        raise InputError(f'{where}: column "{column}" is {_q(raw)}, not a finite number; {hint}')
    return value


def _read_text(path: Path, source: str) -> str:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"GCP file {source} does not exist; check the path") from None
    except IsADirectoryError:
        raise InputError(
            f"GCP file {source} is a folder, not a file; give the path of the GCP file"
        ) from None
    except OSError as exc:
        raise InputError(
            f"GCP file {source} cannot be read ({exc.strerror}); check its permissions"
        ) from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise InputError(
            f"{source} line {line}: the file is not UTF-8 text; save it as UTF-8 (plain CSV or text)"
        ) from None


def _split_header(line: str) -> tuple[str, list[str]]:
    """Best delimiter for a CSV header line and its lower-cased column names."""
    best: tuple[int, str, list[str]] | None = None
    for delim in (",", ";", "\t"):
        names = [c.strip().lower() for c in next(csv.reader([line], delimiter=delim))]
        score = len(set(names) & set(CSV_COLUMNS))
        if best is None or score > best[0]:
            best = (score, delim, names)
    assert best is not None
    return best[1], best[2]


def _parse_csv(text: str, source: str, delim: str) -> _Rows:
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delim)
    header: list[str] | None = None
    col: dict[str, int] = {}
    rows = _Rows([], [], [], [], [], [])
    for row in reader:
        line = reader.line_num
        if all(not c.strip() for c in row):
            continue
        if header is None:
            header = [c.strip().lower() for c in row]
            for name in CSV_COLUMNS:
                hits = [k for k, h in enumerate(header) if h == name]
                if len(hits) > 1:
                    raise InputError(
                        f'{source} line {line}: column "{name}" appears {len(hits)} times in the '
                        "header; keep one"
                    )
                if hits:
                    col[name] = hits[0]
            continue
        ncols = len(header)
        if len(row) < ncols or any(c.strip() for c in row[ncols:]):
            raise InputError(
                f"{source} line {line}: {len(row)} values but the header has {ncols} columns; "
                "check for missing or extra delimiters (quote text that contains them)"
            )
        gcp_id = row[col["id"]].strip()
        if not gcp_id:
            raise InputError(f'{source} line {line}: column "id" is empty; give every GCP a unique id')
        where = f"{source} line {line} (id {_q(gcp_id)})"
        vals = tuple(_number(row[col[c]], c, where, _HINTS[c]) for c in ("x", "y", "z", "u", "v"))
        role = row[col["role"]].strip().lower() if "role" in col else ""
        role = role or ROLE_CONTROL
        if role not in ROLES:
            raise InputError(
                f'{where}: column "role" is {_q(row[col["role"]].strip())}; use "control" (used in the fit) '
                'or "check" (independent check point), or leave it empty for "control"'
            )
        sigma = 1.0
        if "sigma_px" in col and row[col["sigma_px"]].strip():
            sigma = _number(row[col["sigma_px"]], "sigma_px", where, _HINTS["sigma_px"])
            if sigma <= 0:
                raise InputError(
                    f'{where}: column "sigma_px" is {_fmt(sigma)}, not > 0; {_HINTS["sigma_px"]}'
                )
        rows.ids.append(gcp_id)
        rows.values.append(vals)  # type: ignore[arg-type]
        rows.roles.append(role)
        rows.sigma.append(sigma)
        rows.lines.append(line)
        rows.images.append("")
    if not rows.ids:
        raise InputError(f"{source} has a header but no GCP rows; add one row per point: id,x,y,z,u,v")
    return rows


def _parse_odm(lines: list[str], first: int, source: str) -> _Rows:
    rows = _Rows([], [], [], [], [], [])
    for k in range(first + 1, len(lines)):
        line = k + 1
        text = lines[k].strip()
        if not text or text.startswith("#"):
            continue
        parts = text.split()
        if len(parts) < 6:
            raise InputError(
                f"{source} line {line}: {len(parts)} values, but an OpenDroneMap GCP row needs at least 6: "
                "geo_x geo_y geo_z im_x im_y image_name [gcp_name]; fix or delete the line"
            )
        gcp_id = parts[6] if len(parts) > 6 else f"row{line}"
        where = f"{source} line {line} (id {_q(gcp_id)})"
        hints = ("x", "y", "z", "u", "v")
        vals = tuple(_number(parts[j], _ODM_COLUMNS[j], where, _HINTS[hints[j]]) for j in range(5))
        rows.ids.append(gcp_id)
        rows.values.append(vals)  # type: ignore[arg-type]
        rows.roles.append(ROLE_CONTROL)
        rows.sigma.append(1.0)
        rows.lines.append(line)
        rows.images.append(parts[5])
    if not rows.ids:
        raise InputError(
            f"{source} has a CRS line but no GCP rows; "
            "add rows: geo_x geo_y geo_z im_x im_y image_name [gcp_name]"
        )
    return rows


def _list_names(names: list[str], limit: int = 10) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def _select_image(rows: _Rows, odm_image: str | None, source: str) -> np.ndarray:
    """Indices of the rows of the requested image (all rows when the file has a single image)."""
    keys: dict[str, str] = {}
    for name in rows.images:
        keys.setdefault(name.lower(), name)
    names = list(keys.values())
    if odm_image is None:
        if len(keys) > 1:
            raise InputError(
                f"{source}: the GCPs belong to {len(keys)} images ({_list_names(names)}); "
                f"say which image the camera sees with --odm-image NAME (e.g. --odm-image {names[0]})"
            )
        return np.arange(len(rows.ids))
    wanted = odm_image.strip().lower()
    wanted_base = os.path.basename(wanted.replace("\\", "/"))
    sel = [
        i
        for i, name in enumerate(rows.images)
        if name.lower() == wanted or os.path.basename(name.lower().replace("\\", "/")) == wanted_base
    ]
    if not sel:
        raise InputError(
            f"{source}: no GCP rows for image {_q(odm_image)}; the file has images {_list_names(names)}; "
            "pass one of them with --odm-image"
        )
    return np.asarray(sel, dtype=np.intp)


def _check_unique_ids(rows: _Rows, idx: np.ndarray, source: str) -> None:
    seen: dict[str, int] = {}
    for i in idx:
        gcp_id = rows.ids[i]
        if gcp_id in seen:
            raise InputError(
                f"{source} line {rows.lines[i]} (id {_q(gcp_id)}): id {_q(gcp_id)} is also used on line "
                f"{seen[gcp_id]}; give every GCP a unique id"
            )
        seen[gcp_id] = rows.lines[i]


def _parse_option_crs(value: str | pyproj.CRS | None, option: str) -> pyproj.CRS | None:
    try:
        return parse_crs(value)
    except InputError as exc:
        raise InputError(f"{option}: {exc}") from None


def _first(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def _resolve_crs(
    x: np.ndarray,
    y: np.ndarray,
    gcp_crs: pyproj.CRS | None,
    crs: pyproj.CRS | None,
    *,
    source: str,
    lines: list[int],
    names: tuple[str, str],
    declared_by: str,
) -> tuple[np.ndarray, np.ndarray, pyproj.CRS | None]:
    """Check x, y against the GCP CRS and transform them to the working CRS."""
    xn, yn = names

    def at(i: int) -> str:
        return f"line {lines[i]}: {xn}={_fmt(x[i])}, {yn}={_fmt(y[i])}"

    if crs is not None and not (crs.is_projected and not is_geographic(crs)):
        hint = " (to read longitude/latitude GCPs give --gcp-crs EPSG:4326)" if is_geographic(crs) else ""
        raise InputError(
            f"working CRS (--crs) {crs_label(crs)} is not a projected CRS{hint}; "
            "give a projected CRS for --crs such as a UTM zone (e.g. EPSG:32616) or leave it out"
        )
    if gcp_crs is None:
        gcp_crs = crs
        declared_by = "given with --crs"
    if gcp_crs is None:
        if looks_like_lonlat(x, y) or looks_like_lonlat(y, x):
            raise InputError(
                f"{source}: the GCP coordinates look like longitude/latitude degrees ({at(0)}) "
                "but no CRS was given; pass --gcp-crs EPSG:4326 (longitude in x, latitude in y)"
            )
        return x, y, None
    if is_geographic(gcp_crs):
        lat_first = (np.abs(y) > 90) & (np.abs(x) <= 90)
        if np.any(lat_first) and np.all(np.abs(x) <= 90):
            i = _first(lat_first)
            raise InputError(
                f"{source}: {yn} should be latitude but reaches {_fmt(y[i])} ({at(i)}) while {xn} stays "
                f"within ±90: the file seems to list latitude first; swap the {xn} and {yn} columns so "
                "longitude comes first"
            )
        bad = (np.abs(x) > 180) | (np.abs(y) > 90)
        if np.any(bad):
            i = _first(bad)
            raise InputError(
                f"{source} {at(i)} is not longitude/latitude in degrees, but the GCP CRS "
                f"{crs_label(gcp_crs)} ({declared_by}) is geographic; "
                "give the file's projected CRS with --gcp-crs (e.g. EPSG:32616)"
            )
        target = crs
        if target is None:
            lat = float(np.mean(y))
            if not -80.0 <= lat <= 84.0:
                raise InputError(
                    f"{source}: the mean latitude ({yn}) of the points is {lat:.6g}, outside the UTM range "
                    f"(-80 to 84), so no UTM zone fits ({at(0)}); if the file lists latitude first, swap the "
                    f"{xn} and {yn} columns, otherwise give a polar projected CRS with --crs"
                )
            target = utm_crs_for(float(np.mean(x)), lat)
    else:
        if not gcp_crs.is_projected:
            raise InputError(
                f"GCP CRS {crs_label(gcp_crs)} ({declared_by}) is neither geographic nor projected; give "
                "--gcp-crs as longitude/latitude (EPSG:4326) or a projected CRS (e.g. EPSG:32616)"
            )
        if looks_like_lonlat(x, y) or looks_like_lonlat(y, x):
            order = "" if looks_like_lonlat(x, y) else ", after swapping the columns so longitude comes first"
            raise InputError(
                f"{source}: the GCP coordinates look like longitude/latitude degrees ({at(0)}) "
                f"but the GCP CRS {crs_label(gcp_crs)} ({declared_by}) is projected; "
                f"pass --gcp-crs EPSG:4326{order}"
            )
        target = crs if crs is not None else gcp_crs
        if target == gcp_crs:
            return x, y, gcp_crs
    tx, ty = transform_xy(x, y, gcp_crs, target)
    bad = ~(np.isfinite(tx) & np.isfinite(ty))
    if np.any(bad):
        i = _first(bad)
        raise InputError(
            f"{source} {at(i)} cannot be transformed from {crs_label(gcp_crs)} to {crs_label(target)}; "
            "check the point and the CRSs (--gcp-crs, --crs)"
        )
    return tx, ty, target


def read_gcps(
    path: str | os.PathLike[str],
    *,
    gcp_crs: str | pyproj.CRS | None = None,
    crs: str | pyproj.CRS | None = None,
    odm_image: str | None = None,
) -> GCPTable:
    """Read a GCP file (CSV or OpenDroneMap ``gcp_list.txt``, see the module docstring) as a GCPTable.

    Args:
        path: the file.
        gcp_crs: CRS of the file's x, y. For CSV it comes only from here; for OpenDroneMap files it overrides
            the CRS line of the file. Geographic CRSs take x = longitude, y = latitude (degrees).
        crs: working projected CRS of the result. Geographic points go to ``crs``, or, when it is ``None``,
            to the WGS 84 UTM zone of their mean position. Projected points are transformed to ``crs`` when
            it differs from ``gcp_crs``. Given alone, ``crs`` is also the CRS of the file. Neither given:
            local coordinates, ``table.crs is None``.
        odm_image: for OpenDroneMap files, keep the rows of this image (case-insensitive). Required when the
            file lists several images. Ignored for CSV.

    Z is passed through unchanged. Raises :class:`~trafficgeo.errors.InputError` (one line, naming the file,
    line and id) for a missing or empty file, missing columns, non-numeric or non-finite values, duplicate
    ids, unknown roles, sigma_px <= 0, latitude-first longitude/latitude files, longitude/latitude values in
    a file declared projected, and bad CRSs.
    """
    p = Path(path)
    source = os.fspath(path)
    text = _read_text(p, source)
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    first = next((k for k, line in enumerate(lines) if line.strip()), None)
    if first is None:
        raise InputError(
            f"GCP file {source} is empty; give a CSV with header id,x,y,z,u,v or an OpenDroneMap gcp_list.txt"
        )
    header = lines[first].strip()
    delim, names = _split_header(header)
    gcp_crs_obj = _parse_option_crs(gcp_crs, "--gcp-crs")
    crs_obj = _parse_option_crs(crs, "--crs")
    declared_by = "given with --gcp-crs"
    if set(REQUIRED_COLUMNS) <= set(names):
        rows = _parse_csv(text, source, delim)
        xy_names = ("x", "y")
    elif len(set(names) & set(CSV_COLUMNS)) >= 2:
        missing = [c for c in REQUIRED_COLUMNS if c not in names]
        raise InputError(
            f"{source} line {first + 1}: the header lacks the column(s) "
            f"{', '.join(repr(c) for c in missing)}; "
            f"a GCP CSV needs the columns id,x,y,z,u,v (any order, any case; found {_q(header, 60)})"
        )
    else:
        try:
            # A CSV-like line (commas but no WKT/PROJJSON brackets) or a comment is no CRS: skip pyproj's slow
            # name search and report the first line directly.
            if header.startswith("#") or ("," in header and not any(ch in header for ch in "[({")):
                raise InputError(header)
            header_crs = parse_crs(header)
        except InputError:
            raise InputError(
                f"{source} line {first + 1}: {_q(header, 60)} is neither a CSV header with columns "
                'id,x,y,z,u,v nor an OpenDroneMap CRS line such as "WGS84 UTM 10N" or "EPSG:32610"; '
                "fix the first line"
            ) from None
        rows = _parse_odm(lines, first, source)
        xy_names = ("geo_x", "geo_y")
        if gcp_crs_obj is None:
            gcp_crs_obj = header_crs
            declared_by = f"from line {first + 1} of the file"
    values = np.asarray(rows.values, dtype=np.float64).reshape(-1, 5)
    # CRS checks and the UTM zone use every row, so all images of an ODM file share one CRS.
    x, y, wcrs = _resolve_crs(
        values[:, 0],
        values[:, 1],
        gcp_crs_obj,
        crs_obj,
        source=source,
        lines=rows.lines,
        names=xy_names,
        declared_by=declared_by,
    )
    idx = _select_image(rows, odm_image, source) if xy_names[0] == "geo_x" else np.arange(len(rows.ids))
    _check_unique_ids(rows, idx, source)
    world = np.column_stack([x[idx], y[idx], values[idx, 2]])
    return GCPTable(
        ids=tuple(rows.ids[i] for i in idx),
        world=world,
        pixels=values[idx, 3:5],
        roles=tuple(rows.roles[i] for i in idx),
        sigma_px=np.asarray(rows.sigma, dtype=np.float64)[idx],
        crs=wcrs,
        source=source,
        lines=tuple(rows.lines[i] for i in idx),
    )


# ------------------------------------------------------------------------------------------ validation


def _image_size(image_size: tuple[int, int]) -> tuple[int, int]:
    try:
        w, h = (int(s) for s in image_size)
        ok = w > 0 and h > 0 and all(float(s) == int(s) for s in image_size)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError(
            f"image size {image_size!r} is not two positive whole numbers; give --image-size W H"
        )
    return w, h


def _unit(crs: pyproj.CRS | None) -> str:
    if crs is None:
        return "units"
    name = crs.axis_info[0].unit_name if crs.axis_info else "units"
    return {"metre": "m", "foot": "ft", "US survey foot": "ftUS"}.get(name, name)


def _clusters(points: np.ndarray, tol: float) -> list[list[int]]:
    """Single-linkage groups of points closer than ``tol`` (connected components of the close pairs), each sorted,
    in order of first row."""
    n = len(points)
    pairs = cKDTree(points).query_pairs(tol, output_type="ndarray").reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    labels = connected_components(graph, directed=False)[1]
    groups: dict[int, list[int]] = {}
    for i, label in enumerate(labels.tolist()):
        groups.setdefault(label, []).append(i)
    return list(groups.values())


def _flatness(points: np.ndarray) -> float:
    """Smallest / largest singular value of the centred 2D points (0 = collinear, 1 = isotropic spread)."""
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0


def _closest_pair(points: np.ndarray, radius: float) -> tuple[int, int, float] | None:
    pairs = cKDTree(points).query_pairs(radius)
    if not pairs:
        return None
    i, j = min(pairs, key=lambda p: (min(p), max(p)))
    i, j = min(i, j), max(i, j)
    return i, j, float(np.linalg.norm(points[i] - points[j]))


def validate_gcps(table: GCPTable, image_size: tuple[int, int], *, min_control: int = 4) -> list[str]:
    """Check that ``table`` can calibrate a camera with a ``(width, height)`` image; return warnings.

    Raises :class:`~trafficgeo.errors.InputError` for: a pixel outside the image; two rows with the same pixel
    (within 0.5 px) or the same world point (within 1e-3 CRS units in 3D); fewer than ``min_control`` control
    points; degenerate control geometry on the ground (after merging control points closer than
    max(0.5 % of the XY extent, 0.2 m) fewer than min(4, min_control) distinct points remain, the distinct
    points are (nearly) collinear, or, with exactly 4 distinct points, 3 of them are) or in the image
    (collinear pixels). "Nearly collinear" means the smallest singular value of the centred coordinates is
    below 1 % of the largest.

    Returns plain-text warnings for: fewer than 6 control points (little redundancy), control pixels covering
    less than 10 % of the image (convex hull), control points merged as coincident.
    """
    w, h = _image_size(image_size)
    warnings: list[str] = []
    src = table.source
    px = table.pixels
    outside = (px[:, 0] < -0.5) | (px[:, 0] > w - 0.5) | (px[:, 1] < -0.5) | (px[:, 1] > h - 0.5)
    if np.any(outside):
        i = _first(outside)
        raise InputError(
            f"{table.where(i)}: pixel (u={_fmt(px[i, 0])}, v={_fmt(px[i, 1])}) is outside the {w}x{h} image "
            f"(u from -0.5 to {w - 0.5}, v from -0.5 to {h - 0.5}, (0, 0) = centre of the top-left pixel); "
            "check --image-size or the pixel"
        )
    if table.n >= 2:
        dup = _closest_pair(px, 0.5)
        if dup is not None:
            i, j, d = dup
            raise InputError(
                f"{table.where(i)} and {table.row_label(j)} have the same pixel ({d:.2g} px apart); "
                "delete the duplicate row or correct its pixel"
            )
        dup = _closest_pair(table.world, 1e-3)
        if dup is not None:
            i, j, d = dup
            raise InputError(
                f"{table.where(i)} and {table.row_label(j)} have the same world point ({d:.2g} "
                f"{_unit(table.crs)} apart); delete the duplicate row or correct its coordinates"
            )
    ctrl = np.flatnonzero(table.is_control)
    n_ctrl = len(ctrl)
    n_check = table.n - n_ctrl
    if n_ctrl < min_control:
        raise InputError(
            f"{src}: {n_ctrl} control point(s), but calibration needs at least {min_control}; check points "
            f'(role "check", {n_check} here) don\'t count; add control points or change some roles to control'
        )
    if n_ctrl == 0:
        return warnings
    unit = _unit(table.crs)
    xy = table.world[ctrl, :2]
    extent = float(np.hypot(*np.ptp(xy, axis=0)))
    try:
        floor = 0.2 / metres_per_unit(table.crs)
    except InputError:
        floor = 0.2
    tol = max(0.005 * extent, floor)
    groups = _clusters(xy, tol)
    merged = [g for g in groups if len(g) > 1]

    def describe(g: list[int]) -> str:
        span = max(float(np.linalg.norm(xy[a] - xy[b])) for a in g for b in g)
        labels = [table.row_label(ctrl[k]) for k in g]
        names = " and ".join(labels) if len(labels) == 2 else ", ".join(labels)
        return f"{names} ({span:.2g} {unit} apart)"

    needed = min(4, min_control)
    if len(groups) < needed:
        what = "; ".join(describe(g) for g in merged) or "all points"
        raise InputError(
            f"{src}: degenerate control points: {what} coincide on the ground "
            f"(closer than {tol:.2g} {unit}), leaving {len(groups)} distinct ground points; "
            f"at least {needed} well-spread points are needed, "
            "so replace the coincident points with points elsewhere in the scene"
        )
    if merged:
        warnings.append(
            f"{src}: control points {'; '.join(describe(g) for g in merged)} nearly coincide on the ground "
            f"(closer than {tol:.2g} {unit}); they add little to the calibration"
        )
    centres = np.array([xy[g].mean(axis=0) for g in groups])
    if len(groups) >= 3:
        flat = _flatness(centres)
        if flat < 0.01:
            raise InputError(
                f"{src}: degenerate control points: the {len(groups)} distinct ground points lie nearly "
                f"on one line (spread across it {flat:.2%} of the spread along it); "
                "add control points away from that line, e.g. across the road"
            )
        if len(groups) == 4:
            for drop in range(4):
                trio = [k for k in range(4) if k != drop]
                flat = _flatness(centres[trio])
                if flat < 0.01:
                    rows = ", ".join(table.row_label(ctrl[groups[k][0]]) for k in trio)
                    raise InputError(
                        f"{src}: degenerate control points: {rows} lie nearly on one line on the ground "
                        "and only 4 distinct points are given, "
                        "which leaves the ground-to-image mapping undetermined; "
                        "add control points or move one off that line"
                    )
    cpx = px[ctrl]
    if n_ctrl >= 3:
        flat = _flatness(cpx)
        if flat < 0.01:
            raise InputError(
                f"{src}: degenerate control points: their pixels lie nearly on one line in the image "
                f"(spread across it {flat:.2%} of the spread along it); "
                "add control points elsewhere in the image"
            )
        try:
            area = float(ConvexHull(cpx).volume)
        except QhullError:
            area = 0.0
        share = area / (w * h)
        if share < 0.10:
            warnings.append(
                f"{src}: the control points cover only {share:.1%} of the image "
                "(convex hull of their pixels); the calibration may be poor away from them, "
                "so add points near the image edges and corners"
            )
    if n_ctrl < 6:
        warnings.append(
            f"{src}: only {n_ctrl} control points; with fewer than 6 there is little redundancy to detect a "
            "wrong point, so add more if you can"
        )
    return warnings
