"""SUMO exchange: floating car data (FCD) in and out, edge/lane mean data in.

Floating car data
-----------------
SUMO's ``--fcd-output`` is ``<fcd-export>`` with one ``<timestep time=...>`` per simulation step holding one
``<vehicle id x y [z] angle type speed pos lane slope .../>`` per vehicle (persons and containers are ignored).
Its position is the middle of the vehicle's **front bumper**, its ``angle`` the heading in degrees clockwise from
(grid) north and its ``speed`` in m/s. :func:`read_fcd` returns a table with the columns :data:`FCD_COLUMNS`:

* ``track_id`` (str, SUMO vehicle id), ``time`` (s), ``x, y, z`` (world CRS units; ``z`` NaN when the file has
  none), ``speed_kmh``, ``heading_deg`` ([0, 360), clockwise from the world CRS's grid north), ``class`` (SUMO
  vType id, "" if absent), ``sumo_lane`` (SUMO lane id, "" if absent) and ``front_bumper`` (True: ``x, y`` are
  SUMO's front bumper, not the footprint centre; shift back by half the vehicle length along the heading to get
  the centre).

Coordinates come in three kinds:

1. **network coordinates** (the default output): with ``net`` (the ``.net.xml``), ``x, y - netOffset`` are the
   coordinates in the network's projection (``<location projParameter>``, a PROJ string), reprojected to ``crs``
   if that is a different projection (the heading is rotated to the new grid north). A network without projection
   (``projParameter="!"``) gives ``x, y - netOffset`` as they are, taken to be in ``crs`` (noted in
   ``table.attrs["notes"]``). A PROJ string names no datum: ``net_crs=`` gives the network's real CRS (e.g.
   "EPSG:2949") when datum shifts to ``crs`` matter.
2. **geo FCD** (``--fcd-output.geo``: ``x`` = longitude, ``y`` = latitude), recognised from the values (within
   +-180/+-90 and moving about 1e-5 of the distance the speeds say, see :func:`_looks_geo`) or forced with
   ``geo=True``: projected to ``crs`` (required without ``net``). SUMO's longitude/latitude are on the geodetic
   datum of the network's projection: with ``net`` they are projected with it first, without ``net`` they are
   taken as WGS 84 and the heading (grid north of an unknown projection) is kept as it is.
3. **plain coordinates** (no ``net``, not geo; e.g. ``--fcd-output.utm``, which writes the network's projected
   coordinates): taken to be in ``crs`` as they are.

SUMO works in metres; ``z`` is converted to the units of ``crs`` (e.g. US survey feet) with ``x, y``. Each table
carries ``attrs["crs"]`` (WKT of the CRS of ``x, y``, or None) and ``attrs["notes"]`` (list of str).

:func:`write_fcd` is the inverse and writes what SUMO would (``speed`` in m/s; ``type`` and ``lane`` on every
vehicle when the table has them, "" if unknown), optionally shifting footprint centres to front bumpers.

Mean data
---------
:func:`read_meandata` reads SUMO's ``edgeData``/``laneData`` output (``<meandata><interval><edge>[<lane>]``).

Parsing speed: an FCD laid out as SUMO writes it (the same attributes in the same order on every vehicle, no
comments in the body) is read by a vectorised byte-level parser, about 3 s per million vehicle rows; anything
else goes through expat (about three times slower). Both need memory of a few times the file size.
"""

from __future__ import annotations

import csv
import html
import io
import os
import re
import warnings
import xml.parsers.expat
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj
from numpy.typing import ArrayLike

from trafficgeo.crs import crs_label, is_geographic, metres_per_unit, parse_crs, same_horizontal_crs, transform_xy
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_open

__all__ = [
    "FCD_COLUMNS",
    "MEANDATA_COLUMNS",
    "NetLocation",
    "read_fcd",
    "read_meandata",
    "read_net_location",
    "write_fcd",
]

FCD_COLUMNS = ["track_id", "time", "x", "y", "z", "speed_kmh", "heading_deg", "class", "sumo_lane", "front_bumper"]
MEANDATA_COLUMNS = ["interval_begin", "interval_end", "interval_id", "edge", "lane", "entered", "left", "speed_kmh",
                    "density", "occupancy"]
_FCD_HINT = "give a SUMO --fcd-output file (<fcd-export><timestep time=..><vehicle id x y .../>)"
_MEAN_HINT = "give a SUMO edgeData/laneData output (<meandata><interval begin end><edge id ...>)"
_VEHICLE_ATTRS = ("id", "x", "y", "z", "angle", "type", "speed", "lane")
_STR_ATTRS = ("id", "type", "lane")
_WS = np.frombuffer(b" \t\r\n", np.uint8)
_NO_PROJECTION = "!"
_SUMO_SPECIAL_PROJ = ("-", "UTM", "DHDN", "DHDN_UTM")
_ROOT = re.compile(rb"\A(?:\xef\xbb\xbf)?(?:\s+|<\?.*?\?>|<!--.*?-->|<!DOCTYPE[^>]*>)*<([\w:.-]+)", re.DOTALL)
_ATTR_NAMES = re.compile(rb'([\w:.-]+)\s*=\s*"')
_XSD = ('xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        'xsi:noNamespaceSchemaLocation="http://sumo.dlr.de/xsd/fcd_file.xsd"')


# ---------------------------------------------------------------------------------------------------- network
@dataclass(frozen=True)
class NetLocation:
    """The ``<location>`` of a SUMO network: ``sumo_xy = projected_xy + offset`` (network units, metres).

    ``crs`` is the network's projection (None when ``projParameter`` is ``"!"``: no projection).
    """

    offset: tuple[float, float]
    crs: pyproj.CRS | None
    proj_parameter: str


class _Stop(Exception):
    """Raised inside expat handlers to stop parsing early."""


def _check_file(path: str | os.PathLike[str], what: str, hint: str) -> Path:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: {what} not found; {hint}")
    return p


def read_net_location(net: str | os.PathLike[str]) -> NetLocation:
    """Read ``<location netOffset projParameter>`` at the top of a SUMO ``.net.xml`` (stops parsing there)."""
    p = _check_file(net, "SUMO network file", "give the .net.xml the simulation used")
    found: dict[str, str] = {}
    root: list[str] = []

    def start(name: str, attrs: dict[str, str]) -> None:
        root.append(name)
        if name == "location":
            found.update(attrs)
            raise _Stop
        if len(root) > 2:  # <location> comes right after <net>
            raise _Stop

    parser = xml.parsers.expat.ParserCreate()
    parser.StartElementHandler = start
    try:
        with open(p, "rb") as fh:
            parser.ParseFile(fh)
    except _Stop:
        pass
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(f"{p}: not readable XML ({exc}); give the .net.xml the simulation used") from None
    if not root or root[0] != "net" or "netOffset" not in found:
        raise InputError(f"{p}: no <net><location netOffset=...> found; give a SUMO network (.net.xml)")
    return NetLocation(_net_offset(p, found["netOffset"]), *_net_crs(p, found.get("projParameter", "!")))


def _net_offset(p: Path, text: str) -> tuple[float, float]:
    try:
        ox, oy = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"{p}: <location netOffset={text!r}> is not 'x,y'; give a valid SUMO network") from None
    return ox, oy


def _net_crs(p: Path, proj: str) -> tuple[pyproj.CRS | None, str]:
    proj = proj.strip()
    if proj == _NO_PROJECTION:
        return None, proj
    if proj in _SUMO_SPECIAL_PROJ:
        raise InputError(f"{p}: projParameter {proj!r} is a SUMO built-in projection trafficgeo cannot reproduce; "
                         "rebuild the network with netconvert --proj '<PROJ string>' (e.g. --proj.utm writes one)")
    try:
        return pyproj.CRS.from_user_input(proj), proj
    except pyproj.exceptions.CRSError:
        raise InputError(f"{p}: projParameter {proj!r} is not a PROJ string pyproj understands; "
                         "rebuild the network with netconvert --proj '<PROJ string>'") from None


def _location(net: str | os.PathLike[str] | None, net_crs: str | pyproj.CRS | None,
              where: str) -> NetLocation | None:
    """The network's location, its CRS replaced by ``net_crs`` when given."""
    if net is None:
        if net_crs is not None:
            raise InputError(f"{where}: net_crs is given without net; pass the .net.xml too, or crs alone")
        return None
    loc = read_net_location(net)
    if net_crs is None:
        return loc
    return NetLocation(loc.offset, _world_crs(net_crs, f"{where}: net_crs"), loc.proj_parameter)


def _label(crs: pyproj.CRS) -> str:
    """:func:`crs_label`, or the PROJ string for a CRS without a name (as built from a SUMO projParameter)."""
    label = crs_label(crs)
    return " ".join(sorted(_proj_tokens(crs)))[:80] if label.startswith("unknown") else label


def _proj_tokens(crs: pyproj.CRS) -> frozenset[str]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "You will likely lose important projection information"
        text = crs.to_proj4() or ""
    return frozenset(text.split()) - {"+no_defs", "+type=crs", "+wktext"}


def _same_projection(a: pyproj.CRS, b: pyproj.CRS) -> bool:
    """Same horizontal CRS, or the same PROJ projection (SUMO's PROJ strings carry no datum name)."""
    return same_horizontal_crs(a, b) or _proj_tokens(a) == _proj_tokens(b)


# ---------------------------------------------------------------------------------------------------- geometry
def _reproject(x: np.ndarray, y: np.ndarray, heading: np.ndarray, src: pyproj.CRS,
               dst: pyproj.CRS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Transform projected points and rotate headings (degrees clockwise from grid north) into ``dst``'s grid."""
    tx, ty = transform_xy(x, y, src, dst)
    h = np.radians(heading)
    ax, ay = transform_xy(x + np.sin(h), y + np.cos(h), src, dst)  # a point one source unit ahead
    new = np.mod(np.degrees(np.arctan2(ax - tx, ay - ty)), 360.0)
    return tx, ty, np.where(np.isfinite(heading), new, np.nan)


def _geodetic(crs: pyproj.CRS) -> pyproj.CRS:
    geo = crs.geodetic_crs
    if geo is None:
        raise InputError(f"CRS {crs_label(crs)} has no geodetic CRS, so longitude/latitude cannot be used with it")
    return geo


def _shift_along(x: np.ndarray, y: np.ndarray, heading: np.ndarray,
                 distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move points ``distance`` (their CRS units) along ``heading`` (degrees clockwise from grid north)."""
    h = np.radians(heading)
    return x + distance * np.sin(h), y + distance * np.cos(h)


def _world_crs(crs: str | pyproj.CRS | None, what: str) -> pyproj.CRS | None:
    parsed = parse_crs(crs)
    if parsed is not None and is_geographic(parsed):
        raise InputError(f"{what}: crs {crs_label(parsed)} is geographic; world coordinates need a projected CRS "
                         "(e.g. a UTM zone such as EPSG:32632)")
    return parsed


# ---------------------------------------------------------------------------------------------------- FCD parsing
def _root_element(head: bytes, p: Path, hint: str) -> re.Match[bytes]:
    m = _ROOT.match(head)
    if m is None:
        raise InputError(f"{p}: not an XML file; {hint}")
    return m


def _tag_mask(arr: np.ndarray, lt: np.ndarray, tag: bytes) -> np.ndarray:
    """Which ``<`` positions ``lt`` open an element ``tag`` (name followed by whitespace)."""
    idx = np.minimum(lt[:, None] + np.arange(1, len(tag) + 2), arr.size - 1)
    head = arr[idx]
    return np.all(head[:, :-1] == np.frombuffer(tag, np.uint8), axis=1) & np.isin(head[:, -1], _WS)


def _preceded_by(arr: np.ndarray, pos: np.ndarray, text: bytes) -> bool:
    """Whether ``text`` ends right before each position ``pos`` (an attribute's opening quote)."""
    sig = np.frombuffer(text, np.uint8)
    idx = pos[:, None] - sig.size + np.arange(sig.size)
    return bool(pos.size == 0 or (idx.min() >= 0 and np.all(arr[idx] == sig)))


def _spans_table(arr: np.ndarray, starts: list[np.ndarray], ends: list[np.ndarray],
                 names: list[str]) -> pd.DataFrame | None:
    """Attribute values at byte spans [start, end) as a table: the spans are cut out into a CSV (separator 0x01,
    which XML text cannot hold) read by pandas' C parser. None if a value does not parse."""
    delta = np.zeros(arr.size + 1, np.int8)
    for s, e in zip(starts, ends, strict=True):
        delta[s] += 1
        delta[e] -= 1
    keep = np.cumsum(delta[:-1], dtype=np.int8) > 0
    out = arr.copy()
    for k, e in enumerate(ends):
        out[e] = 10 if k == len(ends) - 1 else 1  # field separator, line end after the last field
        keep[e] = True
    dtypes = {n: (str if n in _STR_ATTRS else np.float64) for n in names}
    try:
        table = pd.read_csv(io.BytesIO(out[keep].tobytes()), sep="\x01", header=None, names=names, dtype=dtypes,
                            quoting=csv.QUOTE_NONE, na_filter=False, engine="c", skip_blank_lines=False)
    except (ValueError, pd.errors.ParserError):
        return None
    return table if len(table) == starts[0].size else None


def _parse_fcd_fast(body: bytes, where: str) -> dict[str, object] | None:
    """Vehicle attributes of an FCD body (from ``<fcd-export``) laid out as SUMO writes it: every vehicle with
    the same attributes in the same order, no comments. Vectorised over the bytes; None if the layout differs."""
    if b"<!--" in body or b"<![CDATA[" in body or not body[-4096:].rstrip().endswith(b"</fcd-export>"):
        return None
    arr = np.frombuffer(body, np.uint8)
    lt, q = np.flatnonzero(arr == ord("<")), np.flatnonzero(arr == ord('"'))
    if q.size % 2:
        return None
    qo, qc = q[0::2], q[1::2]
    first = np.searchsorted(qo, lt)
    count = np.diff(np.append(first, qo.size))
    veh, ts = _tag_mask(arr, lt, b"vehicle"), _tag_mask(arr, lt, b"timestep")
    if not veh.any():
        return None if b"<vehicle" in body else {"time": np.empty(0)}
    vfirst, k = first[veh], int(count[veh][0])
    names = _ATTR_NAMES.findall(body[lt[veh][0]:qc[vfirst[0] + k - 1] + 1]) if k else []
    tix = np.searchsorted(lt[ts], lt[veh]) - 1
    if (len(names) != k or np.any(count[veh] != k) or tix[0] < 0 or np.any(count[ts] < 1)
            or not _preceded_by(arr, qo[first[ts]], b" time=")
            or not all(_preceded_by(arr, qo[vfirst + j], b" " + n + b"=") for j, n in enumerate(names))):
        return None
    wanted = [j for j, n in enumerate(names) if n.decode() in _VEHICLE_ATTRS]
    if not wanted:
        return None
    table = _spans_table(arr, [qo[vfirst + j] + 1 for j in wanted], [qc[vfirst + j] for j in wanted],
                         [names[j].decode() for j in wanted])
    if table is None:
        return None
    t = first[ts]
    stamps = [body[a + 1:b] for a, b in zip(qo[t].tolist(), qc[t].tolist(), strict=True)]
    cols: dict[str, object] = {c: table[c] if c in _STR_ATTRS else table[c].to_numpy() for c in table.columns}
    cols["time"] = _parse_time(np.asarray(stamps), where)[tix]
    return cols


def _parse_fcd_expat(p: Path) -> dict[str, object]:
    """Vehicle attributes of any well-formed FCD file (slower, general)."""
    rows: list[dict[str, str]] = []
    now: list[str | None] = [None]

    def start(name: str, attrs: dict[str, str]) -> None:
        if name == "vehicle":
            attrs["time"] = now[0]  # type: ignore[assignment]
            rows.append(attrs)
        elif name == "timestep":
            now[0] = attrs.get("time")

    parser = xml.parsers.expat.ParserCreate()
    parser.StartElementHandler = start
    try:
        with open(p, "rb") as fh:
            parser.ParseFile(fh)
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(f"{p}: broken XML ({exc}; a truncated file from an interrupted run?); {_FCD_HINT}") from None
    wanted = set(_VEHICLE_ATTRS)
    keys = {k for r in rows for k in r.keys() & wanted}
    return {k: [r.get(k) for r in rows] for k in keys | {"time"}}


def _plain(value: object) -> str:
    """A value as a user typed it: numpy scalars as plain numbers (``nan``, not ``np.float64(nan)``)."""
    if isinstance(value, np.generic):
        value = value.item()
    return f"{value:g}" if isinstance(value, float) else repr(value)


def _fcd_columns(p: Path) -> dict[str, object]:
    text = p.read_bytes()
    root = _root_element(text[:1 << 20], p, _FCD_HINT)
    if root.group(1) != b"fcd-export":
        raise InputError(f"{p}: root element is <{root.group(1).decode(errors='replace')}>, not <fcd-export>; "
                         f"{_FCD_HINT}")
    cols = _parse_fcd_fast(text[root.start(1) - 1:], str(p))
    return cols if cols is not None else _parse_fcd_expat(p)


def _parse_time(values: ArrayLike, where: str) -> np.ndarray:
    """Times (s) from SUMO text: seconds, or ``[[d:]h:]m:s`` with --human-readable-time."""
    arr = np.asarray(values)
    try:
        return arr.astype(np.float64)
    except (ValueError, TypeError):
        pass
    uniq, inverse = np.unique(arr.astype(str), return_inverse=True)
    out = np.empty(uniq.size)
    for i, text in enumerate(uniq):
        try:
            parts = [float(v) for v in text.split(":")]
        except ValueError:
            raise InputError(f"{where}: time {str(text)!r} is not seconds nor h:mm:ss; {_FCD_HINT}") from None
        scale = (86400.0, 3600.0, 60.0, 1.0)[-len(parts):] if 1 <= len(parts) <= 4 else ()
        if not scale:
            raise InputError(f"{where}: time {str(text)!r} is not seconds nor h:mm:ss; {_FCD_HINT}")
        out[i] = sum(a * b for a, b in zip(parts, scale, strict=True))
    return out[inverse]


def _float_column(cols: dict[str, object], key: str, n: int, where: str) -> np.ndarray:
    """A numeric attribute as float64 (NaN where absent)."""
    if key not in cols:
        return np.full(n, np.nan)
    values = cols[key]
    if isinstance(values, list):
        values = ["nan" if v is None else v for v in values]
    try:
        return np.asarray(values).astype(np.float64)
    except ValueError:
        bad = next(v for v in np.asarray(values).tolist() if not _is_float(v))
        raise InputError(f"{where}: vehicle attribute {key}={bad!r} is not a number; {_FCD_HINT}") from None


def _is_float(v: object) -> bool:
    try:
        float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return True


def _str_column(cols: dict[str, object], key: str, n: int) -> pd.Series:
    """A text attribute as str ("" where absent), XML entities resolved."""
    values = cols.get(key)
    if values is None:
        return pd.Series(np.full(n, ""), dtype=str)
    if isinstance(values, list):
        return pd.Series(["" if v is None else v for v in values], dtype=str)
    series = values if isinstance(values, pd.Series) else pd.Series(values)
    series = series.astype(str).reset_index(drop=True)
    if series.str.contains("&", regex=False).any():  # the fast path leaves entities as they are in the file
        series = series.map(html.unescape).astype(str)
    return series


def _require(cols: dict[str, object], p: Path) -> int:
    n = len(cols["time"])
    for key in ("id", "x", "y", "time"):
        values = cols.get(key)
        if n and (values is None or (isinstance(values, list) and any(v is None for v in values))):
            what = "<timestep> without time" if key == "time" else f"<vehicle> without attribute {key}"
            raise InputError(f"{p}: {what}; {_FCD_HINT}")
    return n


# ---------------------------------------------------------------------------------------------------- FCD reading
def _looks_geo(x: np.ndarray, y: np.ndarray, time: np.ndarray, ids: np.ndarray, speed: np.ndarray) -> bool:
    """Whether FCD positions are longitude/latitude: all within +-180/+-90 and, where vehicles move, displaced by
    about 1e-5 of what their speeds (m/s) say (degrees, not metres); without motion, a span below one degree."""
    if x.size == 0 or not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        return False
    if np.any(np.abs(x) > 180.0) or np.any(np.abs(y) > 90.0):
        return False
    codes = pd.factorize(ids)[0]
    o = np.lexsort((time, codes))
    dt = np.diff(time[o])
    travelled = 0.5 * (speed[o][1:] + speed[o][:-1]) * dt  # m
    moving = (codes[o][1:] == codes[o][:-1]) & (dt > 0) & (travelled > 0.5)
    if np.any(moving):
        step = np.hypot(np.diff(x[o]), np.diff(y[o]))[moving]
        return bool(np.median(step / travelled[moving]) < 1e-2)
    return bool(np.ptp(x) < 1.0 and np.ptp(y) < 1.0)


@dataclass
class _Frame:
    """Working coordinates of an FCD being read or written."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    heading: np.ndarray
    crs: pyproj.CRS | None  # CRS of x, y (None: local)
    notes: list[str]


def _to_world(f: _Frame, geo: bool, loc: NetLocation | None, crs: pyproj.CRS | None, p: Path) -> _Frame:
    """FCD coordinates (network, geo or plain) -> world coordinates in ``crs`` (or the network's CRS)."""
    if geo:
        src = loc.crs if loc is not None else pyproj.CRS.from_epsg(4326)
        if loc is not None and loc.crs is None:
            raise InputError(f"{p}: a geo FCD (lon/lat) needs a projection, but the network has none "
                             "(projParameter '!'); pass the FCD in network coordinates")
        if loc is None and crs is None:
            raise InputError(f"{p}: x, y are longitude/latitude (--fcd-output.geo); pass crs= (the projected CRS "
                             "to return, e.g. a UTM zone) or net= (the .net.xml)")
        f.x, f.y = transform_xy(f.x, f.y, _geodetic(src), src if loc is not None else crs)
        f.crs = src if loc is not None else crs
        if loc is None:
            f.notes.append("geo FCD without network: lon/lat taken as WGS 84; heading kept as SUMO wrote it")
            f.z = f.z / metres_per_unit(crs)
            return f
    elif loc is not None:
        f.x, f.y = f.x - loc.offset[0], f.y - loc.offset[1]
        f.crs = loc.crs
        if loc.crs is None:
            f.notes.append("network has no projection (projParameter '!'): x, y are network coordinates minus "
                           "netOffset, taken to be in crs")
            f.crs = crs
    else:
        f.crs = crs
    if crs is not None and f.crs is not None and not _same_projection(f.crs, crs):
        f.x, f.y, f.heading = _reproject(f.x, f.y, f.heading, f.crs, crs)
        f.z = f.z * metres_per_unit(f.crs) / metres_per_unit(crs)
        f.notes.append(f"reprojected from {_label(f.crs)} to {_label(crs)}")
        f.crs = crs
    return f


def _empty_fcd() -> pd.DataFrame:
    return pd.DataFrame({c: pd.Series(dtype=bool if c == "front_bumper" else str if c in (
        "track_id", "class", "sumo_lane") else np.float64) for c in FCD_COLUMNS})


def read_fcd(path: str | os.PathLike[str], *, net: str | os.PathLike[str] | None = None,
             crs: str | pyproj.CRS | None = None, geo: bool | None = None,
             net_crs: str | pyproj.CRS | None = None) -> pd.DataFrame:
    """Read a SUMO FCD file into a table with :data:`FCD_COLUMNS` (see the module docstring for coordinates).

    ``net``: the network's ``.net.xml`` (its netOffset and projection); ``crs``: the projected CRS of the returned
    ``x, y, z`` (default: the network's projection); ``geo``: whether ``x, y`` are lon/lat (None: detect);
    ``net_crs``: the CRS of the network's projected coordinates when its ``projParameter`` is not enough (a PROJ
    string names no datum, so e.g. NAD83(CSRS) and NAD83 look alike: give "EPSG:2949" to get datum shifts right).
    Rows are in file order (by time, vehicles as SUMO wrote them); speeds km/h, times s, headings degrees.

    Raises:
        InputError: missing file, not FCD XML, vehicles without id/x/y, non-numeric values, a geo FCD without
            ``crs`` or ``net``, a geographic ``crs``.
    """
    p = _check_file(path, "FCD file", _FCD_HINT)
    target = _world_crs(crs, str(p))
    loc = _location(net, net_crs, str(p))
    cols = _fcd_columns(p)
    n = _require(cols, p)
    if n == 0:
        out = _empty_fcd()
        out.attrs.update(crs=_wkt(target or (loc.crs if loc else None)), notes=["no vehicles in the file"])
        return out
    ids = _str_column(cols, "id", n)
    time = _parse_time(cols["time"], str(p))
    x, y = _float_column(cols, "x", n, str(p)), _float_column(cols, "y", n, str(p))
    speed = _float_column(cols, "speed", n, str(p))
    is_geo = _looks_geo(x, y, time, ids, speed) if geo is None else bool(geo)
    f = _Frame(x, y, _float_column(cols, "z", n, str(p)), np.mod(_float_column(cols, "angle", n, str(p)), 360.0),
               None, [])
    f = _to_world(f, is_geo, loc, target, p)
    out = pd.DataFrame({
        "track_id": ids, "time": time, "x": f.x, "y": f.y, "z": f.z, "speed_kmh": speed * 3.6,
        "heading_deg": f.heading, "class": _str_column(cols, "type", n), "sumo_lane": _str_column(cols, "lane", n),
        "front_bumper": np.ones(n, dtype=bool),
    })
    out.attrs.update(crs=_wkt(f.crs), notes=f.notes)
    return out


def _wkt(crs: pyproj.CRS | None) -> str | None:
    return None if crs is None else crs.to_wkt()


# ---------------------------------------------------------------------------------------------------- FCD writing
def _points_numbers(points: pd.DataFrame) -> dict[str, np.ndarray]:
    """Check the points table; float arrays of its numeric columns."""
    if not isinstance(points, pd.DataFrame):
        raise InputError(f"write_fcd: points must be a pandas DataFrame, got {type(points).__name__}")
    need = ["track_id", "time", "x", "y", "speed_kmh", "heading_deg"]
    missing = [c for c in need if c not in points.columns]
    if missing:
        raise InputError(f"write_fcd: points lack column(s) {', '.join(missing)} (have: "
                         f"{', '.join(map(str, points.columns))}); give track_id, time (s), x, y (CRS units), "
                         "speed_kmh, heading_deg and optionally z, class, sumo_lane or lane")
    num = {}
    for c in ("time", "x", "y", "z", "speed_kmh", "heading_deg"):
        if c in points.columns:
            values = pd.to_numeric(points[c], errors="coerce").to_numpy(dtype=np.float64)
            bad = ~np.isfinite(values) if c in ("time", "x", "y") else (np.isnan(values) & points[c].notna().to_numpy())
            if bad.any():
                row = int(np.flatnonzero(bad)[0])
                raise InputError(f"write_fcd: points row {row}: {c} = {_plain(points[c].iloc[row])} is not a finite "
                                 "number; fix or drop that row")
            num[c] = values
    return num


def _front_offset(front_offset_m: ArrayLike | None, n: int, points: pd.DataFrame) -> np.ndarray:
    """Per-row shift (m) from footprint centre to front bumper; 0 where ``front_bumper`` is already True."""
    if front_offset_m is None:
        return np.zeros(n)
    off = np.broadcast_to(np.asarray(front_offset_m, dtype=np.float64), (n,)).copy() if np.ndim(
        front_offset_m) == 0 or np.size(front_offset_m) == n else None
    if off is None:
        raise InputError(f"write_fcd: front_offset_m has {np.size(front_offset_m)} values for {n} points; give one "
                         "number (metres) or one per row")
    if not np.all(np.isfinite(off)):
        raise InputError("write_fcd: front_offset_m must be finite metres (e.g. half the vehicle length)")
    if "front_bumper" in points.columns:
        off[points["front_bumper"].fillna(False).to_numpy(dtype=bool)] = 0.0
    return off


def _to_sumo(f: _Frame, geo: bool, loc: NetLocation | None) -> _Frame:
    """World coordinates -> FCD coordinates (network, geo or plain); the inverse of :func:`_to_world`."""
    if geo and loc is not None and loc.crs is None:
        raise InputError("write_fcd: geo=True needs a projection, but the network has none (projParameter '!')")
    if geo and loc is None and f.crs is None:
        raise InputError("write_fcd: geo=True needs crs= (the projected CRS of x, y), e.g. 'EPSG:32632'")
    net_crs = loc.crs if loc is not None else None
    if net_crs is not None and f.crs is not None and not _same_projection(f.crs, net_crs):
        f.x, f.y, f.heading = _reproject(f.x, f.y, f.heading, f.crs, net_crs)
        f.z = f.z * metres_per_unit(f.crs) / metres_per_unit(net_crs)
        f.crs = net_crs
    if geo:
        src = net_crs if net_crs is not None else f.crs
        f.x, f.y = transform_xy(f.x, f.y, src, _geodetic(net_crs) if net_crs is not None else
                                pyproj.CRS.from_epsg(4326))
        if net_crs is None:
            f.z = f.z * metres_per_unit(src)
    elif loc is not None:
        f.x, f.y = f.x + loc.offset[0], f.y + loc.offset[1]
    return f


def _slope_deg(track: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray, mpu: float) -> np.ndarray:
    """Slope (degrees) along each track from consecutive points (rows sorted by track then time); 0 if unknown."""
    same = track[1:] == track[:-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.degrees(np.arctan2(np.diff(z), np.hypot(np.diff(x), np.diff(y)) * mpu))
    s = np.where(same & np.isfinite(s), s, np.nan)
    fwd = np.append(s, np.nan)
    out = np.where(np.isfinite(fwd), fwd, np.insert(s, 0, np.nan))
    return np.where(np.isfinite(out), out, 0.0)


def _attr(name: str, values: np.ndarray | None, spec: str, n: int) -> list[str]:
    """`` name="value"`` pieces: '' where a number is NaN or for every row when ``values`` is None."""
    if values is None:
        return [""] * n
    if values.dtype.kind == "f":
        return [f' {name}="{v:{spec}}"' if v == v else "" for v in values.tolist()]
    return [f' {name}="{v}"' for v in values.tolist()]


def _xml_text(values: np.ndarray) -> np.ndarray:
    uniq, inverse = np.unique(values.astype(str), return_inverse=True)
    esc = np.array([html.escape(u, quote=True) for u in uniq.tolist()], dtype=object)
    return esc[inverse] if esc.size else values.astype(object)


def _time_text(t: np.ndarray) -> list[str]:
    ms = np.all(np.abs(t * 1000.0 - np.round(t * 1000.0)) < 1e-6)
    return [f"{v:.3f}" if ms else f"{v:.6f}" for v in t.tolist()]


def _text_column(points: pd.DataFrame, names: tuple[str, ...]) -> np.ndarray | None:
    """The first of the columns ``names`` as XML-escaped text ("" for missing values); None if there is none."""
    for name in names:
        if name in points.columns:
            return _xml_text(points[name].fillna("").astype(str).to_numpy())
    return None


def write_fcd(path: str | os.PathLike[str], points: pd.DataFrame, *, crs: str | pyproj.CRS | None,
              net: str | os.PathLike[str] | None = None, geo: bool = False,
              front_offset_m: ArrayLike | None = None, decimals: int = 4,
              net_crs: str | pyproj.CRS | None = None) -> None:
    """Write track points as a SUMO FCD file (atomically): ``<timestep>`` blocks by time, vehicles by id.

    ``points``: ``track_id, time`` (s), ``x, y`` (``crs`` units), ``speed_kmh``, ``heading_deg`` and optionally
    ``z`` (``crs`` units), ``class`` (written as ``type``), ``sumo_lane`` or ``lane`` (``lane``), ``front_bumper``.
    Coordinates: with ``net`` the network's (reprojected to its projection, plus netOffset); ``geo=True``
    longitude/latitude (on the network projection's datum with ``net``, else WGS 84); otherwise ``crs``
    coordinates as they are. ``front_offset_m`` (metres, scalar or per row) moves footprint centres forward along
    the heading to SUMO's front bumper (rows with ``front_bumper`` True are not moved; metres become CRS units by
    the unit alone, the projection's scale factor, 1 +- 0.0004 in a local CRS, is ignored). Speeds are written in m/s;
    ``slope`` (degrees) when ``z`` is given, ``pos`` from a ``sumo_pos`` column. ``decimals`` applies to metres,
    m/s and degrees (lon/lat get ``decimals + 5``: 4 -> 0.1 mm). ``net_crs`` as in :func:`read_fcd`.

    Raises:
        InputError: missing or non-numeric columns, duplicate (track_id, time), geo without a CRS.
    """
    num = _points_numbers(points)
    target = _world_crs(crs, "write_fcd")
    loc = _location(net, net_crs, "write_fcd")
    if isinstance(decimals, bool) or not isinstance(decimals, int | np.integer) or not 0 <= decimals <= 9:
        raise InputError(f"write_fcd: decimals must be an integer 0..9 (digits after the point), got {decimals!r}")
    ids = points["track_id"].astype(str).to_numpy()
    order = np.lexsort((ids, num["time"]))
    dup = (np.diff(num["time"][order]) == 0) & (ids[order][1:] == ids[order][:-1])
    if dup.any():
        k = order[np.flatnonzero(dup)[0]]
        raise InputError(f"write_fcd: track {ids[k]!r} has two points at time {num['time'][k]:g} s; "
                         "keep one point per track and time")
    n = len(points)
    mpu = metres_per_unit(target)
    shift = _front_offset(front_offset_m, n, points)
    if np.any((shift != 0) & ~np.isfinite(num["heading_deg"])):
        raise InputError("write_fcd: front_offset_m needs heading_deg on every shifted row; fill the headings")
    x, y = _shift_along(num["x"], num["y"], num["heading_deg"], shift / mpu)
    z = num.get("z", np.full(n, np.nan))
    slope = None
    if "z" in num and np.isfinite(z).any():
        o = np.lexsort((num["time"], ids))
        slope = np.empty(n)
        slope[o] = _slope_deg(ids[o], x[o], y[o], z[o], mpu)
    f = _to_sumo(_Frame(x, y, z, np.mod(num["heading_deg"], 360.0), target, []), geo, loc)
    pieces = _vehicle_pieces(points, ids, f, num["speed_kmh"] / 3.6, slope, geo, decimals)
    _write_blocks(path, num["time"], order, pieces, target, loc, geo)


def _vehicle_pieces(points: pd.DataFrame, ids: np.ndarray, f: _Frame, speed: np.ndarray, slope: np.ndarray | None,
                    geo: bool, decimals: int) -> list[str]:
    """One ``<vehicle .../>`` line per row of ``points`` (input order)."""
    n = len(ids)
    xy_spec = f".{decimals + 5}f" if geo else f".{decimals}f"
    spec = f".{decimals}f"
    pos = pd.to_numeric(points["sumo_pos"], errors="coerce").to_numpy(np.float64) if "sumo_pos" in points else None
    cols = [
        _attr("id", _xml_text(ids), "", n), _attr("x", f.x, xy_spec, n), _attr("y", f.y, xy_spec, n),
        _attr("z", f.z, spec, n), _attr("angle", f.heading, spec, n),
        _attr("type", _text_column(points, ("class",)), "", n), _attr("speed", speed, spec, n),
        _attr("pos", pos, spec, n), _attr("lane", _text_column(points, ("sumo_lane", "lane")), "", n),
        _attr("slope", slope, spec, n),
    ]
    return ["        <vehicle" + "".join(parts) + "/>\n" for parts in zip(*cols, strict=True)]


def _write_blocks(path: str | os.PathLike[str], time: np.ndarray, order: np.ndarray, lines: list[str],
                  crs: pyproj.CRS | None, loc: NetLocation | None, geo: bool) -> None:
    kind = "lon/lat" if geo else "network coordinates" if loc is not None else f"{crs_label(crs)} coordinates"
    note = f"written by trafficgeo: SUMO FCD, x/y in {kind}, speed m/s, angle degrees clockwise from north"
    header = ('<?xml version="1.0" encoding="UTF-8"?>\n\n'
              f"<!-- {note.replace('--', '- -')} -->\n\n<fcd-export {_XSD}>\n")
    t_sorted = time[order]
    starts = np.flatnonzero(np.concatenate([[True], t_sorted[1:] != t_sorted[:-1]])) if order.size else []
    stamps = _time_text(t_sorted[starts]) if order.size else []
    bounds = [*list(starts), order.size]
    with atomic_open(path, "w") as fh:
        fh.write(header)
        for k, stamp in enumerate(stamps):
            fh.write(f'    <timestep time="{stamp}">\n')
            fh.writelines(lines[i] for i in order[bounds[k]:bounds[k + 1]].tolist())
            fh.write("    </timestep>\n")
        fh.write("</fcd-export>\n")


# ---------------------------------------------------------------------------------------------------- mean data
def _meandata_rows(p: Path) -> list[dict[str, str]]:
    rows: list[dict[str, str]] = []
    state: dict[str, object] = {"interval": {}, "edge": None, "lanes": False, "root": None}

    def start(name: str, attrs: dict[str, str]) -> None:
        if state["root"] is None:
            state["root"] = name
        if name == "interval":
            state["interval"] = attrs
        elif name == "edge":
            state["edge"], state["lanes"] = attrs, False
        elif name == "lane" and state["edge"] is not None:
            state["lanes"] = True
            rows.append({**_interval(state), "edge": state["edge"].get("id", ""), **attrs, "lane": attrs.get("id", "")})

    def end(name: str) -> None:
        if name == "edge" and state["edge"] is not None:
            if not state["lanes"]:
                rows.append({**_interval(state), **state["edge"], "edge": state["edge"].get("id", ""), "lane": ""})
            state["edge"] = None

    parser = xml.parsers.expat.ParserCreate()
    parser.StartElementHandler, parser.EndElementHandler = start, end
    try:
        with open(p, "rb") as fh:
            parser.ParseFile(fh)
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(f"{p}: broken XML ({exc}); {_MEAN_HINT}") from None
    if state["root"] != "meandata":
        raise InputError(f"{p}: root element is <{state['root']}>, not <meandata>; {_MEAN_HINT}")
    return rows


def _interval(state: dict[str, object]) -> dict[str, str]:
    iv = state["interval"]
    assert isinstance(iv, dict)
    return {"interval_begin": iv.get("begin"), "interval_end": iv.get("end"), "interval_id": iv.get("id", "")}


def read_meandata(path: str | os.PathLike[str]) -> pd.DataFrame:
    """Read SUMO edgeData/laneData output: one row per interval and edge (``lane`` "") or lane.

    Columns :data:`MEANDATA_COLUMNS` (``interval_begin/end`` s; ``entered``, ``left`` vehicles; ``speed_kmh``
    converted from SUMO's m/s; ``density`` veh/km; ``occupancy`` %; NaN where the file has no such attribute),
    then every other attribute SUMO wrote under its own name (``sampledSeconds``, ``traveltime``, ...; numeric).

    Raises:
        InputError: missing file, broken XML, not ``<meandata>``, an interval without begin/end.
    """
    p = _check_file(path, "SUMO mean data file", _MEAN_HINT)
    rows = _meandata_rows(p)
    table = pd.DataFrame(rows)
    if table.empty:
        return pd.DataFrame({c: pd.Series(dtype=str if c in ("interval_id", "edge", "lane") else np.float64)
                             for c in MEANDATA_COLUMNS})
    if table["interval_begin"].isna().any() or table["interval_end"].isna().any():
        raise InputError(f"{p}: an <interval> lacks begin or end; {_MEAN_HINT}")
    for c in ("interval_begin", "interval_end"):
        table[c] = _parse_time(table[c].to_numpy(), str(p))
    table = table.drop(columns=["id"], errors="ignore")
    extra = [c for c in table.columns if c not in MEANDATA_COLUMNS and c not in ("speed",)]
    for c in [*extra, "entered", "left", "density", "occupancy", "speed"]:
        if c in table.columns:
            table[c] = pd.to_numeric(table[c], errors="coerce")
    table["speed_kmh"] = table["speed"] * 3.6 if "speed" in table.columns else np.nan
    for c in MEANDATA_COLUMNS:
        if c not in table.columns:
            table[c] = np.nan
    for c in ("interval_id", "edge", "lane"):
        table[c] = table[c].fillna("").astype(str)
    return table[MEANDATA_COLUMNS + extra].reset_index(drop=True)
