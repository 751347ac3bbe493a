"""Benchmark: the video pipeline's speed against decoding alone, and its accuracy on the demo world, in one run.

A demo world is built once (1080p at 30 fps, 60 s, three counting lines; seed 5) into ``out/bench-video-world``.

Part 1, speed (wall clock, this machine's 2 cores): frames per second of

* decoding alone (PyAV, threaded, to BGR arrays) - the ceiling;
* decode + detect (the default background detector) + track (ByteTrack), i.e. ``process`` without ``analyze``;

and their ratio, and the pipeline's speed as a multiple of real time (30 fps). ``analyze`` is timed apart.

Part 2, accuracy against the world's truth, with the true camera and a DEM from the world's lidar:

* detection precision and recall at IoU >= 0.5 against the rendered truth boxes of vehicles at least half visible
  and at least 12 px tall (a detection matching a hidden vehicle is neither);
* per-lane counts at the three lines (1 - sum |counted - true| / sum true);
* speed at the lines: each crossing against the true crossing of the same line and lane nearest in time
  (within 0.5 s), mean absolute error.

Run ``python benchmarks/bench_video.py [--world DIR] [--seconds S]``.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np
import pandas as pd

from trafficgeo.camera.io import read_camera_json
from trafficgeo.geo.load import load_surface
from trafficgeo.synth.world import WorldOptions, build_world, truth_lane_name
from trafficgeo.traffic.analyze import analyze
from trafficgeo.traffic.lanes import read_lanes
from trafficgeo.traffic.lines import read_count_lines
from trafficgeo.video.pipeline import ProcessOptions, detect_and_track, tracks_table_to_image_tracks
from trafficgeo.video.reader import iter_frames, video_info

ROOT = Path(__file__).resolve().parents[1]
WORLD = WorldOptions(seed=5, fps=30.0, duration_s=60.0, count_stations=(-20.0, 20.0, 60.0))


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    x1 = np.maximum(a[:, None, 0], b[None, :, 0])
    y1 = np.maximum(a[:, None, 1], b[None, :, 1])
    x2 = np.minimum(a[:, None, 2], b[None, :, 2])
    y2 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area = lambda r: (r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])  # noqa: E731
    return inter / np.maximum(area(a)[:, None] + area(b)[None, :] - inter, 1e-9)


def detection_scores(detections: pd.DataFrame, truth: pd.DataFrame, fps: float) -> tuple[float, float, int]:
    """Precision and recall at IoU >= 0.5 (greedy by IoU), over frames with detections or truth."""
    det = detections.groupby("frame")
    tru = truth.groupby("frame")
    tp = fp = fn = 0
    for f in sorted(set(detections["frame"]) | set(truth["frame"])):
        d = det.get_group(f)[["x1", "y1", "x2", "y2"]].to_numpy() if f in det.groups else np.zeros((0, 4))
        g = tru.get_group(f) if f in tru.groups else truth.iloc[:0]
        gb = g[["x1", "y1", "x2", "y2"]].to_numpy()
        counted = g["counted"].to_numpy()
        matched_d = np.zeros(len(d), dtype=bool)
        matched_g = np.zeros(len(gb), dtype=bool)
        if len(d) and len(gb):
            iou = _iou(d, gb)
            for i, j in sorted(zip(*np.nonzero(iou >= 0.5), strict=True), key=lambda p: -iou[p]):
                if not matched_d[i] and not matched_g[j]:
                    matched_d[i] = matched_g[j] = True
        tp += int(np.sum(matched_g & counted))
        fn += int(np.sum(~matched_g & counted))
        # a detection matching a vehicle too hidden or small to be required is not a false positive
        fp += int(np.sum(~matched_d))
    return tp / max(tp + fp, 1), tp / max(tp + fn, 1), tp + fn


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--world", type=Path, default=ROOT / "out" / "bench-video-world")
    ap.add_argument("--seconds", type=float, default=None, help="process only the first S seconds")
    args = ap.parse_args()
    wdir = args.world
    if not (wdir / "world.json").is_file():
        print(f"building the demo world into {wdir} ...")
        t = time.perf_counter()
        build_world(wdir, WORLD)
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
    detections, tracks = detect_and_track(video, camera, surface, out, ProcessOptions(end_s=end), restart=True)
    t_pipe = time.perf_counter() - t
    lanes = read_lanes(wdir / "lanes.gpkg", crs=surface.crs)
    lines = read_count_lines(wdir / "count_lines.gpkg", crs=surface.crs)
    t = time.perf_counter()
    result = analyze(camera, surface, tracks_table_to_image_tracks(tracks), lanes=lanes, lines=lines)
    t_analyze = time.perf_counter() - t

    print("\n| step | frames/s | x real time | vs decode only |\n|---|---|---|---|")
    print(f"| decode only (PyAV, threaded) | {n / t_decode:.1f} | {n / t_decode / info.fps:.2f} | 1.00 |")
    print(f"| decode + detect + track | {n / t_pipe:.1f} | {n / t_pipe / info.fps:.2f} | "
          f"{t_decode / t_pipe:.2f} |")
    print(f"| analyze ({len(tracks)} track boxes) | {n / t_analyze:.0f} | {n / t_analyze / info.fps:.1f} | |")

    truth = pd.read_csv(wdir / "truth_tracks.csv")
    truth = truth[truth["time"] < end]
    boxes = truth.dropna(subset=["x1", "y1", "x2", "y2"]).copy()
    boxes["counted"] = (boxes["visible_fraction"] >= 0.5) & (boxes["y2"] - boxes["y1"] >= 12)
    precision, recall, n_true = detection_scores(detections, boxes, info.fps)
    tc = pd.read_csv(wdir / "truth_counts.csv")
    tc = tc[tc["time"] < end]
    tc["lane_name"] = truth_lane_name(tc["direction"], tc["lane"])
    true_counts = tc.groupby([tc["line"].astype(str), "lane_name"]).size()
    counted = result.crossings.groupby(["line", "lane"]).size()
    both = pd.concat([true_counts.rename("true"), counted.rename("counted")], axis=1).fillna(0).astype(int)
    count_acc = 1 - np.abs(both["counted"] - both["true"]).sum() / max(both["true"].sum(), 1)
    # speeds at the lines: match each crossing to the true crossing of the same line, lane and nearest time
    errs = []
    for (line, lane), g in result.crossings.groupby(["line", "lane"]):
        tg = tc[(tc["line"].astype(str) == line) & (tc["lane_name"] == lane)]
        for _, c in g.iterrows():
            if len(tg):
                k = int(np.argmin(np.abs(tg["time"].to_numpy() - c["time"])))
                if abs(tg["time"].iloc[k] - c["time"]) < 0.5:
                    errs.append(c["speed_kmh"] - tg["speed_kmh"].iloc[k])
    errs = np.asarray(errs)
    n_matched = errs.size
    errs = errs[np.isfinite(errs)]  # tracks seen under 1 s carry no speed
    print("\n| measure | result | target |\n|---|---|---|")
    print(f"| detection precision at IoU 0.5 | {precision:.1%} | |")
    print(f"| detection recall at IoU 0.5 ({n_true} visible vehicle boxes) | {recall:.1%} | |")
    print(f"| per-lane counts, 1 - sum abs err / sum true ({int(both['true'].sum())} true) | {count_acc:.1%} | "
          ">= 98 % |")
    print(f"| speed at the lines, mean abs error ({errs.size} of {n_matched} matched crossings with a speed) | "
          f"{np.mean(np.abs(errs)):.2f} km/h (bias {np.mean(errs):+.2f}) | <= 2 km/h |")
    print("\ncounts per line and lane:")
    print(both.to_string())


if __name__ == "__main__":
    main()
