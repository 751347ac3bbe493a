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


# ------------------------------------------------------------------------------------------------ movements
NEAR_M = 3.0  # m: a run trajectory point this close to a true vehicle's position at the same time is of it


def truth_of_run_vehicles(truth_tracks: pd.DataFrame, points: pd.DataFrame, *, near_m: float = NEAR_M
                          ) -> dict[str, str]:
    """The true vehicle of each run vehicle (``points``: ``track_id, time, x, y`` of trajectories.csv): the one
    within ``near_m`` (CRS units, metres in the generated worlds) of most of its points at the same frame times.
    A run vehicle near no true one is left out (a phantom)."""
    truth = truth_tracks[["time", "vehicle", "x", "y"]].assign(t=np.rint(truth_tracks["time"] * 1000).astype(np.int64))
    pts = points[["track_id", "time", "x", "y"]].assign(track_id=points["track_id"].astype(str),
                                                        t=np.rint(points["time"] * 1000).astype(np.int64))
    m = pts.merge(truth, on="t", suffixes=("", "_true"))
    m = m[np.hypot(m["x"] - m["x_true"], m["y"] - m["y_true"]) < near_m]
    votes = m.groupby(["track_id", "vehicle"]).size().rename("n").reset_index()
    best = votes.sort_values("n", ascending=False, kind="stable").drop_duplicates("track_id")
    return dict(zip(best["track_id"], best["vehicle"].astype(str), strict=True))


@dataclass(frozen=True)
class MovementScores:
    """Turning movements against the truth of a junction world, over the vehicles that entered and left during
    the run: ``table`` (origin, destination, true, counted), ``accuracy`` (1 - sum |counted - true| / sum true),
    the heavy-vehicle shares (%), and what became of each true vehicle (``outcomes``: counted, wrong arm,
    incomplete, missed) with the run's ``duplicates`` and ``phantoms``."""

    table: pd.DataFrame
    accuracy: float
    heavy_true_pct: float
    heavy_counted_pct: float
    outcomes: dict[str, int]
    duplicates: int
    phantoms: int


def movement_scores(truth_movements: pd.DataFrame, movements: pd.DataFrame, vehicle_of: dict[str, str], *,
                    end_s: float | None = None) -> MovementScores:
    """Score ``movements`` (movements.csv) against ``truth_movements`` (truth_movements.csv, read with
    ``keep_default_na=False``), the run's vehicles matched to true ones by ``vehicle_of``
    (:func:`truth_of_run_vehicles`; a movement of joined halves takes its first track's). Only true vehicles that
    entered and left (before ``end_s``) are scored; run movements of other true vehicles (already inside when the
    run began, still inside at its end) are left out, those of no true vehicle count as phantoms."""
    heavy = ("truck", "bus")
    both = truth_movements[(truth_movements["entry_time"] != "") & (truth_movements["exit_time"] != "")]
    if end_s is not None:
        both = both[both["exit_time"].astype(float) < end_s]
    scored = set(both["vehicle"].astype(str))
    moves = movements.assign(track_id=movements["track_id"].astype(str))
    ids = moves["track_ids"].astype(str) if "track_ids" in moves.columns else moves["track_id"]
    moves["vehicle"] = [next((vehicle_of[t] for t in i.split(";") if t in vehicle_of), "") for i in ids]
    complete = moves["complete"].astype(str).str.lower().isin(("true", "1"))
    done = moves[complete & (moves["vehicle"].isin(scored) | (moves["vehicle"] == ""))]
    key = ["origin", "destination"]
    table = pd.concat([both.groupby(key).size().rename("true"), done.groupby(key).size().rename("counted")],
                      axis=1).fillna(0).astype(int).reset_index()
    accuracy = 1.0 - float((table["counted"] - table["true"]).abs().sum()) / max(int(table["true"].sum()), 1)
    outcomes = {"counted": 0, "wrong arm": 0, "incomplete": 0, "missed": 0}
    for _, t in both.iterrows():
        mine = moves[moves["vehicle"] == str(t["vehicle"])]
        whole = mine[complete[mine.index]]
        right = (whole["origin"] == t["origin"]) & (whole["destination"] == t["destination"])
        key_ = "counted" if right.any() else "wrong arm" if len(whole) else "incomplete" if len(mine) else "missed"
        outcomes[key_] += 1
    return MovementScores(
        table, accuracy,
        100.0 * float(both["class"].isin(heavy).mean()) if len(both) else float("nan"),
        100.0 * float(done["class"].isin(heavy).mean()) if len(done) else float("nan"),
        outcomes, int(done[done["vehicle"] != ""].duplicated("vehicle").sum()), int((done["vehicle"] == "").sum()))
