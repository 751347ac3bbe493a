"""Benchmark: where the junction's turning-movement counts are lost between exact boxes and the detector's (issue 39).

For each junction world that ``bench_junction.py`` has run (``out/bench-junction-world-*`` with
``run-process/detections.csv``), the same tracker as ``process --gates`` (``JUNCTION_TRACKER``, on ``process``'s
detection frames) is fed boxes that differ in one thing at a time, and its tracks are analysed with ``analyze
--gates``:

* ``true``: the true box of every vehicle at least 50 % visible;
* ``true, found``: only those the detector found (one of its boxes with IoU >= 0.5, matched one to one);
* ``true ids, detector boxes``: the tracks of ``true, found``, analysed with the detector's matched boxes in place
  of the true ones (what the boxes' scatter costs the analysis alone);
* ``detector, matched``: the detector's matched boxes, tracked and analysed (unmatched boxes left out);
* ``detector ids, true boxes``: the tracks of ``detector, matched``, analysed with the true boxes (what the boxes'
  scatter costs the tracker alone);
* ``detector, all``: every box the detector gave (``process`` re-tracked; its own tracks may differ slightly);
* ``detector ids (all), true boxes``: the tracks of ``detector, all``, analysed with the true box where one matches
  (the detector's boxes that match no true one kept).

With ``--min-iou 0.1,0.3``: only ``detector, all``, once per overlap gate of the tracker (``TrackerOptions.min_iou``;
the junction's is 0.3, the road's 0.1) - how the gate moves the counts on the same detections.

Scored as ``bench_junction.py`` scores (:func:`bench_junction.score`). Run ``python benchmarks/bench_junction_losses.py
[--seeds 5,6,7] [--box-sigma-share 0.05] [--min-iou 0.1,0.3]`` (the analysis's junction default, or the share given).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from bench_junction import OUT, score

BOX = ["x1", "y1", "x2", "y2"]
MIN_IOU = 0.5
MIN_VISIBLE = 0.5


def matched_boxes(world: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The detector's boxes (detections.csv) and the true boxes on its frames, each with ``pair``: the row of the
    other table it is matched to one to one (IoU >= MIN_IOU), -1 where none."""
    from trafficgeo.video.detections import box_iou

    det = pd.read_csv(world / "run-process" / "detections.csv", keep_default_na=False)
    truth = pd.read_csv(world / "truth_tracks.csv")
    w, h = json.loads((world / "camera_truth.json").read_text()).get("image_size", [1920, 1080])
    true = truth[truth["frame"].isin(set(det["frame"]))].copy()
    true[["x1", "x2"]] = true[["x1", "x2"]].clip(0, w - 1)
    true[["y1", "y2"]] = true[["y1", "y2"]].clip(0, h - 1)
    true = true[(true["visible_fraction"] >= MIN_VISIBLE) & (true["x2"] - true["x1"] >= 4)
                & (true["y2"] - true["y1"] >= 4)].reset_index(drop=True)
    det = det.reset_index(drop=True)
    det["pair"], true["pair"] = -1, -1
    by_frame = dict(tuple(true.groupby("frame")))
    for frame, d in det.groupby("frame"):
        t = by_frame.get(frame)
        if t is None:
            continue
        m = box_iou(t[BOX].to_numpy(float)[:, None], d[BOX].to_numpy(float)[None, :])
        ti, di = linear_sum_assignment(-m)
        ok = m[ti, di] >= MIN_IOU
        det.loc[d.index[di[ok]], "pair"] = t.index[ti[ok]]
        true.loc[t.index[ti[ok]], "pair"] = d.index[di[ok]]
    return det, true


def track(world: Path, boxes: pd.DataFrame, frames: np.ndarray, min_iou: float | None = None) -> pd.DataFrame:
    """``boxes`` (frame, x1..y2, score, class, row) through ``process --gates``'s tracker (with its overlap gate
    ``min_iou`` when given); its tracks with each box's ``row`` (the index of the box it came from)."""
    from dataclasses import replace

    from trafficgeo.video import track as vt
    from trafficgeo.video.detections import DetectionFrames
    from trafficgeo.video.pipeline import JUNCTION_TRACKER

    fps = json.loads((world / "world.json").read_text())["options"]["fps"]
    step = int(np.min(np.diff(frames)))
    boxes = boxes.sort_values("frame", kind="stable")
    dets = DetectionFrames(frame_index=frames, time_s=frames / fps, row=np.searchsorted(frames, boxes["frame"]),
                           boxes=boxes[BOX].to_numpy(float), scores=boxes["score"].to_numpy(float),
                           classes=boxes["class"].astype(str).to_numpy(object))
    tracker = JUNCTION_TRACKER if min_iou is None else replace(JUNCTION_TRACKER, min_iou=min_iou)
    out = vt.track_frames(dets, fps / step, tracker).as_written().to_table()
    # each tracked box back to its source row (the tracker writes the detection's own box, to the thousandth)
    out["row"] = -1
    by_frame = dict(tuple(boxes.groupby("frame")))
    for frame, rows in out.groupby("frame"):
        given = by_frame.get(frame)
        if given is None:
            continue
        diff = np.abs(rows[BOX].to_numpy(float)[:, None, :] - given[BOX].to_numpy(float)[None, :, :]).max(axis=2)
        best = diff.argmin(axis=1)
        near = diff[np.arange(len(rows)), best] < 0.01
        out.loc[rows.index[near], "row"] = given["row"].to_numpy()[best[near]]
    if (out["row"] < 0).any():
        print(f"{world.name}: {int((out['row'] < 0).sum())} tracked boxes not found among the inputs", flush=True)
    return out


def analysed(world: Path, name: str, tracks: pd.DataFrame, box_sigma_share: float | None) -> dict[str, object]:
    folder = world / "losses" / name.replace(" ", "_").replace(",", "").replace("(", "").replace(")", "")
    folder.mkdir(parents=True, exist_ok=True)
    tracks.drop(columns=["row"]).to_csv(folder / "tracks.csv", index=False, float_format="%.3f")
    extra = [] if box_sigma_share is None else ["--box-sigma-share", str(box_sigma_share)]
    cmd = [str(Path(sys.executable).with_name("trafficgeo")), "analyze", str(world / "camera_truth.json"),
           str(folder / "tracks.csv"), "--surface", str(world / "dem.tif"), "--gates", str(world / "gates.gpkg"),
           "-o", str(folder / "run"), *extra]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"analyze failed for {folder}:\n{done.stderr[-2000:]}")
    return score(world, folder / "run")


def _row(world: Path, name: str, s: dict[str, object]) -> dict[str, object]:
    return {"world": world.name.replace("bench-junction-world-", ""), "boxes": name,
            "errors": round((1.0 - s["accuracy"]) * s["true"]), **s}


def world_gates(world: Path, ious: list[float], box_sigma_share: float | None) -> list[dict[str, object]]:
    """``detector, all`` once per tracker overlap gate of ``ious``."""
    det = pd.read_csv(world / "run-process" / "detections.csv", keep_default_na=False)
    frames = np.unique(det["frame"])
    rows = []
    for iou in ious:
        name = f"detector, all, IoU {iou:g}"
        rows.append(_row(world, name, analysed(world, name, track(world, det.assign(row=det.index), frames, iou),
                                               box_sigma_share)))
    return rows


def world_losses(world: Path, box_sigma_share: float | None) -> list[dict[str, object]]:
    det, true = matched_boxes(world)
    frames = np.unique(det["frame"])
    true_in = true.assign(score=1.0, row=true.index)
    found = true_in[true_in["pair"] >= 0]
    matched = det[det["pair"] >= 0].assign(row=lambda d: d.index)
    everything = det.assign(row=det.index)

    def swap(tracks: pd.DataFrame, source: pd.DataFrame, into: pd.DataFrame, keep_unmatched: bool) -> pd.DataFrame:
        pair = source["pair"].reindex(tracks["row"]).to_numpy()
        has = np.nan_to_num(pair, nan=-1) >= 0
        out = tracks.copy()
        out.loc[has, BOX] = into.loc[pair[has].astype(int), BOX].to_numpy(float)
        return out if keep_unmatched else out[has]

    runs = {}
    runs["true"] = track(world, true_in, frames)
    runs["true, found"] = track(world, found, frames)
    runs["true ids, detector boxes"] = swap(runs["true, found"], true, det, keep_unmatched=False)
    runs["detector, matched"] = track(world, matched, frames)
    runs["detector ids, true boxes"] = swap(runs["detector, matched"], det, true, keep_unmatched=False)
    runs["detector, all"] = track(world, everything, frames)
    runs["detector ids (all), true boxes"] = swap(runs["detector, all"], det, true, keep_unmatched=True)
    rows = []
    for name, tracks in runs.items():
        rows.append(_row(world, name, analysed(world, name, tracks, box_sigma_share)))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="5,6,7,41,42,43,44,45,46")
    ap.add_argument("--box-sigma-share", type=float, default=None)
    ap.add_argument("--min-iou", default=None, help="tracker overlap gates, e.g. 0.1,0.3: 'detector, all' per gate")
    args = ap.parse_args()
    ious = [float(v) for v in args.min_iou.split(",")] if args.min_iou else None
    rows = []
    for seed in args.seeds.split(","):
        for world in sorted(OUT.glob(f"bench-junction-world-seed{seed}-*")):
            if (world / "run-process" / "detections.csv").is_file():
                found = (world_gates(world, ious, args.box_sigma_share) if ious
                         else world_losses(world, args.box_sigma_share))
                rows += found
                print(pd.DataFrame(found)[["world", "boxes", "true", "accuracy", "errors"]].to_string(index=False),
                      flush=True)
    table = pd.DataFrame(rows)
    pooled = table.groupby("boxes", sort=False)[["true", "errors", "counted", "wrong arm", "incomplete", "missed",
                                                 "duplicates"]].sum()
    pooled.insert(1, "accuracy", 1.0 - pooled["errors"] / pooled["true"])
    with pd.option_context("display.float_format", "{:.3f}".format, "display.width", 200):
        print("\nPooled over the worlds:")
        print(pooled.to_string())


if __name__ == "__main__":
    main()
