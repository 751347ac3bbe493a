"""SUMO demand at a junction from the observed turning movements (a run analyzed with ``--gates``).

Gates on the network: each gate (a line across a junction arm, :mod:`trafficgeo.site.gates`) is taken into the
network's coordinates and intersected with the centre line of every lane of every non-internal edge
(:func:`trafficgeo.simulation.mapping.net_lane_crossings`, the gate as a counting line named by its arm). A lane
that crosses the gate towards the junction centre belongs to the arm's **in-edge**, one crossing it away from the
centre to its **out-edge** (towards / away from the centre as :func:`trafficgeo.traffic.movements.gate_crossings`
judges it, with the gate's direction from its first to its last point). When several edges cross a gate in one
sense, the one whose crossing is nearest the gate's midpoint is taken (with a warning). A gate that crosses no edge
of the network is refused (:class:`GateMappingError`, naming the arm).

Demand: for every interval, origin and destination arm and class, the observed count of complete movements
(:func:`trafficgeo.traffic.movements.movement_counts`, re-counted from ``movements.csv`` per the scenario's
interval) becomes that many vehicles of the class on the route ``in-edge ... out-edge`` (sumolib's shortest path).
The vehicles entering by one arm in one interval get times at its gate spread evenly (with a seeded jitter, in a
random order) over the first :data:`SPREAD_SHARE` of the observed part of the interval (the rest leaves room for a
vehicle whose insertion is held up by a queue). Each is inserted :data:`~trafficgeo.simulation.demand.ENTRY_M`
before the gate on the in-edge (at its start when the gate is nearer), on the best lane for its route, and departs
earlier by its free-flow travel time to the gate (distance / the lane's speed limit), so that it crosses the
origin gate in the interval it was counted in. SUMO time = observed time + ``time_offset_s`` (at least 10 s before
the first departure).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj

from trafficgeo.errors import InputError
from trafficgeo.geo.cuboids import dimensions_for
from trafficgeo.simulation.demand import ENTRY_M, SampledDemand, VehicleType
from trafficgeo.simulation.mapping import net_lane_crossings
from trafficgeo.site.gates import Gate, Junction
from trafficgeo.site.lines import CountLine
from trafficgeo.traffic.movements import movement_counts

__all__ = ["GATE_MAPPING_COLUMNS", "SPREAD_SHARE", "GateMapping", "GateMappingError", "counts_in_period",
           "map_gates", "movement_demand", "movement_routes", "movement_vehicle_types", "observed_movement_counts",
           "read_run_junction", "run_has_movements", "simulated_movement_counts"]

SPREAD_SHARE = 0.9  # vehicles cross their origin gate within this share of the observed part of their interval
DEFAULT_SPEED_FACTOR = (1.0, 0.1, 0.2, 2.0)  # SUMO's own default normc(1, 0.1, 0.2, 2): movements carry no speeds
GATE_MAPPING_COLUMNS = ["arm", "in_edge", "in_lane", "in_pos_m", "in_speed_mps", "out_edge", "out_lane", "out_pos_m",
                        "x_net", "y_net"]


class GateMappingError(InputError):
    """A gate crossing no edge of the network (the message names the arm)."""


@dataclass(frozen=True)
class GateMapping:
    """Each arm's in- and out-edge on the network: ``table`` (:data:`GATE_MAPPING_COLUMNS`, one row per arm; ``''``
    / NaN where the gate crosses no edge in that sense), the length (m) of every edge, and warnings."""

    net: Path
    table: pd.DataFrame
    edge_lengths_m: dict[str, float]
    warnings: tuple[str, ...] = ()

    def in_edge(self, arm: str) -> str:
        return str(self.table.set_index("arm").at[arm, "in_edge"])

    def out_edge(self, arm: str) -> str:
        return str(self.table.set_index("arm").at[arm, "out_edge"])


def run_has_movements(outputs: frozenset[str] | set[str]) -> bool:
    """Whether a run's output files (its manifest) hold a junction's movements."""
    return {"movements.csv", "movement_counts.csv", "trajectories.gpkg"} <= set(outputs)


def read_run_junction(folder: str | os.PathLike[str], crs: pyproj.CRS | None) -> Junction:
    """The junction of a run: the ``gates`` layer of its ``trajectories.gpkg`` (lines with ``arm``), in ``crs``."""
    from trafficgeo.run.folder import RunFolder

    junction = RunFolder(folder).junction(crs)
    if junction is None:
        raise InputError(f"{folder}: no gates layer in trajectories.gpkg; run analyze with --gates",
                         parameters=("run",))
    return junction


def _centre_left(gate: Gate, centre: np.ndarray) -> bool:
    """Whether the junction centre lies left of the gate (its first to its last point), as gate_crossings judges
    it for a straight gate."""
    c = np.asarray(gate.geometry.coords, dtype=np.float64)[:, :2]
    a, d = c[0], c[-1] - c[0]
    return bool(d[0] * (centre[1] - a[1]) - d[1] * (centre[0] - a[0]) >= 0)


def map_gates(junction: Junction, net: str | os.PathLike[str], run_crs: pyproj.CRS | None, *,
              net_crs: str | pyproj.CRS | None = None) -> GateMapping:
    """The in- and out-edge of each arm of ``junction`` (gates in ``run_crs``) on ``net`` (module docstring).

    Raises:
        GateMappingError: a gate crosses no edge of the network.
        InputError: the network cannot be read or placed.
    """
    net = Path(net)
    lines = [CountLine(g.arm, g.geometry) for g in junction.gates]
    crossings, _loc, lengths, bbox = net_lane_crossings(net, lines, run_crs, net_crs=net_crs)
    rows, warnings = [], []
    for gate in junction.gates:
        mine = [c for c in crossings if c.line == gate.arm]
        if not mine:
            x0, y0, x1, y1 = bbox
            raise GateMappingError(f"net {net}: the gate of arm {gate.arm!r} crosses no edge of the network (its "
                                   f"lanes span x {x0:.0f}..{x1:.0f}, y {y0:.0f}..{y1:.0f} in network coordinates); "
                                   "check that the network covers the junction and its CRS (net_crs), and that the "
                                   "gate is drawn across the arm", parameters=("net", "net_crs", "gates"))
        left = _centre_left(gate, junction.centre)
        xy = np.array([[c.x_net, c.y_net] for c in mine])
        mid = xy.mean(axis=0)
        row: dict = {"arm": gate.arm, "x_net": float(mid[0]), "y_net": float(mid[1])}
        for sense, entering in (("in", True), ("out", False)):
            cands = [c for c in mine if ((c.direction == 1) != left) == entering]
            edges = sorted({c.edge for c in cands})
            if len(edges) > 1:
                # the edge nearest the middle of the gate's crossings
                best_edge = min(cands, key=lambda c: math.hypot(c.x_net - mid[0], c.y_net - mid[1])).edge
                warnings.append(f"arm {gate.arm}: its gate crosses edges {', '.join(edges)} "
                                f"{'towards' if entering else 'away from'} the junction; {best_edge} taken")
                cands = [c for c in cands if c.edge == best_edge]
            best = min(cands, key=lambda c: c.pos_m) if cands else None  # the lane nearest the edge's start
            row[f"{sense}_edge"] = best.edge if best else ""
            row[f"{sense}_lane"] = best.lane if best else ""
            row[f"{sense}_pos_m"] = float(np.mean([c.pos_m for c in cands])) if cands else np.nan
            if entering:
                row["in_speed_mps"] = best.speed_limit_mps if best else np.nan
        rows.append(row)
    return GateMapping(net, pd.DataFrame(rows, columns=GATE_MAPPING_COLUMNS), lengths, tuple(warnings))


def observed_movement_counts(movements: pd.DataFrame, vehicles: pd.DataFrame, junction: Junction,
                             interval_s: float, begin_s: float, end_s: float) -> pd.DataFrame:
    """The run's complete movements counted per ``interval_s`` over ``[begin_s, end_s)`` (s) as ``analyze`` counts
    them (:func:`~trafficgeo.traffic.movements.movement_counts`; time first seen from ``vehicles.csv``), movements
    whose time falls outside the period left out."""
    first_seen = vehicles.set_index(vehicles["track_id"].astype(str))["first_time"]
    return counts_in_period(movements, junction, interval_s, begin_s, end_s, first_seen)


def counts_in_period(movements: pd.DataFrame, junction: Junction, interval_s: float, begin_s: float, end_s: float,
                     first_seen: pd.Series) -> pd.DataFrame:
    """:func:`~trafficgeo.traffic.movements.movement_counts` of the movements counted at a time in
    ``[begin_s, end_s)`` (it puts earlier and later ones into the first and last interval)."""
    from trafficgeo.traffic.movements import movement_time

    m = movements.assign(track_id=movements["track_id"].astype(str), complete=movements["complete"].astype(bool))
    t = movement_time(m, first_seen)
    m = m[(t >= begin_s) & (t < end_s)]
    return movement_counts(m, junction, interval_s, begin_s, end_s, first_seen=first_seen)


def movement_vehicle_types(counts: pd.DataFrame, vehicles: pd.DataFrame) -> list[VehicleType]:
    """One vehicle type per class of the counted movements: its share of them, length the median observed length
    of the run's vehicles of the class (else its typical length), SUMO's default speed factor."""
    per = counts.groupby(counts["class"].astype(str).str.lower().replace("", "car"))["count"].sum()
    per = per[per > 0]
    total = int(per.sum())
    cls = vehicles["class"].fillna("").astype(str).str.lower() if "class" in vehicles else pd.Series(dtype=str)
    out = []
    for name, n in per.items():
        dims = dimensions_for([name])[0]
        ln = vehicles.loc[cls == name, "length_m"].to_numpy(np.float64) if "length_m" in vehicles else np.zeros(0)
        ln = ln[np.isfinite(ln) & (ln > 0)]
        out.append(VehicleType(str(name), int(n) / total, float(np.median(ln)) if ln.size else float(dims[0]),
                               float(dims[1]), DEFAULT_SPEED_FACTOR, int(n)))
    return out


def movement_routes(net: str | os.PathLike[str], gates: GateMapping, counts: pd.DataFrame
                    ) -> tuple[dict[tuple[str, str], list[str]], tuple[str, ...]]:
    """The route (edges) of every counted movement, ``in-edge`` of its origin to ``out-edge`` of its destination by
    sumolib's shortest path; and warnings for the counted movements without one (their vehicles left out).

    Raises:
        InputError: an arm with counted movements has no in- (out-) edge on the network.
    """
    import sumolib

    try:
        sumo_net = sumolib.net.readNet(str(net), withInternal=False)
    except Exception as exc:  # sumolib raises plain exceptions for bad XML
        raise InputError(f"net {net}: not a readable SUMO network ({type(exc).__name__}); give the .net.xml",
                         parameters=("net",)) from None
    done = counts[counts["count"] > 0].groupby(["origin", "destination"])["count"].sum()
    routes, warnings = {}, []
    for (o, d), n in done.items():
        src, dst = gates.in_edge(str(o)), gates.out_edge(str(d))
        for arm, edge, what in ((o, src, "towards"), (d, dst, "away from")):
            if not edge:
                raise InputError(f"net {net}: the gate of arm {arm!r} crosses no edge heading {what} the junction, "
                                 f"but {int(n)} vehicle(s) went {o} -> {d}; check the network's lanes there",
                                 parameters=("net",))
        path, _cost = sumo_net.getShortestPath(sumo_net.getEdge(src), sumo_net.getEdge(dst))
        if not path:
            warnings.append(f"movement {o} -> {d}: no route from edge {src} to edge {dst} on the network; its "
                            f"{int(n)} vehicle(s) left out")
            continue
        routes[(str(o), str(d))] = [e.getID() for e in path]
    return routes, tuple(warnings)


def movement_demand(counts: pd.DataFrame, routes: dict[tuple[str, str], list[str]], gates: GateMapping, *,
                    seed: int) -> SampledDemand:
    """The vehicles of the movement counts on their routes (module docstring): gate times spread per interval and
    origin, departures moved earlier by the free-flow time from the insertion point to the origin gate."""
    rng = np.random.default_rng(seed)
    table = gates.table.set_index("arm")
    c = counts[(counts["count"] > 0)]
    c = c[[(str(o), str(d)) in routes for o, d in zip(c["origin"], c["destination"], strict=True)]]
    times, route_of, vclass, pos, lag = [], [], [], [], []
    for (start, origin), g in c.groupby(["interval_start", "origin"], sort=True):
        who = [(str(r.destination), str(r["class"]) or "car") for _, r in g.iterrows() for _ in range(int(r["count"]))]
        span = SPREAD_SHARE * float(g["observed_s"].iloc[0])
        n = len(who)
        at = float(start) + (np.arange(n) + rng.uniform(0.2, 0.8, n)) * span / n
        in_pos = float(table.at[origin, "in_pos_m"])
        entry = max(0.0, in_pos - ENTRY_M)
        speed = float(table.at[origin, "in_speed_mps"])
        for t, k in zip(at, rng.permutation(n), strict=True):  # the vehicles in a random order along the times
            dest, cls = who[k]
            times.append(t)
            route_of.append(routes[(str(origin), dest)])
            vclass.append(cls.lower())
            pos.append(entry)
            lag.append((in_pos - entry) / max(speed, 1.0))
    lag_a = np.asarray(lag, dtype=np.float64)
    gate_t = np.asarray(times, dtype=np.float64)
    begin = float(counts["interval_start"].min()) if len(counts) else 0.0
    max_lag = float(lag_a.max()) if lag_a.size else 0.0
    offset = 10.0 * math.ceil(max(0.0, max_lag + 10.0 - begin) / 10.0)
    n = len(route_of)
    return SampledDemand(gate_t + offset - lag_a, route_of, vclass, ["best"] * n, np.full(n, np.nan),
                         np.asarray(pos, dtype=np.float64), offset, max_lag)


def simulated_movement_counts(points: pd.DataFrame, junction: Junction, interval_s: float, begin_s: float,
                              end_s: float, *, metres_per_unit: float = 1.0) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The simulated vehicles' movements and their counts, found like the observed ones: ``points`` (simulated
    trajectories in the run's CRS and observed time, :func:`trafficgeo.traffic.validation.simulated_points`) through
    :func:`~trafficgeo.traffic.movements.vehicle_movements` at the run's gates, counted per ``interval_s`` over
    ``[begin_s, end_s)`` by the time each entered (else was first seen)."""
    from trafficgeo.traffic.movements import vehicle_movements

    tid = points["track_id"].astype(str)
    g = points.assign(track_id=tid).groupby("track_id", sort=False)
    vehicles = pd.DataFrame({"track_id": g["class"].first().index, "class": g["class"].first().to_numpy(),
                             "first_time": g["time"].min().to_numpy()})
    moves = vehicle_movements(points.assign(track_id=tid), vehicles, junction, metres_per_unit=metres_per_unit)
    first_seen = vehicles.set_index("track_id")["first_time"]
    return moves, counts_in_period(moves, junction, interval_s, begin_s, end_s, first_seen)
