"""Journeys: the fragments of one vehicle's track joined into one vehicle, in world coordinates.

A tracker loses a vehicle whenever its detector misses it on a few frames: a bus hides a car, a far tile is not
run on every frame, a blob of the background detector flickers. The vehicle comes back under a new id, and its
two fragments would count as two vehicles, or as none at a line that lies in the gap. :func:`join_fragments`
runs after the world trajectories are formed (:func:`trafficgeo.traffic.trajectories.world_trajectories`) and
joins the fragments of one vehicle, with what an image tracker does not have: a calibrated ground position and its
uncertainty, speed and heading in metres, class and length.

**The link cost.** For the end of fragment ``a`` (its last ``end_window_s`` seconds, a straight-line fit) and the
start of a later fragment ``b`` a gap ``g`` seconds after it, both are carried to the middle of the gap at their
velocities; the difference is scored as a Mahalanobis distance (2 dof) under the two positions' uncertainty, their
velocities' uncertainty over ``g / 2`` and the manoeuvre the vehicle may make in the gap: ``accel_sigma_mps2``
along its direction of travel, ``lateral_sigma_mps`` across it (a lane change takes a few seconds). The change of
velocity is scored the same way. A *glimpse*, a fragment too short for its velocity to be known within
``weak_velocity_sigma_mps``, is met by the other fragment carried over the whole gap, and two glimpses are never
joined to each other (a glimpse may be a bad box: only a fragment with a known motion vouches for it). At a
junction (:meth:`JourneyOptions.at_junction`) glimpses are not joined at all (``join_glimpses``): vehicles queue,
turn and cross there, and the motion of one fragment carried over seconds fits another vehicle's glimpse
more often than its own (on 29 generated junction worlds, of the 349 glimpse joins made 176 were of two vehicles,
146 of one: ``benchmarks/bench_junction_links.py``). A
different class (both known), a different length (both measured) and a different lane at the two ends add to the
cost, and each second of gap adds ``gap_cost_per_s``. A pair is never
joined when the two overlap in time (two vehicles seen at the same time), when ``b`` starts more than
``max_gap_s`` after ``a`` ends, when either distance is beyond ``gate`` (chi-square, 2 dof), when the two ends'
positions are together less sure than ``max_position_sigma_m`` (where anything would fit), when going from one
to the other takes more than ``max_speed_mps`` (no vehicle teleports), when the two move in directions more
than ``max_turn_deg`` apart (where each one's own motion tells its direction), or when they stand in lanes of
opposite directions of travel (lanes with bearings).

**Global association.** Every end may join at most one start and every start at most one end. The links are
chosen together, by a linear assignment (Hungarian, :func:`scipy.optimize.linear_sum_assignment`, with the
"no link" alternatives of Jaqaman et al. 2008) that minimises the total cost, where leaving an end or a start
unlinked costs ``no_link_cost``. It runs over a window of ``window_s`` seconds of fragment ends at a time; links
whose end lies in the last ``max_gap_s`` of a window are decided again in the next one, so the association
streams over any length of video (time chunks and batch segments, whose tracks reach ``analyze`` joined).

**Stationary objects.** A vehicle that never moves more than ``stationary_m`` metres (or three position sigmas of
its best-placed piece of track) from where it stands, over at least ``stationary_min_s`` seconds, is a parked
vehicle, a billboard or a shadow: it stays in ``vehicles.csv`` with ``stationary`` true and its (near-zero) speeds,
counts at no line and is left out of the speed statistics (summary, report). A vehicle queued at a signal for all
the time it is seen is flagged too: over the time seen it cannot be told from a parked one.

Outputs: the points of :class:`~trafficgeo.traffic.trajectories.WorldTracks` with ``track_id`` the vehicle and
``fragment`` the fragment it came from (the world track's id), one vehicle row per journey (``fragments``,
``tracker_ids``, ``stationary`` added) and the links chosen (:class:`Journeys`). Units: positions in the CRS
units of the points (``metres_per_unit`` gives metres), times in seconds, speeds in m/s unless ``_kmh``.

What still links elsewhere, and why: the tracker (image boxes frame to frame, where appearance and overlap decide
within a fraction of a second), the re-join of one tracker id's parts in
:mod:`trafficgeo.traffic.trajectories` (a stretch of bad points cut out of one id: the parts are smoothed again
as one), :mod:`trafficgeo.video.stitch` (the same vehicle in two overlapping time chunks, matched by box overlap
before any world position exists) and :mod:`trafficgeo.traffic.occlusion` (a vehicle that vanishes behind a
nearer one and is never seen again: carried on to the lines it passes unseen).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from itertools import pairwise

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from trafficgeo.errors import InputError
from trafficgeo.site.lanes import Lanes, angle_between
from trafficgeo.traffic.duplicates import DuplicateOptions, merge_duplicates
from trafficgeo.traffic.smoothing import CHI2_2DOF_999
from trafficgeo.traffic.trajectories import VEHICLE_COLUMNS, WorldTracks

__all__ = ["JOURNEY_COLUMNS", "LINK_COLUMNS", "JourneyOptions", "Journeys", "fragment_ends", "join_fragments",
           "link_candidates"]

JOURNEY_COLUMNS = ["fragments", "tracker_ids", "stationary"]  # added to the vehicle table
LINK_COLUMNS = ["from_fragment", "to_fragment", "gap_s", "cost", "position_d2", "velocity_d2"]
_BIG = 1e9  # cost of a forbidden pair in the assignment
MOVING_MPS = 2.0  # m/s: below this a direction of travel is not used
_MAY_BE_ZERO = ("class_cost", "lane_cost", "gap_cost_per_s", "no_link_cost", "stationary_m", "stationary_min_s")


@dataclass(frozen=True)
class JourneyOptions:
    """How fragments are joined into journeys (module docstring). ``enabled=False`` keeps every fragment a vehicle
    of its own (the stationary flag is still set)."""

    enabled: bool = True
    max_gap_s: float = 4.0  # s, the longest time a vehicle may go unseen between two fragments
    end_window_s: float = 1.0  # s of a fragment's end over which its end velocity is fitted
    accel_sigma_mps2: float = 2.0  # m/s^2, change of speed along the direction of travel over a gap (1 sigma)
    lateral_sigma_mps: float = 0.8  # m/s, drift across the direction of travel over a gap (1 sigma)
    min_velocity_sigma_mps: float = 0.5  # m/s, the least uncertainty of an end's velocity
    unknown_velocity_sigma_mps: float = 8.0  # m/s, that of a fragment too short to have a velocity
    weak_velocity_sigma_mps: float = 3.0  # m/s: an end whose velocity is less sure is a glimpse (module docstring)
    gate: float = CHI2_2DOF_999  # chi-square (2 dof) above which a position or velocity difference forbids a join
    max_speed_mps: float = 70.0  # m/s: farther jumps are not one vehicle (no teleporting)
    max_position_sigma_m: float = 5.0  # m: ends placed worse than this (both together) are not joined
    max_turn_deg: float = 100.0  # deg: ends moving in directions farther apart are not one vehicle
    class_cost: float = 3.0  # added when both classes are known and differ
    lane_cost: float = 2.0  # added when the lanes at the two ends are known and differ
    gap_cost_per_s: float = 1.0  # added per second of gap: of two fits, the shorter gap wins
    no_link_cost: float = 6.0  # cost of leaving an end, or a start, without a link
    window_s: float = 60.0  # s of fragment ends per assignment
    stationary_m: float = 2.5  # m: a vehicle never farther than this from where it stands is stationary ...
    stationary_min_s: float = 3.0  # ... when seen at least this long
    duplicates: DuplicateOptions | None = field(default_factory=DuplicateOptions)  # None: not merged
    join_glimpses: bool = True  # a glimpse may be joined to a fragment whose motion is known; off at a junction

    @classmethod
    def at_junction(cls, **changes: object) -> JourneyOptions:
        """The defaults for a junction's turning movements (glimpses not joined: module docstring), with
        ``changes``."""
        return cls(**{"join_glimpses": False, **changes})

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if isinstance(value, bool | dict) or value is None:
                continue
            if not np.isfinite(value) or value < 0 or (value == 0 and name not in _MAY_BE_ZERO):
                raise InputError(f"journey option {name}={value!r} is out of range; it must be a positive number",
                                 parameters=(name,))
        if self.window_s <= 2.0 * self.max_gap_s:
            raise InputError(f"journey option window_s={self.window_s:g} must be more than twice max_gap_s="
                             f"{self.max_gap_s:g}", parameters=("window_s",))


    @classmethod
    def with_gap(cls, max_gap_s: float, *, at_junction: bool = False) -> JourneyOptions:
        """The defaults (:meth:`at_junction`'s with ``at_junction``) with fragments joined across gaps up to
        ``max_gap_s`` s (0: not joined)."""
        if not np.isfinite(max_gap_s) or max_gap_s < 0:
            raise InputError(f"max_gap_s={max_gap_s:g}: give the longest time (s) a vehicle may go unseen between "
                             "two pieces of its track, e.g. 4 (0: pieces are not joined)", parameters=("max_gap_s",))
        make = cls.at_junction if at_junction else cls
        if max_gap_s == 0:
            return make(enabled=False)
        return make(max_gap_s=float(max_gap_s), window_s=max(cls.window_s, 3.0 * float(max_gap_s)))


@dataclass(frozen=True)
class Journeys:
    """The vehicles of a set of world tracks, fragments joined.

    Attributes:
        points: the world track points (sorted by vehicle, then time) with ``track_id`` the vehicle and ``fragment``
            the world track it was part of.
        vehicles: one row per vehicle: the columns of the world tracks' vehicle table, over the whole journey,
            plus :data:`JOURNEY_COLUMNS` (``tracker_ids``: the tracker's ids, ``;``-separated, in time order).
        links: the joins made (:data:`LINK_COLUMNS`), in time order.
        dropped: points left out, by reason: ``short_track`` (vehicles with fewer than ``min_points`` points in
            all: short glimpses that joined no other fragment), ``duplicate`` (a second track of a vehicle at the
            same time: :mod:`trafficgeo.traffic.duplicates`).
    """

    points: pd.DataFrame
    vehicles: pd.DataFrame
    links: pd.DataFrame
    dropped: dict[str, int] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------ fragment ends
def _line_velocity(t: np.ndarray, xy: np.ndarray) -> np.ndarray | None:
    """Velocity of the least-squares straight line through ``xy`` (n, 2) at times ``t``; None for fewer than two
    distinct times."""
    if t.size < 2 or np.ptp(t) <= 0:
        return None
    tc = t - t.mean()
    return (tc @ (xy - xy.mean(axis=0))) / float(tc @ tc)


def fragment_ends(points: pd.DataFrame, vehicles: pd.DataFrame, *, metres_per_unit: float = 1.0,
                  origin: np.ndarray | None = None, lanes: Lanes | None = None,
                  options: JourneyOptions | None = None) -> pd.DataFrame:
    """One row per fragment (world track, in the order of ``vehicles``): its start and end time ``t0, t1`` (s), the
    positions there ``x0, y0, x1, y1`` (m from ``origin``, CRS units; default: the first point), the velocities
    ``vx0, vy0, vx1, vy1`` (m/s, a straight line over ``end_window_s`` at each end; NaN when too short), their
    sigmas ``sv0, sv1`` (m/s), the position sigmas ``sp0, sp1`` (m), ``class``, ``length_m``, ``length_std_m``,
    ``lane0, lane1`` (the lanes at the two ends, "" unknown), ``bearing0, bearing1`` (the direction of travel of
    the lane each end stands in, deg; NaN unknown), ``extent_m``, the farthest any point lies from the fragment's
    median position (m), and ``median_sigma_m``, its points' median position sigma (m)."""
    opts = options or JourneyOptions()
    m = float(metres_per_unit)
    if origin is None:
        origin = points[["x", "y"]].to_numpy(dtype=np.float64)[0] if len(points) else np.zeros(2)
    origin = np.asarray(origin, dtype=np.float64)
    groups = points.groupby("track_id", sort=False).indices if len(points) else {}
    t_all = points["time"].to_numpy(dtype=np.float64) if len(points) else np.zeros(0)
    xy_all = (points[["x", "y"]].to_numpy(dtype=np.float64) - origin) * m if len(points) else np.zeros((0, 2))
    std_all = points["position_std_m"].to_numpy(dtype=np.float64) if len(points) else np.zeros(0)
    rows = []
    for tid in vehicles["track_id"].astype(str):
        idx = groups.get(tid)
        if idx is None or idx.size == 0:
            rows.append({"track_id": tid, "t0": np.nan, "t1": np.nan})
            continue
        idx = idx[np.argsort(t_all[idx], kind="stable")]
        t, xy, sd = t_all[idx], xy_all[idx], std_all[idx]
        row = {"track_id": tid, "t0": float(t[0]), "t1": float(t[-1])}
        for end, near in (("0", t <= t[0] + opts.end_window_s), ("1", t >= t[-1] - opts.end_window_s)):
            k = 0 if end == "0" else -1
            v = _line_velocity(t[near], xy[near])
            sp = float(sd[k]) if np.isfinite(sd[k]) else 1.0
            if v is None:
                v, sv = np.array([np.nan, np.nan]), opts.unknown_velocity_sigma_mps
            else:
                span = float(np.ptp(t[near]))
                sv = float(np.hypot(opts.min_velocity_sigma_mps, 2.0 * np.sqrt(3.0) * sp / max(span, 1e-3)
                                    / np.sqrt(max(near.sum() / 2.0, 1.0))))
            row.update({f"x{end}": float(xy[k, 0]), f"y{end}": float(xy[k, 1]), f"vx{end}": float(v[0]),
                        f"vy{end}": float(v[1]), f"sv{end}": sv, f"sp{end}": sp})
        row["extent_m"] = float(np.max(np.hypot(*(xy - np.median(xy, axis=0)).T)))
        row["median_sigma_m"] = float(np.nanmedian(sd)) if np.isfinite(sd).any() else 0.0
        rows.append(row)
    ends = pd.DataFrame(rows, columns=["track_id", "t0", "t1"]) if not rows else pd.DataFrame(rows)
    for c in ("x0", "y0", "x1", "y1", "vx0", "vy0", "vx1", "vy1", "sv0", "sv1", "sp0", "sp1", "extent_m",
              "median_sigma_m"):
        if c not in ends.columns:
            ends[c] = np.nan
    veh = vehicles.reset_index(drop=True)
    ends["class"] = veh["class"].fillna("").astype(str).to_numpy() if len(veh) else []
    for c in ("length_m", "length_std_m"):
        ends[c] = veh[c].to_numpy(dtype=np.float64) if c in veh.columns and len(veh) else np.nan
    if lanes is not None and len(ends):
        ok0, ok1 = np.isfinite(ends["x0"]).to_numpy(), np.isfinite(ends["x1"]).to_numpy()
        ends["lane0"], ends["lane1"] = "", ""
        bearing_of = dict(zip(lanes.names, lanes.bearings or [np.nan] * len(lanes.names), strict=True))
        for end, ok in (("0", ok0), ("1", ok1)):
            xy = ends[[f"x{end}", f"y{end}"]].to_numpy()[ok] / m + origin
            heading = np.degrees(np.arctan2(ends[f"vx{end}"].to_numpy()[ok], ends[f"vy{end}"].to_numpy()[ok])) % 360
            ends.loc[ok, f"lane{end}"] = lanes.assign(xy[:, 0], xy[:, 1], heading)
            # the direction of travel of the lane the end stands in, whatever the end's own (noisy) heading
            ends[f"bearing{end}"] = np.nan
            ends.loc[ok, f"bearing{end}"] = [bearing_of.get(n, np.nan) for n in lanes.assign(xy[:, 0], xy[:, 1])]
    else:
        ends["lane0"], ends["lane1"] = "", ""
    for c in ("bearing0", "bearing1"):
        if c not in ends.columns:
            ends[c] = np.nan
    return ends


# ------------------------------------------------------------------------------------------------ link costs
def _mahalanobis2(e: np.ndarray, base_var: np.ndarray, along_var: np.ndarray, across_var: np.ndarray,
                  u: np.ndarray) -> np.ndarray:
    """e^T S^-1 e for S = base_var I + R diag(along_var, across_var) R^T (R from ``u``; all (N,))."""
    along = e[:, 0] * u[:, 0] + e[:, 1] * u[:, 1]
    across = -e[:, 0] * u[:, 1] + e[:, 1] * u[:, 0]
    return along**2 / (base_var + along_var) + across**2 / (base_var + across_var)


def link_candidates(ends: pd.DataFrame, options: JourneyOptions | None = None) -> pd.DataFrame:
    """Every allowed join of the end of one fragment to the start of a later one (rows of ``ends``, from
    :func:`fragment_ends`): columns ``a, b`` (row numbers), ``gap_s``, ``position_d2``, ``velocity_d2`` and
    ``cost`` (module docstring)."""
    opts = options or JourneyOptions()
    t0, t1 = ends["t0"].to_numpy(dtype=np.float64), ends["t1"].to_numpy(dtype=np.float64)
    order = np.argsort(np.where(np.isfinite(t0), t0, np.inf), kind="stable")
    t0_sorted = t0[order]
    pairs_a, pairs_b = [], []
    for a in np.flatnonzero(np.isfinite(t1)):
        lo = np.searchsorted(t0_sorted, t1[a], side="right")  # strictly after a's end: never seen together
        hi = np.searchsorted(t0_sorted, t1[a] + opts.max_gap_s, side="right")
        if hi > lo:
            pairs_a.append(np.full(hi - lo, a))
            pairs_b.append(order[lo:hi])
    empty = pd.DataFrame({"a": pd.Series(dtype=int), "b": pd.Series(dtype=int), "gap_s": pd.Series(dtype=float),
                          "position_d2": pd.Series(dtype=float), "velocity_d2": pd.Series(dtype=float),
                          "cost": pd.Series(dtype=float)})
    if not pairs_a:
        return empty
    a, b = np.concatenate(pairs_a), np.concatenate(pairs_b)
    col = {c: ends[c].to_numpy() for c in ends.columns}
    gap = t0[b] - t1[a]
    p1 = np.column_stack([col["x1"][a], col["y1"][a]]).astype(np.float64)
    p0 = np.column_stack([col["x0"][b], col["y0"][b]]).astype(np.float64)
    v1 = np.column_stack([col["vx1"][a], col["vy1"][a]]).astype(np.float64)
    v0 = np.column_stack([col["vx0"][b], col["vy0"][b]]).astype(np.float64)
    sv1, sv0 = col["sv1"][a].astype(np.float64), col["sv0"][b].astype(np.float64)
    with np.errstate(invalid="ignore"):  # directions of travel, where each end's own motion tells one
        s1, s0 = np.hypot(*v1.T), np.hypot(*v0.T)
        cos = np.sum(v1 * v0, axis=1) / np.maximum(s1 * s0, 1e-9)
        turned = ((s1 > np.maximum(MOVING_MPS, 2.0 * sv1)) & (s0 > np.maximum(MOVING_MPS, 2.0 * sv0))
                  & (cos < np.cos(np.radians(opts.max_turn_deg))))
        against = angle_between(col["bearing1"][a].astype(np.float64), col["bearing0"][b].astype(np.float64)) > 90.0
    strong1 = np.all(np.isfinite(v1), axis=1) & (sv1 <= opts.weak_velocity_sigma_mps)
    strong0 = np.all(np.isfinite(v0), axis=1) & (sv0 <= opts.weak_velocity_sigma_mps)
    # Both velocities known: each end carried to the middle of the gap. One of them a glimpse (its velocity
    # unknown or poor): the other carried over the whole gap to it. Two glimpses are never joined.
    both = strong1 & strong0
    v1 = np.where(strong1[:, None], v1, v0)
    v0 = np.where(strong0[:, None], v0, v1)
    sv1 = np.where(strong1, sv1, 0.0)
    sv0 = np.where(strong0, sv0, 0.0)
    lead1 = np.where(both, 0.5 * gap, np.where(strong1, gap, 0.0))  # s each end is carried
    lead0 = gap - lead1
    e = (p1 + v1 * lead1[:, None]) - (p0 - v0 * lead0[:, None])
    mean_v = np.where(both[:, None], 0.5 * (v1 + v0), v1)
    speed = np.hypot(*mean_v.T)
    moving = speed > MOVING_MPS
    u = np.where(moving[:, None], mean_v / np.maximum(speed, 1e-9)[:, None], [1.0, 0.0])
    base = (col["sp1"][a].astype(np.float64) ** 2 + col["sp0"][b].astype(np.float64) ** 2
            + sv1**2 * lead1**2 + sv0**2 * lead0**2)
    along = (0.5 * opts.accel_sigma_mps2) ** 2 * (lead1**4 + lead0**4)
    across = np.where(moving, opts.lateral_sigma_mps**2 * (lead1**2 + lead0**2), along)
    d2_pos = _mahalanobis2(e, base, along, across, u)
    dv = v1 - v0
    d2_vel = np.where(both, _mahalanobis2(dv, sv1**2 + sv0**2, (opts.accel_sigma_mps2 * gap) ** 2,
                                          np.where(moving, opts.lateral_sigma_mps**2,
                                                   (opts.accel_sigma_mps2 * gap) ** 2), u), 0.0)
    jump = np.hypot(*(p0 - p1).T) / np.maximum(gap, 1e-6)
    cls_a, cls_b = col["class"][a].astype(str), col["class"][b].astype(str)
    cost = d2_pos + d2_vel + opts.gap_cost_per_s * gap
    cost += np.where((cls_a != "") & (cls_b != "") & (cls_a != cls_b), opts.class_cost, 0.0)
    lane_a, lane_b = col["lane1"][a].astype(str), col["lane0"][b].astype(str)
    cost += np.where((lane_a != "") & (lane_b != "") & (lane_a != lane_b), opts.lane_cost, 0.0)
    la, lb = col["length_m"][a].astype(np.float64), col["length_m"][b].astype(np.float64)
    sa = np.nan_to_num(col["length_std_m"][a].astype(np.float64), nan=1.0)
    sb = np.nan_to_num(col["length_std_m"][b].astype(np.float64), nan=1.0)
    length_d2 = np.where(np.isfinite(la) & np.isfinite(lb), (la - lb) ** 2 / (sa**2 + sb**2 + 0.5**2), 0.0)
    cost += np.minimum(length_d2, opts.gate)
    placed = np.hypot(col["sp1"][a].astype(np.float64), col["sp0"][b].astype(np.float64)) <= opts.max_position_sigma_m
    ok = ((d2_pos <= opts.gate) & (d2_vel <= opts.gate) & (jump <= opts.max_speed_mps) & ~turned & ~against & placed
          & ((strong1 | strong0) if opts.join_glimpses else (strong1 & strong0)) & np.isfinite(cost))
    out = pd.DataFrame({"a": a, "b": b, "gap_s": gap, "position_d2": d2_pos, "velocity_d2": d2_vel, "cost": cost})
    return out[ok].reset_index(drop=True) if ok.any() else empty


# ------------------------------------------------------------------------------------------------ association
def _assign(cands: pd.DataFrame, ends_rows: np.ndarray, start_rows: np.ndarray, no_link: float) -> list[int]:
    """Row numbers of ``cands`` chosen by one linear assignment with "no link" alternatives (Jaqaman et al. 2008:
    the matrix [[C, D_end], [D_start, C^T-pattern]])."""
    n, k = ends_rows.size, start_rows.size
    ei = {int(r): i for i, r in enumerate(ends_rows)}
    sj = {int(r): j for j, r in enumerate(start_rows)}
    big = np.full((n + k, k + n), _BIG)
    which = np.full((n, k), -1)
    for row, a, b, c in zip(cands.index.to_numpy(), cands["a"].to_numpy(), cands["b"].to_numpy(),
                            cands["cost"].to_numpy(), strict=True):
        i, j = ei[int(a)], sj[int(b)]
        if c < big[i, j]:
            big[i, j], which[i, j] = c, row
            big[n + j, k + i] = 0.0
    big[np.arange(n), k + np.arange(n)] = no_link
    big[n + np.arange(k), np.arange(k)] = no_link
    rows, cols = linear_sum_assignment(big)
    chosen = []
    for r, c in zip(rows, cols, strict=True):
        if r < n and c < k and which[r, c] >= 0 and big[r, c] < _BIG:
            chosen.append(int(which[r, c]))
    return chosen


def associate(ends: pd.DataFrame, cands: pd.DataFrame, options: JourneyOptions | None = None) -> pd.DataFrame:
    """The links chosen among ``cands`` (:func:`link_candidates`): one assignment per window of ``window_s`` s of
    fragment ends, the links of a window's last ``max_gap_s`` decided again in the next (module docstring)."""
    opts = options or JourneyOptions()
    if not len(cands):
        return cands
    t1 = ends["t1"].to_numpy(dtype=np.float64)
    cand_t = t1[cands["a"].to_numpy()]
    start, last = float(np.nanmin(cand_t)), float(np.nanmax(cand_t))
    taken_ends: set[int] = set()
    taken_starts: set[int] = set()
    chosen: list[int] = []
    while start <= last:
        stop = start + opts.window_s
        final = stop > last
        keep_until = np.inf if final else stop - opts.max_gap_s
        here = cands[(cand_t >= start) & (cand_t < stop)]
        here = here[~here["a"].isin(taken_ends) & ~here["b"].isin(taken_starts)]
        if len(here):
            picked = _assign(here, np.unique(here["a"].to_numpy()), np.unique(here["b"].to_numpy()),
                             opts.no_link_cost)
            for row in picked:
                a, b = int(cands.at[row, "a"]), int(cands.at[row, "b"])
                if t1[a] < keep_until:
                    chosen.append(row)
                    taken_ends.add(a)
                    taken_starts.add(b)
        # ends before keep_until are settled (linked or not); the rest are looked at again with what follows,
        # from the next end that has a candidate (hours without traffic are skipped, not stepped through)
        ahead = cand_t[cand_t >= keep_until] if not final else cand_t[:0]
        start = float(ahead.min()) if ahead.size else np.inf
    return cands.loc[sorted(chosen, key=lambda r: t1[int(cands.at[r, "a"])])]


# ------------------------------------------------------------------------------------------------ journeys
def _chains(n: int, links: pd.DataFrame, t0: np.ndarray) -> list[list[int]]:
    """Fragments (row numbers) of each journey in time order, journeys in the order of their first fragment."""
    succ = dict(zip(links["a"].astype(int), links["b"].astype(int), strict=True))
    has_pred = set(succ.values())
    heads = [r for r in range(n) if r not in has_pred]
    chains = []
    for h in heads:
        chain = [h]
        while chain[-1] in succ:
            chain.append(succ[chain[-1]])
        chains.append(chain)
    return chains


def _weighted_class(classes: list[str], durations: list[float]) -> str:
    """The class seen longest; "" (unknown) only when unknown was seen longer than every known class together."""
    total: dict[str, float] = {}
    for c, d in zip(classes, durations, strict=True):
        total[c] = total.get(c, 0.0) + max(d, 1e-3)
    known = {c: w for c, w in total.items() if c}
    if not known:
        return ""
    best = max(known, key=lambda c: (known[c], c))
    return best if sum(known.values()) >= total.get("", 0.0) else ""


def _journey_row(cols: dict[str, np.ndarray], chain: list[int], gaps_m: float) -> dict:
    """One vehicle row over the fragments ``chain`` (rows of the fragment table, given as its ``cols``: column ->
    array; ``gaps_m``: the distance between the fragments, m)."""
    idx = np.asarray(chain, dtype=np.int64)

    def f(c: str) -> np.ndarray:
        return cols[c][idx]

    def num(c: str) -> np.ndarray:
        return np.asarray(f(c), dtype=np.float64)

    first, last = float(np.min(num("first_time"))), float(np.max(num("last_time")))
    duration = last - first
    row = {c: cols[c][idx[0]] for c in VEHICLE_COLUMNS}
    row.update(first_time=first, last_time=last, duration_s=duration, points=int(np.sum(num("points"))),
               outliers=int(np.sum(num("outliers"))), path_length_m=float(np.sum(num("path_length_m"))) + gaps_m,
               travel_m=float(np.sum(num("travel_m"))) + gaps_m, min_distance_m=float(np.nanmin(num("min_distance_m")))
               if np.isfinite(num("min_distance_m")).any() else np.nan)
    classes = ["" if (isinstance(c, float) and c != c) else str(c) for c in f("class")]
    row["class"] = _weighted_class(classes, list(num("duration_s")))
    # the headline speed of the fragment whose speed window is longest (where the calibration knows the scale)
    window = num("speed_end_time") - num("speed_start_time")
    if np.isfinite(window).any():
        best = idx[int(np.nanargmax(window))]
        for c in ("speed_kmh", "speed_std_kmh", "speed_start_time", "speed_end_time"):
            row[c] = cols[c][best]
    if len(chain) > 1 and duration > 0:
        seen = num("duration_s")
        row["travel_speed_kmh"] = 3.6 * row["travel_m"] / duration
        row["mean_speed_kmh"] = 3.6 * row["path_length_m"] / duration
        med = num("median_speed_kmh")
        if np.isfinite(med).any():
            ok = np.isfinite(med)
            row["median_speed_kmh"] = float(np.average(med[ok], weights=np.maximum(seen[ok], 1e-3)))
        ps, n = num("point_speed_std_kmh"), num("points")
        if np.isfinite(ps).any():
            ok = np.isfinite(ps)
            row["point_speed_std_kmh"] = float(np.sqrt(np.average(ps[ok] ** 2, weights=n[ok])))
        length, sigma = num("length_m"), num("length_std_m")
        ok = np.isfinite(length) & np.isfinite(sigma) & (sigma > 0)
        if ok.any():
            w = 1.0 / sigma[ok] ** 2
            row["length_m"], row["length_std_m"] = float(np.sum(w * length[ok]) / w.sum()), float(1 / np.sqrt(w.sum()))
    row["fragments"] = len(chain)
    row["tracker_ids"] = ";".join(dict.fromkeys(str(t) for t in f("source_track")))
    return row


def join_fragments(world: WorldTracks, *, metres_per_unit: float = 1.0, lanes: Lanes | None = None,
                   options: JourneyOptions | None = None, min_points: int = 1) -> Journeys:
    """The journeys of the world tracks ``world`` (:func:`~trafficgeo.traffic.trajectories.world_trajectories`;
    positions in CRS units with ``metres_per_unit`` metres each; ``lanes``: the lanes at the fragments' ends add
    to the cost): fragments of one vehicle joined, stationary objects flagged (module docstring). Vehicles none of
    whose fragments has ``min_points`` points are left out: a short glimpse is kept only where it extends a
    longer track."""
    opts = options or JourneyOptions()
    points, frag = world.points, world.vehicles.reset_index(drop=True)
    absorbed: dict[str, list[str]] = {}
    dropped = {"short_track": 0, "duplicate": 0}
    if opts.enabled and opts.duplicates is not None and len(frag) > 1:
        merged = merge_duplicates(points, frag, metres_per_unit=metres_per_unit, options=opts.duplicates)
        for other, keep in merged.absorbed.items():  # a piece a merge cut out of a fragment keeps its tracker id
            absorbed.setdefault(keep, []).append(merged.sources.get(other, other))
        points, frag, dropped["duplicate"] = merged.points, merged.vehicles.reset_index(drop=True), \
            merged.dropped_points
    ends = fragment_ends(points, frag, metres_per_unit=metres_per_unit, lanes=lanes, options=opts)
    if opts.enabled and len(frag) > 1:
        cands = link_candidates(ends, opts)
        chosen = associate(ends, cands, opts)
    else:
        chosen = link_candidates(ends.iloc[:0], opts)
    t0 = ends["t0"].to_numpy(dtype=np.float64) if len(ends) else np.zeros(0)
    chains = _chains(len(frag), chosen, t0)
    names = frag["track_id"].astype(str).to_numpy()
    rows, order, vehicle_of = [], [], {}
    cols = {c: frag[c].to_numpy() for c in frag.columns}  # arrays, not per-row pandas look-ups
    ecols = {c: ends[c].to_numpy(dtype=np.float64) for c in ("x0", "y0", "x1", "y1", "extent_m", "median_sigma_m")}
    absorbed = {k: v for k, v in absorbed.items() if k in set(names)}
    for chain in chains:
        gaps_m = 0.0
        for a, b in pairwise(chain):
            gaps_m += float(np.hypot(ecols["x0"][b] - ecols["x1"][a], ecols["y0"][b] - ecols["y1"][a]))
        row = _journey_row(cols, chain, gaps_m)
        also = [t for r in chain for t in absorbed.get(names[r], [])]
        if also:  # second tracks of this vehicle at the same time, merged into it
            row["fragments"] += len(also)
            row["tracker_ids"] = ";".join(dict.fromkeys([*row["tracker_ids"].split(";"), *also]))
        extent = _journey_extent(ecols, chain)
        sigma = float(np.nanmin(ecols["median_sigma_m"][chain]))  # its best-placed piece's
        row["stationary"] = bool(row["duration_s"] >= opts.stationary_min_s
                                 and extent <= max(opts.stationary_m, 3.0 * sigma))
        rows.append(row)
        for r in chain:
            vehicle_of[names[r]] = row["track_id"]
            order.append(names[r])
    vehicles = pd.DataFrame(rows, columns=[*VEHICLE_COLUMNS, *JOURNEY_COLUMNS])
    # a vehicle needs min_points in all and one piece of track that long: glimpses only extend a real track
    points_of = np.asarray(cols["points"], dtype=np.int64) if len(frag) else np.zeros(0, dtype=np.int64)
    longest = {row["track_id"]: int(points_of[chain].max()) for row, chain in zip(rows, chains, strict=True)}
    short = set(vehicles.loc[(vehicles["points"] < min_points)
                             | (vehicles["track_id"].map(longest) < min_points), "track_id"].astype(str)) \
        if len(vehicles) else set()
    vehicles = vehicles[~vehicles["track_id"].astype(str).isin(short)].reset_index(drop=True)
    if len(vehicles):
        vehicles["fragments"] = vehicles["fragments"].astype(int)
        vehicles["stationary"] = vehicles["stationary"].astype(bool)
    pts = points.copy()
    if len(pts):
        frag_id = pts["track_id"].astype(str)
        gone = frag_id.map(vehicle_of).isin(short).to_numpy()
        dropped["short_track"] = int(gone.sum())
        pts, frag_id = pts[~gone], frag_id[~gone]
        rank = frag_id.map({n: k for k, n in enumerate(order)}).to_numpy()
        pts["fragment"] = frag_id.to_numpy()
        pts["track_id"] = frag_id.map(vehicle_of).to_numpy()
        journey_rank = pts["track_id"].map({v: k for k, v in enumerate(vehicles["track_id"])}).to_numpy()
        pts = pts.iloc[np.lexsort((pts["time"].to_numpy(), rank, journey_rank))].reset_index(drop=True)
    else:
        pts["fragment"] = pd.Series(dtype=object)
    links = pd.DataFrame({"from_fragment": names[chosen["a"].to_numpy(dtype=int)] if len(chosen) else [],
                          "to_fragment": names[chosen["b"].to_numpy(dtype=int)] if len(chosen) else [],
                          **{c: chosen[c].to_numpy() if len(chosen) else [] for c in ("gap_s", "cost", "position_d2",
                                                                                      "velocity_d2")}},
                         columns=LINK_COLUMNS)
    return Journeys(points=pts, vehicles=vehicles, links=links, dropped={k: v for k, v in dropped.items() if v})


def _journey_extent(ecols: dict[str, np.ndarray], chain: list[int]) -> float:
    """The farthest a journey's fragments reach from the median of their ends (m): the fragments' own extents and
    the distances between their ends (``ecols``: columns of :func:`fragment_ends`)."""
    idx = np.asarray(chain, dtype=np.int64)
    xy = np.concatenate([np.column_stack([ecols["x0"][idx], ecols["y0"][idx]]),
                         np.column_stack([ecols["x1"][idx], ecols["y1"][idx]])]).astype(np.float64)
    spread = float(np.max(np.hypot(*(xy - np.median(xy, axis=0)).T))) if len(xy) else 0.0
    return max(spread, float(np.max(ecols["extent_m"][idx])))
