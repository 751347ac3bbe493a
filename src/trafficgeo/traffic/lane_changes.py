"""Each vehicle's lanes over time: the stretches it drove in each lane (lane changes) and its main lane."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


@dataclass(frozen=True)
class LaneVisit:
    """A stretch of a track in one lane: ``lane`` from ``start`` to ``end`` (s)."""

    lane: str
    start: float
    end: float


def lane_visits(time: ArrayLike, lanes: ArrayLike, *, min_dwell_s: float = 1.0) -> list[LaneVisit]:
    """The lanes a track drove in, in order, ignoring points outside every lane and stays shorter than
    ``min_dwell_s`` (jitter across a lane line is not a lane change). ``time`` (N,) s increasing."""
    t = np.asarray(time, dtype=np.float64).reshape(-1)
    lane = np.asarray(lanes, dtype=object).reshape(-1)
    use = lane != ""
    t, lane = t[use], lane[use]
    if t.size == 0:
        return []
    change = np.flatnonzero(lane[1:] != lane[:-1]) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [t.size]])
    runs = [LaneVisit(str(lane[s]), float(t[s]), float(t[e - 1])) for s, e in zip(starts, ends, strict=True)]
    longest = max(r.end - r.start for r in runs)
    kept = [r for r in runs if r.end - r.start >= min(min_dwell_s, longest)]
    merged: list[LaneVisit] = []
    for r in kept:
        if merged and merged[-1].lane == r.lane:
            merged[-1] = LaneVisit(r.lane, merged[-1].start, r.end)
        else:
            merged.append(r)
    return merged


def main_lane(visits: list[LaneVisit]) -> str:
    """The lane a vehicle spent the most time in (``""`` if none)."""
    if not visits:
        return ""
    totals: dict[str, float] = {}
    for v in visits:
        totals[v.lane] = totals.get(v.lane, 0.0) + (v.end - v.start)
    return max(totals, key=lambda k: totals[k])
