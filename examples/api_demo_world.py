"""The whole chain on the demo world through the Python API only (no command line), each figure next to the truth.

    python examples/api_demo_world.py                  # the demo's world (60 s), in demo-out/world if it is there
    python examples/api_demo_world.py --seconds 10     # a shorter world of its own, faster

Steps: GCPs -> calibrate -> the ground from the lidar -> pixels to the ground -> the video processed (detect,
track, georeference, count) -> the counts against the truth -> the observation against the world's SUMO run.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

import trafficgeo as tg
from trafficgeo.demo import DEMO_WORLD
from trafficgeo.synth.scoring import count_scores
from trafficgeo.synth.sumo_world import WARMUP_S
from trafficgeo.synth.world import build_world


def main(argv: list[str] | None = None) -> dict[str, float]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("api-out"), help="output folder")
    ap.add_argument("--world", type=Path, default=None, help="a demo world folder to use (default: demo-out/world "
                    "if it exists, else one built in OUT/world)")
    ap.add_argument("--seconds", type=float, default=None, help="build a world of this many seconds instead")
    args = ap.parse_args(argv)
    out = args.out
    opts = DEMO_WORLD if args.seconds is None else replace(DEMO_WORLD, duration_s=args.seconds)
    world = args.world or (Path("demo-out/world") if args.seconds is None else None)
    if world is None or not (world / "world.json").is_file():
        world = out / "world"
        print(f"building the demo world in {world} ...")
        build_world(world, opts)

    # 1. Calibrate the camera from the GCPs (noisy clicks, planted blunders), check it against the true camera.
    gcps = tg.read_gcps(world / "gcps.csv", crs=opts.crs)
    truth_cam = tg.load_camera(world / "camera_truth.json").camera  # the true projection, to check against
    cal = tg.calibrate(gcps, truth_cam.image_size)
    camera = cal.calibrated_camera()  # the camera and what the calibration knows (it places the headline speeds)
    off_m = float(np.linalg.norm(camera.camera.position - truth_cam.position))
    print(f"calibrated: {int(cal.inlier.sum())} of {len(gcps.ids)} GCPs kept; the camera is {off_m:.2f} m from "
          "its true position")

    # 2. The road surface from the lidar, and the vehicles' true pixels mapped back to the ground.
    surface = tg.load_surface(world / "cloud.laz", camera)
    truth = pd.read_csv(world / "truth_tracks.csv")
    seen = truth[(truth["visible_fraction"] > 0.5) & np.isfinite(truth["u"])].iloc[::25]
    ground = tg.georeference(camera, truth_cam.project(seen[["x", "y", "z"]].to_numpy()), surface)
    err = np.hypot(*(ground.xyz[:, :2] - seen[["x", "y"]].to_numpy()).T)
    print(f"pixels to the ground: median error {np.nanmedian(err):.2f} m over {np.isfinite(err).sum()} points")

    # 3. The video: detect, track, georeference and count (resumable; the run folder holds every table).
    site = tg.Site.load(camera, surface, lanes=world / "lanes.gpkg", lines=world / "count_lines.gpkg")
    run = tg.process_video(world / "video.mp4", site, out / "video", options=tg.ProcessOptions(restart=True))
    knows = run.traffic.options["speed_scale_knowledge"]  # what placed each headline speed: covariance, GCPs
    score = count_scores(run.traffic.crossings, pd.read_csv(world / "truth_counts.csv"))
    errs = score.speed_errors[np.isfinite(score.speed_errors)]
    print(f"video: {run.realtime_factor:.2f}x real time; {int(score.table['counted'].sum())} of "
          f"{int(score.table['true'].sum())} vehicles counted at the lines, per-lane counts {score.accuracy:.1%}, "
          f"speed at the lines {np.mean(np.abs(errs)):.2f} km/h mean abs error; headline speeds placed by {knows}")

    # 4. The observation against the world's own SUMO run.
    cmp = tg.compare_with_sumo(out / "video", world / "sumo" / "fcd.xml", net=world / "sumo" / "road.net.xml",
                               net_crs=opts.crs, time_offset_s=WARMUP_S)
    share = cmp.count_summary["share_geh_below_5"]
    print(f"against the simulation: GEH < 5 for {share:.0%} of line x lane x direction x interval counts")
    vehicles = tg.RunFolder(out / "video").vehicles()
    print(f"vehicles.csv: {len(vehicles)} vehicles, mean speed {vehicles['speed_kmh'].mean():.1f} km/h")
    return {"count_accuracy": score.accuracy, "share_geh_below_5": float(share),
            "ground_median_error_m": float(np.nanmedian(err)), "speed_scale_knowledge": knows}


if __name__ == "__main__":
    main()
