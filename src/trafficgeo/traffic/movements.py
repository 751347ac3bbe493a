"""Turning movements at a junction: where each vehicle came from and went to, from its world trajectory and the
junction's gates (:mod:`trafficgeo.site.gates`, whose conventions hold here).

* :func:`gate_crossings` - every crossing of every gate, entering (towards the centre) or leaving.
* :func:`vehicle_movements` - one row per vehicle that came through the junction: ``origin`` = the gate of its
  first crossing when that crossing enters, ``destination`` = the gate of its last crossing when it leaves.
  A vehicle first seen inside the gates (its first crossing leaves, or it has none) gets its origin **by its path**
  when that is unambiguous: its first position lies on an arm's approach (within the arm's sector, at least
  :data:`APPROACH_SHARE` of the way from the centre to the gate) and its first 2 m of travel head into the
  junction (within 45 degrees); the destination likewise from its last position and travel. Otherwise the end is
  unknown (``''``) and the movement **incomplete**: listed, not counted.
* a **U-turn** (out by the arm it came in by) only where the track went well into the junction and turned round
  (:data:`U_TURN_REACH_SHARE`, :data:`U_TURN_MIN_DEG`) onto the other side of the road: at the same distances
  along the arm, the way out lies at least :data:`U_TURN_MIN_SWING_M` to the side of the way in (no vehicle
  turns round on the spot; a track that reverses along its own path is a tracker's identity passed from a vehicle
  queued on the approach to one leaving by the same arm). A piece of track that crossed its gate twice without
  doing so keeps the end that agrees with its motion along the arm and is a half.
* pieces of one vehicle - **halves** of a track broken inside the junction, **doubles** seen at once - joined
  into one movement (:mod:`trafficgeo.traffic.movement_pieces`).
* :func:`movement_counts` - complete movements per interval (by the time the vehicle entered: its entry crossing,
  else the time first seen), origin, destination and class.
* :func:`turning_movement_table` - the layout junction tools import: one row per interval, per approach arm the
  left, through, right and U counts, the total and the heavy vehicles
  (:data:`~trafficgeo.traffic.measurements.HEAVY_CLASSES`).
* :func:`peak_hour` - the busiest hour of whole intervals, its volume and peak-hour factor (PHF = hour volume /
  (intervals per hour x the busiest interval's volume)).

Times are seconds on the tracks' clock; ``stopped_s`` is the time at a smoothed speed below :data:`STOPPED_KMH`
between entering (else first seen) and leaving (else last seen).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.site.gates import MOVEMENTS, Junction
from trafficgeo.traffic.counts import MIN_INTERVAL_S, interval_edges, segment_crossings
from trafficgeo.traffic.measurements import HEAVY_CLASSES
from trafficgeo.traffic.movement_pieces import join_judged_halves, merge_doubles, pair_halves

APPROACH_SHARE = 0.2  # a first/last position at least this share of the centre-to-gate distance out is on the arm
# (a vehicle queued at the stop line when the video starts is there: the stop line is where the junction begins; a
# vehicle found again or lost just past it, its travel along the arm, is judged there too: on 29 generated junction
# worlds 0.3 -> 0.2 took the count errors from 60 to 53 of 703 vehicles, 4 fewer incomplete and 1 fewer wrong arm)
HEADING_TOLERANCE_DEG = 45.0  # travel within this of straight into (out of) the junction along the arm
PATH_TRAVEL_M = 2.0  # metres of travel that give a vehicle's initial / final direction
STOPPED_KMH = 5.0  # km/h: slower than this is stopped
MOVEMENT_COLUMNS = ["track_id", "class", "origin", "destination", "movement", "entry_time", "exit_time",
                    "travel_time_s", "stopped_s", "origin_by", "destination_by", "complete", "track_ids"]
U_TURN_REACH_SHARE = 0.5  # a U-turn reaches this share of the centre-to-gate distance from the centre
MOVEMENT_INTERVAL_S = 900.0  # s: turning movements are counted per 15 minutes
U_TURN_MIN_DEG = 120.0  # and turns by at least this much between its first and last travel
U_TURN_MIN_SWING_M = 3.0  # m: and comes back at least this far to the side of the way it went in (a lane)


def check_movement_interval(movement_interval_s: float) -> float:
    """``movement_interval_s`` (s) if it is a usable interval for movement counts (finite, at least
    :data:`~trafficgeo.traffic.counts.MIN_INTERVAL_S`)."""
    if not (np.isfinite(movement_interval_s) and movement_interval_s >= MIN_INTERVAL_S):
        raise InputError(f"movement_interval_s {float(movement_interval_s):g}: the interval of the turning-movement "
                         f"counts must be a finite number of seconds, at least {MIN_INTERVAL_S:g}; 900 (15 min) is "
                         "what junction studies use", parameters=("movement_interval_s",))
    return float(movement_interval_s)


def gate_crossings(points: pd.DataFrame, junction: Junction) -> pd.DataFrame:
    """Every crossing of every gate by the trajectories in ``points`` (sorted by track, then time; columns
    ``track_id, time, x, y``): ``track_id, arm, time, entering`` (True towards the centre), sorted by track and
    time."""
    cols = {"track_id": pd.Series(dtype=object), "arm": pd.Series(dtype=object),
            "time": pd.Series(dtype=float), "entering": pd.Series(dtype=bool)}
    if len(points) < 2:
        return pd.DataFrame(cols)
    tid = points["track_id"].astype(str).to_numpy()
    xy = points[["x", "y"]].to_numpy(dtype=np.float64)
    t = points["time"].to_numpy(dtype=np.float64)
    same = (tid[1:] == tid[:-1]) & np.all(np.isfinite(xy[1:]) & np.isfinite(xy[:-1]), axis=1)
    i0 = np.flatnonzero(same)
    p, q = xy[i0], xy[i0 + 1]
    parts = []
    for gate in junction.gates:
        coords = np.asarray(gate.geometry.coords, dtype=np.float64)[:, :2]
        for k in range(len(coords) - 1):
            a, b = coords[k], coords[k + 1]
            s, sign = segment_crossings(p, q, a, b)
            hit = np.flatnonzero(np.isfinite(s))
            if hit.size == 0:
                continue
            d = b - a
            c = junction.centre
            centre_left = d[0] * (c[1] - a[1]) - d[1] * (c[0] - a[0]) >= 0
            seg = i0[hit]
            parts.append(pd.DataFrame({"track_id": tid[seg], "arm": gate.arm,
                                       "time": t[seg] + s[hit] * (t[seg + 1] - t[seg]),
                                       "entering": (sign[hit] == 1) != centre_left}))
    if not parts:
        return pd.DataFrame(cols)
    out = pd.concat(parts, ignore_index=True)
    return out.sort_values(["track_id", "time"], kind="stable").reset_index(drop=True)


@dataclass(frozen=True)
class _Arms:
    """Per arm: bearing (rad), unit vector out of the centre, the gate's distance from the centre and the half
    width of its sector (rad)."""

    names: list[str]
    bearing: np.ndarray
    out: np.ndarray
    reach: np.ndarray
    half_sector: np.ndarray

    @classmethod
    def of(cls, junction: Junction) -> _Arms:
        names = junction.arms
        b = np.radians([junction.bearings_deg[a] for a in names])
        out = np.column_stack([np.sin(b), np.cos(b)])
        reach = np.array([np.hypot(*(g.midpoint - junction.centre)) for g in junction.gates])
        half = np.empty(len(names))
        for i in range(len(names)):
            gaps = [abs(_wrap(b[j] - b[i])) for j in range(len(names)) if j != i]
            half[i] = 0.5 * min(gaps)
        return cls(names, b, out, reach, half)


def _wrap(a: float | np.ndarray) -> float | np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _travel_direction(xy: np.ndarray, from_start: bool, metres_per_unit: float) -> np.ndarray | None:
    """Unit vector of the first (last) :data:`PATH_TRAVEL_M` of travel, None if the vehicle never moved that far."""
    seq = xy if from_start else xy[::-1]
    d = np.hypot(*(seq - seq[0]).T) * metres_per_unit
    far = np.flatnonzero(d >= PATH_TRAVEL_M)
    if far.size == 0:
        return None
    v = seq[far[0]] - seq[0]
    v = v / np.hypot(*v)
    return v if from_start else -v


def _arm_by_path(arms: _Arms, centre: np.ndarray, xy: np.ndarray, start: bool, metres_per_unit: float) -> str:
    """The arm a vehicle came from (``start``) or went to, judged from its first (last) position and travel; ''
    where that is ambiguous (module docstring)."""
    p = xy[0] if start else xy[-1]
    rel = p - centre
    dist = np.hypot(*rel)
    if dist == 0:
        return ""
    ang = np.arctan2(rel[0], rel[1])
    off = np.abs(_wrap(ang - arms.bearing))
    i = int(np.argmin(off))
    if off[i] > arms.half_sector[i] or dist < APPROACH_SHARE * arms.reach[i]:
        return ""
    v = _travel_direction(xy, start, metres_per_unit)
    if v is None:
        return ""
    into = -arms.out[i] if start else arms.out[i]  # into the junction at the start, out of it at the end
    if float(v @ into) < np.cos(np.radians(HEADING_TOLERANCE_DEG)):
        return ""
    return arms.names[i]


def vehicle_movements(points: pd.DataFrame, vehicles: pd.DataFrame, junction: Junction, *,
                      metres_per_unit: float = 1.0) -> pd.DataFrame:
    """One row per vehicle of ``vehicles`` that came through the junction (module docstring; stationary vehicles
    left out): columns :data:`MOVEMENT_COLUMNS`, with ``origin_by``/``destination_by`` = ``gate``, ``path`` or ''
    (unknown). ``points``: the trajectories (sorted by track and time; ``track_id, time, x, y, speed_kmh``)."""
    veh = vehicles
    if "stationary" in veh.columns:
        veh = veh[~veh["stationary"].astype(bool)]
    classes = dict(zip(veh["track_id"].astype(str), veh["class"].fillna("").astype(str), strict=True))
    trackers = dict(zip(veh["track_id"].astype(str), (set(str(v).split(";")) for v in veh["tracker_ids"]),
                        strict=True)) if "tracker_ids" in veh.columns else {}
    pts = points[points["track_id"].astype(str).isin(set(classes))]
    events = gate_crossings(pts, junction)
    by_track = dict(tuple(events.groupby("track_id", sort=False))) if len(events) else {}
    arms = _Arms.of(junction)
    rows = []
    groups = pts.groupby(pts["track_id"].astype(str), sort=False) if len(pts) else []
    for tid, g in groups:
        xy = g[["x", "y"]].to_numpy(dtype=np.float64)
        t = g["time"].to_numpy(dtype=np.float64)
        ok = np.all(np.isfinite(xy), axis=1)
        xy, t = xy[ok], t[ok]
        pieces = (g["fragment"].fillna(tid).astype(str).to_numpy(dtype=object)[ok] if "fragment" in g.columns
                  else np.full(len(t), tid, dtype=object))  # each point's world fragment
        if len(xy) == 0:
            continue
        ev = by_track.get(tid)
        origin = destination = origin_by = destination_by = ""
        entry = exit_ = np.nan
        if ev is not None:
            first, last = ev.iloc[0], ev.iloc[-1]
            if bool(first["entering"]):
                origin, origin_by, entry = str(first["arm"]), "gate", float(first["time"])
            if not bool(last["entering"]):
                destination, destination_by, exit_ = str(last["arm"]), "gate", float(last["time"])
        elif _outside_every_gate(arms, junction.centre, xy):
            continue  # seen on an arm only, never in the junction
        if not origin:
            origin = _arm_by_path(arms, junction.centre, xy, True, metres_per_unit)
            origin_by = "path" if origin else ""
        if not destination:
            destination = _arm_by_path(arms, junction.centre, xy, False, metres_per_unit)
            destination_by = "path" if destination else ""
        start = entry if np.isfinite(entry) else t[0]
        end = exit_ if np.isfinite(exit_) else t[-1]
        speed = g["speed_kmh"].to_numpy(dtype=np.float64)[ok] / 3.6 if "speed_kmh" in g.columns else np.zeros(len(t))
        rows.append({"track_id": tid, "class": classes.get(tid, ""), "origin": origin, "destination": destination,
                     "entry_time": entry, "exit_time": exit_, "stopped_s": _stopped_s(g, start, end),
                     "origin_by": origin_by, "destination_by": destination_by, "track_ids": tid,
                     "_t0": t[0], "_t1": t[-1], "_p0": xy[0], "_p1": xy[-1],
                     "_v0": float(np.nan_to_num(speed[0])) if len(speed) else 0.0,
                     "_v1": float(np.nan_to_num(speed[-1])) if len(speed) else 0.0,
                     "_d0": _travel_direction(xy, True, metres_per_unit),
                     "_d1": _travel_direction(xy, False, metres_per_unit), "_t": t, "_xy": xy,
                     "_trackers": trackers.get(tid, set()), "_classes": Counter({classes.get(tid, ""): len(t)})})
        _check_u_turn(rows[-1], pieces, arms, junction.centre, metres_per_unit)
    rows = pair_halves(rows, metres_per_unit)
    rows = pair_halves(merge_doubles(rows, metres_per_unit), metres_per_unit)  # halves that doubles completed
    rows = join_judged_halves(rows)
    for r in rows:
        o, d, e, x = r["origin"], r["destination"], r["entry_time"], r["exit_time"]
        r["movement"] = junction.movement(o, d) if o and d else ""
        r["travel_time_s"] = x - e if np.isfinite(e) and np.isfinite(x) else np.nan
        r["complete"] = bool(o and d)
    table = pd.DataFrame(rows, columns=MOVEMENT_COLUMNS)
    table["complete"] = table["complete"].astype(bool)
    return table.sort_values(["entry_time", "track_id"], kind="stable", na_position="last").reset_index(drop=True)


def _swing_m(xy: np.ndarray, k: int, centre: np.ndarray, out: np.ndarray, metres_per_unit: float) -> float:
    """How far (m) a path that goes in along an arm (unit vector ``out`` from the centre) and back out again comes
    back to the side of the way it went in: the median sideways distance between its two halves (split at point
    ``k``, where it comes nearest the centre) at the same distances along the arm; inf where the halves share no
    such distance."""
    rel = xy - centre
    along, side = rel @ out, rel @ np.array([-out[1], out[0]])
    (a_in, s_in), (a_out, s_out) = (along[: k + 1], side[: k + 1]), (along[k:], side[k:])
    lo, hi = max(a_in.min(), a_out.min()), min(a_in.max(), a_out.max())
    if a_in.size < 2 or a_out.size < 2 or not hi > lo:
        return float("inf")
    at = np.linspace(lo, hi, 9)
    i, o = np.argsort(a_in, kind="stable"), np.argsort(a_out, kind="stable")
    gap = np.interp(at, a_in[i], s_in[i]) - np.interp(at, a_out[o], s_out[o])
    return float(np.median(np.abs(gap))) * metres_per_unit


def _one_piece_turns(xy: np.ndarray, pieces: np.ndarray, k: int, metres_per_unit: float) -> bool:
    """Whether the piece of track (``pieces``: each point's world fragment) holding point ``k``, where the path
    comes nearest the centre, turns round by itself (its own first and last travel :data:`U_TURN_MIN_DEG` or more
    apart): a U-turn made only by joining pieces of track (a vehicle's way in and another's way out) is not shown by
    any of them."""
    mine = xy[pieces == pieces[k]]
    if len(mine) == len(xy):
        return True  # one piece: its turn is the whole path's (checked by the caller)
    d0, d1 = _travel_direction(mine, True, metres_per_unit), _travel_direction(mine, False, metres_per_unit)
    return d0 is not None and d1 is not None and float(d0 @ d1) <= np.cos(np.radians(U_TURN_MIN_DEG))


def _check_u_turn(row: dict, pieces: np.ndarray, arms: _Arms, centre: np.ndarray, metres_per_unit: float) -> None:
    """A vehicle that leaves by the arm it came from made a U-turn only if it went well into the junction (within
    :data:`U_TURN_REACH_SHARE` of the gate's distance from the centre), turned round (its first and last travel
    :data:`U_TURN_MIN_DEG` or more apart, where both are known) within one piece of track (``pieces``: each point's
    world fragment; :func:`_one_piece_turns`) and came back on the other side of the road (at least
    :data:`U_TURN_MIN_SWING_M` to the side of the way in: :func:`_swing_m`). Otherwise the piece of track crossed
    its gate twice without turning (a box jittering at the gate, the two ends of a bus) or went back along its own
    way (the tracker's identity passed from a queued vehicle to one leaving by the same arm): the end that goes
    against its motion along the arm is dropped, leaving a half for
    :func:`~trafficgeo.traffic.movement_pieces.pair_halves` (in place)."""
    if not row["origin"] or row["origin"] != row["destination"]:
        return
    i = arms.names.index(row["origin"])
    along = (row["_xy"] - centre) @ arms.out[i]
    reach = np.hypot(*(row["_xy"] - centre).T)
    k = int(np.argmin(reach))  # where it comes nearest the centre
    deep = float(reach[k]) <= U_TURN_REACH_SHARE * arms.reach[i]
    d0, d1 = row["_d0"], row["_d1"]
    turned = d0 is None or d1 is None or float(d0 @ d1) <= np.cos(np.radians(U_TURN_MIN_DEG))
    if deep and turned and _one_piece_turns(row["_xy"], pieces, k, metres_per_unit) \
            and _swing_m(row["_xy"], k, centre, arms.out[i], metres_per_unit) >= U_TURN_MIN_SWING_M:
        return
    if along[-1] > along[0]:  # moving out along the arm: it left by it, it did not come from it
        row.update(origin="", origin_by="", entry_time=np.nan)
    else:
        row.update(destination="", destination_by="", exit_time=np.nan)


def _outside_every_gate(arms: _Arms, centre: np.ndarray, xy: np.ndarray) -> bool:
    """True if every point is beyond the gate of the arm whose sector it lies in (on an arm, outside the
    junction)."""
    rel = xy - centre
    ang = np.arctan2(rel[:, 0], rel[:, 1])
    off = np.abs(_wrap(ang[:, None] - arms.bearing[None, :]))
    i = np.argmin(off, axis=1)
    along = np.einsum("ij,ij->i", rel, arms.out[i])
    return bool(np.all(along > arms.reach[i]))


def _stopped_s(g: pd.DataFrame, start: float, end: float) -> float:
    """Seconds at a smoothed speed below :data:`STOPPED_KMH` between ``start`` and ``end``."""
    if "speed_kmh" not in g.columns or not end > start:
        return 0.0
    t = g["time"].to_numpy(dtype=np.float64)
    v = g["speed_kmh"].to_numpy(dtype=np.float64)
    dt = np.diff(t)
    mid = 0.5 * (t[1:] + t[:-1])
    slow = (0.5 * (v[1:] + v[:-1]) < STOPPED_KMH) & (mid >= start) & (mid <= end)
    return float(np.sum(dt[slow]))


def movement_time(movements: pd.DataFrame, first_seen: pd.Series | None = None) -> np.ndarray:
    """The time a movement is counted at: its entry crossing, else ``first_seen`` (by track id) when given."""
    t = movements["entry_time"].to_numpy(dtype=np.float64).copy()
    if first_seen is not None:
        missing = ~np.isfinite(t)
        t[missing] = movements.loc[missing, "track_id"].map(first_seen).to_numpy(dtype=np.float64)
    return t


def movement_counts(movements: pd.DataFrame, junction: Junction, interval_s: float, start: float, end: float, *,
                    first_seen: pd.Series | None = None) -> pd.DataFrame:
    """Complete movements per interval (of ``interval_s`` over [start, end), s), origin, destination and class:
    ``interval_start, interval_end, observed_s, origin, destination, movement, class, count``; every interval x
    origin x destination x class seen is listed, zeros too. ``first_seen``: time first seen by track id, for the
    vehicles without an entry crossing."""
    edges = interval_edges(start, end, interval_s)
    done = movements[movements["complete"].astype(bool)]
    t = movement_time(done, first_seen)
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
    classes = sorted(set(done["class"].astype(str))) or [""]
    arms = junction.arms
    index = pd.MultiIndex.from_product([range(len(edges) - 1), arms, arms, classes],
                                       names=["k", "origin", "destination", "class"])
    counted = (pd.DataFrame({"k": k, "origin": done["origin"].to_numpy(), "destination": done["destination"].to_numpy(),
                             "class": done["class"].astype(str).to_numpy()})
               .groupby(["k", "origin", "destination", "class"]).size())
    full = counted.reindex(index, fill_value=0).rename("count").reset_index()
    full.insert(0, "interval_start", edges[full["k"].to_numpy()])
    full.insert(1, "interval_end", edges[full["k"].to_numpy() + 1])
    full.insert(2, "observed_s", full["interval_end"] - full["interval_start"])
    full["movement"] = [junction.movement(o, d) for o, d in zip(full["origin"], full["destination"], strict=True)]
    return full[["interval_start", "interval_end", "observed_s", "origin", "destination", "movement", "class",
                 "count"]].astype({"count": int})


def turning_movement_table(counts: pd.DataFrame, junction: Junction) -> pd.DataFrame:
    """Turning-movement counts per interval in the layout junction tools import: ``interval_start, interval_end``,
    then for each approach arm (in gate order) ``<arm>_left, <arm>_through, <arm>_right, <arm>_U``, then
    ``total``, ``heavy`` (trucks and buses) and ``heavy_pct``."""
    keys = ["interval_start", "interval_end"]
    base = counts[keys].drop_duplicates().reset_index(drop=True)
    out = base.copy()
    c = counts.assign(col=counts["origin"].astype(str) + "_" + counts["movement"].astype(str))
    wide = c.groupby(keys + ["col"])["count"].sum().unstack("col", fill_value=0) if len(c) else None
    for arm in junction.arms:
        for mv in MOVEMENTS:
            name = f"{arm}_{mv}"
            out[name] = (base.merge(wide[[name]].reset_index(), on=keys, how="left")[name].fillna(0).astype(int)
                         .to_numpy() if wide is not None and name in wide.columns else 0)
    tot = c.groupby(keys)["count"].sum() if len(c) else None
    heavy = c[c["class"].isin(HEAVY_CLASSES)].groupby(keys)["count"].sum() if len(c) else None
    out["total"] = _per_interval(base, tot, keys)
    out["heavy"] = _per_interval(base, heavy, keys)
    with np.errstate(invalid="ignore", divide="ignore"):
        out["heavy_pct"] = np.where(out["total"] > 0, 100.0 * out["heavy"] / out["total"].clip(lower=1), np.nan)
    return out


def _per_interval(base: pd.DataFrame, series: pd.Series | None, keys: list[str]) -> np.ndarray:
    if series is None or not len(series):
        return np.zeros(len(base), dtype=int)
    return base.merge(series.rename("n").reset_index(), on=keys, how="left")["n"].fillna(0).astype(int).to_numpy()


@dataclass(frozen=True)
class PeakHour:
    """The busiest hour of whole intervals: ``start``/``end`` (s), ``volume`` (vehicles), ``phf`` (peak-hour
    factor) and ``heavy_pct`` (trucks and buses, %)."""

    start: float
    end: float
    volume: int
    phf: float
    heavy_pct: float


def peak_hour(table: pd.DataFrame, interval_s: float) -> PeakHour | None:
    """The peak hour of a :func:`turning_movement_table` (its full-length intervals only); None when an hour does
    not divide into whole intervals or less than an hour of whole intervals was observed."""
    per_hour = 3600.0 / interval_s
    n = round(per_hour)
    if n < 1 or abs(per_hour - n) > 1e-9:
        return None
    full = table[np.isclose(table["interval_end"] - table["interval_start"], interval_s)].reset_index(drop=True)
    if len(full) < n:
        return None
    tot = full["total"].to_numpy(dtype=np.int64)
    heavy = full["heavy"].to_numpy(dtype=np.int64)
    starts = full["interval_start"].to_numpy()
    best, best_k = -1, -1
    for k in range(len(full) - n + 1):
        if not np.isclose(starts[k + n - 1] - starts[k], (n - 1) * interval_s):
            continue  # not consecutive
        v = int(tot[k:k + n].sum())
        if v > best:
            best, best_k = v, k
    if best_k < 0:
        return None
    window = tot[best_k:best_k + n]
    phf = best / (n * window.max()) if window.max() > 0 else float("nan")
    hv = int(heavy[best_k:best_k + n].sum())
    return PeakHour(float(starts[best_k]), float(starts[best_k] + n * interval_s), best, float(phf),
                    100.0 * hv / best if best else float("nan"))


MOVEMENT_KEYS = ["interval_start", "interval_end", "origin", "destination", "movement"]
COMPARE_MOVEMENT_COLUMNS = [*MOVEMENT_KEYS, "observed_s", "observed", "simulated", "observed_flow_veh_h",
                            "simulated_flow_veh_h", "geh", "geh_ok"]


def compare_movement_counts(observed: pd.DataFrame, simulated: pd.DataFrame) -> pd.DataFrame:
    """Observed and simulated :func:`movement_counts` side by side per interval and movement (origin,
    destination; classes summed): vehicles, hourly flows (count x 3600 / the observed seconds of the interval) and
    their GEH (:func:`trafficgeo.traffic.compare.geh`; ``geh_ok``: below 5). Movements with no vehicle on either
    side are left out (a GEH of 0 for nothing would flatter the share); a key missing on one side counts 0."""
    from trafficgeo.traffic.compare import GEH_LIMIT, geh

    def per(table: pd.DataFrame, name: str) -> pd.DataFrame:
        t = table.assign(origin=table["origin"].astype(str), destination=table["destination"].astype(str),
                         movement=table["movement"].fillna("").astype(str))
        return t.groupby([*MOVEMENT_KEYS, "observed_s"], sort=True)["count"].sum().rename(name).reset_index()

    obs, sim = per(observed, "observed"), per(simulated, "simulated")
    keys = [*MOVEMENT_KEYS, "observed_s"]
    times = ["interval_start", "interval_end", "observed_s"]
    for t in (obs, sim):  # the same intervals on both sides: match them to a millisecond
        t[times] = t[times].round(3)
    table = obs.merge(sim, on=keys, how="outer")
    table["observed"] = table["observed"].fillna(0).astype(np.int64)
    table["simulated"] = table["simulated"].fillna(0).astype(np.int64)
    table = table[(table["observed"] > 0) | (table["simulated"] > 0)].reset_index(drop=True)
    hours = table["observed_s"].to_numpy(np.float64) / 3600.0
    table["observed_flow_veh_h"] = table["observed"] / hours
    table["simulated_flow_veh_h"] = table["simulated"] / hours
    table["geh"] = geh(table["observed_flow_veh_h"].to_numpy(), table["simulated_flow_veh_h"].to_numpy())
    table["geh_ok"] = table["geh"] < GEH_LIMIT
    return table[COMPARE_MOVEMENT_COLUMNS].sort_values(MOVEMENT_KEYS, kind="stable").reset_index(drop=True)


def movement_comparison_summary(table: pd.DataFrame) -> dict:
    """The headline of a :func:`compare_movement_counts` table, with the keys of
    :func:`trafficgeo.traffic.compare.count_summary`: ``rows`` (interval x movement), ``share_geh_below_5``,
    ``mean_geh``, ``total_observed``, ``total_simulated``, ``geh_total`` (GEH of the total hourly flows) and
    ``groups``: per movement (``origin``, ``destination``, ``movement``) its vehicles, hourly flows and GEH."""
    from trafficgeo.traffic.compare import GEH_LIMIT, geh

    def totals(t: pd.DataFrame) -> dict:
        hours = float(t[["interval_start", "observed_s"]].drop_duplicates()["observed_s"].sum()) / 3600.0
        o, s = int(t["observed"].sum()), int(t["simulated"].sum())
        fo, fs = (o / hours, s / hours) if hours > 0 else (np.nan, np.nan)
        return {"observed": o, "simulated": s, "observed_flow_veh_h": fo, "simulated_flow_veh_h": fs,
                "geh": float(geh(fo, fs)) if hours > 0 else np.nan}

    n = len(table)
    total = totals(table) if n else {"observed": 0, "simulated": 0, "geh": np.nan}
    groups = [{"origin": o, "destination": d, "movement": m, **totals(g)}
              for (o, d, m), g in table.groupby(["origin", "destination", "movement"], sort=True)] if n else []
    return {"rows": n, "share_geh_below_5": float((table["geh"] < GEH_LIMIT).mean()) if n else np.nan,
            "mean_geh": float(table["geh"].mean()) if n else np.nan, "total_observed": total["observed"],
            "total_simulated": total["simulated"], "geh_total": total["geh"], "groups": groups}
