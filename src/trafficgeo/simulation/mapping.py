"""Counting line x lane x direction of an observed run -> the SUMO edge and lane it crosses, by geometry.

Frames: the run's lines, lanes and crossings are in the run's CRS; a SUMO network's coordinates are its projected
coordinates plus ``netOffset`` (``sumo_xy = projected_xy + netOffset``, :mod:`trafficgeo.io.sumo_net`), in the
projection of its ``projParameter`` (or ``net_crs`` when given). Each counting line is taken into the network's
coordinates and intersected with the centre line (shape) of every lane of every (non-internal) edge; a lane crossing
the line from its left to its right is in direction +1, the other way -1, the convention of ``crossings.csv``.

An observed group (line, lane, direction) is mapped to the SUMO lanes crossing its line in its direction

* whose crossing point lies in the group's lane polygon (the run's lanes), or, when no SUMO lane (of either
  direction) crosses the line there, the one nearest to the median of its observed crossing points, within
  :data:`MAX_DISTANCE_M`;
* all of them when the run has no lanes (lane "");

all of them must belong to one edge (the group's SUMO lane: the one nearest to its observed crossings). A group that
crosses no edge in its direction, or lanes of two edges, is a problem: :class:`MappingError` (an
:class:`~trafficgeo.errors.InputError`) says so in one line and carries the table of every group
(:attr:`MappingError.table`). A group of very few vehicles (at most :data:`MINOR_VEHICLES`, or :data:`MINOR_SHARE`
of its line's: a wrong-way track, a vehicle on the shoulder) is left out with a warning instead.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj
import shapely

from trafficgeo.crs import crs_label, transform_xy
from trafficgeo.errors import InputError
from trafficgeo.io.sumo_net import NetLocation, net_location, same_projection
from trafficgeo.site.lines import CountLine
from trafficgeo.traffic.counts import counted_groups, segment_crossings
from trafficgeo.traffic.validation import ObservedRun

__all__ = ["MAX_DISTANCE_M", "LaneMapping", "MappingError", "SumoLaneCrossing", "map_observations",
           "net_lane_crossings"]

MINOR_VEHICLES = 2  # an unmapped group of at most this many vehicles (or MINOR_SHARE of its line's) is left out
MINOR_SHARE = 0.02
MAX_DISTANCE_M = 5.0  # m: farthest a SUMO lane crossing may be from a group's observed crossings without a polygon
MAPPING_COLUMNS = ["line", "lane", "direction", "sumo_edge", "sumo_lane", "pos_m", "x_net", "y_net", "problem"]


class MappingError(InputError):
    """Observations that cross no SUMO edge, or an ambiguous one; ``table`` lists every group (see the module)."""

    def __init__(self, message: str, table: pd.DataFrame) -> None:
        super().__init__(message, parameters=("net", "net_crs"))
        self.table = table


@dataclass(frozen=True)
class SumoLaneCrossing:
    """Where a SUMO lane's centre line crosses a counting line (network coordinates, metres)."""

    line: str
    direction: int  # +1: the lane crosses the line from its left to its right
    edge: str
    lane: str
    pos_m: float  # position along the lane (SUMO lane position, m)
    x_net: float
    y_net: float
    speed_limit_mps: float


@dataclass(frozen=True)
class LaneMapping:
    """The mapping of a run's observations onto a SUMO network.

    ``table``: one row per observed (line, lane, direction) with ``sumo_edge``, ``sumo_lane``, ``pos_m`` (position
    of the line on that lane, m), the crossing point ``x_net, y_net`` and ``problem`` ("" when mapped);
    ``crossings``: every SUMO lane each line crosses; ``location``: the network's location.
    """

    net: Path
    table: pd.DataFrame
    crossings: list[SumoLaneCrossing]
    location: NetLocation
    edge_lengths_m: dict[str, float]  # every non-internal edge of the network
    warnings: tuple[str, ...] = ()  # groups left out (too few vehicles to stop the mapping)

    @property
    def mapped(self) -> pd.DataFrame:
        """The rows of ``table`` that map to a SUMO edge."""
        return self.table[self.table["problem"] == ""]

    def edge_of(self) -> dict[tuple[str, str, int], str]:
        """(line, lane, direction) -> SUMO edge id, of the mapped groups."""
        t = self.mapped
        return {(str(r.line), str(r.lane), int(r.direction)): str(r.sumo_edge) for r in t.itertuples()}


def _sumolib_net(net: Path):
    try:
        import sumolib
    except ImportError:
        raise InputError("sumolib is not installed; install it with: pip install sumolib") from None
    try:
        return sumolib.net.readNet(str(net), withInternal=False)
    except Exception as exc:  # sumolib raises plain exceptions for bad XML
        raise InputError(f"net {net}: not a readable SUMO network ({type(exc).__name__}); give the .net.xml",
                         parameters=("net",)) from None


def _to_net(x: np.ndarray, y: np.ndarray, run_crs: pyproj.CRS | None, loc: NetLocation,
            net: Path) -> tuple[np.ndarray, np.ndarray]:
    """Run CRS -> network coordinates (projected + netOffset)."""
    if (run_crs is None) != (loc.crs is None):
        raise InputError(f"net {net}: the run is in {crs_label(run_crs)} but the network has "
                         f"{'no projection' if loc.crs is None else 'a projection'}; give net_crs (the CRS of the "
                         "network's coordinates) or rebuild the network with netconvert --proj",
                         parameters=("net", "net_crs"))
    if run_crs is not None and loc.crs is not None and not same_projection(run_crs, loc.crs):
        x, y = transform_xy(x, y, run_crs, loc.crs)
    return np.asarray(x, dtype=np.float64) + loc.offset[0], np.asarray(y, dtype=np.float64) + loc.offset[1]


def _geometry_to_net(geom: shapely.Geometry, run_crs, loc: NetLocation, net: Path) -> shapely.Geometry:
    return shapely.transform(geom, lambda xy: np.column_stack(_to_net(xy[:, 0], xy[:, 1], run_crs, loc, net)))


def net_lane_crossings(net: str | os.PathLike[str], lines: list[CountLine], run_crs: pyproj.CRS | None, *,
                       net_crs: str | pyproj.CRS | None = None
                       ) -> tuple[list[SumoLaneCrossing], NetLocation, dict[str, float], tuple[float, ...]]:
    """Every SUMO lane (of non-internal edges) whose centre line crosses a counting line (given in ``run_crs``), the
    network's location, the length (m) of each of its edges and the bounding box of its lanes (xmin, ymin, xmax,
    ymax in network coordinates)."""
    net = Path(net)
    loc = net_location(net, net_crs, "net")
    sumo_net = _sumolib_net(net)
    segs, owners = [], []
    lengths: dict[str, float] = {}
    for edge in sumo_net.getEdges():
        if edge.getFunction() == "internal":
            continue
        lengths[edge.getID()] = float(edge.getLength())
        for lane in edge.getLanes():
            shape = np.asarray(lane.getShape(), dtype=np.float64)[:, :2]
            if len(shape) < 2:
                continue
            steps = np.linalg.norm(np.diff(shape, axis=0), axis=1)
            start = np.concatenate([[0.0], np.cumsum(steps)[:-1]])
            scale = lane.getLength() / max(float(steps.sum()), 1e-9)  # SUMO lane length may differ from its shape
            for k in range(len(shape) - 1):
                segs.append((*shape[k], *shape[k + 1], start[k] * scale, steps[k] * scale))
                owners.append((edge.getID(), lane.getID(), float(lane.getSpeed())))
    if not segs:
        raise InputError(f"net {net}: the network has no lanes; give the .net.xml the simulation uses",
                         parameters=("net",))
    arr = np.asarray(segs)
    p, q = arr[:, 0:2], arr[:, 2:4]
    out: list[SumoLaneCrossing] = []
    for line in lines:
        coords = np.asarray(_geometry_to_net(line.geometry, run_crs, loc, net).coords, dtype=np.float64)[:, :2]
        seen: set[tuple[str, int]] = set()
        for k in range(len(coords) - 1):
            s, sign = segment_crossings(p, q, coords[k], coords[k + 1])
            for i in np.flatnonzero(np.isfinite(s)):
                edge, lane, speed = owners[i]
                if (lane, int(sign[i])) in seen:
                    continue
                seen.add((lane, int(sign[i])))
                c = p[i] + s[i] * (q[i] - p[i])
                out.append(SumoLaneCrossing(line.name, int(sign[i]), edge, lane, float(arr[i, 4] + s[i] * arr[i, 5]),
                                            float(c[0]), float(c[1]), speed))
    bbox = (*np.minimum(p.min(axis=0), q.min(axis=0)), *np.maximum(p.max(axis=0), q.max(axis=0)))
    return out, loc, lengths, tuple(float(v) for v in bbox)


def _groups(observed: ObservedRun) -> pd.DataFrame:
    """Observed (line, lane, direction) groups with the median crossing point (run CRS) and their ``vehicles``."""
    names = [ln.name for ln in observed.lines]
    cr = observed.crossings[observed.crossings["line"].astype(str).isin(names)]
    keys = ["line", "lane", "direction"]
    if len(cr):
        g = cr.assign(line=cr["line"].astype(str), lane=cr["lane"].fillna("").astype(str),
                      direction=cr["direction"].astype(int)).groupby(keys, sort=True)
        med = g[["x", "y"]].median().join(g.size().rename("vehicles")).reset_index()
    else:
        med = pd.DataFrame(columns=[*keys, "x", "y", "vehicles"])
    counts = counted_groups(observed.counts[observed.counts["line"].astype(str).isin(names)])
    seen = counts.assign(line=counts["line"].astype(str), lane=counts["lane"].fillna("").astype(str),
                         direction=counts["direction"].astype(int))[keys].drop_duplicates()
    out = seen.merge(med, on=keys, how="outer").sort_values(keys, kind="stable").reset_index(drop=True)
    out["vehicles"] = out["vehicles"].fillna(0).astype(int)
    return out


def map_observations(observed: ObservedRun, net: str | os.PathLike[str], *,
                     net_crs: str | pyproj.CRS | None = None) -> LaneMapping:
    """Map each observed (line, lane, direction) of ``observed`` to the SUMO edge and lane it crosses in ``net``.

    Raises:
        InputError: the run has no counting lines, or the network cannot be read or placed.
        MappingError: a group crosses no edge in its direction, or lanes of several edges (table attached).
    """
    net = Path(net)
    if not net.is_file():
        raise InputError(f"net {net}: SUMO network file not found; give the .net.xml of the network to simulate",
                         parameters=("net",))
    if not observed.lines:
        raise InputError(f"{observed.folder}: the run has no counting lines (trajectories.gpkg, layer count_lines); "
                         "run analyze with --lines")
    crossings, loc, lengths, bbox = net_lane_crossings(net, observed.lines, observed.crs, net_crs=net_crs)
    groups = _groups(observed)
    lane_poly = {}
    if observed.lanes is not None:
        lane_poly = {n: _geometry_to_net(p, observed.crs, loc, net).buffer(0.1)
                     for n, p in zip(observed.lanes.names, observed.lanes.polygons, strict=True)}
    gx, gy = _to_net(groups["x"].to_numpy(np.float64), groups["y"].to_numpy(np.float64), observed.crs, loc, net) \
        if len(groups) else (np.zeros(0), np.zeros(0))
    rows = []
    for i, g in enumerate(groups.itertuples()):
        cands = [c for c in crossings if c.line == g.line and c.direction == g.direction]
        chosen: list[SumoLaneCrossing] = []
        if g.lane in lane_poly:
            under = [c for c in crossings if c.line == g.line
                     and lane_poly[g.lane].contains(shapely.Point(c.x_net, c.y_net))]
            chosen = [c for c in under if c.direction == g.direction]
            if not under and cands and np.isfinite(gx[i]):  # the SUMO lane is beside the drawn one: the nearest
                d = np.array([np.hypot(c.x_net - gx[i], c.y_net - gy[i]) for c in cands])
                chosen = [cands[int(np.argmin(d))]] if d.min() <= MAX_DISTANCE_M else []
        else:  # no lane polygon: every SUMO lane of this direction under the line
            chosen = cands
        edges = sorted({c.edge for c in chosen})
        problem = ""
        if not cands:
            problem = "crosses no SUMO edge in this direction"
        elif not chosen:
            problem = "no SUMO lane of this direction under the observed lane"
        elif len(edges) > 1:
            problem = f"ambiguous: lanes of edges {', '.join(edges)}"
        if chosen and np.isfinite(gx[i]):
            best = min(chosen, key=lambda c: np.hypot(c.x_net - gx[i], c.y_net - gy[i]))
        else:
            best = chosen[0] if chosen else None
        rows.append({"line": g.line, "lane": g.lane, "direction": int(g.direction),
                     "sumo_edge": best.edge if best and not problem else "",
                     "sumo_lane": best.lane if best and not problem else "",
                     "pos_m": best.pos_m if best and not problem else np.nan,
                     "x_net": best.x_net if best else np.nan, "y_net": best.y_net if best else np.nan,
                     "problem": problem})
    table = pd.DataFrame(rows, columns=MAPPING_COLUMNS)
    for line in observed.lines:
        if not any(c.line == line.name for c in crossings):
            mid = _geometry_to_net(line.geometry, observed.crs, loc, net).centroid
            x0, y0, x1, y1 = bbox
            raise MappingError(f"net {net}: counting line {line.name!r} crosses no edge of the network (it is at "
                               f"{mid.x:.0f}, {mid.y:.0f} in network coordinates, the lanes span x {x0:.0f}..{x1:.0f}, "
                               f"y {y0:.0f}..{y1:.0f}); check that the network covers the camera's view and its CRS "
                               "(net_crs), and that the line is not inside a junction", table)
    # a handful of vehicles in a direction or lane the network does not have (a wrong-way track, a vehicle on the
    # shoulder) is left out with a warning, not an error
    line_total = groups.groupby("line")["vehicles"].transform("sum").to_numpy()
    minor = (table["problem"] != "").to_numpy() & (groups["vehicles"].to_numpy() <= np.maximum(
        MINOR_VEHICLES, MINOR_SHARE * line_total))
    warnings = tuple(f"line {r.line!r} lane {r.lane or '(none)'!r} direction {int(r.direction):+d}: {r.problem}; its "
                     f"{int(n)} vehicle(s) left out" for r, n in zip(table[minor].itertuples(),
                                                                      groups["vehicles"].to_numpy()[minor],
                                                                      strict=True))
    bad = table[(table["problem"] != "").to_numpy() & ~minor]
    if len(bad):
        r = bad.iloc[0]
        raise MappingError(f"net {net}: line {r['line']!r} lane {r['lane'] or '(none)'!r} direction "
                           f"{int(r['direction']):+d}: {r['problem']} ({len(bad)} of {len(table)} line/lane/direction "
                           "groups not mapped); check the network and its CRS (net_crs)", table)
    return LaneMapping(net, table, crossings, loc, lengths, warnings)
