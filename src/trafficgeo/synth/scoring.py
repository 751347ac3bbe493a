"""Scores against the demo world's truth: detections against the rendered boxes, counts and spot speeds against the
true line crossings. Used by ``trafficgeo demo`` and the benchmarks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from trafficgeo.synth.world import truth_lane_name
from trafficgeo.video.detect import box_iou


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
