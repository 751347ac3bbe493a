"""Benchmark: turning-movement counts on generated junction worlds, against the simulation's truth (issue 39).

Each world (:func:`trafficgeo.synth.junction_world.build_junction_world`: a signalised four-arm SUMO junction, 2
lanes each way, a camera on a pole at a corner) is built once into ``out/bench-junction-world-seed<N>-<camera>``.
The movement rules were written against constructed paths (tests/test_movements.py) and checked on development
seeds (marked in the table): 5-7 first, then 41-46, 51-58, 59-66, 67-74, 75-78, 79-82, 83-86 and 87-90 once
their held-out figures had been taken (59-62 at the sixth pass and again at the seventh, 63-66 at the seventh,
67-74 at the eighth, 75-78 at the ninth, 79-82 at the tenth, 83-86 at the eleventh, 87-90 at the twelfth:
benchmarks/README.md); a new figure needs seeds never run before (91 on).
Where the counts are lost between exact boxes and the detector's: ``bench_junction_losses.py``.

Per world, side by side on the same truth:

* ``ideal`` - the true footprint centres of every vehicle in the frame, every frame, through ``analyze --gates``:
  the ceiling set by the gates, the path rules and the journeys (a vehicle hidden by another is still "seen");
* ``ideal detector`` - the true boxes of every vehicle at least 50 % visible, exactly, through the default tracker
  (ByteTrack) and ``analyze --gates``: what the tracker, occlusion and the movement rules lose;
* ``process`` - the default ``trafficgeo process --gates`` (learned detector, its default schedule and backend) on
  the rendered video.

Scored over the vehicles that entered and left during the video (truth_movements.csv with both gate times):

* per-movement counts: ``1 - sum |counted - true| / sum true`` over origin x destination (the issue's target:
  >= 95 %), the complete movements counted by the run over the same time window (entry time, else first seen,
  within the video);
* heavy-vehicle share (trucks and buses) of those movements, true against counted (target: within 3 points);
* what became of each true vehicle (the run's vehicles are matched to the true ones by their trajectories: the
  true vehicle within 3 m at most of its points): counted with its true arms, counted with a wrong arm, incomplete
  (an end unknown: not counted), or missed (no run vehicle); and the run's duplicates (a second complete movement
  of one vehicle) and phantoms (complete movements of no true vehicle);
* x real time of ``process`` and the CPU it ran on.

Run ``python benchmarks/bench_junction.py [--seeds 41,42] [--seconds 180] [--cameras pole12,pole18]
[--reanalyze]`` (cameras are paired with the seeds in turn).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

from bench_video import cpu_flags  # this machine's CPU and SIMD flags, as the video benchmark prints them

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "out"
DEVELOPMENT_SEEDS = {5, 6, 7, *range(41, 47), *range(51, 91)}  # rules and defaults were developed on these
CAMERAS = {  # name -> JunctionOptions fields
    "pole12": {"camera_height": 12.0, "camera_corner": "SE"},
    "pole18": {"camera_height": 18.0, "camera_corner": "NW", "azimuth_deg": -10.0},
}
HEAVY = ("truck", "bus")


def build(seed: int, camera: str, seconds: float) -> Path:
    from trafficgeo.synth.junction_sumo import JunctionOptions
    from trafficgeo.synth.junction_world import build_junction_world

    folder = OUT / f"bench-junction-world-seed{seed}-{camera}-{seconds:g}s"
    if not (folder / "world.json").is_file() or not (folder / "video.mp4").is_file():
        t = time.perf_counter()
        build_junction_world(folder, JunctionOptions(seed=seed, duration_s=seconds, **CAMERAS[camera]))
        print(f"built {folder.name} in {time.perf_counter() - t:.0f} s", flush=True)
    return folder


def trafficgeo(*args: object) -> float:
    t = time.perf_counter()
    done = subprocess.run([str(Path(sys.executable).with_name("trafficgeo")), *map(str, args)], capture_output=True,
                          text=True)
    if done.returncode != 0:
        raise SystemExit(f"trafficgeo {' '.join(map(str, args[:2]))} failed:\n{done.stderr[-2000:]}")
    return time.perf_counter() - t


def ideal_run(world: Path) -> Path:
    run = world / "run-ideal"
    if not (run / "movements.csv").is_file():
        truth = pd.read_csv(world / "truth_tracks.csv")
        cam = json.loads((world / "camera_truth.json").read_text())
        w, h = cam.get("image_size", [1920, 1080])
        seen = truth[(truth["u"] >= 0) & (truth["u"] < w) & (truth["v"] >= 0) & (truth["v"] < h)]
        seen.rename(columns={"vehicle": "track_id"})[["frame", "time", "track_id", "u", "v", "class"]].to_csv(
            world / "ideal_tracks.csv", index=False)
        trafficgeo("analyze", world / "camera_truth.json", world / "ideal_tracks.csv", "--surface", world / "dem.tif",
                   "--gates", world / "gates.gpkg", "-o", run)
    return run


def ideal_detector_run(world: Path) -> Path:
    from trafficgeo.camera.calibrated import read_camera_json
    from trafficgeo.run.tracks import TRACK_COLUMNS
    from trafficgeo.synth.detections import ideal_detections
    from trafficgeo.video.pipeline import ProcessOptions, settled_options
    from trafficgeo.video.track import VehicleTracker

    run = world / "run-ideal-detector"
    if not (run / "movements.csv").is_file():
        truth = pd.read_csv(world / "truth_tracks.csv")
        camera = read_camera_json(world / "camera_truth.json")
        fps = json.loads((world / "world.json").read_text())["options"]["fps"]
        tracker = VehicleTracker(fps, settled_options(ProcessOptions(), fps).tracker)
        rows = []
        for frame, time_s, dets in ideal_detections(truth, camera.image_size, min_visible=0.5):
            tracked = tracker.update(dets)
            rows += [(frame, time_s, int(i), *b, sc, c) for i, b, sc, c in
                     zip(tracked.track_ids, tracked.boxes, tracked.scores, tracked.classes, strict=True)]
        pd.DataFrame(rows, columns=list(TRACK_COLUMNS)).to_csv(world / "ideal_detector_tracks.csv", index=False)
        trafficgeo("analyze", world / "camera_truth.json", world / "ideal_detector_tracks.csv", "--surface",
                   world / "dem.tif", "--gates", world / "gates.gpkg", "-o", run)
    return run


def process_run(world: Path, reanalyze: bool = False) -> tuple[Path, float | None]:
    """The default ``process --gates`` run (kept between runs of the benchmark); with ``reanalyze``, its tracks
    (tracks.csv) analysed again by the current code into ``run-process-analysis`` - what ``process`` gives now when
    only the analysis changed (detection and tracking are not re-run)."""
    run = world / "run-process"
    seconds = None
    if not (run / "movements.csv").is_file():
        seconds = trafficgeo("process", world / "video.mp4", "--camera", world / "camera_truth.json", "--surface",
                             world / "dem.tif", "--gates", world / "gates.gpkg", "-o", run)
    if reanalyze:
        again = world / "run-process-analysis"
        trafficgeo("analyze", world / "camera_truth.json", run / "tracks.csv", "--surface", world / "dem.tif",
                   "--gates", world / "gates.gpkg", "-o", again)
        return again, seconds
    return run, seconds


def score(world: Path, run: Path) -> dict[str, object]:
    """Per-movement counts and outcomes (module docstring; :func:`trafficgeo.synth.scoring.movement_scores`, the run's
    vehicles matched to the true ones by their trajectories)."""
    from trafficgeo.synth.scoring import movement_scores, truth_of_run_vehicles

    truth = pd.read_csv(world / "truth_movements.csv", keep_default_na=False)
    moves = pd.read_csv(run / "movements.csv", keep_default_na=False, dtype={"track_id": str, "track_ids": str})
    of = truth_of_run_vehicles(pd.read_csv(world / "truth_tracks.csv"),
                               pd.read_csv(run / "trajectories.csv", dtype={"track_id": str}))
    s = movement_scores(truth, moves, of)
    done = moves[moves["complete"].astype(str).str.lower() == "true"]
    return {"true": int(s.table["true"].sum()), "run_complete": int(s.table["counted"].sum()),
            "accuracy": s.accuracy, "heavy_true": s.heavy_true_pct, "heavy_got": s.heavy_counted_pct, **s.outcomes,
            "duplicates": s.duplicates, "phantoms": s.phantoms,
            "by_path": int(((done["origin_by"] == "path") | (done["destination_by"] == "path")).sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="41,42")
    ap.add_argument("--cameras", default="pole12,pole18")
    ap.add_argument("--seconds", type=float, default=180.0)
    ap.add_argument("--reanalyze", action="store_true",
                    help="analyse the kept process runs' tracks again with the current code")
    args = ap.parse_args()
    print(f"CPU: {cpu_flags()}")
    rows = []
    seeds = [int(s) for s in args.seeds.split(",")]
    cameras = args.cameras.split(",")
    for seed, camera in zip(seeds, cameras * len(seeds), strict=False):
        world = build(seed, camera, args.seconds)
        runs = (("ideal points", (ideal_run(world), None)), ("ideal detector", (ideal_detector_run(world), None)),
                ("process", process_run(world, args.reanalyze)))
        for name, (run, seconds) in runs:
            s = score(world, run)
            s.update(world=f"seed {seed}{' (dev)' if seed in DEVELOPMENT_SEEDS else ''}, {camera}", run=name,
                     x_real_time=(args.seconds / seconds) if seconds else None)
            rows.append(s)
            print(pd.DataFrame([s]).to_string(index=False), flush=True)
    table = pd.DataFrame(rows)[["world", "run", "true", "run_complete", "accuracy", "heavy_true", "heavy_got",
                                "counted", "wrong arm", "incomplete", "missed", "duplicates", "phantoms", "by_path",
                                "x_real_time"]]
    with pd.option_context("display.float_format", "{:.3f}".format, "display.width", 200):
        print("\nPer-movement counts (vehicles that entered and left in the video), ideal vs process:")
        print(table.to_string(index=False))


if __name__ == "__main__":
    main()
