"""One vehicle tracked twice at the same time: fragments that stand inside each other are one vehicle.

A detector sometimes gives one vehicle two boxes on the same frames - the blob of the background detector split in
two (the cab and the trailer of a truck), a tile's box beside the full frame's - and the tracker follows both. In
world coordinates the two tracks cannot be two vehicles: over their common frames their ground positions stay
closer than a vehicle is long along the direction of travel (``along_m``, or half the longer vehicle's length
where that is more) and than ``across_m`` across it, so one vehicle would stand inside the other.
:func:`find_duplicates` finds such pairs (on at least ``min_share`` of their common frames, and on at least
``min_common`` of them); :func:`merge_duplicates` keeps the points of the fragment with more of them over their
common span, and the other fragment's points outside that span become fragments of their own (``<id>:1`` before it,
``<id>:2`` after it), which :mod:`trafficgeo.traffic.journeys` then joins like any other fragment.

Two vehicles side by side (a lane apart, 3.5 m) or one behind the other (a car length and a gap apart) are never
found: the distances are those of one vehicle's own footprint. Positions in CRS units (``metres_per_unit`` gives
metres), times in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from trafficgeo.geo.cuboids import dimensions_for

__all__ = ["DuplicateOptions", "Merged", "find_duplicates", "merge_duplicates"]


@dataclass(frozen=True)
class DuplicateOptions:
    """When two fragments seen at the same time are one vehicle (module docstring)."""

    along_m: float = 3.0  # m along the direction of travel (or half the longer vehicle's length, if more)
    across_m: float = 1.5  # m across it
    min_share: float = 0.8  # of the common frames within both distances
    min_common: int = 2  # common frames at least


@dataclass(frozen=True)
class Merged:
    """``points`` and ``vehicles`` (one row per fragment) after the duplicates were merged; ``absorbed``: each
    fragment whose points were all inside another's span -> that fragment (its tracker id goes with the vehicle);
    ``dropped_points``: the duplicate points removed; ``sources``: the tracker id (``source_track``) of every
    fragment, the pieces a merge cut out of one (``<id>:1``, ``<id>:2``) included."""

    points: pd.DataFrame
    vehicles: pd.DataFrame
    absorbed: dict[str, str]
    dropped_points: int
    sources: dict[str, str] = field(default_factory=dict)


def _times_key(t: np.ndarray) -> np.ndarray:
    return np.rint(np.asarray(t, dtype=np.float64) * 1000.0).astype(np.int64)  # ms: frames of one video


def find_duplicates(points: pd.DataFrame, vehicles: pd.DataFrame, *, metres_per_unit: float = 1.0,
                    options: DuplicateOptions | None = None) -> list[tuple[str, str, int]]:
    """Pairs of fragments (world track ids of ``vehicles``) that are one vehicle seen twice (module docstring), with
    their number of common frames, most common frames first."""
    opts = options or DuplicateOptions()
    if len(vehicles) < 2 or not len(points):
        return []
    m = float(metres_per_unit)
    ids = vehicles["track_id"].astype(str).to_numpy()
    t0 = vehicles["first_time"].to_numpy(dtype=np.float64)
    t1 = vehicles["last_time"].to_numpy(dtype=np.float64)
    half_length = 0.5 * np.where(np.isfinite(vehicles["length_m"].to_numpy(dtype=np.float64)),
                                 vehicles["length_m"].to_numpy(dtype=np.float64),
                                 dimensions_for(vehicles["class"].fillna("").astype(str).to_numpy())[:, 0])
    groups = points.groupby(points["track_id"].astype(str), sort=False).indices
    key = _times_key(points["time"].to_numpy())
    xy = points[["x", "y"]].to_numpy(dtype=np.float64)
    heading = np.radians(points["heading_deg"].to_numpy(dtype=np.float64)) if "heading_deg" in points.columns \
        else np.full(len(points), np.nan)
    order = np.argsort(t0, kind="stable")
    found = []
    for n, i in enumerate(order):
        for j in order[n + 1:]:
            if t0[j] > t1[i]:
                break
            a, b = groups.get(ids[i]), groups.get(ids[j])
            if a is None or b is None:
                continue
            common, ia, ib = np.intersect1d(key[a], key[b], return_indices=True)
            if common.size < opts.min_common:
                continue
            pa, pb = a[ia], b[ib]
            d = (xy[pb] - xy[pa]) * m
            h = np.where(np.isfinite(heading[pa]), heading[pa], heading[pb])
            h = np.where(np.isfinite(h), h, 0.0)
            along = np.abs(d[:, 0] * np.sin(h) + d[:, 1] * np.cos(h))
            across = np.abs(d[:, 0] * np.cos(h) - d[:, 1] * np.sin(h))
            reach = max(opts.along_m, float(np.nanmax([half_length[i], half_length[j]])))
            inside = (along <= reach) & (across <= opts.across_m)
            if inside.mean() >= opts.min_share:
                found.append((ids[i], ids[j], int(common.size)))
    return sorted(found, key=lambda p: -p[2])


def _piece_row(row: pd.Series, pts: pd.DataFrame, name: str, m: float) -> dict:
    """The vehicle row of a piece ``pts`` of fragment ``row``: its own times, points and distances, the rest
    (speeds, class, length) the fragment's."""
    out = row.to_dict()
    t = pts["time"].to_numpy(dtype=np.float64)
    xy = pts[["x", "y"]].to_numpy(dtype=np.float64) * m
    step = float(np.hypot(*np.diff(xy, axis=0).T).sum()) if len(xy) > 1 else 0.0
    out.update(track_id=name, first_time=float(t[0]), last_time=float(t[-1]), duration_s=float(t[-1] - t[0]),
               points=len(pts), outliers=int(pts["outlier"].sum()) if "outlier" in pts.columns else 0,
               path_length_m=step, travel_m=step)
    if "distance_m" in pts.columns and pts["distance_m"].notna().any():
        out["min_distance_m"] = float(pts["distance_m"].min())
    return out


def merge_duplicates(points: pd.DataFrame, vehicles: pd.DataFrame, *, metres_per_unit: float = 1.0,
                     options: DuplicateOptions | None = None) -> Merged:
    """Merge the fragments :func:`find_duplicates` finds (module docstring), pair by pair, most common frames
    first; a fragment changed by one merge waits for the next round (at most 3 rounds)."""
    m = float(metres_per_unit)
    absorbed: dict[str, str] = {}
    ids = vehicles["track_id"].astype(str)
    sources = dict(zip(ids, vehicles["source_track"].astype(str) if "source_track" in vehicles.columns else ids,
                       strict=True))
    dropped = 0
    for _round in range(3):
        pairs = find_duplicates(points, vehicles, metres_per_unit=m, options=options)
        if not pairs:
            break
        rows = {str(r["track_id"]): r for _, r in vehicles.iterrows()}
        touched: set[str] = set()
        remove: set[str] = set()
        new_rows: list[dict] = []
        keep_mask = np.ones(len(points), dtype=bool)
        renamed = points["track_id"].astype(str).to_numpy().copy()
        pid = points["track_id"].astype(str).to_numpy()
        for a, b, _n in pairs:
            if a in touched or b in touched:
                continue
            touched.update((a, b))
            keep, other = (a, b) if rows[a]["points"] >= rows[b]["points"] else (b, a)
            times = points["time"].to_numpy(dtype=np.float64)
            lo, hi = float(times[pid == keep].min()), float(times[pid == keep].max())
            mine = np.flatnonzero(pid == other)
            t = times[mine]
            inside = (t >= lo - 1e-6) & (t <= hi + 1e-6)
            keep_mask[mine[inside]] = False
            dropped += int(inside.sum())
            remove.add(other)
            pieces = [(mine[t < lo - 1e-6], f"{other}:1"), (mine[t > hi + 1e-6], f"{other}:2")]
            pieces = [(idx, name) for idx, name in pieces if idx.size]
            for k, v in absorbed.items():  # what ``other`` absorbed before goes with the vehicle it is part of
                if v == other:
                    absorbed[k] = keep
            if not pieces:
                absorbed[other] = keep
            for idx, name in pieces:
                sources[name] = sources.get(other, other)
                renamed[idx] = name
                new_rows.append(_piece_row(rows[other], points.iloc[idx], name, m))
        points = points.assign(track_id=renamed)[keep_mask].reset_index(drop=True)
        kept = vehicles[~vehicles["track_id"].astype(str).isin(remove)]
        vehicles = pd.concat([kept, pd.DataFrame(new_rows, columns=vehicles.columns)], ignore_index=True) \
            if new_rows else kept.reset_index(drop=True)
    for k, v in list(absorbed.items()):  # an absorber absorbed in turn: follow to the end
        while v in absorbed:
            v = absorbed[v]
        absorbed[k] = v
    return Merged(points=points, vehicles=vehicles, absorbed=absorbed, dropped_points=dropped, sources=sources)
