"""Joining the track tables of time chunks of one video (``process --start/--end`` runs, e.g. on several machines).

Chunks are put in time order whatever order they are given in (:func:`plan_chunks`). A chunk given twice, or one
that lies inside another's time range, is refused: its vehicles would be counted twice or its frames cut away. A
gap between chunks is allowed with a warning (vehicles passing in it are missing). Consecutive chunks that
overlap by a few seconds have the vehicles seen in both matched by box overlap (:func:`stitch_tracks`).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import pairwise

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.video.detections import box_iou

HINT = "give each part of the video once, as the --out folders of 'trafficgeo process --start/--end' runs"


def _s(t: float) -> str:
    return f"{float(t):g} s"


def plan_chunks(ranges: Sequence[tuple[float, float]], names: Sequence[str] | None = None,
                videos: Sequence[str | None] | None = None) -> tuple[list[int], list[str]]:
    """The order in which to join chunks with time ``ranges`` ((start, end) s of video each), and warnings.

    Raises:
        InputError: no chunks, chunks of different ``videos`` (names; None: unknown), a range that is not finite
            with start < end, two chunks with the same range, or a chunk whose range lies inside another's.
    """
    n = len(ranges)
    if not n:
        raise InputError(f"no chunks to stitch; {HINT}")
    names = list(names) if names is not None else [f"chunk {k + 1}" for k in range(n)]
    videos = list(videos) if videos is not None else [None] * n
    named = {v: k for k, v in enumerate(videos) if v}
    if len(named) > 1:
        a, b = sorted(named.values())[:2]
        raise InputError(f"{names[a]} is of {videos[a]} but {names[b]} of {videos[b]}: stitch joins time chunks of "
                         "one video; stitch each video's chunks apart")
    for k, (lo, hi) in enumerate(ranges):
        if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
            raise InputError(f"{names[k]}: time range {lo:g} to {hi:g} s is empty or not finite; {HINT}")
    order = sorted(range(n), key=lambda k: (ranges[k][0], ranges[k][1]))
    for i, a in enumerate(order):
        for b in order[i + 1:]:
            (a0, a1), (b0, b1) = ranges[a], ranges[b]
            if b0 >= a1:
                break
            if (a0, a1) == (b0, b1):
                what = f"{videos[a]}, " if videos[a] is not None and videos[a] == videos[b] else ""
                raise InputError(f"{names[b]} and {names[a]} are the same chunk ({what}{_s(a0)} to {_s(a1)}); {HINT}")
            if b1 <= a1 or (b0 == a0 and b1 >= a1):
                inner, outer = (b, a) if b1 <= a1 else (a, b)
                raise InputError(f"{names[inner]} ({_s(ranges[inner][0])} to {_s(ranges[inner][1])}) lies inside "
                                 f"{names[outer]} ({_s(ranges[outer][0])} to {_s(ranges[outer][1])}); {HINT}")
    warnings = []
    for a, b in pairwise(order):
        if ranges[b][0] > ranges[a][1]:
            warnings.append(f"{names[a]} ends at {_s(ranges[a][1])} but {names[b]} starts at {_s(ranges[b][0])}: "
                            "vehicles passing in between are missing and those seen on both sides get two ids; "
                            "process chunks that overlap by a few seconds")
        elif ranges[b][0] == ranges[a][1]:
            warnings.append(f"{names[a]} and {names[b]} meet at {_s(ranges[a][1])} without overlapping: a vehicle "
                            "seen in both gets two ids; process chunks that overlap by a few seconds")
    return order, warnings


def _time_range(table: pd.DataFrame) -> tuple[float, float]:
    t = pd.to_numeric(table["time"], errors="coerce") if len(table) else pd.Series([], dtype=float)
    return (float(t.min()), float(t.max())) if t.notna().any() else (np.nan, np.nan)


def stitch_tracks(chunks: list[pd.DataFrame], *, min_iou: float = 0.5) -> pd.DataFrame:
    """Join the track tables of overlapping time chunks of one video into one table.

    Chunks are taken in time order (of their first and last track times), and refused as :func:`plan_chunks`
    does. Chunk ``k``'s ids (``k`` in the order given) become ``c<k>:<id>``. In the time two consecutive chunks
    both cover, a track of the later one whose boxes overlap a track of the earlier one with a mean IoU of at least
    ``min_iou`` over their common frames is the same vehicle: it takes the earlier id. Each chunk keeps the frames
    up to the middle of the overlap, so no frame is counted twice. Chunks without tracks add nothing.
    """
    if not chunks:
        raise InputError(f"no chunks to stitch; {HINT}")
    labelled = [(k, t) for k, t in enumerate(chunks) if len(t)]
    if not labelled:
        return chunks[0].iloc[:0].copy()
    ranges = [_time_range(t) for _, t in labelled]
    # a chunk whose vehicles were seen for an instant only has start == end: widen it for the checks
    ranges = [(lo, hi if hi > lo else lo + 1e-6) for lo, hi in ranges]
    order, _ = plan_chunks(ranges, [f"chunk {k + 1}" for k, _ in labelled])
    out: list[pd.DataFrame] = []
    names: dict[str, str] = {}
    prev = None
    for k, table in (labelled[i] for i in order):
        t = table.copy()
        t["track_id"] = [f"c{k}:{i}" for i in t["track_id"]]
        if prev is not None:
            lo, hi = t["time"].min(), prev["time"].max()
            if hi > lo:  # overlap
                _match(prev[prev["time"] >= lo], t[t["time"] <= hi], names, min_iou)
                mid = 0.5 * (lo + hi)
                out[-1] = out[-1][out[-1]["time"] < mid]
                t = t[t["time"] >= mid]
        t["track_id"] = [names.get(i, i) for i in t["track_id"]]
        out.append(t)
        prev = table.assign(track_id=[f"c{k}:{i}" for i in table["track_id"]])
    return pd.concat(out, ignore_index=True).sort_values(["track_id", "time"], kind="stable").reset_index(drop=True)


def _match(a: pd.DataFrame, b: pd.DataFrame, names: dict[str, str], min_iou: float) -> None:
    """Give each track of ``b`` the id of the track of ``a`` it overlaps best (mean IoU >= ``min_iou``)."""
    m = a.merge(b, on="frame", suffixes=("_a", "_b"))
    if not len(m):
        return
    m["iou"] = box_iou(m[["x1_a", "y1_a", "x2_a", "y2_a"]].to_numpy(), m[["x1_b", "y1_b", "x2_b", "y2_b"]].to_numpy())
    score = m.groupby(["track_id_b", "track_id_a"])["iou"].mean().reset_index()
    score = score[score["iou"] >= min_iou].sort_values("iou", ascending=False)
    used_a, used_b = set(), set()
    for _, r in score.iterrows():
        if r["track_id_a"] not in used_a and r["track_id_b"] not in used_b:
            names[r["track_id_b"]] = names.get(r["track_id_a"], r["track_id_a"])
            used_a.add(r["track_id_a"])
            used_b.add(r["track_id_b"])
