"""Reading SUMO FCD files into track-point tables in a world CRS (see :mod:`trafficgeo.io.sumo`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj

from trafficgeo.crs import metres_per_unit, transform_xy
from trafficgeo.errors import InputError
from trafficgeo.io.fcd_parse import (
    FCD_HINT,
    fcd_columns,
    float_column,
    parse_sumo_time,
    require_fcd_columns,
    str_column,
)
from trafficgeo.io.sumo_net import (
    FcdFrame,
    NetLocation,
    check_input_file,
    checked_world_crs,
    geodetic_of,
    net_crs_label,
    net_location,
    reproject_with_headings,
    same_projection,
    wkt_or_none,
)

FCD_COLUMNS = ["track_id", "time", "x", "y", "z", "speed_kmh", "heading_deg", "class", "sumo_lane", "front_bumper"]


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


def _to_world(f: FcdFrame, geo: bool, loc: NetLocation | None, crs: pyproj.CRS | None, p: Path) -> FcdFrame:
    """FCD coordinates (network, geo or plain) -> world coordinates in ``crs`` (or the network's CRS)."""
    if geo:
        src = loc.crs if loc is not None else pyproj.CRS.from_epsg(4326)
        if loc is not None and loc.crs is None:
            raise InputError(f"{p}: a geo FCD (lon/lat) needs a projection, but the network has none "
                             "(projParameter '!'); pass the FCD in network coordinates")
        if loc is None and crs is None:
            raise InputError(f"{p}: x, y are longitude/latitude (--fcd-output.geo); pass crs= (the projected CRS "
                             "to return, e.g. a UTM zone) or net= (the .net.xml)")
        f.x, f.y = transform_xy(f.x, f.y, geodetic_of(src), src if loc is not None else crs)
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
    if crs is not None and f.crs is not None and not same_projection(f.crs, crs):
        f.x, f.y, f.heading = reproject_with_headings(f.x, f.y, f.heading, f.crs, crs)
        f.z = f.z * metres_per_unit(f.crs) / metres_per_unit(crs)
        f.notes.append(f"reprojected from {net_crs_label(f.crs)} to {net_crs_label(crs)}")
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
    p = check_input_file(path, "FCD file", FCD_HINT)
    target = checked_world_crs(crs, str(p))
    loc = net_location(net, net_crs, str(p))
    cols = fcd_columns(p)
    n = require_fcd_columns(cols, p)
    if n == 0:
        out = _empty_fcd()
        out.attrs.update(crs=wkt_or_none(target or (loc.crs if loc else None)), notes=["no vehicles in the file"])
        return out
    ids = str_column(cols, "id", n)
    time = parse_sumo_time(cols["time"], str(p))
    x, y = float_column(cols, "x", n, str(p)), float_column(cols, "y", n, str(p))
    speed = float_column(cols, "speed", n, str(p))
    is_geo = _looks_geo(x, y, time, ids, speed) if geo is None else bool(geo)
    f = FcdFrame(x, y, float_column(cols, "z", n, str(p)), np.mod(float_column(cols, "angle", n, str(p)), 360.0),
               None, [])
    f = _to_world(f, is_geo, loc, target, p)
    out = pd.DataFrame({
        "track_id": ids, "time": time, "x": f.x, "y": f.y, "z": f.z, "speed_kmh": speed * 3.6,
        "heading_deg": f.heading, "class": str_column(cols, "type", n), "sumo_lane": str_column(cols, "lane", n),
        "front_bumper": np.ones(n, dtype=bool),
    })
    out.attrs.update(crs=wkt_or_none(f.crs), notes=f.notes)
    return out


