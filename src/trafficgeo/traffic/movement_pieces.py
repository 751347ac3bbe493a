"""Pieces of track that are one vehicle's movement through a junction (:mod:`trafficgeo.traffic.movements`).

Inside a junction vehicles turn, queue and hide one another, out of the motion model that joins the pieces of a
track on a road (:mod:`trafficgeo.traffic.journeys`). The movement rows of the pieces (each with what is known of
its origin and destination, :func:`~trafficgeo.traffic.movements.vehicle_movements`) are joined here:

* :func:`pair_halves` - two **halves** of one vehicle (its track broken inside the junction): a movement known only
  by its origin and a later one known only by its destination are one vehicle's when the second begins within
  :data:`PAIR_GAP_S` of the first's end, no farther from it than the faster of its speeds where the first ends and
  the second begins covers in the gap (at least :data:`PAIR_MIN_SPEED_MPS`) plus :data:`PAIR_SLACK_M`, ahead of it
  as it turns (the line between the two within :data:`CHORD_TOLERANCE_DEG` of the mean of the directions where the
  first ends and the second begins, as an arc's chord runs, widened by the angle the position error
  :data:`PAIR_SLACK_M` subtends over that line), and their classes are of one family (car or van; truck or bus; or
  unknown). A vehicle lost while it stood (the first half ends slower than :data:`QUEUE_STOPPED_MPS`: in a queue,
  at a red light) may go unseen up to :data:`QUEUE_GAP_S`, if found again no farther than a queue creeps
  (:data:`QUEUE_CREEP_M` plus :data:`PAIR_SLACK_M`) ahead. The pairs are chosen all at once by an assignment that
  prefers the arc whose length best matches what their speeds cover in the gap, and ranks a standing vehicle's
  pairs (nearest first) behind most of a moving one's. A tail that begins up to :data:`PAIR_OVERLAP_S` before its
  head ends is paired only where the two stand together meanwhile (as doubles do), or, beginning at most
  :data:`TOUCH_S` before, within :data:`PAIR_SLACK_M` of where the head ends. Two halves are never joined into a
  U-turn: a U-turn is counted only where one piece of track shows it.
* :func:`merge_doubles` - two pieces of track seen at once (for :data:`SAME_MIN_OVERLAP_S` or more: two ids on one
  vehicle, a bus detected in two boxes) are one vehicle when they stand together - the medians over their common
  time of the distance across the travel within :data:`SAME_ACROSS_M` (half a lane) and along it within
  :data:`SAME_ALONG_M` (half the longer vehicle: 6 m if either is a truck or bus) - and their ends agree (the same
  arm, or unknown in one, or judged by the path in one where the other crossed a gate: the gate's is kept).
* :func:`join_judged_halves` - two movements under one tracker id, each whole only by the end judged from its path
  (the track cut where the vehicle set off), agreeing on both arms: one vehicle's.

:func:`~trafficgeo.traffic.movements.vehicle_movements` pairs halves, merges doubles, pairs the halves that
merging completed, then joins the halves judged whole. A joined row's ``track_ids`` lists its pieces and its class
is that of the piece seen longest, or heavy where heavy pieces hold :data:`HEAVY_PIECE_SHARE` of its points.

The rows are dicts with the movement columns and private keys (``_t``, ``_xy``: the piece's times and positions;
``_t0, _t1, _p0, _p1, _v0, _v1, _d0, _d1``: its first/last time, position, speed (m/s) and unit direction of
travel (None if unknown); ``_classes``: its number of points per class (a Counter); ``_trackers``: the tracker
ids it came from). Positions in CRS units (``metres_per_unit`` gives metres), times in seconds.
"""

from __future__ import annotations

import numpy as np

from trafficgeo.traffic.measurements import HEAVY_CLASSES

__all__ = ["join_judged_halves", "merge_doubles", "pair_halves"]

CHORD_TOLERANCE_DEG = 45.0  # the chord between two halves runs within this of the mean of their directions
PAIR_GAP_S = 5.0  # s: the longest a vehicle may go unseen between the two halves of its movement
PAIR_SLACK_M = 4.0  # m of position error allowed where the two halves meet, beyond the distance the speed covers
PAIR_MIN_SPEED_MPS = 3.0  # m/s assumed at least for the distance a hidden vehicle may cover
SAME_ACROSS_M = 1.5  # m: two pieces of track seen at once, this close across their travel (half a lane) ...
SAME_ALONG_M = {"light": 2.5, "heavy": 6.0}  # ... and this close along it (half the longer vehicle) are one vehicle
SAME_MIN_OVERLAP_S = 0.3  # s: seen at once for at least this long
PAIR_OVERLAP_S = 2.0  # s: a tail may begin this long before its head ends if the two stand together meanwhile
TOUCH_S = 0.5  # s: ... or this long before, anyway, where it begins within PAIR_SLACK_M of where the head ends
QUEUE_GAP_S = 120.0  # s: a vehicle lost while it stood (in a queue, at a red light) may go unseen this long
QUEUE_STOPPED_MPS = 2.5  # m/s: a head that ends slower than this ended standing
QUEUE_CREEP_M = 10.0  # m: and its vehicle may have crept this far ahead (plus PAIR_SLACK_M) meanwhile
HEAVY_PIECE_SHARE = 0.35  # a joined movement is heavy when pieces of a heavy class hold this share of its points


def _joined_class(a: dict, b: dict) -> dict:
    """The class of two pieces joined, and its points per class (``_classes``): heavy (the most frequent heavy class)
    when pieces of a heavy class hold :data:`HEAVY_PIECE_SHARE` or more of their points - the detector takes a
    truck's box for a van's or a car's far more often than the reverse - else that of the piece seen longer."""
    tally = a["_classes"] + b["_classes"]
    heavy = {k: n for k, n in tally.items() if k in HEAVY_CLASSES}
    if heavy and sum(heavy.values()) >= HEAVY_PIECE_SHARE * tally.total():
        return {"class": max(heavy, key=heavy.get), "_classes": tally}
    longer = a if a["_classes"].total() >= b["_classes"].total() else b
    return {"class": longer["class"] or a["class"] or b["class"], "_classes": tally}


def _family(vehicle_class: str) -> str:
    """Light (car, van) or heavy (truck, bus) - the classes a detector confuses with each other - else the class."""
    return "light" if vehicle_class in ("car", "van") else "heavy" if vehicle_class in HEAVY_CLASSES else vehicle_class


def _arc_length_m(chord: np.ndarray, d_end: np.ndarray | None, d_start: np.ndarray | None) -> float | None:
    """The length (m) of the circular arc from the end of one half (direction ``d_end``) to the start of the next
    (direction ``d_start``) over ``chord`` (m); None when the chord does not run between the two directions (the
    second half is not ahead of the first, turning as it does). The chord itself where a direction is unknown or the
    chord is shorter than the position error :data:`PAIR_SLACK_M` (its direction is noise)."""
    dist = float(np.hypot(*chord))
    if d_end is None or d_start is None or dist < PAIR_SLACK_M:
        return dist
    turn = float(np.arctan2(d_end[0] * d_start[1] - d_end[1] * d_start[0], d_end @ d_start))  # signed, radians
    mid = np.arctan2(d_end[1], d_end[0]) + 0.5 * turn  # an arc's chord runs at the mean of its end directions
    off = abs((np.arctan2(chord[1], chord[0]) - mid + np.pi) % (2 * np.pi) - np.pi)
    if off > np.radians(CHORD_TOLERANCE_DEG) + np.arctan2(PAIR_SLACK_M, dist):
        return None
    half = 0.5 * abs(turn)
    return dist * half / np.sin(half) if half > 1e-6 else dist


def _together(a: dict, b: dict, metres_per_unit: float, min_overlap_s: float = SAME_MIN_OVERLAP_S) -> float | None:
    """How far apart two pieces of track seen at once stand, as a share of what one vehicle allows (<= 1: one
    vehicle; module docstring), from the medians over their common time of the distance across and along the
    travel of ``a`` (``b``'s points against ``a``'s positions interpolated at their times); None if they share less
    than :data:`SAME_MIN_OVERLAP_S` or stand farther apart."""
    ta, tb = a["_t"], b["_t"]
    lo, hi = max(ta[0], tb[0]), min(ta[-1], tb[-1])
    if hi - lo < min_overlap_s or ta.size < 2:
        return None
    both = (tb >= lo) & (tb <= hi)
    if not both.any():
        return None
    at = np.column_stack([np.interp(tb[both], ta, a["_xy"][:, 0]), np.interp(tb[both], ta, a["_xy"][:, 1])])
    ahead = np.column_stack([np.interp(tb[both] + 0.5, ta, a["_xy"][:, 0]),
                             np.interp(tb[both] + 0.5, ta, a["_xy"][:, 1])]) - \
        np.column_stack([np.interp(tb[both] - 0.5, ta, a["_xy"][:, 0]), np.interp(tb[both] - 0.5, ta, a["_xy"][:, 1])])
    d = (b["_xy"][both] - at) * metres_per_unit
    norm = np.hypot(*ahead.T)
    moving = norm * metres_per_unit > 0.5  # direction known where it moved 0.5 m in the second around the sample
    u = np.where(moving[:, None], ahead / np.maximum(norm, 1e-12)[:, None], 0.0)
    along = np.abs(np.einsum("ij,ij->i", d, u))
    across = np.where(moving, np.abs(d[:, 0] * u[:, 1] - d[:, 1] * u[:, 0]), np.hypot(*d.T))
    heavy = "heavy" in (_family(a["class"]), _family(b["class"]))
    share = max(float(np.median(across)) / SAME_ACROSS_M,
                float(np.median(along)) / SAME_ALONG_M["heavy" if heavy else "light"])
    return share if share <= 1.0 else None


def _agree(a: dict, b: dict, end: str) -> bool:
    """The two pieces' ``end`` ("origin" or "destination") can be one vehicle's: equal, or one of them unknown or
    judged by the path where the other crossed a gate."""
    x, y = a[end], b[end]
    if not x or not y or x == y:
        return True
    return {a[f"{end}_by"], b[f"{end}_by"]} == {"gate", "path"}


def merge_doubles(rows: list[dict], metres_per_unit: float) -> list[dict]:
    """Pieces of track seen at once that stand together (:func:`_together`: two ids on one vehicle, or a long
    vehicle detected in two boxes) are one vehicle when their ends agree (:func:`_agree`): merged, nearest first,
    the origin taken from the piece seen first (a gate crossing before a path), the destination from the piece seen
    last, the class from the piece seen longer; never into a U-turn that neither piece shows."""
    rows = list(rows)
    order = sorted(range(len(rows)), key=lambda k: rows[k]["_t0"])
    pairs = []
    for x, i in enumerate(order):
        for j in order[x + 1:]:
            if rows[j]["_t0"] > rows[i]["_t1"] - SAME_MIN_OVERLAP_S:
                break
            share = _together(rows[i], rows[j], metres_per_unit)
            if share is not None and _agree(rows[i], rows[j], "origin") and _agree(rows[i], rows[j], "destination"):
                pairs.append((share, i, j))
    merged_into: dict[int, int] = {}
    for _share, i, j in sorted(pairs):
        while i in merged_into:
            i = merged_into[i]
        while j in merged_into:
            j = merged_into[j]
        if i == j or not (_agree(rows[i], rows[j], "origin") and _agree(rows[i], rows[j], "destination")):
            continue
        a, b = (i, j) if rows[i]["_t0"] <= rows[j]["_t0"] else (j, i)
        both = dict(rows[a])
        _absorb(both, rows[b])
        if both["origin"] and both["origin"] == both["destination"] and not any(
                r["origin"] == r["destination"] != "" for r in (rows[a], rows[b])):
            continue  # no U-turn from two pieces (pair_halves)
        rows[a] = both
        merged_into[b] = a
    return [r for k, r in enumerate(rows) if k not in merged_into]


def _absorb(a: dict, b: dict) -> None:
    """Merge piece ``b`` (seen at the same time as ``a``, starting no earlier) into ``a`` (in place)."""
    def pick(end: str, time: str, first: bool) -> None:  # a known end over none, a gate over a path, else ``first``
        mine, other = (a, b) if first else (b, a)

        def rank(r: dict) -> tuple[bool, bool]:
            return bool(r[end]), r[f"{end}_by"] == "gate"

        take = mine if rank(mine) >= rank(other) else other
        a.update({end: take[end], f"{end}_by": take[f"{end}_by"], time: take[time]})

    late = b["_t1"] > a["_t1"]
    pick("origin", "entry_time", True)
    pick("destination", "exit_time", not late)
    if late:
        a.update(_t1=b["_t1"], _p1=b["_p1"], _v1=b["_v1"], _d1=b["_d1"])
    t = np.concatenate([a["_t"], b["_t"]])
    xy = np.concatenate([a["_xy"], b["_xy"]])
    keep = np.argsort(t, kind="stable")
    a.update(_t=t[keep], _xy=xy[keep], track_ids=f"{a['track_ids']};{b['track_ids']}",
             _trackers=a["_trackers"] | b["_trackers"],
             stopped_s=max(a["stopped_s"], b["stopped_s"]), **_joined_class(a, b))


def pair_halves(rows: list[dict], metres_per_unit: float) -> list[dict]:
    """Join movements known only by their origin to later ones known only by their destination (module docstring)."""
    from scipy.optimize import linear_sum_assignment

    heads = [i for i, r in enumerate(rows) if r["origin"] and not r["destination"]]
    tails = [j for j, r in enumerate(rows) if r["destination"] and not r["origin"]]
    if not heads or not tails:
        return rows
    big = 1e9
    cost = np.full((len(heads), len(tails)), big)
    for a, i in enumerate(heads):
        h = rows[i]
        for b, j in enumerate(tails):
            t = rows[j]
            gap = t["_t0"] - h["_t1"]
            queued = PAIR_GAP_S < gap <= QUEUE_GAP_S and h["_v1"] < QUEUE_STOPPED_MPS
            if not (-PAIR_OVERLAP_S <= gap <= PAIR_GAP_S or queued) or t["_t0"] <= h["_t0"] or t["_t1"] <= h["_t1"]:
                continue
            if _family(h["class"]) != _family(t["class"]) and h["class"] and t["class"]:
                continue
            if h["origin"] == t["destination"]:
                continue  # a U-turn is counted only where one piece of track shows it
            if gap <= 0.0:  # seen at once for a moment (a piece merged into the tail began earlier)
                share = _together(h, t, metres_per_unit, min_overlap_s=0.0)
                if share is not None:
                    cost[a, b] = share
                    continue
                if gap < -TOUCH_S:
                    continue
                gap = 0.0  # the tail began as the head ended: where the head ended, give or take the slack
            chord = (t["_p0"] - h["_p1"]) * metres_per_unit
            dist_m = float(np.hypot(*chord))
            reach_m = (QUEUE_CREEP_M if queued else max(h["_v1"], t["_v0"], PAIR_MIN_SPEED_MPS) * gap) + PAIR_SLACK_M
            if dist_m > reach_m:
                continue
            path_m = _arc_length_m(chord, h["_d1"], t["_d0"])
            if path_m is None:
                continue
            if queued:  # 2-3: behind a moving vehicle's pairs (mostly under 2), the nearer the better
                cost[a, b] = 2.0 + dist_m / reach_m
                continue
            travelled_m = 0.5 * (h["_v1"] + t["_v0"]) * gap  # what its speeds on both sides cover in the gap
            cost[a, b] = abs(path_m - travelled_m) / (travelled_m + PAIR_SLACK_M) + gap / PAIR_GAP_S
    ra, rb = linear_sum_assignment(cost)
    drop = set()
    for a, b in zip(ra, rb, strict=True):
        if cost[a, b] >= big:
            continue
        _join(rows[heads[a]], rows[tails[b]])
        drop.add(tails[b])
    return [r for k, r in enumerate(rows) if k not in drop]


def _join(h: dict, t: dict) -> None:
    """Join the later half ``t`` of a vehicle's movement to its head ``h`` (in place): the destination is ``t``'s."""
    later = t["_t"] > h["_t"][-1]
    h.update(destination=t["destination"], destination_by=t["destination_by"], exit_time=t["exit_time"],
             stopped_s=h["stopped_s"] + t["stopped_s"], track_ids=f"{h['track_ids']};{t['track_ids']}",
             _t1=t["_t1"], _p1=t["_p1"], _v1=t["_v1"], _d1=t["_d1"],
             _t=np.concatenate([h["_t"], t["_t"][later]]), _xy=np.concatenate([h["_xy"], t["_xy"][later]]),
             _trackers=h["_trackers"] | t["_trackers"], **_joined_class(h, t))


def join_judged_halves(rows: list[dict]) -> list[dict]:
    """Two movements of one tracked vehicle that each look whole only by their path: the first crossed its origin's
    gate and its destination is judged by its path, the second's origin is judged by its path and it crossed its
    destination's gate, and the two agree on both arms. They are one vehicle's halves (its track cut inside the
    junction where it stopped or started, each half judged whole) when the tracker followed both under one id and the
    second begins no earlier than the first and within :data:`PAIR_GAP_S` of its end (or while it is still seen: one
    id's pieces can interleave): joined, the origin's gate of the first and the destination's gate of the second
    kept. Where several pairs could be made, the shortest gap first."""
    heads = [i for i, r in enumerate(rows) if r["origin_by"] == "gate" and r["destination_by"] == "path"]
    tails = [j for j, r in enumerate(rows) if r["origin_by"] == "path" and r["destination_by"] == "gate"]
    pairs = []
    for i in heads:
        h = rows[i]
        for j in tails:
            t = rows[j]
            gap = t["_t0"] - h["_t1"]
            if (h["origin"], h["destination"]) != (t["origin"], t["destination"]) or gap > PAIR_GAP_S \
                    or t["_t0"] < h["_t0"] or t["_t1"] < h["_t1"] or not h["_trackers"] & t["_trackers"]:
                continue
            pairs.append((abs(gap), i, j))
    used: set[int] = set()
    drop = set()
    for _gap, i, j in sorted(pairs):
        if i in used or j in used:
            continue
        _join(rows[i], rows[j])
        used |= {i, j}
        drop.add(j)
    return [r for k, r in enumerate(rows) if k not in drop]
