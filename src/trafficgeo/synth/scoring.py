"""Scores against the demo world's truth: detections against the rendered boxes, counts and spot speeds against the
true line crossings. Used by ``trafficgeo demo`` and the benchmarks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from trafficgeo.synth.world import truth_lane_name
from trafficgeo.video.detections import box_iou


def detection_scores(detections: pd.DataFrame, truth_tracks: pd.DataFrame, *, min_visible: float = 0.5,
                     min_height_px: float = 12.0, iou: float = 0.5) -> tuple[float, float, int]:
    """Precision and recall of boxes (``frame, x1, y1, x2, y2``) against the truth boxes of ``truth_tracks.csv``
    at IoU >= ``iou`` (greedy, best IoU first). Vehicles less than ``min_visible`` visible or lower than
    ``min_height_px`` need not be found; a detection of one is neither right nor wrong. Returns (precision,
    recall, number of vehicle boxes to find)."""
    truth = truth_tracks.dropna(subset=["x1", "y1", "x2", "y2"])
    need = ((truth["visible_fraction"] >= min_visible) & (truth["y2"] - truth["y1"] >= min_height_px)).to_numpy()
    det_groups = detections.groupby("frame").indices
    tru_groups = truth.groupby("frame").indices
    dbox = detections[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    tbox = truth[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    tp = fp = fn = 0
    for f in set(det_groups) | set(tru_groups):
        di = det_groups.get(f, np.zeros(0, dtype=int))
        ti = tru_groups.get(f, np.zeros(0, dtype=int))
        md = np.zeros(di.size, dtype=bool)
        mt = np.zeros(ti.size, dtype=bool)
        if di.size and ti.size:
            m = box_iou(dbox[di][:, None], tbox[ti][None, :])
            pairs = sorted(zip(*np.nonzero(m >= iou), strict=True), key=lambda p: -m[p])
            for i, j in pairs:
                if not md[i] and not mt[j]:
                    md[i] = mt[j] = True
        required = need[ti]
        tp += int(np.sum(mt & required))
        fn += int(np.sum(~mt & required))
        fp += int(np.sum(~md))
    return tp / max(tp + fp, 1), tp / max(tp + fn, 1), tp + fn


@dataclass(frozen=True)
class CountScore:
    """Per line and lane: ``table`` (true, counted), ``accuracy`` = 1 - sum |counted - true| / sum true, and the
    spot-speed errors (km/h) of crossings matched to a true crossing of the same line and lane within
    ``max_dt`` seconds (NaN where the track carries no speed)."""

    table: pd.DataFrame
    accuracy: float
    speed_errors: np.ndarray


def count_scores(crossings: pd.DataFrame, truth_counts: pd.DataFrame, *, end_s: float | None = None,
                 max_dt: float = 0.5) -> CountScore:
    """Score ``analyze``'s crossings (lanes named as in the world's ``lanes.gpkg``) against ``truth_counts.csv``."""
    tc = truth_counts if end_s is None else truth_counts[truth_counts["time"] < end_s]
    tc = tc.assign(line=tc["line"].astype(str), lane=truth_lane_name(tc["direction"], tc["lane"]))
    cr = crossings.assign(line=crossings["line"].astype(str))
    both = pd.concat([tc.groupby(["line", "lane"]).size().rename("true"),
                      cr.groupby(["line", "lane"]).size().rename("counted")], axis=1).fillna(0).astype(int)
    acc = 1.0 - float(np.abs(both["counted"] - both["true"]).sum()) / max(float(both["true"].sum()), 1.0)
    errors = []
    for (line, lane), g in cr.groupby(["line", "lane"]):
        t = tc[(tc["line"] == line) & (tc["lane"] == lane)]
        if not len(t):
            continue
        times = t["time"].to_numpy()
        for tm, sp in zip(g["time"].to_numpy(), g["speed_kmh"].to_numpy(), strict=True):
            k = int(np.argmin(np.abs(times - tm)))
            if abs(times[k] - tm) < max_dt:
                errors.append(sp - t["speed_kmh"].iloc[k])
    return CountScore(both, acc, np.asarray(errors, dtype=np.float64))


def crossing_outcomes(crossings: pd.DataFrame, truth_counts: pd.DataFrame, truth_tracks: pd.DataFrame, *,
                      max_dt: float = 0.7, touch_px: float = 3.0) -> tuple[pd.DataFrame, int]:
    """What became of each true crossing, and why it may have gone wrong: for finding the causes of count errors.

    Each true crossing takes the nearest unused crossing of its line within ``max_dt`` seconds: first those of its
    lane (true crossings in time order), then, for the ones left, of any lane. ``outcome`` is "counted", "wrong
    lane" or "missed". With it, from the truth at the frame nearest the crossing: ``visible`` (the vehicle's
    visible fraction) and ``touching``, which other vehicles' true boxes come within ``touch_px`` pixels of its
    box: "none", or "+"-joined "same lane", "next lane" (another lane of its direction) and "other direction".
    Returns the table (columns ``line, vehicle, lane, time, outcome, visible, touching``) and the number of
    crossings matched to no true one (extra counts).
    """
    tc = truth_counts.assign(line=truth_counts["line"].astype(str),
                             lane=truth_lane_name(truth_counts["direction"], truth_counts["lane"]))
    tc = tc.sort_values("time", kind="stable").reset_index(drop=True)
    line = crossings["line"].astype(str).to_numpy()
    lane = crossings["lane"].astype(str).to_numpy()
    time = crossings["time"].to_numpy(dtype=np.float64)
    used = np.zeros(len(crossings), dtype=bool)
    outcome = np.full(len(tc), "missed", dtype=object)
    # First every true crossing takes a crossing of its own lane, then the rest any lane (in time order each).
    for same_lane in (True, False):
        for i, c in enumerate(tc.itertuples(index=False)):
            if outcome[i] != "missed":
                continue
            cand = (line == c.line) & (np.abs(time - c.time) < max_dt) & ~used & ((lane == c.lane) | (not same_lane))
            pick = np.flatnonzero(cand)
            if pick.size:
                k = pick[np.argmin(np.abs(time[pick] - c.time))]
                used[k] = True
                outcome[i] = "counted" if lane[k] == c.lane else "wrong lane"
    boxed = truth_tracks.dropna(subset=["x1", "y1", "x2", "y2"])
    by_vehicle = truth_tracks.groupby("vehicle").indices
    by_frame = boxed.groupby("frame").indices
    rows = []
    for i, c in enumerate(tc.itertuples(index=False)):
        mine = truth_tracks.iloc[by_vehicle[c.vehicle]] if c.vehicle in by_vehicle else truth_tracks.iloc[:0]
        visible, touching = float("nan"), "none"
        if len(mine):
            me = mine.iloc[int(np.argmin(np.abs(mine["time"].to_numpy() - c.time)))]
            visible = float(me["visible_fraction"])
            if np.isfinite(me[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)).all():
                others = boxed.iloc[by_frame.get(me["frame"], np.zeros(0, dtype=int))]
                others = others[others["vehicle"] != c.vehicle]
                near = others[(others["x1"] < me["x2"] + touch_px) & (others["x2"] > me["x1"] - touch_px)
                              & (others["y1"] < me["y2"] + touch_px) & (others["y2"] > me["y1"] - touch_px)]
                kinds = {("same lane" if o.lane == me["lane"] else "next lane") if o.direction == me["direction"]
                         else "other direction" for o in near.itertuples(index=False)}
                touching = "+".join(sorted(kinds)) or "none"
        rows.append({"line": c.line, "vehicle": c.vehicle, "lane": c.lane, "time": float(c.time),
                     "outcome": outcome[i], "visible": visible, "touching": touching})
    columns = ["line", "vehicle", "lane", "time", "outcome", "visible", "touching"]
    return pd.DataFrame(rows, columns=columns), int((~used).sum())
