"""SUMO exchange: floating car data (FCD) in and out, edge/lane mean data in.

Floating car data
-----------------
SUMO's ``--fcd-output`` is ``<fcd-export>`` with one ``<timestep time=...>`` per simulation step holding one
``<vehicle id x y [z] angle type speed pos lane slope .../>`` per vehicle (persons and containers are ignored).
Its position is the middle of the vehicle's **front bumper**, its ``angle`` the heading in degrees clockwise from
(grid) north and its ``speed`` in m/s. :func:`~trafficgeo.io.fcd_read.read_fcd` returns a table with the columns
:data:`~trafficgeo.io.fcd_read.FCD_COLUMNS`:

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

:func:`~trafficgeo.io.fcd_write.write_fcd` is the inverse and writes what SUMO would (``speed`` in m/s; ``type``
and ``lane`` on every vehicle when the table has them, "" if unknown), optionally shifting footprint centres to
front bumpers.

Mean data
---------
:func:`read_meandata` reads SUMO's ``edgeData``/``laneData`` output (``<meandata><interval><edge>[<lane>]``).

Parsing: an FCD laid out as SUMO writes it (the same attributes in the same order on every vehicle, no comments
in the body) is read by a vectorised byte-level parser in pieces of about 8 MB (:mod:`trafficgeo.io.fcd_parse`),
anything else by expat. Measured by ``benchmarks/bench_fcd.py`` on 1e6 vehicle rows (a 139 MB file, 2 shared
cores): 2.6 s and 239 MB peak memory above the start (the returned table alone is 93 MB), against 8.3 s and
625 MB for sumolib's ``parse_fast_nested``, 10.6 s and 626 MB for ``xml.etree.ElementTree.iterparse`` and 13.5 s
and 809 MB for the expat fallback.
"""

from __future__ import annotations

import os
import xml.parsers.expat
from pathlib import Path

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.io.fcd_parse import parse_sumo_time
from trafficgeo.io.sumo_net import check_input_file

__all__ = ["MEANDATA_COLUMNS", "read_meandata"]

MEANDATA_COLUMNS = ["interval_begin", "interval_end", "interval_id", "edge", "lane", "entered", "left", "speed_kmh",
                    "density", "occupancy"]
_MEAN_HINT = "give a SUMO edgeData/laneData output (<meandata><interval begin end><edge id ...>)"


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
    p = check_input_file(path, "SUMO mean data file", _MEAN_HINT)
    rows = _meandata_rows(p)
    table = pd.DataFrame(rows)
    if table.empty:
        return pd.DataFrame({c: pd.Series(dtype=str if c in ("interval_id", "edge", "lane") else np.float64)
                             for c in MEANDATA_COLUMNS})
    if table["interval_begin"].isna().any() or table["interval_end"].isna().any():
        raise InputError(f"{p}: an <interval> lacks begin or end; {_MEAN_HINT}")
    for c in ("interval_begin", "interval_end"):
        table[c] = parse_sumo_time(table[c].to_numpy(), str(p))
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
