"""Coordinate reference system (CRS) helpers built on pyproj.

Conventions used throughout trafficgeo:

* **World coordinates** are in a *projected* CRS with X east, Y north and Z up, expressed in the CRS's own
  linear unit (metres, international feet or US survey feet; see :func:`metres_per_unit`), stored as float64.
  Whatever the axis order a CRS declares (some EPSG CRSs list northing first), trafficgeo always uses
  (X=easting, Y=northing): every transformation here uses ``always_xy=True``.
* **Geographic coordinates** are (longitude, latitude) in degrees, longitude first, for the same reason.
* ``None`` as a CRS means "unknown local coordinates": no transformation is possible and the unit is
  assumed to be the metre.

This module is a foundation layer: it imports nothing from trafficgeo except :mod:`trafficgeo.errors`.
The only state it keeps is an :func:`functools.lru_cache` of pyproj transformers keyed on CRS WKT strings.
"""

from __future__ import annotations

import functools
import math
import re

import numpy as np
import pyproj
from numpy.typing import ArrayLike
from pyproj.exceptions import CRSError

from trafficgeo.errors import InputError

__all__ = [
    "WGS84",
    "crs_label",
    "is_geographic",
    "lonlat_to_projected",
    "looks_like_lonlat",
    "metres_per_unit",
    "parse_crs",
    "projected_to_lonlat",
    "transform_xy",
    "utm_crs_for",
]

#: WGS 84 geographic 2D CRS (EPSG:4326). Used with ``always_xy=True``, i.e. (longitude, latitude).
WGS84: pyproj.CRS = pyproj.CRS.from_epsg(4326)

_EXAMPLES = 'e.g. "EPSG:32616", "WGS84 UTM 10N", "WGS84 longlat" or a WKT/PROJ string'
_ODM_UTM = re.compile(r"^WGS\s*-?\s*84\s+UTM\s+(\d{1,2})\s*([NS])$", re.IGNORECASE)
_ODM_LONLAT = re.compile(r"^WGS\s*-?\s*84\s+(longlat|lonlat)$", re.IGNORECASE)


def _shorten(text: str, limit: int = 60) -> str:
    """One-line, length-limited rendering of user text for error messages."""
    one_line = " ".join(str(text).split())
    return one_line if len(one_line) <= limit else one_line[: limit - 3] + "..."


def crs_label(crs: pyproj.CRS | None) -> str:
    """Short human-readable name of a CRS for messages, e.g. ``EPSG:2949 (NAD83(CSRS) / MTM zone 7)``."""
    if crs is None:
        return "no CRS (local coordinates)"
    auth = crs.to_authority(min_confidence=90)
    if auth is not None:
        return f"{auth[0]}:{auth[1]} ({crs.name})"
    return _shorten(crs.name or crs.srs)


def parse_crs(text: str | pyproj.CRS | None) -> pyproj.CRS | None:
    """Parse a CRS given by the user.

    Accepts anything pyproj understands ("EPSG:2949", WKT, PROJ strings such as
    "+proj=utm +zone=10 +datum=WGS84"), a :class:`pyproj.CRS` (returned unchanged), and the
    OpenDroneMap header forms "WGS84 UTM 10N" / "WGS84 UTM 17S" (-> EPSG:32610 / EPSG:32717) and
    "WGS84 longlat" / "WGS84 lonlat" (-> EPSG:4326, used as longitude, latitude). ``None`` returns ``None``.

    Raises:
        InputError: the text is empty or not a CRS; the message quotes it and shows valid examples.
    """
    if text is None:
        return None
    if isinstance(text, pyproj.CRS):
        return text
    if not isinstance(text, str):
        try:
            return pyproj.CRS.from_user_input(text)
        except CRSError as exc:
            raise InputError(
                f"{text!r} is not a coordinate reference system; give one as text, {_EXAMPLES}"
            ) from exc
    stripped = text.strip().strip("'\"").strip()
    if not stripped:
        raise InputError(f"the CRS is empty; give one, {_EXAMPLES}")
    match = _ODM_UTM.match(stripped)
    if match:
        zone = int(match.group(1))
        if not 1 <= zone <= 60:
            raise InputError(
                f'CRS "{_shorten(stripped)}": UTM zone {zone} does not exist; zones are 1 to 60, {_EXAMPLES}'
            )
        south = match.group(2).upper() == "S"
        return pyproj.CRS.from_epsg((32700 if south else 32600) + zone)
    if _ODM_LONLAT.match(stripped):
        return WGS84
    try:
        return pyproj.CRS.from_user_input(stripped)
    except CRSError as exc:
        raise InputError(
            f'"{_shorten(stripped)}" is not a coordinate reference system pyproj knows; give one, {_EXAMPLES}'
        ) from exc


def _horizontal(crs: pyproj.CRS) -> pyproj.CRS:
    """The horizontal part of a CRS: source CRS of a bound CRS, first component of a compound CRS."""
    if crs.is_bound and crs.source_crs is not None:
        crs = crs.source_crs
    if crs.is_compound and crs.sub_crs_list:
        crs = crs.sub_crs_list[0]
        if crs.is_bound and crs.source_crs is not None:
            crs = crs.source_crs
    return crs


def same_horizontal_crs(a: pyproj.CRS, b: pyproj.CRS) -> bool:
    """Whether two CRSs have the same horizontal CRS (axis order ignored; vertical parts are not compared)."""
    ha, hb = _horizontal(a), _horizontal(b)
    return bool(ha.equals(hb, ignore_axis_order=True) or ha == hb)


def is_geographic(crs: pyproj.CRS | None) -> bool:
    """True when the horizontal coordinates of ``crs`` are angles (longitude/latitude); False for ``None``."""
    if crs is None:
        return False
    return bool(_horizontal(crs).is_geographic)


def metres_per_unit(crs: pyproj.CRS | None) -> float:
    """Length in metres of one unit of the horizontal axes of ``crs``.

    1.0 for ``None`` (local coordinates are assumed to be metres) and for metre CRSs, 0.3048 for the
    international foot (e.g. EPSG:2994), 1200/3937 = 0.30480060960121924 for the US survey foot (e.g.
    EPSG:2240), as given by the PROJ database.

    Raises:
        InputError: ``crs`` is geographic (degrees have no fixed length) or declares no linear unit.
    """
    if crs is None:
        return 1.0
    horizontal = _horizontal(crs)
    if horizontal.is_geographic:
        raise InputError(
            f"CRS {crs_label(crs)} is geographic (degrees), so it has no linear unit; "
            "use a projected CRS such as a UTM zone (e.g. EPSG:32616)"
        )
    for axis in horizontal.axis_info[:2]:
        factor = axis.unit_conversion_factor
        if factor and math.isfinite(factor) and factor > 0 and axis.unit_name not in ("degree", "radian"):
            return float(factor)
    raise InputError(
        f"CRS {crs_label(crs)} declares no linear unit for its horizontal axes; "
        "use a projected CRS with metre or foot axes (e.g. EPSG:32616)"
    )


def utm_crs_for(lon: float, lat: float) -> pyproj.CRS:
    """WGS 84 / UTM CRS (EPSG:326zz north, 327zz south) of the zone containing (lon, lat) in degrees.

    Uses the standard 6-degree zones with the Norway (32V) and Svalbard (31X-37X) exceptions.

    Raises:
        InputError: lon/lat are not finite or out of range (|lon| > 180 or |lat| > 90 degrees), or the
            latitude is outside the UTM range (80 degrees south to 84 degrees north).
    """
    lon = float(lon)
    lat = float(lat)
    if not (math.isfinite(lon) and math.isfinite(lat)) or abs(lon) > 180 or abs(lat) > 90:
        raise InputError(
            f"longitude {lon!r}, latitude {lat!r} is not a position on Earth; give longitude in [-180, 180] "
            "and latitude in [-90, 90] degrees"
        )
    if not -80.0 <= lat <= 84.0:
        raise InputError(
            f"latitude {lat!r} is outside the UTM range (-80 to 84 degrees), so no UTM zone fits; "
            "use a polar projected CRS (e.g. EPSG:3031 or EPSG:3413)"
        )
    zone = min(math.floor((lon + 180.0) / 6.0) + 1, 60)
    if 56.0 <= lat < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    elif 72.0 <= lat <= 84.0 and 0.0 <= lon < 42.0:
        if lon < 9.0:
            zone = 31
        elif lon < 21.0:
            zone = 33
        elif lon < 33.0:
            zone = 35
        else:
            zone = 37
    return pyproj.CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)


def _crs_key(crs: pyproj.CRS) -> str:
    return crs.to_wkt() or crs.srs


@functools.lru_cache(maxsize=64)
def _transformer(src_key: str, dst_key: str) -> pyproj.Transformer:
    return pyproj.Transformer.from_crs(
        pyproj.CRS.from_user_input(src_key), pyproj.CRS.from_user_input(dst_key), always_xy=True
    )


def transform_xy(
    x: ArrayLike, y: ArrayLike, src_crs: pyproj.CRS, dst_crs: pyproj.CRS
) -> tuple[np.ndarray, np.ndarray]:
    """Transform horizontal coordinates between two CRSs (east/longitude first, ``always_xy=True``).

    Units are those of each CRS (degrees for geographic, CRS units for projected). Vectorized; returns
    float64 arrays of the broadcast input shape. Points that cannot be transformed come back as inf/NaN.
    """
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    if src_crs == dst_crs:
        return xa.copy(), ya.copy()
    tx, ty = _transformer(_crs_key(src_crs), _crs_key(dst_crs)).transform(xa, ya)
    return np.asarray(tx, dtype=np.float64), np.asarray(ty, dtype=np.float64)


def _require_projected(crs: pyproj.CRS, what: str) -> None:
    if crs is None or not _horizontal(crs).is_projected:
        raise InputError(
            f"{what} needs a projected CRS but got {crs_label(crs)}; use a projected CRS such as a UTM zone "
            "(e.g. EPSG:32616)"
        )


def lonlat_to_projected(lon: ArrayLike, lat: ArrayLike, crs: pyproj.CRS) -> tuple[np.ndarray, np.ndarray]:
    """WGS 84 longitude/latitude (degrees) to (X east, Y north) in the units of the projected ``crs``.

    Raises:
        InputError: ``crs`` is not projected.
    """
    _require_projected(crs, "converting longitude/latitude to map coordinates")
    return transform_xy(lon, lat, WGS84, crs)


def projected_to_lonlat(x: ArrayLike, y: ArrayLike, crs: pyproj.CRS) -> tuple[np.ndarray, np.ndarray]:
    """(X east, Y north) in the projected ``crs`` units to WGS 84 (longitude, latitude) in degrees.

    Points with a non-finite x or y (no position) get NaN.

    Raises:
        InputError: ``crs`` is not projected.
    """
    _require_projected(crs, "converting map coordinates to longitude/latitude")
    xa, ya = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    lon = np.full(xa.shape, np.nan)
    lat = np.full(xa.shape, np.nan)
    finite = np.isfinite(xa) & np.isfinite(ya)
    if finite.any():
        lon[finite], lat[finite] = transform_xy(xa[finite], ya[finite], crs, WGS84)
    return lon, lat


def looks_like_lonlat(x: ArrayLike, y: ArrayLike) -> bool:
    """Heuristic: do these x, y look like longitude/latitude degrees rather than projected coordinates?

    True when every |x| <= 180 and |y| <= 90 and the points span less than 1 unit in both x and y
    (a scene spans many metres or feet in a projected CRS, but only a tiny fraction of a degree).
    Returns False for empty or non-finite input.
    """
    xa = np.asarray(x, dtype=np.float64).ravel()
    ya = np.asarray(y, dtype=np.float64).ravel()
    if xa.size == 0 or xa.shape != ya.shape or not (np.all(np.isfinite(xa)) and np.all(np.isfinite(ya))):
        return False
    if np.any(np.abs(xa) > 180.0) or np.any(np.abs(ya) > 90.0):
        return False
    return bool(np.ptp(xa) < 1.0 and np.ptp(ya) < 1.0)
