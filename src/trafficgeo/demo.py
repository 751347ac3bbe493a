"""``trafficgeo demo``: the pipeline on a generated scene with known truth, every result compared with the truth.

It generates a road scene (2.5 % grade, crowned 2 % each way) seen by a phone-like 1080p camera on an 8 m pole,
with realistic pixel and survey noise, check points and planted blunders (a wrong click, a wrong point-cloud Z, a
wrong orthophoto feature), and an airborne-lidar-like point cloud of the site (ground, trees, poles). It then runs
what exists: checks the GCP heights against the cloud, calibrates from the noisy GCPs, builds a ground DEM from
the cloud, maps road pixels to the ground on that DEM and on the GCP plane, writes the accuracy map and the site
as GIS layers, and prints every result next to the truth. Video and traffic stages will extend it as they land.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from trafficgeo.calibration import read_gcps, run_calibration
from trafficgeo.camera.io import write_camera_json
from trafficgeo.report.terminal import print_calibration_report
from trafficgeo.synth import make_gcp_scene
from trafficgeo.synth.gcp_scene import GCPScene


def _angle_diff(a: float, b: float) -> float:
    return float((a - b + 180.0) % 360.0 - 180.0)


def run_demo(out: Path, *, seed: int = 7, console: Console | None = None) -> dict[str, float]:
    """Generate, calibrate and compare; writes gcps.csv, camera_truth.json, camera.json, report.json to ``out``.

    Returns the truth comparison (errors) as a dictionary.
    """
    con = console or Console()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    size = (1920, 1080)
    scene = make_gcp_scene(seed, image_size=size, n_control=14, n_check=5, n_outliers=3, n_elevated=2,
                           pixel_sigma=1.0, survey_sigma=0.02, grade=0.025, crossfall=0.02, camera_height=8.0)
    gcp_path = out / "gcps.csv"
    scene.gcps.to_csv(gcp_path)
    write_camera_json(out / "camera_truth.json", scene.camera)
    con.print(f"[bold]trafficgeo demo[/bold]: generated scene (seed {seed}) -> {gcp_path}: "
              f"{int(scene.gcps.is_control.sum())} control and {int(scene.gcps.is_check.sum())} check points, "
              f"{int(scene.outlier.sum())} planted blunders ({', '.join(k for k in scene.outlier_kind if k)})")
    con.print(f"$ trafficgeo calibrate {gcp_path} --image-size {size[0]}x{size[1]} --crs EPSG:2949 "
              f"-o {out / 'camera.json'} --report {out / 'report.json'}\n")
    gcps = read_gcps(gcp_path, crs="EPSG:2949")
    run = run_calibration(gcps, size, camera_path=out / "camera.json", report_path=out / "report.json")
    print_calibration_report(run.report, con)

    cam, truth = run.calibration.camera, scene.camera
    flagged = ~run.calibration.inlier & gcps.is_control
    tp = int(np.sum(flagged & scene.outlier))
    check = gcps.is_check
    ground = cam.intersect_horizontal_plane(gcps.pixels[check], scene.true_world[check, 2])
    ground_err = np.hypot(*(ground[:, :2] - scene.true_world[check, :2]).T)
    o, ot = cam.orientation, truth.orientation
    cmp = {
        "position_error_m": float(np.linalg.norm(cam.position - truth.position)),
        "focal_error_pct": float(100 * (cam.focal_px - truth.focal_px) / truth.focal_px),
        "heading_error_deg": _angle_diff(o.heading_deg, ot.heading_deg),
        "tilt_error_deg": o.tilt_deg - ot.tilt_deg,
        "roll_error_deg": o.roll_deg - ot.roll_deg,
        "check_ground_rmse_true_m": float(np.sqrt(np.mean(ground_err ** 2))),
        "blunders_found": tp,
        "blunders_planted": int(scene.outlier.sum()),
        "good_points_flagged": int(np.sum(flagged & ~scene.outlier)),
    }
    t = Table(title="Demo: estimate vs truth")
    t.add_column("quantity")
    t.add_column("estimate", justify="right")
    t.add_column("truth", justify="right")
    t.add_column("error", justify="right")
    t.add_row("camera X, Y, Z", ", ".join(f"{v:.2f}" for v in cam.position),
              ", ".join(f"{v:.2f}" for v in truth.position), f"{cmp['position_error_m']:.3f} m")
    t.add_row("focal (px)", f"{cam.focal_px:.1f}", f"{truth.focal_px:.1f}", f"{cmp['focal_error_pct']:+.2f} %")
    t.add_row("k1", f"{cam.dist[0]:.4f}", f"{truth.dist[0]:.4f}", f"{cam.dist[0] - truth.dist[0]:+.4f}")
    t.add_row("heading (deg)", f"{o.heading_deg:.2f}", f"{ot.heading_deg:.2f}", f"{cmp['heading_error_deg']:+.3f}")
    t.add_row("tilt (deg)", f"{o.tilt_deg:.2f}", f"{ot.tilt_deg:.2f}", f"{cmp['tilt_error_deg']:+.3f}")
    t.add_row("roll (deg)", f"{o.roll_deg:.2f}", f"{ot.roll_deg:.2f}", f"{cmp['roll_error_deg']:+.3f}")
    t.add_row("check points on the ground (RMS vs true XY)", "", "", f"{cmp['check_ground_rmse_true_m']:.3f} m")
    t.add_row("planted blunders found", str(tp), str(cmp["blunders_planted"]),
              f"{cmp['good_points_flagged']} good point(s) flagged")
    con.print(t)
    cmp.update(_georeference(out, scene, seed, con))
    con.print("Video processing and traffic counts are not built yet: the demo stops after calibration and "
              "georeferencing.")
    return cmp


def _georeference(out: Path, scene: GCPScene, seed: int, con: Console) -> dict[str, float]:
    """Point cloud -> GCP height check, DEM, pixels -> ground on DEM and plane, accuracy map and site GIS."""
    import pandas as pd

    from trafficgeo.camera.io import read_camera_document
    from trafficgeo.geo.georef import check_gcp_heights, georeference_table
    from trafficgeo.geo.load import load_surface
    from trafficgeo.geo.pointcloud import GroundIndex, cloud_to_dem, write_point_cloud
    from trafficgeo.geo.raster import write_geotiff
    from trafficgeo.geo.site import site_layers
    from trafficgeo.geo.uncertainty import CameraCovariance, accuracy_grid, footprint_polygon
    from trafficgeo.io.gis import write_gis
    from trafficgeo.io.tables import write_point_table
    from trafficgeo.synth.terrain import road_point_cloud

    truth = scene.camera
    centre = truth.position[:2] + 60.0 * truth.optical_axis[:2] / np.linalg.norm(truth.optical_axis[:2])
    reach = float(np.max(np.abs(scene.true_world[:, :2] - centre))) + 10.0
    cloud = road_point_cloud(scene.road, centre, max(110.0, reach), density=8.0, seed=seed, crs="EPSG:2949")
    write_point_cloud(out / "cloud.laz", cloud)
    con.print(f"\n[bold]Georeferencing[/bold] (airborne-lidar-like cloud: {len(cloud.xyz):,} points -> "
              f"{out / 'cloud.laz'})")
    # 1. GCP heights against the cloud (the paper's point 7: a Z taken from a tree instead of the road).
    gcp_table = pd.read_csv(out / "gcps.csv")
    checked = check_gcp_heights(gcp_table, GroundIndex.from_cloud(cloud), cloud.crs)
    write_point_table(out / "gcps_z.csv", checked, None)
    elevated = np.abs(scene.true_world[:, 2] - scene.road.z(scene.true_world[:, 0], scene.true_world[:, 1])) > 0.3
    flagged = checked["z_check"].isin(["disagrees", "rough"]).to_numpy()
    z_blunder = np.array([k == "elevation" for k in scene.outlier_kind])
    con.print(f"$ trafficgeo gcp-z {out / 'gcps.csv'} --cloud {out / 'cloud.laz'} -o {out / 'gcps_z.csv'}")
    for _, row in checked[flagged].iterrows():
        con.print(f"  GCP {row['id']}: {row['z_check']}, z - ground = {row['dz_m']:+.2f} m")
    # 2. DEM from the cloud.
    dem = cloud_to_dem(cloud, 0.25)
    write_geotiff(out / "dem.tif", dem.data, dem.transform, dem.crs, nodata=float("nan"),
                  descriptions=dem.descriptions)
    con.print(f"$ trafficgeo dem {out / 'cloud.laz'} --resolution 0.25 -o {out / 'dem.tif'}  "
              f"({dem.cols}x{dem.rows} cells)")
    # 3. Road pixels (lane centres every 5 m, true projection + 1 px noise) -> ground, DEM vs GCP plane.
    cam, doc = read_camera_document(out / "camera.json")
    rng = np.random.default_rng(seed)
    s_road = np.arange(-100.0, 100.0, 5.0)
    pts = scene.road.points(np.repeat(s_road, 3), np.tile([-3.5, 0.0, 3.5], s_road.size))
    uv = truth.project(pts)
    dist = np.hypot(*(pts[:, :2] - truth.position[:2]).T)
    keep = truth.in_image(uv, margin=5) & (dist < 90) & (dist > 5)
    pixels = pd.DataFrame({"u": uv[keep, 0] + rng.normal(0, 1, keep.sum()),
                           "v": uv[keep, 1] + rng.normal(0, 1, keep.sum()), "true_distance_m": dist[keep]})
    pixels.to_csv(out / "road_pixels.csv", index=False)
    results = {}
    for label, spec in (("DEM", str(out / "dem.tif")), ("GCP plane", "plane")):
        surf = load_surface(spec, cam, doc)
        world = georeference_table(cam, pixels, surf)
        name = "road_world_dem.gpkg" if label == "DEM" else "road_world_plane.csv"
        write_point_table(out / name, world, cam.crs and surf.crs)
        err = np.linalg.norm(world[["x", "y", "z"]].to_numpy() - pts[keep], axis=1)
        far = pixels["true_distance_m"].to_numpy() > 50
        results[label] = (float(np.sqrt(np.nanmean(err ** 2))), float(np.sqrt(np.nanmean(err[far] ** 2))))
        con.print(f"$ trafficgeo georef {out / 'camera.json'} {out / 'road_pixels.csv'} --surface {spec} "
                  f"-o {out / name}")
    # 4. Accuracy map and the site as GIS layers.
    surf = load_surface(str(out / "dem.tif"), cam, doc)
    grid = accuracy_grid(cam, surf, CameraCovariance.from_document(doc, cam), pixel_sigma=1.0,
                         max_distance_m=150.0)
    write_geotiff(out / "accuracy.tif", grid.bands, grid.transform, grid.crs, nodata=float("nan"),
                  descriptions=grid.band_names)
    foot = footprint_polygon(grid)
    write_gis(out / "site.gpkg", site_layers(cam, doc, foot), cam.crs)
    con.print(f"$ trafficgeo accuracy {out / 'camera.json'} --surface {out / 'dem.tif'} -o {out / 'accuracy.tif'} "
              f"--gis {out / 'site.gpkg'} --max-distance 150")
    # Predicted vs actual error at the road points.
    from trafficgeo.geo.uncertainty import ground_uncertainty

    unc = ground_uncertainty(cam, pixels[["u", "v"]].to_numpy(), surf, CameraCovariance.from_document(doc, cam), 1.0)
    t = Table(title="Georeferencing vs truth")
    t.add_column("quantity")
    t.add_column("result", justify="right")
    t.add_column("truth", justify="right")
    t.add_row("GCP heights flagged against the cloud", f"{int(flagged.sum())}",
              f"{int(z_blunder.sum())} Z blunder(s) + {int(elevated.sum())} pole top(s)")
    t.add_row(f"road points 5-90 m ({int(keep.sum())}), RMS 3-D error on the DEM", f"{results['DEM'][0]:.3f} m",
              f"predicted {float(np.sqrt(np.nanmean(unc.radial_m ** 2))):.3f} m (horizontal)")
    far = pixels["true_distance_m"].to_numpy() > 50
    t.add_row("  same, beyond 50 m", f"{results['DEM'][1]:.3f} m",
              f"predicted {float(np.sqrt(np.nanmean(unc.radial_m[far] ** 2))):.3f} m (horizontal)")
    t.add_row("road points on the GCP plane (ignores the crown)", f"{results['GCP plane'][0]:.3f} m", "")
    t.add_row("  same, beyond 50 m", f"{results['GCP plane'][1]:.3f} m", "")
    t.add_row("visible ground (footprint)", f"{foot.area:,.0f} m2", "")
    con.print(t)
    return {"road_rmse_dem_m": results["DEM"][0], "road_rmse_plane_m": results["GCP plane"][0],
            "gcp_heights_flagged": int(flagged.sum())}
