"""Reading GCP files: CSV (``id,x,y,z,u,v[,role,sigma_px]``) and OpenDroneMap ``gcp_list.txt``, with their CRS
(:func:`read_gcps`). See :mod:`trafficgeo.calibration.gcp_table` for the conventions."""

from __future__ import annotations

import csv
import io
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj

from trafficgeo.calibration.gcp_table import (
    COLUMN_ALIASES,
    COLUMN_HINTS,
    ODM_COLUMNS,
    PIXEL_BESIDE_LONLAT,
    ROLE_CONTROL,
    ROLES,
    GCPTable,
    first_index,
    format_number,
    quote_text,
)
from trafficgeo.crs import (
    crs_label,
    is_geographic,
    looks_like_lonlat,
    parse_crs,
    transform_xy,
    utm_crs_for,
)
from trafficgeo.errors import InputError

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
        raise InputError(f'{where}: column "{column}" is {quote_text(raw)}, not a number; {hint}{extra}') from None
    if not math.isfinite(value):
        raise InputError(f'{where}: column "{column}" is {quote_text(raw)}, not a finite number; {hint}')
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


def _normal(name: str) -> str:
    """A column name as the aliases are written: lower case, runs of other characters as one underscore."""
    return re.sub(r"[^a-z0-9]+", "_", name.strip().lower()).strip("_")


@dataclass(frozen=True)
class _Header:
    """How a CSV header was understood: the column index of each of id, x, y, z, u, v, role, sigma_px that is
    there, the file's own name of each, whether x, y are longitude, latitude by their names, and the note."""

    col: dict[str, int]
    names: dict[str, str]
    lonlat: bool
    note: str


def _understand(raw: list[str]) -> _Header:
    """Map a header's columns to id, x, y, z, u, v, role, sigma_px by :data:`COLUMN_ALIASES` (see
    :func:`read_gcps`)."""
    normal = [_normal(c) for c in raw]

    def find(key: str) -> int | None:
        for alias in COLUMN_ALIASES[key]:
            if alias in normal:
                return normal.index(alias)
        return None

    keys = ("id", "u", "v", "x", "y", "z", "role", "sigma_px", "image")
    col = {k: i for k in keys if (i := find(k)) is not None}
    lon, lat = find("lon"), find("lat")
    lonlat = False
    if lon is not None and lat is not None:
        if "u" not in col and "v" not in col:
            for nu, nv in PIXEL_BESIDE_LONLAT:  # x, y beside lon, lat are the pixel's
                if nu in normal and nv in normal:
                    col["u"], col["v"] = normal.index(nu), normal.index(nv)
                    if nu == "x":  # they were taken for the world's x, y above
                        del col["x"], col["y"]
                    break
        if "x" not in col and "y" not in col:
            col["x"], col["y"], lonlat = lon, lat, True
    names = {k: raw[i].strip() for k, i in col.items()}
    renamed = [f"{names[k]} -> {k}" for k in keys
               if k in names and _normal(names[k]) != k]
    note = ", ".join(renamed)
    if lonlat:
        note += " (longitude, latitude by their names)"
    return _Header(col, names, lonlat, note)


def _split_header(line: str) -> tuple[str, list[str]]:
    """Best delimiter for a CSV header line and its column names as written (stripped)."""
    best: tuple[int, str, list[str]] | None = None
    for delim in (",", ";", "\t"):
        names = [c.strip() for c in next(csv.reader([line], delimiter=delim))]
        score = len(_understand(names).col)
        if best is None or score > best[0]:
            best = (score, delim, names)
    assert best is not None
    return best[1], best[2]


def _parse_csv(text: str, source: str, delim: str, ground_z: float | None = None) -> _Rows:
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delim, skipinitialspace=True)
    header: list[str] | None = None
    col: dict[str, int] = {}
    rows = _Rows([], [], [], [], [], [])
    for row in reader:
        line = reader.line_num
        if all(not c.strip() for c in row):
            continue
        if header is None:
            header = [c.strip() for c in row]
            understood = _understand(header)
            for k in understood.col.values():
                same = [j for j, h in enumerate(header) if _normal(h) == _normal(header[k])]
                if len(same) > 1:
                    raise InputError(
                        f'{source} line {line}: column "{header[k]}" appears {len(same)} times in the '
                        "header; keep one"
                    )
            col = understood.col
            named = understood.names
            continue
        ncols = len(header)
        if len(row) < ncols or any(c.strip() for c in row[ncols:]):
            raise InputError(
                f"{source} line {line}: {len(row)} values but the header has {ncols} columns; "
                "check for missing or extra delimiters (quote text that contains them)"
            )
        gcp_id = row[col["id"]].strip() if "id" in col else f"line{line}"
        if not gcp_id:
            raise InputError(f'{source} line {line}: column "{named["id"]}" is empty; give every GCP a unique id')
        where = f"{source} line {line} (id {quote_text(gcp_id)})"
        vals = tuple(ground_z if c == "z" and "z" not in col else _number(row[col[c]], named[c], where, COLUMN_HINTS[c])
                     for c in ("x", "y", "z", "u", "v"))
        role = row[col["role"]].strip().lower() if "role" in col else ""
        role = role or ROLE_CONTROL
        if role not in ROLES:
            raise InputError(
                f'{where}: column "role" is {quote_text(row[col["role"]].strip())}; use "control" (used in the fit) '
                'or "check" (independent check point), or leave it empty for "control"'
            )
        sigma = 1.0
        if "sigma_px" in col and row[col["sigma_px"]].strip():
            sigma = _number(row[col["sigma_px"]], "sigma_px", where, COLUMN_HINTS["sigma_px"])
            if sigma <= 0:
                raise InputError(
                    f'{where}: column "sigma_px" is {format_number(sigma)}, not > 0; {COLUMN_HINTS["sigma_px"]}'
                )
        rows.ids.append(gcp_id)
        rows.values.append(vals)  # type: ignore[arg-type]
        rows.roles.append(role)
        rows.sigma.append(sigma)
        rows.lines.append(line)
        rows.images.append(row[col["image"]].strip() if "image" in col else "")
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
        where = f"{source} line {line} (id {quote_text(gcp_id)})"
        hints = ("x", "y", "z", "u", "v")
        vals = tuple(_number(parts[j], ODM_COLUMNS[j], where, COLUMN_HINTS[hints[j]]) for j in range(5))
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


def _parse_qgis_points(lines: list[str], first: int, names: list[str], source: str,
                       ground_z: float | None) -> tuple[_Rows, str]:
    """A QGIS Georeferencer ``.points`` file: ``mapX,mapY,sourceX,sourceY,enable[,dX,dY,residual]`` (older files:
    ``pixelX,pixelY``). Source coordinates are GDAL's, from the top-left *corner* of the image with the row
    negated, so u = sourceX - 0.5 and v = -sourceY - 0.5. Points with ``enable`` 0 are left out. The file has no
    heights: they come from ``ground_z``."""
    normal = [_normal(c) for c in names]
    at = {k: normal.index(k) for k in ("mapx", "mapy", "sourcex", "sourcey", "pixelx", "pixely", "enable")
          if k in normal}
    iu, iv = (at["sourcex"], at.get("sourcey")) if "sourcex" in at else (at["pixelx"], at.get("pixely"))
    if "mapy" not in at or iv is None:
        raise InputError(f"{source} line {first + 1}: a QGIS .points header needs mapX,mapY,sourceX,sourceY; "
                         f"found {quote_text(lines[first].strip(), 60)}")
    if ground_z is None:
        raise InputError(f"{source}: a QGIS .points file has no heights; give the ground's height with ground_z "
                         "(e.g. 0 for flat ground), or add a z column and save it as CSV",
                         parameters=("ground_z",))
    rows = _Rows([], [], [], [], [], [])
    disabled = 0
    for k in range(first + 1, len(lines)):
        text = lines[k].strip()
        if not text or text.startswith("#"):
            continue
        row = next(csv.reader([text], skipinitialspace=True))
        line = k + 1
        where = f"{source} line {line}"
        if len(row) < len(names):
            raise InputError(f"{where}: {len(row)} values but the header has {len(names)} columns; "
                             "check for missing delimiters")
        if "enable" in at and row[at["enable"]].strip() in ("0", "false", "False"):
            disabled += 1
            continue
        mx, my, sx, sy = (_number(row[i], names[i], where, COLUMN_HINTS[c])
                          for i, c in ((at["mapx"], "x"), (at["mapy"], "y"), (iu, "u"), (iv, "v")))
        if sy > 0:
            raise InputError(
                f'{where}: column "{names[iv]}" is {format_number(sy)}, but QGIS writes image rows as negative '
                "numbers: these points were taken on a georeferenced raster (map units); save them again on the "
                "plain image (without its world file)")
        rows.ids.append(f"line{line}")
        rows.values.append((mx, my, float(ground_z), sx - 0.5, -sy - 0.5))
        rows.roles.append(ROLE_CONTROL)
        rows.sigma.append(1.0)
        rows.lines.append(line)
        rows.images.append("")
    if not rows.ids:
        raise InputError(f"{source} has no enabled points; enable some in QGIS's Georeferencer or add rows")
    note = (f"QGIS Georeferencer points: mapX, mapY -> x, y; {names[iu]} - 0.5, -{names[iv]} - 0.5 -> u, v (pixel "
            f"corners to centres); z = {format_number(ground_z)} (ground_z); points named by their line")
    if disabled:
        note += f"; {disabled} disabled point(s) left out"
    return rows, note


def _list_names(names: list[str], limit: int = 10) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def _select_image(rows: _Rows, odm_image: str | None, source: str, column: str = "") -> np.ndarray:
    """Indices of the rows of the requested image (all rows when the file has a single image); ``column`` names
    the CSV column the images are in."""
    keys: dict[str, str] = {}
    for name in rows.images:
        keys.setdefault(name.lower(), name)
    names = list(keys.values())
    if odm_image is None:
        if len(keys) > 1:
            raise InputError(
                f"{source}: the GCPs belong to {len(keys)} images or cameras{column} ({_list_names(names)}); "
                f"say which image the camera sees with odm_image (e.g. odm_image {names[0]})",
                parameters=("odm_image",),
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
            f"{source}: no GCP rows for image {quote_text(odm_image)}; the file has images{column} "
            f"{_list_names(names)}; "
            "pass one of them as odm_image",
            parameters=("odm_image",),
        )
    return np.asarray(sel, dtype=np.intp)


def _check_unique_ids(rows: _Rows, idx: np.ndarray, source: str) -> None:
    seen: dict[str, int] = {}
    for i in idx:
        gcp_id = rows.ids[i]
        if gcp_id in seen:
            raise InputError(
                f"{source} line {rows.lines[i]} (id {quote_text(gcp_id)}): id {quote_text(gcp_id)} is also used on "
                f"line "
                f"{seen[gcp_id]}; give every GCP a unique id"
            )
        seen[gcp_id] = rows.lines[i]


def _parse_option_crs(value: str | pyproj.CRS | None, option: str) -> pyproj.CRS | None:
    try:
        return parse_crs(value)
    except InputError as exc:
        raise InputError(f"{option}: {exc}", parameters=(option,)) from None




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
        return f"line {lines[i]}: {xn}={format_number(x[i])}, {yn}={format_number(y[i])}"

    if crs is not None and not (crs.is_projected and not is_geographic(crs)):
        hint = " (to read longitude/latitude GCPs give gcp_crs EPSG:4326)" if is_geographic(crs) else ""
        raise InputError(
            f"working CRS (`crs`) {crs_label(crs)} is not a projected CRS{hint}; "
            "give a projected CRS for `crs` such as a UTM zone (e.g. EPSG:32616) or leave it out",
            parameters=("crs", "gcp_crs"),
        )
    if gcp_crs is None:
        gcp_crs = crs
        declared_by = "given with `crs`"
    if gcp_crs is None:
        if looks_like_lonlat(x, y) or looks_like_lonlat(y, x):
            raise InputError(
                f"{source}: the GCP coordinates look like longitude/latitude degrees ({at(0)}) "
                "but no CRS was given; pass gcp_crs EPSG:4326 (longitude in x, latitude in y)",
                parameters=("gcp_crs",),
            )
        return x, y, None
    if is_geographic(gcp_crs):
        lat_first = (np.abs(y) > 90) & (np.abs(x) <= 90)
        if np.any(lat_first) and np.all(np.abs(x) <= 90):
            i = first_index(lat_first)
            raise InputError(
                f"{source}: {yn} should be latitude but reaches {format_number(y[i])} ({at(i)}) while {xn} stays "
                f"within ±90: the file seems to list latitude first; swap the {xn} and {yn} columns so "
                "longitude comes first"
            )
        bad = (np.abs(x) > 180) | (np.abs(y) > 90)
        if np.any(bad):
            i = first_index(bad)
            raise InputError(
                f"{source} {at(i)} is not longitude/latitude in degrees, but the GCP CRS "
                f"{crs_label(gcp_crs)} ({declared_by}) is geographic; "
                "give the file's projected CRS with gcp_crs (e.g. EPSG:32616)",
                parameters=("gcp_crs", "crs"),
            )
        target = crs
        if target is None:
            lat = float(np.mean(y))
            if not -80.0 <= lat <= 84.0:
                raise InputError(
                    f"{source}: the mean latitude ({yn}) of the points is {lat:.6g}, outside the UTM range "
                    f"(-80 to 84), so no UTM zone fits ({at(0)}); if the file lists latitude first, swap the "
                    f"{xn} and {yn} columns, otherwise give a polar projected CRS with `crs`",
                    parameters=("crs",),
                )
            target = utm_crs_for(float(np.mean(x)), lat)
    else:
        if not gcp_crs.is_projected:
            raise InputError(
                f"GCP CRS {crs_label(gcp_crs)} ({declared_by}) is neither geographic nor projected; give "
                "gcp_crs as longitude/latitude (EPSG:4326) or a projected CRS (e.g. EPSG:32616)",
                parameters=("gcp_crs", "crs"),
            )
        if looks_like_lonlat(x, y) or looks_like_lonlat(y, x):
            order = "" if looks_like_lonlat(x, y) else ", after swapping the columns so longitude comes first"
            raise InputError(
                f"{source}: the GCP coordinates look like longitude/latitude degrees ({at(0)}) "
                f"but the GCP CRS {crs_label(gcp_crs)} ({declared_by}) is projected; "
                f"pass gcp_crs EPSG:4326{order}",
                parameters=("gcp_crs", "crs"),
            )
        target = crs if crs is not None else gcp_crs
        if target == gcp_crs:
            return x, y, gcp_crs
    tx, ty = transform_xy(x, y, gcp_crs, target)
    bad = ~(np.isfinite(tx) & np.isfinite(ty))
    if np.any(bad):
        i = first_index(bad)
        raise InputError(
            f"{source} {at(i)} cannot be transformed from {crs_label(gcp_crs)} to {crs_label(target)}; "
            "check the point and the CRSs (gcp_crs, `crs`)",
            parameters=("gcp_crs", "crs"),
        )
    return tx, ty, target


def read_gcps(
    path: str | os.PathLike[str],
    *,
    gcp_crs: str | pyproj.CRS | None = None,
    crs: str | pyproj.CRS | None = None,
    odm_image: str | None = None,
    ground_z: float | None = None,
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
        odm_image: keep the rows of this image (case-insensitive), in an OpenDroneMap file or a CSV with an image
            or camera column (``camera``, ``image``, ...). Required when the file lists several.
        ground_z: the height of every point of a CSV without a height column (points on flat ground; the
            camera's height is then measured from this plane). Ignored when the file has heights.

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
    qgis_crs_line = None
    if header.upper().startswith("#CRS:"):  # QGIS 3 Georeferencer .points: the map CRS, then the header
        qgis_crs_line = first
        first = next((k for k in range(first + 1, len(lines)) if lines[k].strip()), first)
        header = lines[first].strip()
    delim, names = _split_header(header)
    understood = _understand(names)
    gcp_crs_obj = _parse_option_crs(gcp_crs, "gcp_crs")
    crs_obj = _parse_option_crs(crs, "crs")
    declared_by = "given with gcp_crs"
    note = understood.note
    if ground_z is not None and not math.isfinite(ground_z):
        raise InputError(f"ground_z is {ground_z}; give the ground's height as a finite number, e.g. 0",
                         parameters=("ground_z",))
    have = set(understood.col) | ({"z"} if ground_z is not None else set())
    normal = [_normal(c) for c in names]
    if "mapx" in normal and ("sourcex" in normal or "pixelx" in normal):
        rows, note = _parse_qgis_points(lines, first, names, source, ground_z)
        xy_names = ("mapX", "mapY")
        if gcp_crs_obj is None and qgis_crs_line is not None:
            crs_text = lines[qgis_crs_line].strip()[5:].strip()
            try:
                gcp_crs_obj = parse_crs(crs_text)
            except InputError:
                raise InputError(
                    f"{source} line {qgis_crs_line + 1}: the map CRS {quote_text(crs_text, 40)} is not a CRS pyproj "
                    "knows; give the points' CRS with gcp_crs", parameters=("gcp_crs",)) from None
            declared_by = f"from line {qgis_crs_line + 1} of the file"
    elif {"x", "y", "z", "u", "v"} <= have:
        rows = _parse_csv(text, source, delim, ground_z)
        xy_names = (understood.names["x"], understood.names["y"])
        if "id" not in understood.col:
            note = ", ".join(filter(None, [note, "no id column: points named by their line"]))
        if understood.lonlat and gcp_crs_obj is None:
            gcp_crs_obj = parse_crs("EPSG:4326")
            declared_by = "taken as EPSG:4326 from the column names"
    elif len(understood.col) >= 2:
        missing = [c for c in ("x", "y", "z", "u", "v") if c not in understood.col]
        height = (" (a height: z, elevation or alt; the GCP web app takes it from a DEM; for points on flat "
                  "ground give ground_z, e.g. 0)" if missing == ["z"] else "")
        raise InputError(
            f"{source} line {first + 1}: the header lacks the column(s) "
            f"{', '.join(repr(c) for c in missing)}{height}; "
            "a GCP CSV needs id,x,y,z,u,v (any order, any case; also pixel_x/pixel_y, col/row, lat/lon, "
            f"easting/northing, elevation, ...; found {quote_text(header, 60)})",
            parameters=("ground_z",) if missing == ["z"] else (),
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
                f"{source} line {first + 1}: {quote_text(header, 60)} is neither a CSV header with columns "
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
    per_image = xy_names[0] == "geo_x" or "image" in understood.col
    column = "" if xy_names[0] == "geo_x" else f' (column {quote_text(understood.names.get("image", ""))})'
    idx = _select_image(rows, odm_image, source, column) if per_image else np.arange(len(rows.ids))
    _check_unique_ids(rows, idx, source)
    world = np.column_stack([x[idx], y[idx], values[idx, 2]])
    return GCPTable(
        columns_note=note if xy_names[0] != "geo_x" else "",
        from_lonlat=gcp_crs_obj is not None and is_geographic(gcp_crs_obj),
        ids=tuple(rows.ids[i] for i in idx),
        world=world,
        pixels=values[idx, 3:5],
        roles=tuple(rows.roles[i] for i in idx),
        sigma_px=np.asarray(rows.sigma, dtype=np.float64)[idx],
        crs=wcrs,
        source=source,
        lines=tuple(rows.lines[i] for i in idx),
    )
