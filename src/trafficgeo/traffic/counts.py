"""Counts at counting lines (virtual detectors; the lines: :mod:`trafficgeo.site.lines`): where trajectories
cross them, and counts, flows, speeds and headways.

A counting line is a polyline in the camera's CRS. A vehicle is counted once per line, at its first crossing, with

* ``direction`` ``+1`` when it crosses from the left to the right of the line, looking from the line's first vertex
  to its last, and ``-1`` the other way;
* the crossing time interpolated between the two trajectory points around it, and the speed there (the points'
  ``speed_kmh``: along the direction of travel, :mod:`trafficgeo.traffic.trajectories`);
* its lane at the crossing point.

A line may be limited to some lanes with a ``lanes`` attribute (comma-separated lane names).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from trafficgeo.errors import InputError
from trafficgeo.site.lanes import Lanes
from trafficgeo.site.lines import CountLine

CROSSING_COLUMNS = ["line", "track_id", "class", "lane", "direction", "time", "speed_kmh", "x", "y"]
MIN_SPACING_M = 3.0  # m of travel: two crossings of one line closer than this are one vehicle (if also side by side)
MIN_LATERAL_M = 1.75  # m along the line: crossings farther apart than this may be vehicles side by side
DEFAULT_SPEED_MPS = 15.0  # m/s assumed for the spacing test when neither crossing has a speed


def segment_crossings(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where track segments p->q (M, 2) cross the line segment a->b (2,): the fraction along p->q (NaN if they do
    not cross) and the sign of the crossing (+1 left to right of a->b).

    A point exactly on the line counts as being on its left side (half-open sides), so a track with a point
    exactly on the line is found crossing once, not twice or never.
    """
    d = b - a
    side_p = d[0] * (p[:, 1] - a[1]) - d[1] * (p[:, 0] - a[0])  # > 0: left of a->b
    side_q = d[0] * (q[:, 1] - a[1]) - d[1] * (q[:, 0] - a[0])
    left_p, left_q = side_p >= 0, side_q >= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip(side_p / (side_p - side_q), 0.0, 1.0)
    c = p + s[:, None] * (q - p)
    r = ((c[:, 0] - a[0]) * d[0] + (c[:, 1] - a[1]) * d[1]) / (d[0] ** 2 + d[1] ** 2)  # along a->b
    ok = (left_p != left_q) & (r >= 0) & (r <= 1)
    return np.where(ok, s, np.nan), np.where(left_p, 1, -1)


def find_crossings(points: pd.DataFrame, lines: list[CountLine], lanes: Lanes | None = None, *,
                   metres_per_unit: float = 1.0) -> pd.DataFrame:
    """Crossings of trajectories with counting lines (columns :data:`CROSSING_COLUMNS` plus ``length_m`` when the
    points have it). Crossings that repeat one vehicle's are dropped (:func:`same_vehicle`; ``metres_per_unit``
    of the points' CRS).

    ``points`` has one row per track point, sorted by track then time, with ``track_id, time, x, y, speed_kmh``
    and optionally ``class``, ``length_m``; positions in the lines' CRS.
    """
    tid = points["track_id"].to_numpy()
    xy = points[["x", "y"]].to_numpy(dtype=np.float64)
    t = points["time"].to_numpy(dtype=np.float64)
    v = points["speed_kmh"].to_numpy(dtype=np.float64)
    same = (tid[1:] == tid[:-1]) & np.all(np.isfinite(xy[1:]) & np.isfinite(xy[:-1]), axis=1)
    i0 = np.flatnonzero(same)
    p, q = xy[i0], xy[i0 + 1]
    rows = []
    for line in lines:
        coords = np.asarray(line.geometry.coords, dtype=np.float64)[:, :2]
        best_s = np.full(i0.size, np.nan)
        best_sign = np.zeros(i0.size, dtype=np.int64)
        for k in range(len(coords) - 1):
            s, sign = segment_crossings(p, q, coords[k], coords[k + 1])
            new = np.isfinite(s) & ~np.isfinite(best_s)
            best_s[new], best_sign[new] = s[new], sign[new]
        hit = np.flatnonzero(np.isfinite(best_s))
        if hit.size == 0:
            continue
        frac = best_s[hit]
        seg = i0[hit]
        cx = xy[seg] + frac[:, None] * (xy[seg + 1] - xy[seg])
        step = xy[seg + 1] - xy[seg]
        heading = np.degrees(np.arctan2(step[:, 0], step[:, 1])) % 360.0  # clockwise from grid north
        table = pd.DataFrame({
            "line": line.name, "track_id": tid[seg], "direction": best_sign[hit],
            "time": t[seg] + frac * (t[seg + 1] - t[seg]), "speed_kmh": v[seg] + frac * (v[seg + 1] - v[seg]),
            "x": cx[:, 0], "y": cx[:, 1],
            "class": points["class"].to_numpy()[seg] if "class" in points.columns else "",
            "lane": lanes.assign(cx[:, 0], cx[:, 1], heading) if lanes is not None else "",
        })
        if "length_m" in points.columns:
            table["length_m"] = points["length_m"].to_numpy()[seg]
        if line.lanes:
            table = table[table["lane"].isin(line.lanes)]
        table = table.sort_values("time").drop_duplicates("track_id", keep="first")
        rows.append(table[~same_vehicle(table, metres_per_unit=metres_per_unit)])
    columns = CROSSING_COLUMNS + (["length_m"] if "length_m" in points.columns else [])
    if not rows:
        return pd.DataFrame({c: pd.Series(dtype=object if c in ("line", "track_id", "class", "lane") else float)
                             for c in columns})
    out = pd.concat(rows, ignore_index=True)[columns]
    return out.sort_values(["line", "time"], kind="stable").reset_index(drop=True)


def same_vehicle(crossings: pd.DataFrame, *, spacing_m: float = MIN_SPACING_M, lateral_m: float = MIN_LATERAL_M,
                 metres_per_unit: float = 1.0) -> np.ndarray:
    """True for crossings of one line (sorted by time) that repeat an earlier one: two tracks of one vehicle (a
    blob split in two, a track broken and continued). Two crossings in the same direction closer in time than
    ``spacing_m`` of travel at their speed, and closer than ``lateral_m`` to each other on the line, cannot be two
    vehicles: one would be inside the other. Of such a pair the crossing with a speed is kept (else the first)."""
    n = len(crossings)
    dup = np.zeros(n, dtype=bool)
    if n < 2:
        return dup
    t = crossings["time"].to_numpy(dtype=np.float64)
    v = crossings["speed_kmh"].to_numpy(dtype=np.float64) / 3.6
    xy = crossings[["x", "y"]].to_numpy(dtype=np.float64)
    direction = crossings["direction"].to_numpy()
    m = float(metres_per_unit)
    for i in range(n):
        if dup[i]:
            continue
        for j in range(i + 1, n):
            dt = t[j] - t[i]
            speed = np.nanmax([v[i], v[j], 0.0]) if np.isfinite([v[i], v[j]]).any() else DEFAULT_SPEED_MPS
            if dt * speed >= spacing_m:
                break
            if dup[j] or direction[j] != direction[i] or np.hypot(*(xy[j] - xy[i])) * m >= lateral_m:
                continue
            if np.isfinite(v[i]) or not np.isfinite(v[j]):
                dup[j] = True
            else:
                dup[i] = True
                break
    return dup


MIN_INTERVAL_S = 1.0  # s, the shortest counting interval: shorter ones count fractions of a vehicle


def check_interval(interval_s: float) -> float:
    """``interval_s`` (s) if it is a usable counting interval (finite, at least :data:`MIN_INTERVAL_S`)."""
    if not (np.isfinite(interval_s) and interval_s >= MIN_INTERVAL_S):
        raise InputError(f"interval_s {float(interval_s):g}: the counting interval must be a finite number of "
                         f"seconds, at least {MIN_INTERVAL_S:g}, e.g. 60 or 900", parameters=("interval_s",))
    return float(interval_s)


MAX_INTERVALS = 100_000  # counting intervals per run: 27.8 h at 1 s, 2.9 years at 15 min


def interval_edges(start: float, end: float, interval_s: float) -> np.ndarray:
    """Interval boundaries (s) on multiples of ``interval_s`` covering [start, end); the first and last are
    clipped to the observation period. More than :data:`MAX_INTERVALS` intervals is an error (a time value far
    from the others would otherwise make counts tables without bound)."""
    check_interval(interval_s)
    if not end > start:
        return np.array([start, start])
    if not (np.isfinite(start) and np.isfinite(end)):
        raise InputError(f"the observed period {start:g} to {end:g} s is not finite: check the time values of the "
                         "tracks")
    k0 = np.floor(start / interval_s)
    k1 = np.ceil(end / interval_s - 1e-9)
    if k1 - k0 > MAX_INTERVALS:
        raise InputError(f"the observed period {start:g} to {end:g} s ({(end - start) / 3600.0:.4g} h) makes "
                         f"{k1 - k0:.0f} counting intervals of {interval_s:g} s, more than {MAX_INTERVALS}: a time "
                         "value far from the others (check the tracks' times, or their frames and `fps`) or an "
                         "interval too short for so long a period (give a longer interval_s)",
                         parameters=("interval_s", "fps"))
    edges = np.arange(k0, k1 + 1) * interval_s
    edges[0], edges[-1] = start, end
    return edges


def aggregate_counts(crossings: pd.DataFrame, interval_s: float, start: float, end: float, *,
                     lines: list[CountLine] | None = None, lanes: Lanes | None = None) -> pd.DataFrame:
    """Counts per line, lane, direction and interval over the observed period [start, end) (s).

    Columns: ``line, lane, direction, interval_start, interval_end, observed_s, count, count_<class>...`` (with
    ``count_unknown`` for the vehicles of unknown class ``""`` when others have a class, so that they add up to
    ``count``), ``flow_veh_h`` (count over the interval's observed duration ``observed_s``; NaN when that is below
    :data:`MIN_FLOW_SHARE` of ``interval_s``, see :func:`flow_rule`), ``time_mean_speed_kmh`` (arithmetic mean of
    the spot speeds, which are along each vehicle's direction of travel), ``space_mean_speed_kmh`` (their harmonic
    mean), ``mean_headway_s``, ``min_headway_s`` (time since the previous vehicle over the same line, in the same
    lane and direction) and ``mean_gap_s`` (headway less the time the previous vehicle took to pass its own length;
    needs ``length_m``).

    Every interval is listed, with a count of 0 where no vehicle crossed, for every line, lane and direction seen
    and, when ``lines`` are given, for every line x lane x direction (+1 and -1) that could be counted: the line's
    own lanes (else all ``lanes``) when ``lanes`` are given, else ``""`` (so a line nobody crossed is listed with
    zeros, not left out). Zero rows have a flow of 0 and NaN speeds and headways.
    """
    return _aggregate(crossings, interval_edges(start, end, interval_s), _expected_groups(lines, lanes),
                      nominal_s=check_interval(interval_s))


def period_counts(crossings: pd.DataFrame, start: float, end: float) -> pd.DataFrame:
    """:func:`aggregate_counts` over the whole observed period [start, end] (s) as one interval, whatever its
    length: every crossing counts (also one outside the period), flows are over ``end - start`` (NaN when the
    period is empty)."""
    return _aggregate(crossings, np.array([float(start), float(end)]), [], nominal_s=None)


MIN_FLOW_SHARE = 0.5  # an interval's flow (veh/h) is given only when at least this share of it was observed


def flow_rule(observed_s: ArrayLike, interval_s: float) -> np.ndarray:
    """Whether a flow (veh/h) may be extrapolated from ``observed_s`` s of an interval of ``interval_s`` s: only
    when at least :data:`MIN_FLOW_SHARE` of the interval was observed (a count over a few seconds, scaled to an
    hour, says little: 3 vehicles in 6.8 s read 1588 veh/h)."""
    return np.asarray(observed_s, dtype=np.float64) >= MIN_FLOW_SHARE * float(interval_s) - 1e-9


MIN_CROSSING_ANGLE_DEG = 20.0  # a lane whose bearing is nearer than this to a line's direction may cross it either way


def lane_directions(line: CountLine, bearing_deg: float) -> tuple[int, ...]:
    """The crossing directions (+1: left to right of the line's first-to-last direction) a lane of travel bearing
    ``bearing_deg`` (deg clockwise from grid north; NaN: unknown) gives at ``line``: one, or both where the bearing is
    unknown or within :data:`MIN_CROSSING_ANGLE_DEG` of the line."""
    coords = np.asarray(line.geometry.coords, dtype=np.float64)[:, :2]
    d = coords[-1] - coords[0]
    if not np.isfinite(bearing_deg) or not np.any(d):
        return (-1, 1)
    b = np.radians(bearing_deg)
    cross = (d[0] * np.cos(b) - d[1] * np.sin(b)) / np.hypot(*d)  # sine of the angle from the line to the heading
    if abs(cross) < np.sin(np.radians(MIN_CROSSING_ANGLE_DEG)):
        return (-1, 1)
    return (1,) if cross < 0 else (-1,)


def _expected_groups(lines: list[CountLine] | None, lanes: Lanes | None) -> list[tuple[str, str, int]]:
    """(line, lane, direction) of every count a set of ``lines`` can give: with ``lanes``, the line's own lanes
    (else all of them) in the direction each lane's bearing crosses the line (both where it is unknown); without
    lanes, the lane ``""`` in both directions."""
    out = []
    for line in lines or []:
        if lanes is None:
            out += [(line.name, "", d) for d in (-1, 1)]
            continue
        bearing = dict(zip(lanes.names, lanes.bearings or [np.nan] * len(lanes.names), strict=True))
        for lane in line.lanes or tuple(lanes.names):
            out += [(line.name, str(lane), d) for d in lane_directions(line, bearing.get(lane, np.nan))]
    return out


def counted_groups(counts: pd.DataFrame) -> pd.DataFrame:
    """The rows of a counts table (:func:`aggregate_counts`) of the (line, lane, direction) groups where at least
    one vehicle was counted: those a comparison or a mapping can use (a zero group may be a wrong-way direction)."""
    if not len(counts):
        return counts
    keys = [counts["line"].astype(str), counts["lane"].fillna("").astype(str), counts["direction"].astype(int)]
    total = counts["count"].groupby(keys).transform("sum")
    return counts[total.to_numpy() > 0]


def _aggregate(crossings: pd.DataFrame, edges: np.ndarray, expected: list[tuple[str, str, int]], *,
               nominal_s: float | None) -> pd.DataFrame:
    """:func:`aggregate_counts` over the intervals between ``edges`` (s), for the groups crossed and the
    ``expected`` (line, lane, direction) groups; flows only where :func:`flow_rule` allows with a nominal interval
    of ``nominal_s`` s (None: always). A crossing before the first edge counts in the first interval, one after the
    last in the last."""
    names = set(crossings["class"].fillna("").astype(str)) if len(crossings) else set()
    classes = sorted(c for c in names if c) + ([""] if "" in names and len(names) > 1 else [])  # "": unknown
    empty = crossings.iloc[:0]
    groups: dict[tuple[str, str, int], pd.DataFrame] = {key: empty for key in expected}
    if len(crossings):
        keyed = crossings.assign(line=crossings["line"].astype(str), lane=crossings["lane"].fillna("").astype(str),
                                 direction=crossings["direction"].astype(int))
        for (line, lane, direction), g in keyed.groupby(["line", "lane", "direction"], sort=False):
            groups[(str(line), str(lane), int(direction))] = g
    rows = []
    for (line, lane, direction) in sorted(groups):
        g = groups[(line, lane, direction)].sort_values("time")
        t = g["time"].to_numpy(dtype=np.float64)
        speed = g["speed_kmh"].to_numpy(dtype=np.float64)
        headway = np.concatenate([[np.nan], np.diff(t)])
        if "length_m" in g.columns:
            lead_len = np.concatenate([[np.nan], g["length_m"].to_numpy(dtype=np.float64)[:-1]])
            lead_speed = np.concatenate([[np.nan], speed[:-1]]) / 3.6
            with np.errstate(divide="ignore", invalid="ignore"):
                gap = headway - lead_len / lead_speed
        else:
            gap = np.full(t.size, np.nan)
        which = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
        for k in range(len(edges) - 1):
            sel = which == k
            dur = edges[k + 1] - edges[k]
            row = {"line": line, "lane": lane, "direction": int(direction), "interval_start": edges[k],
                   "interval_end": edges[k + 1], "observed_s": dur, "count": int(sel.sum())}
            cls = g["class"].fillna("").astype(str).to_numpy()[sel]
            for c in classes:
                row[f"count_{c or 'unknown'}"] = int(np.sum(cls == c))
            s = speed[sel]
            s = s[np.isfinite(s) & (s > 0)]
            enough = dur > 0 and (nominal_s is None or bool(flow_rule(dur, nominal_s)))
            row["flow_veh_h"] = row["count"] * 3600.0 / dur if enough else np.nan
            row["time_mean_speed_kmh"] = float(s.mean()) if s.size else np.nan
            row["space_mean_speed_kmh"] = float(s.size / np.sum(1.0 / s)) if s.size else np.nan
            h, gp = headway[sel], gap[sel]
            row["mean_headway_s"] = float(np.nanmean(h)) if np.isfinite(h).any() else np.nan
            row["min_headway_s"] = float(np.nanmin(h)) if np.isfinite(h).any() else np.nan
            row["mean_gap_s"] = float(np.nanmean(gp)) if np.isfinite(gp).any() else np.nan
            rows.append(row)
    columns = ["line", "lane", "direction", "interval_start", "interval_end", "observed_s", "count",
               *[f"count_{c or 'unknown'}" for c in classes], "flow_veh_h", "time_mean_speed_kmh",
               "space_mean_speed_kmh", "mean_headway_s", "min_headway_s", "mean_gap_s"]
    return pd.DataFrame(rows, columns=columns)
