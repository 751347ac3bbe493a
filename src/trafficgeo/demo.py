"""``trafficgeo demo``: everything that exists, run on the demo world, every result compared with the truth.

The demo world (:mod:`trafficgeo.synth.world`) is built once and cached in ``OUT/world`` (rebuilt when its options
change): SUMO traffic on a crowned road, an orthophoto, lidar, a roadside 1080p camera with lens distortion, an
H.264 video, noisy GCPs with planted blunders (wrong clicks and a lidar Z from a tree), and the truth. The demo
then checks the GCP heights against the lidar, calibrates the camera from the GCPs, builds a ground DEM from the
lidar, maps the vehicles' true ground points (as a perfect detector would report them) to the ground on the DEM
and on the GCP plane, and writes the accuracy map and the site as GIS layers; the orthophoto then refines the
camera (``refine``: the video's still without traffic matched to the orthophoto, judged by the GCPs). Then
traffic: simulated tracker output (truth boxes with a detector's and tracker's faults,
:mod:`trafficgeo.synth.detections`) goes through ``analyze`` (speeds, lanes, counts at three counting lines) and
``compare-sumo`` against the world's SUMO run.
Finally the whole chain runs on the video itself (``process``: decode, the built-in learned detector, ByteTrack,
analyze), and the loop is closed: the video's counts become SUMO demand on the world's network (routeSampler),
SUMO runs it, and the simulated counts are compared with the video's and with the truth (GEH); the scenario stays
in ``OUT/sumo`` for sumo-gui. Every result is printed next to the truth, and ``report.html`` shows them all on one
page.
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pandas as pd
from rich.console import Console
from rich.table import Table

from trafficgeo.calibration import read_gcps, run_calibration
from trafficgeo.camera.calibrated import CalibratedCamera, read_camera_json
from trafficgeo.report.terminal import print_calibration_report
from trafficgeo.synth.world import WorldOptions, build_world

DEMO_WORLD = WorldOptions(seed=7, n_outliers=2, n_z_outliers=1, count_stations=(-20.0, 20.0, 60.0))


def _angle_diff(a: float, b: float) -> float:
    return float((a - b + 180.0) % 360.0 - 180.0)


def _cached_world(folder: Path, opts: WorldOptions, con: Console, rebuild: bool) -> dict:
    """Build the world unless ``folder`` already holds one made with the same options."""
    meta = folder / "world.json"
    wanted = json.loads(json.dumps({k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(opts).items()}))
    if not rebuild and meta.is_file():
        summary = json.loads(meta.read_text(encoding="utf-8"))
        if summary.get("options") == wanted and (folder / "video.mp4").is_file():
            con.print(f"reusing the demo world in {folder}")
            return summary
    from rich.progress import BarColumn, Progress, TimeRemainingColumn

    con.print(f"$ trafficgeo synth --out {folder} --seed {opts.seed} --duration {opts.duration_s:g} ...")
    with Progress("[progress.description]{task.description}", BarColumn(), "{task.completed}/{task.total} frames",
                  TimeRemainingColumn(), console=con, transient=True) as progress:
        task = progress.add_task("building the demo world", total=None)
        return build_world(folder, opts, progress=lambda i, n: progress.update(task, completed=i, total=n))


def run_demo(out: Path, *, seed: int = 7, console: Console | None = None, world: WorldOptions | None = None,
             rebuild: bool = False) -> dict[str, float]:
    """Build (or reuse) the demo world in ``out/world`` and run calibration and georeferencing on it.

    Returns the comparison with the truth as a dictionary.
    """
    con = console or Console()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    opts = world or replace(DEMO_WORLD, seed=seed)
    wdir = out / "world"
    summary = _cached_world(wdir, opts, con, rebuild)
    con.print(f"[bold]trafficgeo demo[/bold]: {summary['vehicles']} vehicles in {summary['frames']} frames, "
              f"{summary['gcps']} GCPs ({opts.n_outliers} wrong clicks and {opts.n_z_outliers} lidar Z blunder "
              f"planted) in {wdir}")
    truth_cam = read_camera_json(wdir / "camera_truth.json")
    size = truth_cam.image_size

    # 1. GCP heights against the lidar.
    from trafficgeo.geo.georef import check_gcp_heights
    from trafficgeo.geo.pointcloud import GroundIndex, cloud_to_dem, read_point_cloud
    from trafficgeo.io.tables import write_point_table

    cloud = read_point_cloud(wdir / "cloud.laz")
    checked = check_gcp_heights(pd.read_csv(wdir / "gcps.csv"), GroundIndex.from_cloud(cloud), cloud.crs)
    write_point_table(out / "gcps_z.csv", checked, None)
    flagged = checked[checked["z_check"].isin(["disagrees", "rough"])]
    con.print(f"$ trafficgeo gcp-z {wdir / 'gcps.csv'} --cloud {wdir / 'cloud.laz'} -o {out / 'gcps_z.csv'}")
    for _, row in flagged.iterrows():
        con.print(f"  GCP {row['id']}: {row['z_check']}, z - ground = {row['dz_m']:+.2f} m")

    # 2. Calibration from the noisy GCPs.
    con.print(f"$ trafficgeo calibrate {wdir / 'gcps.csv'} --image-size {size[0]}x{size[1]} --crs {opts.crs} "
              f"-o {out / 'camera.json'} --report {out / 'report.json'}\n")
    gcps = read_gcps(wdir / "gcps.csv", crs=opts.crs)
    run = run_calibration(gcps, size, camera_path=out / "camera.json", report_path=out / "report.json")
    print_calibration_report(run.report, con)
    calibrated = CalibratedCamera.read(out / "camera.json")
    cam = calibrated.camera

    # 3. Ground DEM from the lidar, and the vehicles' true ground points mapped back to the ground.
    from trafficgeo.geo.georef import georeference_table
    from trafficgeo.geo.raster import write_geotiff
    from trafficgeo.geo.uncertainty import accuracy_grid, footprint_polygon, ground_uncertainty
    from trafficgeo.io.gis import write_gis
    from trafficgeo.site.layers import site_layers
    from trafficgeo.site.surface import load_surface

    dem = cloud_to_dem(cloud, 0.25)
    write_geotiff(out / "dem.tif", dem.data, dem.transform, dem.crs, nodata=float("nan"),
                  descriptions=dem.descriptions)
    con.print(f"$ trafficgeo dem {wdir / 'cloud.laz'} --resolution 0.25 -o {out / 'dem.tif'}")
    tracks = pd.read_csv(wdir / "truth_tracks.csv")
    seen = tracks[(tracks["visible_fraction"] > 0.5) & np.isfinite(tracks["u"])]
    seen = seen[truth_cam.in_image(seen[["u", "v"]].to_numpy(), margin=2)].iloc[::5]
    pixels = seen[["frame", "vehicle", "u", "v"]].reset_index(drop=True)
    pixels.to_csv(out / "vehicle_pixels.csv", index=False)
    truth_xyz = seen[["x", "y", "z"]].to_numpy()
    dist = np.hypot(truth_xyz[:, 0] - truth_cam.position[0], truth_xyz[:, 1] - truth_cam.position[1])
    # The video's ground points include the camera shake; without it they are the true camera's projections.
    steady = pixels.copy()
    steady[["u", "v"]] = truth_cam.project(truth_xyz)
    shake_rms = float(np.sqrt(np.mean((pixels[["u", "v"]].to_numpy() - steady[["u", "v"]].to_numpy()) ** 2)))
    errors = {}
    for label, spec in (("DEM", str(out / "dem.tif")), ("GCP plane", "plane")):
        surf = load_surface(spec, calibrated)
        world = georeference_table(cam, pixels, surf)
        name = "vehicles_world_dem.gpkg" if label == "DEM" else "vehicles_world_plane.csv"
        write_point_table(out / name, world, cam.crs and surf.crs)
        con.print(f"$ trafficgeo georef {out / 'camera.json'} {out / 'vehicle_pixels.csv'} --surface {spec} "
                  f"-o {out / name}")
        errors[label] = np.hypot(*(world[["x", "y"]].to_numpy() - truth_xyz[:, :2]).T)
        steady_world = georeference_table(cam, steady, surf)
        errors[label + " steady"] = np.hypot(*(steady_world[["x", "y"]].to_numpy() - truth_xyz[:, :2]).T)
    surf = load_surface(str(out / "dem.tif"), calibrated)
    cov = calibrated.covariance
    grid = accuracy_grid(cam, surf, cov, pixel_sigma=1.0, max_distance_m=150.0)
    write_geotiff(out / "accuracy.tif", grid.bands, grid.transform, grid.crs, nodata=float("nan"),
                  descriptions=grid.band_names)
    foot = footprint_polygon(grid)
    write_gis(out / "site.gpkg", site_layers(calibrated, foot), cam.crs)
    con.print(f"$ trafficgeo accuracy {out / 'camera.json'} --surface {out / 'dem.tif'} -o {out / 'accuracy.tif'} "
              f"--gis {out / 'site.gpkg'} --max-distance 150")
    predicted_steady = ground_uncertainty(cam, steady[["u", "v"]].to_numpy(), surf, cov, 0.0).radial_m
    predicted = ground_uncertainty(cam, pixels[["u", "v"]].to_numpy(), surf, cov, shake_rms).radial_m

    # 4. The comparison.
    o, ot = cam.orientation, truth_cam.orientation
    blunder_ids = set(checked.loc[checked["z_check"] == "disagrees", "id"])
    inl = run.calibration.inlier
    flagged_px = {g for g, ok, role in zip(gcps.ids, inl, gcps.roles, strict=True) if role == "control" and not ok}
    cmp = {
        "position_error_m": float(np.linalg.norm(cam.position - truth_cam.position)),
        "focal_error_pct": float(100 * (cam.focal_px - truth_cam.focal_px) / truth_cam.focal_px),
        "heading_error_deg": _angle_diff(o.heading_deg, ot.heading_deg),
        "tilt_error_deg": o.tilt_deg - ot.tilt_deg,
        "roll_error_deg": o.roll_deg - ot.roll_deg,
        "ground_median_dem_m": float(np.nanmedian(errors["DEM"])),
        "ground_median_plane_m": float(np.nanmedian(errors["GCP plane"])),
        "gcps_flagged_by_lidar": len(blunder_ids),
        "gcps_rejected_by_calibration": len(flagged_px),
    }
    t = Table(title="Demo world: estimate vs truth")
    for col, just in (("quantity", "left"), ("estimate", "right"), ("truth", "right"), ("error", "right")):
        t.add_column(col, justify=just)  # type: ignore[arg-type]
    t.add_row("camera X, Y, Z", ", ".join(f"{v:.2f}" for v in cam.position),
              ", ".join(f"{v:.2f}" for v in truth_cam.position), f"{cmp['position_error_m']:.3f} m")
    t.add_row("focal (px)", f"{cam.focal_px:.1f}", f"{truth_cam.focal_px:.1f}", f"{cmp['focal_error_pct']:+.2f} %")
    t.add_row("k1, k2", f"{cam.dist[0]:.4f}, {cam.dist[1]:.4f}", f"{truth_cam.dist[0]:.4f}, {truth_cam.dist[1]:.4f}",
              "")
    t.add_row("heading / tilt / roll (deg)", f"{o.heading_deg:.2f} / {o.tilt_deg:.2f} / {o.roll_deg:.2f}",
              f"{ot.heading_deg:.2f} / {ot.tilt_deg:.2f} / {ot.roll_deg:.2f}",
              f"{cmp['heading_error_deg']:+.3f} / {cmp['tilt_error_deg']:+.3f} / {cmp['roll_error_deg']:+.3f}")
    t.add_row("GCP Z flagged by the lidar (disagrees)", ", ".join(sorted(blunder_ids)) or "-",
              f"{opts.n_z_outliers} blunder + pole tops", "")
    t.add_row("GCPs rejected by the calibration", ", ".join(sorted(flagged_px)) or "-",
              f"{opts.n_outliers} wrong clicks + {opts.n_z_outliers} Z blunder", "")
    for lo, hi in ((0, 40), (40, 80), (80, 200)):
        band = (dist >= lo) & (dist < hi)
        if band.any():
            t.add_row(f"vehicle ground points {lo}-{hi} m ({int(band.sum())}), steady camera: DEM / GCP plane",
                      f"{np.nanmedian(errors['DEM steady'][band]):.3f} / "
                      f"{np.nanmedian(errors['GCP plane steady'][band]):.3f} m",
                      f"predicted {np.nanmedian(predicted_steady[band]):.3f} m", "median horizontal")
            t.add_row(f"  same, as seen in the video (shake {shake_rms:.2f} px RMS): DEM / GCP plane",
                      f"{np.nanmedian(errors['DEM'][band]):.3f} / {np.nanmedian(errors['GCP plane'][band]):.3f} m",
                      f"predicted {np.nanmedian(predicted[band]):.3f} m", "")
    con.print(t)
    cmp.update(_refine(out, wdir, surf, truth_cam, steady, truth_xyz, dist, con))
    cmp.update(_traffic(out, wdir, cam, surf, opts, con))
    cmp.update(_video(out, wdir, cam, surf, con))
    cmp.update(_simulation(out, wdir, opts, con))
    _report(out, wdir, con)
    return cmp


def true_line_counts(rows: pd.DataFrame, truth: pd.DataFrame, mapping: pd.DataFrame) -> np.ndarray:
    """The true count of each count row (``line, lane, direction, interval_start, interval_end``; lanes named as
    :func:`~trafficgeo.synth.world.truth_lane_name`) from the world's ``truth_counts.csv`` rows. A lane's true
    vehicles cross a line one way, the way its SUMO lane runs (``mapping``: the scenario's ``mapping.csv``, mapped
    rows with an empty ``problem``); a row counted the other way (a crossing seen against the traffic) has none."""
    from trafficgeo.synth.world import truth_lane_name

    lane = truth_lane_name(truth["direction"], truth["lane"])
    line = truth["line"].astype(str).to_numpy()
    time = truth["time"].to_numpy(float)
    with_traffic = {(str(r.line), str(r.lane), int(r.direction)) for r in mapping.itertuples() if r.problem == ""}
    return np.array([int(((line == str(r.line)) & (lane == r.lane) & (time >= r.interval_start)
                          & (time < r.interval_end)).sum())
                     if (str(r.line), str(r.lane), int(r.direction)) in with_traffic else 0
                     for r in rows.itertuples()], dtype=int)


def _simulation(out: Path, wdir: Path, opts: WorldOptions, con: Console) -> dict[str, float]:
    """Step 7: the loop closed - the video's counts -> SUMO demand on the world's network -> SUMO run -> the
    simulated counts against the video's and against the truth; the scenario stays in OUT/sumo for sumo-gui."""
    from trafficgeo.simulation.loop import close_sumo_loop
    from trafficgeo.traffic.compare import geh

    net, scenario, interval_s = wdir / "sumo" / "road.net.xml", out / "sumo", 60.0
    con.print(f"\n$ trafficgeo sumo-demand {out / 'video'} --net {net} --net-crs {opts.crs} --interval "
              f"{interval_s:g} --out {scenario}")
    con.print(f"$ trafficgeo sumo-validate {scenario} {out / 'video'} --out {out / 'video'}")
    loop = close_sumo_loop(out / "video", net, scenario, interval_s=interval_s, net_crs=opts.crs,
                           comparison_dir=out / "video")
    val = loop.validation
    rows = val.comparison.counts
    true_n = true_line_counts(rows, pd.read_csv(wdir / "truth_counts.csv"),
                              pd.read_csv(scenario / "mapping.csv", keep_default_na=False, dtype={"line": str}))
    per_hour = 3600.0 / (rows["interval_end"] - rows["interval_start"]).to_numpy(float)  # GEH is on hourly flows
    geh_truth = np.asarray(geh(rows["simulated_flow_veh_h"].to_numpy(float), np.asarray(true_n, float) * per_hour),
                           dtype=float)
    t = Table(title=f"The loop closed: SUMO demand fitted to the video's counts ({interval_s:g} s intervals), "
                    "simulated against the video and the truth")
    for col in ("line", "lane", "dir", "interval (s)", "truth", "video", "simulated", "GEH vs video", "GEH vs truth"):
        t.add_column(col, justify="left" if col in ("line", "lane") else "right")
    for r, n, g in zip(rows.itertuples(), true_n, geh_truth, strict=True):
        t.add_row(str(r.line), str(r.lane), f"{int(r.direction):+d}", f"{r.interval_start:.0f}-{r.interval_end:.0f}",
                  str(n), str(int(r.observed)), str(int(r.simulated)), f"{r.geh:.2f}", f"{g:.2f}")
    con.print(t)
    m = {"sumo_share_geh_below_5": float(val.share_geh_below_5),
         "sumo_share_geh_below_5_vs_truth": float(np.mean(geh_truth < 5.0)) if geh_truth.size else float("nan"),
         "sumo_max_speed_difference_kmh": float(val.max_abs_speed_difference_kmh)}
    con.print(f"GEH < 5 for {m['sumo_share_geh_below_5']:.0%} of the counts against the video (practice asks 85 %), "
              f"{m['sumo_share_geh_below_5_vs_truth']:.0%} against the truth; mean speeds per line and lane within "
              f"{m['sumo_max_speed_difference_kmh']:.1f} km/h; built in {loop.build_s:.1f} s, run and compared in "
              f"{loop.run_and_compare_s:.1f} s. Open {scenario / 'scenario.sumocfg'} in sumo-gui to watch it.",
              markup=False, highlight=False)
    return m


def _refine(out: Path, wdir: Path, surf, truth_cam, steady: pd.DataFrame, truth_xyz: np.ndarray, dist: np.ndarray,
            con: Console) -> dict[str, float]:
    """Step 4b: the orthophoto refines the calibration (``trafficgeo refine``); the vehicles' true ground points are
    mapped again through the refined camera. Later steps keep the GCP camera."""
    from trafficgeo.geo.georef import georeference_table
    from trafficgeo.registration.run import refine_camera_files
    from trafficgeo.video.background_frame import background_frame

    con.print(f"\n$ trafficgeo refine {out / 'camera.json'} --video {wdir / 'video.mp4'} --ortho {wdir / 'ortho.tif'} "
              f"--surface {out / 'dem.tif'} -o {out / 'camera_refined.json'} --report {out / 'refine.json'}")
    still = background_frame(wdir / "video.mp4")
    result = refine_camera_files(out / "camera.json", still, wdir / "ortho.tif", surf, out / "camera_refined.json",
                                 report_path=out / "refine.json", progress=con.print)
    con.print(("refined: " if result.accepted else "refused: ") + result.reason, markup=False, highlight=False)
    t = Table(title="Vehicle ground points (steady camera), median horizontal error on the DEM")
    for col in ("distance", "points", "GCP camera", "refined camera"):
        t.add_column(col, justify="left" if col == "distance" else "right")
    errors = {}
    for label, camera in (("gcp", read_camera_json(out / "camera.json")), ("refined", result.camera)):
        world = georeference_table(camera, steady, surf)
        errors[label] = np.hypot(*(world[["x", "y"]].to_numpy() - truth_xyz[:, :2]).T)
    for lo, hi in ((0, 40), (40, 80), (80, 200)):
        band = (dist >= lo) & (dist < hi)
        if band.any():
            t.add_row(f"{lo}-{hi} m", str(int(band.sum())), f"{np.nanmedian(errors['gcp'][band]):.3f} m",
                      f"{np.nanmedian(errors['refined'][band]):.3f} m")
    con.print(t)
    return {"refine_accepted": float(result.accepted), "refine_matches": float(result.n_kept),
            "ground_median_refined_m": float(np.nanmedian(errors["refined"]))}


def _report(out: Path, wdir: Path, con: Console) -> None:
    """Step 8: everything above on one HTML page (calibration, the orthophoto refinement, accuracy map, both traffic
    runs, the simulation)."""
    from trafficgeo.report.html import write_report_html

    con.print(f"\n$ trafficgeo report {out} --ortho {wdir / 'ortho.tif'} --video {wdir / 'video.mp4'} "
              f"--refine-report {out / 'refine.json'} -o {out / 'report.html'}")
    page = write_report_html(out / "report.html", out, ortho=wdir / "ortho.tif", video=wdir / "video.mp4",
                             refine_report=out / "refine.json")
    con.print(f"wrote {out / 'report.html'} ({len(page.html.encode('utf-8')) / 1e6:.1f} MB): "
              f"{', '.join(page.sections)}", markup=False, highlight=False)


def _video(out: Path, wdir: Path, cam, surf, con: Console) -> dict[str, float]:
    """Step 6: the whole chain on the video itself - decode, detect (the built-in learned detector, tiled over the
    far road), track, analyze."""
    from rich.progress import BarColumn, Progress, TimeRemainingColumn

    from trafficgeo.pipeline.run import RunCallbacks, process_video
    from trafficgeo.report.traffic import print_analysis
    from trafficgeo.site.site import Site
    from trafficgeo.synth.scoring import count_scores, detection_scores
    from trafficgeo.video.pipeline import ProcessOptions
    from trafficgeo.video.reader import video_info

    folder = out / "video"
    con.print(f"\n$ trafficgeo process {wdir / 'video.mp4'} --camera {out / 'camera.json'} --surface "
              f"{out / 'dem.tif'} --lanes {wdir / 'lanes.gpkg'} --lines {wdir / 'count_lines.gpkg'} --out {folder}")
    info = video_info(wdir / "video.mp4")
    with Progress("detect + track", BarColumn(), "{task.completed}/{task.total} frames", TimeRemainingColumn(),
                  console=con, transient=True) as bar:
        task = bar.add_task("video", total=info.frame_count)
        site = Site.load(out / "camera.json", surf, wdir / "lanes.gpkg", wdir / "count_lines.gpkg")
        run = process_video(wdir / "video.mp4", site, folder,  # the defaults: NanoDet, tiles, ~10 Hz
                            options=ProcessOptions(restart=True),
                            callbacks=RunCallbacks(progress=lambda d, n, t: bar.update(task, completed=d, total=n),
                                                   notice=lambda text: con.print(text, markup=False)))
    result, detections, options, elapsed = run.traffic, run.detections, run.options, run.seconds
    print_analysis(result, con)
    truth = pd.read_csv(wdir / "truth_tracks.csv")
    truth = truth[truth["frame"] % options.every == 0]  # the frames it detected on
    precision, recall, n_boxes = detection_scores(detections.to_table(), truth)
    score = count_scores(result.crossings, pd.read_csv(wdir / "truth_counts.csv"))
    errs = score.speed_errors[np.isfinite(score.speed_errors)]
    m = {"video_realtime_factor": info.duration_s / elapsed, "detection_precision": precision,
         "detection_recall": recall, "video_count_accuracy": score.accuracy,
         "video_spot_speed_mae_kmh": float(np.mean(np.abs(errs))) if errs.size else float("nan")}
    step = {1: "every frame", 2: "every 2nd frame", 3: "every 3rd frame"}.get(options.every,
                                                                           f"every {options.every}th frame")
    t = Table(title=f"Demo world video, the default detector (built-in NanoDet + tiles, {step}): measured vs truth")
    for col in ("quantity", "measured"):
        t.add_column(col, justify="right" if col != "quantity" else "left")
    t.add_row("speed of decode + detect + track", f"{m['video_realtime_factor']:.2f} x real time")
    t.add_row(f"detection precision / recall at IoU 0.5 ({n_boxes} visible vehicle boxes)",
              f"{precision:.1%} / {recall:.1%}")
    t.add_row("vehicles counted at the lines", f"{int(score.table['counted'].sum())} of "
              f"{int(score.table['true'].sum())}")
    t.add_row("per-lane counts, 1 - sum |error| / sum true", f"{score.accuracy:.1%}")
    t.add_row(f"speed at the lines, mean abs error ({errs.size} crossings with a speed)",
              f"{m['video_spot_speed_mae_kmh']:.2f} km/h")
    con.print(t)
    con.print("The default detector is the built-in learned one (NanoDet-g, shipped with trafficgeo): on this world it "
              "counts far better than background subtraction (--detector background), which merges vehicles that "
              "overlap in the image and is faster. Tiles over the far road bring far vehicles to a size it sees; "
              "benchmarks/bench_video.py compares the two.")
    return m


def _traffic(out: Path, wdir: Path, cam, surf, opts: WorldOptions, con: Console) -> dict[str, float]:
    """Step 5: tracker output -> analyze -> speeds, lanes and counts against the truth, and compare-sumo."""
    from trafficgeo.report.traffic import print_analysis, print_comparison
    from trafficgeo.synth.detections import noisy_tracks
    from trafficgeo.synth.scoring import count_scores
    from trafficgeo.synth.sumo_world import WARMUP_S
    from trafficgeo.synth.world import truth_lane_name
    from trafficgeo.traffic.analyze import analyze_tracks, write_analysis
    from trafficgeo.traffic.validation import compare_with_sumo

    truth = pd.read_csv(wdir / "truth_tracks.csv")
    noisy = noisy_tracks(truth, cam.image_size, seed=opts.seed)
    noisy.drop(columns="vehicle").to_csv(out / "tracks.csv", index=False, float_format="%.2f")
    con.print(f"\n$ trafficgeo analyze {out / 'camera.json'} {out / 'tracks.csv'} --fps {opts.fps:g} --surface "
              f"{out / 'dem.tif'} --lanes {wdir / 'lanes.gpkg'} --lines {wdir / 'count_lines.gpkg'} "
              f"--out {out / 'traffic'}")
    # the camera JSON, as the command above: its covariance and control points place the headline speed windows
    result = analyze_tracks(out / "camera.json", surf, out / "tracks.csv", wdir / "lanes.gpkg",
                            wdir / "count_lines.gpkg", fps=opts.fps)
    write_analysis(out / "traffic", result, cam)
    print_analysis(result, con)
    # against the truth
    vehicle_of = noisy.set_index(["track_id", "frame"])["vehicle"]
    truth["lane_name"] = truth_lane_name(truth["direction"], truth["lane"])
    by_frame = truth.set_index(["vehicle", "frame"])
    pts = result.points
    veh = [vehicle_of.get(k, "") for k in zip(pts["source_track"], pts["frame"], strict=True)]
    keys = list(zip(veh, pts["frame"], strict=True))
    true_lane = np.array([by_frame["lane_name"].get(k, "") for k in keys], dtype=object)
    true_speed = np.array([by_frame["speed_kmh"].get(k, np.nan) for k in keys])
    score = count_scores(result.crossings, pd.read_csv(wdir / "truth_counts.csv"))
    both = score.table
    m = {
        "point_speed_mae_kmh": float(np.nanmean(np.abs(pts["speed_kmh"].to_numpy() - true_speed))),
        "spot_speed_mae_kmh": float(np.nanmean(np.abs(score.speed_errors))),
        "lane_accuracy": float(np.mean((pts["lane"].to_numpy() == true_lane)[true_lane != ""])),
        "count_accuracy": score.accuracy,
    }
    t = Table(title="Demo world traffic: measured vs truth")
    for col in ("quantity", "measured", "truth"):
        t.add_column(col, justify="right" if col != "quantity" else "left")
    t.add_row("vehicles counted at the lines (all lanes)", str(int(both["counted"].sum())),
              str(int(both["true"].sum())))
    t.add_row("per-lane counts, 1 - sum |error| / sum true", f"{m['count_accuracy']:.1%}", "")
    t.add_row("lane of each track point", f"{m['lane_accuracy']:.1%} right", "")
    t.add_row("speed at the lines, mean abs error", f"{m['spot_speed_mae_kmh']:.2f} km/h", "")
    t.add_row("speed of every track point, mean abs error", f"{m['point_speed_mae_kmh']:.2f} km/h", "")
    con.print(t)
    # the simulation (here the world's own SUMO run) against the observation
    net = wdir / "sumo" / "road.net.xml"
    con.print(f"$ trafficgeo compare-sumo {out / 'traffic'} {wdir / 'sumo' / 'fcd.xml'} --net {net} --net-crs "
              f"{opts.crs} --time-offset {WARMUP_S:g}")
    comparison = compare_with_sumo(out / "traffic", wdir / "sumo" / "fcd.xml", net=net, net_crs=opts.crs,
                                   time_offset_s=WARMUP_S, out_dir=out / "traffic")
    print_comparison(comparison, con)
    m["share_geh_below_5"] = float(comparison.count_summary["share_geh_below_5"])
    return m


# ------------------------------------------------------------------------------------------------ junction
def _movement_scores(world: Path, moves: pd.DataFrame, points: pd.DataFrame, end_s: float):
    """Turning movements against the truth (:func:`trafficgeo.synth.scoring.movement_scores`), the run's vehicles
    matched to the true ones by their trajectories."""
    from trafficgeo.synth.scoring import movement_scores, truth_of_run_vehicles

    truth = pd.read_csv(world / "truth_movements.csv", keep_default_na=False)
    of = truth_of_run_vehicles(pd.read_csv(world / "truth_tracks.csv"), points)
    return movement_scores(truth, moves, of, end_s=end_s)


def run_junction_demo(out: Path, *, seed: int = 3, duration_s: float = 60.0, process_s: float | None = 20.0,
                      console: Console | None = None, rebuild: bool = False) -> dict[str, float]:
    """``trafficgeo demo --junction``: a signalised four-arm junction world (built once into ``out/world``), the
    camera calibrated from its GCPs, simulated tracker output and (unless ``process_s`` is None) the first
    ``process_s`` s of the video through ``analyze``/``process --gates``, the turning movements against the truth,
    and ``report.html`` with the movement diagram. Returns the scores."""
    from trafficgeo.report.traffic import print_analysis
    from trafficgeo.synth.detections import noisy_tracks
    from trafficgeo.synth.junction_sumo import JunctionOptions
    from trafficgeo.synth.junction_world import build_junction_world
    from trafficgeo.traffic.analyze import analyze_tracks, write_analysis

    con = console or Console()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    wdir = out / "world"
    opts = JunctionOptions(seed=seed, duration_s=duration_s)
    wanted = json.loads(json.dumps({k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(opts).items()}))
    meta = wdir / "world.json"
    if (rebuild or not meta.is_file() or json.loads(meta.read_text(encoding="utf-8")).get("options") != wanted
            or not (wdir / "video.mp4").is_file()):
        con.print(f"$ trafficgeo synth --junction --out {wdir} --seed {seed} --duration {duration_s:g}")
        build_junction_world(wdir, opts)
    else:
        con.print(f"reusing the junction world in {wdir}")
    summary = json.loads(meta.read_text(encoding="utf-8"))
    con.print(f"[bold]trafficgeo demo --junction[/bold]: {summary['vehicles']} vehicles through a signalised "
              f"four-arm junction, {summary['frames']} frames, camera {opts.camera_height:g} m up at its "
              f"{opts.camera_corner} corner")
    con.print(f"$ trafficgeo calibrate {wdir / 'gcps.csv'} --image-size {opts.image_size[0]}x{opts.image_size[1]} "
              f"--crs {opts.crs} -o {out / 'camera.json'}")
    gcps = read_gcps(wdir / "gcps.csv", crs=opts.crs)
    run_calibration(gcps, opts.image_size, camera_path=out / "camera.json", report_path=out / "report.json")
    calibrated = CalibratedCamera.read(out / "camera.json")
    truth_cam = read_camera_json(wdir / "camera_truth.json")
    con.print(f"camera position off by {np.linalg.norm(calibrated.camera.position - truth_cam.position):.3f} m")
    scores: dict[str, float] = {}
    t = Table(title="Junction demo: turning movements measured vs truth (vehicles that entered and left)")
    for col in ("tracks from", "movements counted", "true", "per-movement counts", "heavy: counted / true"):
        t.add_column(col, justify="right" if col != "tracks from" else "left")
    truth = pd.read_csv(wdir / "truth_tracks.csv")
    noisy = noisy_tracks(truth, opts.image_size, seed=opts.seed)
    noisy.drop(columns="vehicle").to_csv(out / "tracks.csv", index=False, float_format="%.2f")
    con.print(f"\n$ trafficgeo analyze {out / 'camera.json'} {out / 'tracks.csv'} --fps {opts.fps:g} --surface "
              f"{wdir / 'dem.tif'} --gates {wdir / 'gates.gpkg'} --out {out / 'traffic'}")
    result = analyze_tracks(out / "camera.json", wdir / "dem.tif", out / "tracks.csv", fps=opts.fps,
                            gates=wdir / "gates.gpkg")
    write_analysis(out / "traffic", result, calibrated.camera)
    print_analysis(result, con)
    sc = _movement_scores(wdir, result.movements, result.points, duration_s)
    scores["tracker_movement_accuracy"] = sc.accuracy
    t.add_row("simulated tracker output", str(int(sc.table["counted"].sum())), str(int(sc.table["true"].sum())),
              f"{sc.accuracy:.1%}", f"{sc.heavy_counted_pct:.0f} / {sc.heavy_true_pct:.0f} %")
    if process_s is not None:
        from trafficgeo.pipeline.run import RunCallbacks, process_video
        from trafficgeo.site.site import Site
        from trafficgeo.video.pipeline import ProcessOptions

        con.print(f"\n$ trafficgeo process {wdir / 'video.mp4'} --camera {out / 'camera.json'} --surface "
                  f"{wdir / 'dem.tif'} --gates {wdir / 'gates.gpkg'} --end {process_s:g} --out {out / 'video'}")
        site = Site.load(out / "camera.json", wdir / "dem.tif", gates=wdir / "gates.gpkg")
        run = process_video(wdir / "video.mp4", site, out / "video",
                            options=ProcessOptions(end_s=process_s, restart=True),
                            callbacks=RunCallbacks(notice=lambda text: con.print(text, markup=False)))
        print_analysis(run.traffic, con)
        sc = _movement_scores(wdir, run.traffic.movements, run.traffic.points, process_s)
        scores["video_movement_accuracy"] = sc.accuracy
        scores["video_realtime_factor"] = process_s / run.seconds
        t.add_row(f"the video (first {process_s:g} s, default detector, {scores['video_realtime_factor']:.2f}x "
                  "real time)", str(int(sc.table["counted"].sum())), str(int(sc.table["true"].sum())),
                  f"{sc.accuracy:.1%}", f"{sc.heavy_counted_pct:.0f} / {sc.heavy_true_pct:.0f} %")
    con.print(t)
    from trafficgeo.report.html import write_report_html

    page = write_report_html(out / "report.html", out, ortho=wdir / "ortho.tif", video=wdir / "video.mp4")
    con.print(f"wrote {out / 'report.html'} ({len(page.html.encode('utf-8')) / 1e6:.1f} MB): "
              f"{', '.join(page.sections)}", markup=False, highlight=False)
    return scores
