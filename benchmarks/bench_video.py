"""Benchmark: the video pipeline's speed against decoding alone, and its accuracy on the demo world, in one run.

A demo world is built once (1080p at 30 fps, 60 s, three counting lines; seed 5) into ``out/bench-video-world``.

Part 1, speed (wall clock, this machine's 2 cores): frames per second of

* decoding alone (PyAV, threaded, to BGR arrays) - the ceiling;
* decode + detect (the default background detector) + track (ByteTrack), i.e. ``process`` without ``analyze``;

and their ratio, and the pipeline's speed as a multiple of real time (30 fps). ``analyze`` is timed apart.

Part 2, accuracy against the world's truth, with the true camera and a DEM from the world's lidar:

* detection precision and recall at IoU >= 0.5 against the rendered truth boxes of vehicles at least half visible
  and at least 12 px tall (a detection matching a hidden vehicle is neither);
* the classes: true class against detected class of the detections matched to one vehicle (IoU >= 0.5, any
  visibility), the classes given to detections that match no single vehicle (most hold several), and the
  vehicles of each class in ``vehicles.csv`` against the world's vehicles seen in the time used;
* per-lane counts at the three lines (1 - sum |counted - true| / sum true);
* speed at the lines: each crossing against the true crossing of the same line and lane nearest in time
  (within 0.5 s), mean absolute error;
* what became of each true crossing (counted, in a wrong lane, missed) against which vehicles touch it in the
  image and how visible it is at the line (:func:`trafficgeo.synth.scoring.crossing_outcomes`): the causes.

Part 3, the ceiling set by occlusion and tracking: the same tracker and ``analyze`` fed by an ideal detector
(the true boxes of every vehicle at least 30 / 50 / 70 % visible, exactly;
:func:`trafficgeo.synth.detections.ideal_detections`).

Run ``python benchmarks/bench_video.py [--world DIR] [--seconds S] [--camera-height H]``.
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from trafficgeo.camera.io import read_camera_json
from trafficgeo.geo.load import load_surface
from trafficgeo.synth.detections import ideal_detections
from trafficgeo.synth.scoring import count_scores, crossing_outcomes, detection_scores
from trafficgeo.synth.world import WorldOptions, build_world
from trafficgeo.traffic.analyze import analyze
from trafficgeo.traffic.lanes import read_lanes
from trafficgeo.traffic.lines import read_count_lines
from trafficgeo.traffic.tracks import tracks_from_table
from trafficgeo.video.detect import box_iou
from trafficgeo.video.pipeline import TRACK_COLUMNS, ProcessOptions, detect_and_track
from trafficgeo.video.reader import iter_frames, video_info
from trafficgeo.video.track import VehicleTracker

ROOT = Path(__file__).resolve().parents[1]
WORLD = WorldOptions(seed=5, fps=30.0, duration_s=60.0, count_stations=(-20.0, 20.0, 60.0))


def class_confusion(detections: pd.DataFrame, truth: pd.DataFrame, *, iou: float = 0.5) -> pd.DataFrame:
    """Counts of (true class, detected class) over the detections (``frame, x1, y1, x2, y2, class``) matched
    one-to-one to a truth box of ``truth_tracks.csv`` at IoU >= ``iou`` (greedy, best first); a detection matched
    to none counts under the true class "(none: N vehicles inside)", N the truth boxes whose bottom centre it holds.
    Class "" is shown as "unknown"."""
    truth = truth.dropna(subset=["x1", "y1", "x2", "y2"])
    truth = truth[truth["visible_fraction"] > 0]
    det_groups = detections.groupby("frame").indices
    tru_groups = truth.groupby("frame").indices
    dbox = detections[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    dcls = detections["class"].fillna("").astype(str).replace("", "unknown").to_numpy()
    tbox = truth[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    tcls = truth["class"].astype(str).to_numpy()
    rows = []
    for f, di in det_groups.items():
        ti = tru_groups.get(f, np.zeros(0, dtype=int))
        match = np.full(di.size, -1)
        if ti.size:
            m = box_iou(dbox[di][:, None], tbox[ti][None, :])
            used = set()
            for i, j in sorted(zip(*np.nonzero(m >= iou), strict=True), key=lambda p: -m[p]):
                if match[i] < 0 and j not in used:
                    match[i] = j
                    used.add(j)
        for i, d in enumerate(di):
            if match[i] >= 0:
                rows.append((tcls[ti[match[i]]], dcls[d]))
                continue
            b, t = dbox[d], tbox[ti]
            cx, cy = 0.5 * (t[:, 0] + t[:, 2]), t[:, 3]
            inside = int(np.sum((cx >= b[0] - 2) & (cx <= b[2] + 2) & (cy >= b[1] - 2) & (cy <= b[3] + 2)))
            rows.append((f"(none: {min(inside, 3)}{'+' if inside >= 3 else ''} vehicles inside)", dcls[d]))
    table = pd.DataFrame(rows, columns=["true", "detected"])
    return pd.crosstab(table["true"], table["detected"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--world", type=Path, default=ROOT / "out" / "bench-video-world")
    ap.add_argument("--seconds", type=float, default=None, help="process only the first S seconds")
    ap.add_argument("--checkpoint", type=float, default=30.0,
                    help="s of video per checkpoint segment (each starts a fresh background model)")
    ap.add_argument("--camera-height", type=float, default=None,
                    help="build the world with the camera this high (m; default 8) - use with another --world")
    args = ap.parse_args()
    wdir = args.world
    if not (wdir / "world.json").is_file():
        print(f"building the demo world into {wdir} ...")
        t = time.perf_counter()
        build_world(wdir, WORLD if args.camera_height is None else replace(WORLD, camera_height=args.camera_height))
        print(f"  built in {time.perf_counter() - t:.0f} s")
    video = wdir / "video.mp4"
    info = video_info(video)
    end = args.seconds or info.duration_s
    print(f"python {platform.python_version()} on {platform.machine()}; video {info.width}x{info.height} at "
          f"{info.fps:g} fps, {end:.0f} s used")

    t = time.perf_counter()
    n = sum(1 for _ in iter_frames(video, end_s=end))
    t_decode = time.perf_counter() - t
    camera = read_camera_json(wdir / "camera_truth.json")
    surface = load_surface(str(wdir / "cloud.laz"), camera)
    out = ROOT / "out" / "bench-video-run"
    t = time.perf_counter()
    options = ProcessOptions(end_s=end, checkpoint_s=args.checkpoint)
    detections, tracks = detect_and_track(video, camera, surface, out, options, restart=True)
    t_pipe = time.perf_counter() - t
    lanes = read_lanes(wdir / "lanes.gpkg", crs=surface.crs)
    lines = read_count_lines(wdir / "count_lines.gpkg", crs=surface.crs)
    t = time.perf_counter()
    result = analyze(camera, surface, tracks_from_table(tracks), lanes=lanes, lines=lines)
    t_analyze = time.perf_counter() - t

    print("\n| step | frames/s | x real time | vs decode only |\n|---|---|---|---|")
    print(f"| decode only (PyAV, threaded) | {n / t_decode:.1f} | {n / t_decode / info.fps:.2f} | 1.00 |")
    print(f"| decode + detect + track | {n / t_pipe:.1f} | {n / t_pipe / info.fps:.2f} | "
          f"{t_decode / t_pipe:.2f} |")
    print(f"| analyze ({len(tracks)} track boxes) | {n / t_analyze:.0f} | {n / t_analyze / info.fps:.1f} | |")

    truth = pd.read_csv(wdir / "truth_tracks.csv")
    truth_counts = pd.read_csv(wdir / "truth_counts.csv")
    precision, recall, n_true = detection_scores(detections, truth[truth["time"] < end])
    score = count_scores(result.crossings, truth_counts, end_s=end)
    both, count_acc = score.table, score.accuracy
    n_matched = score.speed_errors.size
    errs = score.speed_errors[np.isfinite(score.speed_errors)]  # tracks seen under 1 s carry no speed
    print("\n| measure | result | target |\n|---|---|---|")
    print(f"| detection precision at IoU 0.5 | {precision:.1%} | |")
    print(f"| detection recall at IoU 0.5 ({n_true} visible vehicle boxes) | {recall:.1%} | |")
    print(f"| per-lane counts, 1 - sum abs err / sum true ({int(both['true'].sum())} true) | {count_acc:.1%} | "
          ">= 98 % |")
    print(f"| speed at the lines, mean abs error ({errs.size} of {n_matched} matched crossings with a speed) | "
          f"{np.mean(np.abs(errs)):.2f} km/h (bias {np.mean(errs):+.2f}) | <= 2 km/h |")
    print("\nclasses of the detections: true class (rows) against detected class (columns):")
    print(class_confusion(detections, truth[truth["time"] < end]).to_string())
    seen = truth[(truth["time"] < end) & (truth["visible_fraction"] > 0)].drop_duplicates("vehicle")
    vehicle_classes = pd.DataFrame({"world (seen)": seen["class"].value_counts(),
                                    "vehicles.csv": result.vehicles["class"].fillna("").astype(str)
                                    .replace("", "unknown").value_counts()}).fillna(0).astype(int)
    print("\nvehicles per class:")
    print(vehicle_classes.to_string())
    print("\ncounts per line and lane:")
    print(both.to_string())

    outcomes, extra = crossing_outcomes(result.crossings, truth_counts, truth)
    outcomes = outcomes[outcomes["time"] < end]
    bad = outcomes["outcome"] != "counted"
    print("\nwhat became of each true crossing, by whose true boxes touch the vehicle's (within 3 px) at the line:")
    print(pd.crosstab(outcomes["touching"], outcomes["outcome"]).to_string())
    print(f"{int((bad & (outcomes['visible'] < 0.3)).sum())} of the {int(bad.sum())} missed or in a wrong lane were "
          f"under 30 % visible at the line; {extra} counted crossings match no true one")

    print("\nthe same tracker and analyze fed by an ideal detector (true boxes of the vehicles at least this visible):")
    print("| seen from | per-lane counts | missed | speed at the lines |\n|---|---|---|---|")
    for min_visible in (0.3, 0.5, 0.7):
        tracker = VehicleTracker(info.fps, ProcessOptions().tracker)
        rows = []
        for frame, time_s, dets in ideal_detections(truth[truth["time"] < end], camera.image_size,
                                                    min_visible=min_visible):
            tracked = tracker.update(dets)
            rows += [(frame, time_s, int(i), *b, s, c) for i, b, s, c in
                     zip(tracked.ids, tracked.boxes, tracked.scores, tracked.classes, strict=True)]
        ideal = analyze(camera, surface, tracks_from_table(pd.DataFrame(rows, columns=TRACK_COLUMNS)),
                        lanes=lanes, lines=lines)
        s_ideal = count_scores(ideal.crossings, truth_counts, end_s=end)
        o_ideal, _ = crossing_outcomes(ideal.crossings, truth_counts, truth)
        o_ideal = o_ideal[o_ideal["time"] < end]
        e = s_ideal.speed_errors[np.isfinite(s_ideal.speed_errors)]
        print(f"| {min_visible:.0%} visible | {s_ideal.accuracy:.1%} | {int((o_ideal['outcome'] != 'counted').sum())} "
              f"of {len(o_ideal)} | {np.mean(np.abs(e)):.2f} km/h |")


if __name__ == "__main__":
    main()
