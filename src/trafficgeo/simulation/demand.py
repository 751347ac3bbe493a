"""SUMO demand that reproduces observed counts: edge data, candidate routes, routeSampler, vehicle types.

Times: observed time ``t`` (s, the run's clock) is SUMO time ``t + time_offset_s``. The observed crossings are
counted per ``interval_s`` over ``[begin_s, end_s)`` (:func:`trafficgeo.traffic.counts.aggregate_counts`); each
line x lane x direction count goes to the SUMO edge it maps to (:mod:`trafficgeo.simulation.mapping`), the lanes of
an edge are summed and, when several lines observe one edge, the first line along it gives its count
(routeSampler wants one ``entered`` count per edge and interval; the others are reproduced by the simulation, or
not, between the lines). ``routeSampler.py --optimize full`` picks vehicles on candidate routes
(``randomTrips.py`` on the network, or the user's routes) so that the counts per edge and interval are met (it
spreads their departures at random over each interval). Each vehicle then takes the time at which an observed
vehicle crossed the first observed line on its route (:func:`place_departures`: an observed vehicle seen there
first, of that interval) and departs its travel time earlier (distance / that vehicle's spot speed), so that the
demand replays the observed arrivals, not only their number per interval; a vehicle left without an observed time
keeps routeSampler's, moved earlier by its travel time at the observed mean speed on that edge. A vehicle whose route
starts on the edge of that line enters :data:`ENTRY_M` before the line (not at the start of the edge), so that it
reaches the line on the lane and at the speed it was given. Demand starts :func:`warmup_s` before the observation,
at the rate of its first interval, so that the vehicles already on the road when it begins are simulated too.

Vehicles: each takes the class, the desired speed (``speedFactor`` = observed spot speed / the speed limit of the
SUMO lane where it was seen) and, when its route starts on that edge, the lane of an observed vehicle at the first
line of its first observed edge in its interval (drawn without replacement while there are enough), and departs at
its desired speed. Drivers keep their desired speed (``sigma="0"``: no random dawdling), so that free-flowing
simulated vehicles pass the lines at the observed speeds. Vehicle types: one ``vType`` per observed class (ids
``car``, ``truck``, ...: the names :func:`trafficgeo.traffic.box_points.dimensions_for` knows, so that the comparison
finds their lengths), length the median observed length (else the class's typical length), in a
``vTypeDistribution`` ``observed`` with the class shares of the observed crossings and a truncated normal
``speedFactor`` from the class's speeds, for vehicles that no observed vehicle was drawn for.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.geo.cuboids import dimensions_for
from trafficgeo.simulation.mapping import LaneMapping
from trafficgeo.simulation.tools import run_sumo_tool
from trafficgeo.traffic.counts import aggregate_counts
from trafficgeo.traffic.validation import ObservedRun

__all__ = ["DemandCounts", "SampledDemand", "VehicleType", "candidate_routes", "candidates_for", "demand_xml",
           "edge_counts", "observed_vehicle_types", "place_departures", "sample_routes", "uncovered_edges",
           "write_edge_data"]

SUMO_VCLASS = {"car": "passenger", "van": "delivery", "truck": "truck", "bus": "bus", "motorcycle": "motorcycle",
               "bicycle": "bicycle"}
_TOOL_TIMEOUT_S = 600.0
MINIMIZE_VEHICLES = 0.9  # routeSampler: prefer routes through several counting locations (one vehicle, not two)
WARMUP_MIN_S = 30.0  # s of demand at least before the observation begins (see warmup_s)
ENTRY_M = 30.0  # m before the first observed line where a vehicle whose route starts on that edge is inserted


@dataclass(frozen=True)
class DemandCounts:
    """Observed counts on the SUMO network: ``lanes`` per line, lane, direction and interval with the mapped
    ``sumo_edge``/``sumo_lane``; ``edges`` per SUMO edge and interval (``entered``, vehicles)."""

    lanes: pd.DataFrame
    edges: pd.DataFrame
    interval_s: float
    begin_s: float
    end_s: float
    warmup_s: float = 0.0  # the first row of ``edges`` per edge is a warm-up interval [begin_s - warmup_s, begin_s)


@dataclass(frozen=True)
class VehicleType:
    """A SUMO vehicle type from the observed vehicles of one class."""

    name: str  # class name, also the vType id
    share: float  # of the observed crossings
    length_m: float
    width_m: float
    speed_factor: tuple[float, float, float, float]  # normc(mean, deviation, min, max) of the speed limit
    observed: int  # crossings of the class

    def xml(self) -> str:
        vclass = SUMO_VCLASS.get(self.name, "passenger")
        sf = "normc({})".format(",".join(f"{v:.4f}" for v in self.speed_factor))
        return (f'        <vType id={quoteattr(self.name)} vClass="{vclass}" length="{self.length_m:.2f}" '
                f'width="{self.width_m:.2f}" speedFactor="{sf}" sigma="0" probability="{self.share:.6f}"/>\n')


def _mapped_crossings(observed: ObservedRun, mapping: LaneMapping, begin_s: float, end_s: float) -> pd.DataFrame:
    cr = observed.crossings.copy()
    cr["line"] = cr["line"].astype(str)
    cr["lane"] = cr["lane"].fillna("").astype(str)
    cr["direction"] = cr["direction"].astype(int)
    cr = cr[(cr["time"] >= begin_s) & (cr["time"] < end_s)]
    m = mapping.mapped[["line", "lane", "direction", "sumo_edge", "sumo_lane", "pos_m"]]
    return cr.merge(m, on=["line", "lane", "direction"], how="inner")


def edge_counts(observed: ObservedRun, mapping: LaneMapping, interval_s: float, begin_s: float,
                end_s: float) -> DemandCounts:
    """Observed crossings of ``[begin_s, end_s)`` counted per ``interval_s`` (s) and mapped to SUMO edges."""
    cr = _mapped_crossings(observed, mapping, begin_s, end_s)
    counts = aggregate_counts(cr, interval_s, begin_s, end_s)
    keys = ["line", "lane", "direction"]
    if len(counts):
        counts = counts.assign(lane=counts["lane"].astype(str), line=counts["line"].astype(str),
                               direction=counts["direction"].astype(int))
    lanes = counts[[*keys, "interval_start", "interval_end", "count"]].merge(
        mapping.mapped[[*keys, "sumo_edge", "sumo_lane", "pos_m"]], on=keys, how="inner")
    first = lanes[lanes["line"] == lanes["sumo_edge"].map(first_lines(mapping))]
    edges = first.groupby(["sumo_edge", "interval_start", "interval_end"], sort=True)["count"].sum().reset_index()
    edges = edges.rename(columns={"count": "entered"}).astype({"entered": int})
    warmup = warmup_s(mapping, cr)
    first_iv = edges[edges["interval_start"] == edges["interval_start"].min()] if len(edges) else edges
    pre = first_iv.assign(entered=np.round(first_iv["entered"] * warmup / (first_iv["interval_end"]
                                                                            - first_iv["interval_start"])).astype(int),
                          interval_start=begin_s - warmup, interval_end=begin_s)
    edges = pd.concat([pre, edges], ignore_index=True) if len(pre) else edges
    return DemandCounts(lanes, edges, float(interval_s), float(begin_s), float(end_s), warmup)


def warmup_s(mapping: LaneMapping, crossings: pd.DataFrame) -> float:
    """Seconds of demand before the observation begins, so that vehicles already between the lines at its start
    are there: 1.5 x the longest distance between two mapped line crossings at the slowest observed mean speed of
    an edge, plus 10 s, rounded up to 10 s; at least 30 s."""
    pts = mapping.mapped[["x_net", "y_net"]].to_numpy(np.float64)
    span = float(np.max(np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1)))) if len(pts) else 0.0
    speed = crossings.groupby("sumo_edge")["speed_kmh"].mean() / 3.6 if len(crossings) else pd.Series(dtype=float)
    v = float(speed[speed > 0.5].min()) if (speed > 0.5).any() else 10.0
    return max(WARMUP_MIN_S, 10.0 * math.ceil((1.5 * span / v + 10.0) / 10.0))


def first_lines(mapping: LaneMapping) -> pd.Series:
    """SUMO edge -> the first counting line along it (smallest lane position): the one its demand is fitted to."""
    return mapping.mapped.sort_values(["pos_m", "line"], kind="stable").groupby("sumo_edge")["line"].first()


def _edge_data_xml(edges: pd.DataFrame) -> str:
    out = ["<data>\n"]
    for k, ((b, e), g) in enumerate(edges.groupby(["interval_start", "interval_end"], sort=True)):
        out.append(f'    <interval id="observed_{k}" begin="{b:.3f}" end="{e:.3f}">\n')
        out += [f'        <edge id={quoteattr(str(r.sumo_edge))} entered="{int(r.entered)}"/>\n'
                for r in g.itertuples()]
        out.append("    </interval>\n")
    out.append("</data>\n")
    return "".join(out)


def write_edge_data(path: str | os.PathLike[str], counts: DemandCounts) -> None:
    """SUMO edge data (``<data><interval begin end><edge id entered/>``), the input of routeSampler."""
    from trafficgeo.io.atomic import write_text_atomic

    write_text_atomic(path, _edge_data_xml(counts.edges))


def candidate_routes(net: Path, out: Path, *, seed: int, trips: int = 500) -> Path:
    """Candidate routes by ``randomTrips.py`` (``trips`` trips routed by duarouter; one-edge trips allowed at the
    fringe, so that a network of a single road has routes); returns ``out``."""
    run_sumo_tool("randomTrips.py", ["-n", str(net), "-o", str(out.with_suffix(".trips.xml")), "-r", str(out),
                                     "--seed", str(seed), "-b", "0", "-e", str(trips), "-p", "1", "--allow-fringe",
                                     "--validate"],
                  _TOOL_TIMEOUT_S, cwd=out.parent)
    if not out.is_file():
        raise InputError(f"net {net}: randomTrips.py wrote no candidate routes; give routes (a .rou.xml)",
                         parameters=("net",))
    return out


def route_edges(path: Path) -> list[list[str]]:
    """The edge lists of the routes in a route file (``<route edges>``, inside vehicles or not)."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise InputError(f"routes {path}: not a readable SUMO route file ({exc}); give a .rou.xml",
                         parameters=("routes",)) from None
    return [r.get("edges", "").split() for r in root.iter("route") if r.get("edges")]


def uncovered_edges(routes: Path, counts: DemandCounts) -> list[str]:
    """Counted edges on no candidate route (routeSampler could not meet their counts)."""
    on_routes = {e for edges in route_edges(routes) for e in edges}
    counted = counts.edges.loc[counts.edges["entered"] > 0, "sumo_edge"].astype(str)
    return sorted(set(counted) - on_routes)


def candidates_for(net: Path, routes: Path | None, work: Path, counts: DemandCounts, *, seed: int) -> Path:
    """The user's ``routes``, checked to pass every counted edge; or randomTrips.py candidates (500 trips, then
    5000 if some counted edge is on none of them)."""
    if routes is not None:
        missing = uncovered_edges(routes, counts)
        if missing:
            raise InputError(f"routes {routes}: no route passes the counted edge(s) {', '.join(missing[:5])}; give "
                             "routes through them", parameters=("routes",))
        return routes
    for trips in (500, 5000):
        cand = candidate_routes(net, work / "candidates.rou.xml", seed=seed, trips=trips)
        missing = uncovered_edges(cand, counts)
        if not missing:
            return cand
    raise InputError(f"net {net}: none of {trips} random trips (randomTrips.py) passes the counted edge(s) "
                     f"{', '.join(missing[:5])}; give candidate routes through them (`routes`, a .rou.xml)",
                     parameters=("net", "routes"))


def observed_vehicle_types(observed: ObservedRun, mapping: LaneMapping, begin_s: float,
                           end_s: float) -> list[VehicleType]:
    """One :class:`VehicleType` per observed class (module docstring)."""
    cr = _mapped_crossings(observed, mapping, begin_s, end_s)
    if not len(cr):
        raise InputError(f"{observed.folder}: no vehicle crossed a counting line between {begin_s:g} and {end_s:g} s; "
                         "give a run with counts (or other begin_s/end_s)", parameters=("begin_s", "end_s"))
    limit = {c.lane: c.speed_limit_mps for c in mapping.crossings}
    cls = cr["class"].fillna("").astype(str).str.lower().replace("", "car").to_numpy()
    factor = cr["speed_kmh"].to_numpy(np.float64) / 3.6 / cr["sumo_lane"].map(limit).to_numpy(np.float64)
    lengths = cr["length_m"].to_numpy(np.float64) if "length_m" in cr else np.full(len(cr), np.nan)
    all_f = factor[np.isfinite(factor) & (factor > 0)]
    out = []
    for name in sorted(set(cls)):
        sel = cls == name
        f = factor[sel]
        f = f[np.isfinite(f) & (f > 0)]
        if f.size < 2:
            f = all_f if all_f.size >= 2 else np.array([0.9, 1.1])
        mean, dev = float(f.mean()), float(f.std(ddof=1))
        dims = dimensions_for([name])[0]
        ln = lengths[sel]
        ln = ln[np.isfinite(ln) & (ln > 0)]
        out.append(VehicleType(name, float(sel.mean()), float(np.median(ln)) if ln.size else float(dims[0]),
                               float(dims[1]), (mean, dev, max(0.2, mean - 3 * dev), mean + 3 * dev), int(sel.sum())))
    return out


@dataclass(frozen=True)
class SampledDemand:
    """The vehicles of the demand, one entry each: departure (SUMO time, s), route edges, and what was drawn from
    an observed vehicle (class, departure lane index or "random", speed factor; "" / NaN when none)."""

    depart_s: np.ndarray
    routes: list[list[str]]
    vclass: list[str]
    depart_lane: list[str]
    speed_factor: np.ndarray
    depart_pos_m: np.ndarray  # front bumper on the first edge (NaN: SUMO's default)
    time_offset_s: float
    max_lag_s: float


def _segments(edges: pd.DataFrame) -> list[pd.DataFrame]:
    """The edge counts cut into runs of consecutive intervals of one length (routeSampler spreads counts over a
    regular grid of intervals; a shorter first or last interval, or the warm-up, gets a run of its own)."""
    iv = edges[["interval_start", "interval_end"]].drop_duplicates().sort_values("interval_start")
    lengths = np.round((iv["interval_end"] - iv["interval_start"]).to_numpy(), 6)
    run = np.concatenate([[0], np.cumsum(lengths[1:] != lengths[:-1])])
    starts = iv["interval_start"].to_numpy()
    return [edges[edges["interval_start"].isin(starts[run == k])] for k in range(int(run[-1]) + 1)] if len(iv) else []


def sample_routes(routes: Path, counts: DemandCounts, work: Path, *, seed: int) -> list[Path]:
    """``routeSampler.py --optimize full`` on candidate ``routes`` for the counts, one run per run of equally long
    intervals (:func:`_segments`, explicit begin, end and interval); returns the route files it wrote."""
    out = []
    for k, seg in enumerate(_segments(counts.edges)):
        b, e = float(seg["interval_start"].min()), float(seg["interval_end"].max())
        length = float((seg["interval_end"] - seg["interval_start"]).iloc[0])
        data, sampled = work / f"counts_{k}.edgedata.xml", work / f"sampled_{k}.rou.xml"
        data.write_text(_edge_data_xml(seg), encoding="utf-8")
        run_sumo_tool("routeSampler.py", ["-r", str(routes), "-d", str(data), "-o", str(sampled), "--optimize",
                                          "full", "-s", str(seed + k), "--prefix", f"s{k}_", "--threads", "1",
                                          "--minimize-vehicles", repr(MINIMIZE_VEHICLES), "-b", f"{b:.3f}", "-e",
                                          f"{e:.3f}", "-i", f"{length:.3f}"],
                      _TOOL_TIMEOUT_S, cwd=work)
        out.append(sampled)
    return out


def _observed_pools(cr: pd.DataFrame, first_pos: pd.Series, mapping: LaneMapping, counts: DemandCounts
                    ) -> dict[tuple[str, float], pd.DataFrame]:
    """The observed vehicles at the first line of each mapped edge, per (edge, interval start): lane index, class,
    speed factor (spot speed / the lane's speed limit), spot speed (m/s) and the time to replay (s, in the order
    of the times; NaN where the vehicle was seen at a mapped line before: it is in the demand by that line). The
    warm-up's pool: the vehicles on the road when the observation begins (first seen downstream of the first line
    of their edge), timed back to that line at their spot speed, then the first interval's vehicles without a time
    (their class, lane and speed only). ``cr``: the mapped crossings of the observation; ``first_pos``: per SUMO
    edge, the position (m) of its first line."""
    t = cr["time"].to_numpy(np.float64)
    seen_first = t <= cr.groupby("track_id")["time"].transform("min").to_numpy(np.float64) + 1e-9
    line_pos = cr["sumo_edge"].map(first_pos).to_numpy(np.float64)
    at_first = (cr["line"] == cr["sumo_edge"].map(first_lines(mapping))).to_numpy()
    speed = cr["speed_kmh"].to_numpy(np.float64) / 3.6
    back = t - (cr["pos_m"].to_numpy(np.float64) - line_pos) / np.where(speed > 0.5, speed, np.nan)
    on_road = seen_first & ~at_first & (back < counts.begin_s)  # NaN (no speed) compares False
    limit = {c.lane: c.speed_limit_mps for c in mapping.crossings}
    starts = np.sort(counts.edges["interval_start"].unique())
    k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, None)
    factor = speed / cr["sumo_lane"].map(limit).to_numpy(np.float64)
    warm = counts.begin_s - counts.warmup_s
    table = pd.DataFrame({"edge": cr["sumo_edge"].astype(str).to_numpy(),
                          "start": np.where(on_road, warm, starts[k] if len(starts) else np.nan),
                          "lane": cr["sumo_lane"].astype(str).str.rpartition("_")[2].to_numpy(),
                          "vclass": cr["class"].fillna("").astype(str).str.lower().replace("", "car").to_numpy(),
                          "speed_factor": np.clip(factor, 0.2, 2.0),
                          "time": np.where(on_road, back, np.where(seen_first, t, np.nan)),
                          "speed_mps": speed})[at_first | on_road]
    pools = {(str(e), float(s)): g.sort_values("time").reset_index(drop=True)
             for (e, s), g in table.groupby(["edge", "start"]) if s != warm}
    for edge in {e for e, _ in pools}:
        first = min(s for e, s in pools if e == edge)
        on = table[(table["edge"] == edge) & (table["start"] == warm)]
        pools[(edge, warm)] = pd.concat([on.sort_values("time"), pools[(edge, first)].assign(time=np.nan)],
                                        ignore_index=True)
    return pools


def place_departures(sampled: list[Path], net_lengths: dict[str, float], observed: ObservedRun, mapping: LaneMapping,
                     counts: DemandCounts, *, seed: int, step_s: float = 0.5) -> SampledDemand:
    """Read routeSampler's vehicles; give each the class, speed factor, time at the line and (when its route
    starts on that edge) lane of an observed vehicle of the first observed line on its route and its interval
    (drawn without replacement while there are enough, their times in the order of routeSampler's departures); make
    each depart its travel time to that line before the observed vehicle crossed it (routeSampler's own departure
    time where no observed vehicle was left to draw). In the warm-up the vehicles on the road when the observation
    begins are replayed; the others pass the last line on their edge before it begins. Times are those of the
    footprint's centre, as the comparison's (:func:`~trafficgeo.traffic.validation.simulated_points`); a vehicle
    entering on the edge of its line departs on a simulation step (``step_s``, s), a little farther back."""
    vehicles = []
    for path in sampled:
        try:
            vehicles += list(ET.parse(path).getroot().iter("vehicle"))
        except (ET.ParseError, OSError) as exc:
            raise InputError(f"routeSampler output {path} is not readable ({exc})") from None
    cr = _mapped_crossings(observed, mapping, counts.begin_s, counts.end_s)
    speed = {str(k): float(v) for k, v in (cr.groupby("sumo_edge")["speed_kmh"].mean() / 3.6).items()
             if np.isfinite(v) and v > 0.5}
    line_pos = mapping.mapped.groupby("sumo_edge")["pos_m"]
    first_pos_m = line_pos.min()
    first_pos = first_pos_m.to_dict()
    span = (line_pos.max() - first_pos_m).to_dict()  # m from the first line of an edge to its last
    starts = np.sort(counts.edges["interval_start"].unique())
    depart, edges_of, dist_of, key_of, at_start, depart_pos = [], [], [], [], [], []
    for veh in vehicles:
        route = veh.find("route")
        edges = (route.get("edges", "") if route is not None else "").split()
        if not edges:
            continue
        t = float(veh.get("depart", "0"))
        dist, k_first = 0.0, None
        for k, e in enumerate(edges):
            if e in first_pos:
                dist += float(first_pos[e])
                k_first = k
                break
            dist += net_lengths.get(e, 0.0)
        entry = max(0.0, float(first_pos[edges[0]]) - ENTRY_M) if k_first == 0 else np.nan
        dist_of.append((dist - (entry if k_first == 0 else 0.0)) if k_first is not None else 0.0)
        depart_pos.append(entry)
        depart.append(t)
        edges_of.append(edges)
        start = float(starts[max(0, np.searchsorted(starts, t, side="right") - 1)]) if len(starts) else np.nan
        key_of.append((edges[k_first], start) if k_first is not None else None)
        at_start.append(k_first == 0)
    drawn = _draw_observed(key_of, at_start, np.asarray(depart, dtype=np.float64),
                           _observed_pools(cr, first_pos_m, mapping, counts), np.random.default_rng(seed))
    edge_speed = np.array([speed.get(k[0], 13.9) if k is not None else 13.9 for k in key_of], dtype=np.float64)
    own = np.isfinite(drawn.speed_mps) & (drawn.speed_mps > 0.5)
    v = np.where(own, drawn.speed_mps, edge_speed)
    half_length = np.where([k is not None for k in key_of], dimensions_for(drawn.vclass)[:, 0] / 2.0, 0.0)
    lag_a = (np.asarray(dist_of, dtype=np.float64) + half_length) / v
    at_line = np.where(np.isfinite(drawn.time_s), drawn.time_s, np.asarray(depart, dtype=np.float64))
    # the warm-up's vehicles without an observed time pass the last line on their edge before the observation begins
    warm, w = counts.begin_s - counts.warmup_s, counts.warmup_s
    for i, k in enumerate(key_of):
        if k is not None and k[1] == warm and not np.isfinite(drawn.time_s[i]):
            clear = min(w, float(span.get(k[0], 0.0)) / edge_speed[i] + 2.0)
            at_line[i] = warm + (at_line[i] - warm) * (w - clear) / w
    max_lag = float(lag_a.max()) if lag_a.size else 0.0
    first = min(counts.begin_s - counts.warmup_s, float(at_line.min()) if at_line.size else 0.0)
    offset = 10.0 * math.ceil(max(0.0, max_lag + 10.0 - first) / 10.0)
    depart_s, pos = at_line + offset - lag_a, np.asarray(depart_pos, dtype=np.float64)
    # SUMO inserts a vehicle at the first step after its departure: one that enters on the edge of its line departs
    # on the step before, as far back as it drives meanwhile
    on_step = np.floor(depart_s / step_s + 1e-9) * step_s
    back = v * (depart_s - on_step)
    snap = np.isfinite(pos) & (pos - back >= 0.0)
    depart_s, pos = np.where(snap, on_step, depart_s), np.where(snap, pos - back, pos)
    return SampledDemand(depart_s, edges_of, drawn.vclass, drawn.lanes, drawn.speed_factor, pos, offset, max_lag)


@dataclass(frozen=True)
class _Drawn:
    """What each vehicle of the demand took from an observed vehicle ("" / "random" / NaN where none)."""

    vclass: list[str]
    lanes: list[str]
    speed_factor: np.ndarray
    time_s: np.ndarray  # when the observed vehicle crossed the line (run clock, s); NaN: keep routeSampler's time
    speed_mps: np.ndarray  # its spot speed there


def _nearest_in_order(depart: np.ndarray, times: np.ndarray) -> set[int]:
    """Positions of ``len(times)`` of the sorted ``depart`` (s), each the nearest free one to a time of the sorted
    ``times`` (s), taken in the order of the times."""
    if len(times) >= len(depart):
        return set(range(len(depart)))
    free = np.ones(len(depart), dtype=bool)
    for t in times:
        q = int(np.argmin(np.where(free, np.abs(depart - t), np.inf)))
        free[q] = False
    return set(np.flatnonzero(~free).tolist())


def _draw_observed(keys: list[tuple[str, float] | None], at_start: list[bool], depart: np.ndarray,
                   pools: dict[tuple[str, float], pd.DataFrame], rng: np.random.Generator) -> _Drawn:
    """For the vehicles of each (edge, interval): the pool's observed vehicles with a time, as many as there are
    vehicles (drawn at random when there are more), go in the order of their times to the vehicles whose departures
    ``depart`` (s) lie nearest them; the other vehicles draw the pool's other observed vehicles in a random order,
    then at random again when the pool is used up, without a time."""
    n = len(keys)
    vclass, lanes = [""] * n, ["random"] * n
    factor, time_s, speed = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    groups: dict[tuple[str, float], list[int]] = {}
    for i, k in enumerate(keys):
        if k is not None and k in pools:
            groups.setdefault(k, []).append(i)
    for k, idx in sorted(groups.items()):
        pool = pools[k]  # in the order of the observed times
        idx = sorted(idx, key=lambda i: (depart[i], i))
        has_time = np.flatnonzero(np.isfinite(pool["time"].to_numpy(np.float64)))
        m = min(len(idx), len(has_time))
        timed = np.sort(rng.choice(has_time, m, replace=False))
        to_time = _nearest_in_order(depart[idx], pool["time"].to_numpy(np.float64)[timed])
        rest = rng.permutation(np.setdiff1d(np.arange(len(pool)), timed))
        rest = np.concatenate([rest, rng.integers(0, len(pool), max(0, len(idx) - m - len(rest)))]).astype(int)
        it, ir = iter(timed), iter(rest)
        for q, i in enumerate(idx):
            j = int(next(it)) if q in to_time else int(next(ir))
            vclass[i] = str(pool.at[j, "vclass"])
            factor[i] = float(pool.at[j, "speed_factor"])
            speed[i] = float(pool.at[j, "speed_mps"])
            if q in to_time:
                time_s[i] = float(pool.at[j, "time"])
            if at_start[i]:
                lanes[i] = str(pool.at[j, "lane"])
    return _Drawn(vclass, lanes, factor, time_s, speed)


def demand_xml(types: list[VehicleType], demand: SampledDemand) -> str:
    """The route file: the observed vehicle types, then the vehicles sorted by departure."""
    out = ["<routes>\n", '    <vTypeDistribution id="observed">\n', *(t.xml() for t in types),
           "    </vTypeDistribution>\n"]
    known = {t.name for t in types}
    order = np.argsort(demand.depart_s, kind="stable")
    for n, i in enumerate(order):
        vtype = demand.vclass[i] if demand.vclass[i] in known else "observed"
        factor = demand.speed_factor[i]
        sf = f' speedFactor="{factor:.4f}"' if np.isfinite(factor) else ""
        pos = demand.depart_pos_m[i]
        sf += f' departPos="{pos:.2f}"' if np.isfinite(pos) else ""
        out.append(f'    <vehicle id="v{n}" type={quoteattr(vtype)} depart="{demand.depart_s[i]:.2f}" '
                   f'departLane="{demand.depart_lane[i]}" departSpeed="desired"{sf}>\n'
                   f'        <route edges="{" ".join(demand.routes[i])}"/>\n    </vehicle>\n')
    out.append("</routes>\n")
    return "".join(out)
