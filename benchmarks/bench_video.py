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

import cv2
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
from trafficgeo.video.detections import box_iou
from trafficgeo.video.pipeline import TRACK_COLUMNS, ProcessOptions, settled_options
from trafficgeo.video.reader import iter_frames, video_info
from trafficgeo.video.run import process_video
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


def part_real_frames() -> None:
    """Precision / recall at IoU 0.5 on the hand-labelled real frames (tests/data/*-labels): background
    subtraction (fed every frame of the sequence or clip in order, scored on the labelled ones after its
    warm-up), the learned detector on the full frame, and with a 2 x 2 grid of tiles (no calibration there)."""
    import sys

    sys.path.insert(0, str(ROOT / "tests"))
    from labelled_frames import INTEL_LABELS, NGSIM_LABELS, Score, load_labels, score_frame
    from trafficgeo.video.detectors.factory import make_detector
    from trafficgeo.video.detectors.tiling import TiledDetector, grid_plan

    shared = ROOT.parent / "shared" / "data"
    nanodet = make_detector("nanodet")
    print("\nhand-labelled real frames, precision / recall at IoU 0.5 (all boxes; background subtraction only on "
          "frames after its warm-up):\n\n| frames | background | learned, full frame | learned, 2 x 2 tiles |"
          "\n|---|---|---|---|")
    sets = {"NGSIM US-101 (22 frames, 791 vehicles)": (NGSIM_LABELS, shared / "ngsim-us101-frames", 1.0),
            "Intel parking lot (12 frames, 16 vehicles)": (INTEL_LABELS, shared / "intel-sample-video", 12.5)}
    for title, (folder, source, fps) in sets.items():
        labels = load_labels(folder)
        shape = next(iter(labels.values())).image.shape[:2]
        tiled = TiledDetector(nanodet, grid_plan(shape, 2))
        scores = {"bg": Score(), "full": Score(), "tiled": Score()}
        for frame in labels.values():
            scores["full"] += score_frame(nanodet.detect(frame.image, 0.0).boxes, frame.boxes)
            scores["tiled"] += score_frame(tiled.detect(frame.image, 0.0).boxes, frame.boxes)
        # background subtraction needs the frames before each labelled one, in order
        frames: dict[str, list[tuple[str, np.ndarray]]] = {}
        if folder == NGSIM_LABELS:
            for seq in ("seq2", "seq4"):
                files = sorted((source / seq).glob("frame_*.jpg"))
                frames[seq] = [(f"{seq}_{f.name}", cv2.imread(str(f))) for f in files]
        else:
            table = pd.read_csv(folder / "frames.csv")
            want = dict(zip(table["frame_index"].astype(int), table["image"], strict=True))
            frames["clip"] = [(want.get(f.index, ""), f.image) for f in iter_frames(source / "car-detection.mp4",
                                                                                    end_s=max(want) / fps + 0.1)]
        if not all(frames.values()):
            scores["bg"] = None
        else:
            for items in frames.values():
                bg = make_detector("background")
                for k, (name, image) in enumerate(items):
                    det = bg.detect(image, k / fps)
                    if name in labels and k / fps >= bg.warmup_s:
                        scores["bg"] += score_frame(det.boxes, labels[name].boxes)
        cells = ["-" if sc is None else f"{sc.precision:.2f} / {sc.recall:.2f} (n {sc.tp + sc.fn})"
                 for sc in scores.values()]
        print(f"| {title} | " + " | ".join(cells) + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--world", type=Path, default=ROOT / "out" / "bench-video-world")
    ap.add_argument("--seconds", type=float, default=None, help="process only the first S seconds")
    ap.add_argument("--checkpoint", type=float, default=30.0,
                    help="s of video per checkpoint segment (each starts a fresh background model)")
    ap.add_argument("--parts", default="real,world", help="comma-separated: real (labelled frames), world")
    ap.add_argument("--detectors", default="background,nanodet-full,nanodet@3,nanodet-bands@3",
                    help="comma-separated runs: background, nanodet-full (no tiles), nanodet (square tiles), "
                    "nanodet-bands (zoom bands); '@N' detects every N-th frame (e.g. nanodet@3)")
    ap.add_argument("--camera-height", type=float, default=None,
                    help="build the world with the camera this high (m; default 8) - use with another --world")
    args = ap.parse_args()
    if "real" in args.parts:
        part_real_frames()
    if "world" not in args.parts:
        return
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
    lanes = read_lanes(wdir / "lanes.gpkg", crs=surface.crs)
    lines = read_count_lines(wdir / "count_lines.gpkg", crs=surface.crs)
    truth = pd.read_csv(wdir / "truth_tracks.csv")
    truth_counts = pd.read_csv(wdir / "truth_counts.csv")

    print(f"\ndecode only (PyAV, threaded): {n / t_decode:.1f} frames/s = {n / t_decode / info.fps:.2f}x real time")
    print("\n| detector | frames/s | x real time | vs decode only | precision | recall | per-lane counts | "
          "speed at the lines (bias) |\n|---|---|---|---|---|---|---|---|")
    runs = {}
    for spec in args.detectors.split(","):
        name, _, every = spec.partition("@")
        detector, tiles, tiling = {"background": ("background", False, "squares"),
                                   "nanodet-full": ("nanodet", False, "squares"),
                                   "nanodet": ("nanodet", True, "squares"),
                                   "nanodet-bands": ("nanodet", True, "bands")}[name]
        options = ProcessOptions(detector=detector, end_s=end, checkpoint_s=args.checkpoint, tiles=tiles,
                                 tiling=tiling, every=int(every or 1))
        out = ROOT / "out" / f"bench-video-run-{spec.replace('@', '-')}"
        run = process_video(video, camera, surface, out, lanes, lines, options=options, restart=True)
        detections, result, t_pipe = run.detections, run.traffic, run.seconds  # t_pipe: decode + detect + track
        step = int(every or 1)  # detection ran on frames 0, step, 2 step, ...: scored there
        precision, recall, n_true = detection_scores(detections, truth[(truth["time"] < end)
                                                                       & (truth["frame"] % step == 0)])
        score = count_scores(result.crossings, truth_counts, end_s=end)
        errs = score.speed_errors[np.isfinite(score.speed_errors)]  # tracks seen under 1 s carry no speed
        frames = n / max(int(every or 1), 1)
        suffix = {"2": "nd", "3": "rd"}.get(every, "th")
        label = {"background": "background subtraction", "nanodet-full": "learned (NanoDet), full frame",
                 "nanodet": "learned (NanoDet) + camera-aware tiles",
                 "nanodet-bands": "learned (NanoDet) + zoom bands"}[name] + (f", every {every}{suffix} frame"
                                                                              if every else "")
        print(f"| {label} | {n / t_pipe:.1f} | {n / t_pipe / info.fps:.2f} | {t_decode / t_pipe:.2f} | "
              f"{precision:.1%} | {recall:.1%} ({n_true}) | {score.accuracy:.1%} | {np.mean(np.abs(errs)):.2f} km/h "
              f"({np.mean(errs):+.2f}, {errs.size} of {score.speed_errors.size}) |", flush=True)
        runs[spec] = (detections, result, score, frames)
    print("targets: per-lane counts >= 98 %, speed at the lines <= 1.5 km/h, >= 1.0x real time")
    best = list(runs)[-1]
    detections, result, score, _ = runs[best]
    both = score.table
    print(f"\nthe rest for {best}:")
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
        tracker = VehicleTracker(info.fps, settled_options(ProcessOptions(), info.fps).tracker)
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
