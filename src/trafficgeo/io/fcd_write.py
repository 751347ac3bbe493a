"""Writing track points as SUMO FCD files (see :mod:`trafficgeo.io.sumo`)."""

from __future__ import annotations

import html
import os

import numpy as np
import pandas as pd
import pyproj
from numpy.typing import ArrayLike

from trafficgeo.crs import crs_label, metres_per_unit, transform_xy
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_open
from trafficgeo.io.sumo_net import (
    FcdFrame,
    NetLocation,
    checked_world_crs,
    geodetic_of,
    net_location,
    reproject_with_headings,
    same_projection,
    shift_along,
)

_XSD = ('xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        'xsi:noNamespaceSchemaLocation="http://sumo.dlr.de/xsd/fcd_file.xsd"')


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


def _to_sumo(f: FcdFrame, geo: bool, loc: NetLocation | None) -> FcdFrame:
    """World coordinates -> FCD coordinates (network, geo or plain); the inverse of :func:`_to_world`."""
    if geo and loc is not None and loc.crs is None:
        raise InputError("write_fcd: geo=True needs a projection, but the network has none (projParameter '!')")
    if geo and loc is None and f.crs is None:
        raise InputError("write_fcd: geo=True needs crs= (the projected CRS of x, y), e.g. 'EPSG:32632'")
    net_crs = loc.crs if loc is not None else None
    if net_crs is not None and f.crs is not None and not same_projection(f.crs, net_crs):
        f.x, f.y, f.heading = reproject_with_headings(f.x, f.y, f.heading, f.crs, net_crs)
        f.z = f.z * metres_per_unit(f.crs) / metres_per_unit(net_crs)
        f.crs = net_crs
    if geo:
        src = net_crs if net_crs is not None else f.crs
        f.x, f.y = transform_xy(f.x, f.y, src, geodetic_of(net_crs) if net_crs is not None else
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
    target = checked_world_crs(crs, "write_fcd")
    loc = net_location(net, net_crs, "write_fcd")
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
    x, y = shift_along(num["x"], num["y"], num["heading_deg"], shift / mpu)
    z = num.get("z", np.full(n, np.nan))
    slope = None
    if "z" in num and np.isfinite(z).any():
        o = np.lexsort((num["time"], ids))
        slope = np.empty(n)
        slope[o] = _slope_deg(ids[o], x[o], y[o], z[o], mpu)
    f = _to_sumo(FcdFrame(x, y, z, np.mod(num["heading_deg"], 360.0), target, []), geo, loc)
    pieces = _vehicle_pieces(points, ids, f, num["speed_kmh"] / 3.6, slope, geo, decimals)
    _write_blocks(path, num["time"], order, pieces, target, loc, geo)


def _vehicle_pieces(points: pd.DataFrame, ids: np.ndarray, f: FcdFrame, speed: np.ndarray, slope: np.ndarray | None,
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



def _plain(value: object) -> str:
    """A value as a user typed it: numpy scalars as plain numbers (``nan``, not ``np.float64(nan)``)."""
    if isinstance(value, np.generic):
        value = value.item()
    return f"{value:g}" if isinstance(value, float) else repr(value)

