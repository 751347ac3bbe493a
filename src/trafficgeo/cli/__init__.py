"""Command line: a thin layer over the Python API.

Exit codes: 0 success; 1 the job ran but could not produce a trustworthy result (explained); 2 bad input (one line
on stderr, no traceback, nothing written).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from trafficgeo.cli.app import app, console, parse_image_size
from trafficgeo.errors import CalibrationError, InputError, TrafficgeoError


def _parse_pattern(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        c, r = (int(p) for p in parts)
    except ValueError:
        raise InputError(f"--pattern '{text}' is not COLSxROWS of inner corners; e.g. --pattern 9x6") from None
    if c < 2 or r < 2:
        raise InputError(f"--pattern '{text}' needs at least 2x2 inner corners")
    return c, r


def _load_intrinsics(path: Path, image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """K and dist from an OpenCV YAML/XML file or a trafficgeo camera JSON; the image size must match."""
    if path.suffix.lower() == ".json":
        from trafficgeo.camera.calibrated import read_camera_json

        cam = read_camera_json(path)
        K, dist, size = cam.K, cam.dist, cam.image_size
    else:
        from trafficgeo.camera.opencv_yaml import read_intrinsics_yaml

        intr = read_intrinsics_yaml(path)
        K, dist, size = intr.K, intr.dist, intr.image_size
    if size is not None and tuple(size) != tuple(image_size):
        raise InputError(f"{path}: intrinsics are for a {size[0]}x{size[1]} image but --image-size is "
                         f"{image_size[0]}x{image_size[1]}; calibrate the camera in the video's own resolution")
    return K, dist


def _distortion_option(text: str) -> str | tuple[str, ...]:
    t = text.strip().lower()
    if t in ("auto", "none"):
        return t
    return tuple(p.strip() for p in t.split(",") if p.strip())


SURVEY_SIGMA_M = 0.03  # the calibrate command's default --survey-sigma (m): surveyed points


@app.command()
def calibrate(
    gcps: Annotated[Path, typer.Argument(help="GCP CSV (id,x,y,z,u,v[,role][,sigma_px]; other names such as "
                                              "pixel_x/pixel_y, col/row, lat/lon, easting/northing/elevation are "
                                              "read too), ODM gcp_list.txt or QGIS .points")],
    image_size: Annotated[str, typer.Option("--image-size", help="video frame size WIDTHxHEIGHT, e.g. 1920x1080")],
    output: Annotated[Path, typer.Option("--output", "-o", help="camera JSON to write")],
    report: Annotated[Path | None, typer.Option(help="validation report JSON to write")] = None,
    crs: Annotated[str | None, typer.Option(help="working projected CRS, e.g. EPSG:2949")] = None,
    gcp_crs: Annotated[str | None, typer.Option(help="CRS of the GCP file's x,y (EPSG:4326: x=lon, y=lat)")] = None,
    odm_image: Annotated[str | None, typer.Option(help="image or camera to use from a file that lists several "
                                                       "(an ODM gcp_list.txt, or a CSV's camera/image column)")] = None,
    ground_z: Annotated[float | None, typer.Option(help="height of every GCP of a file without heights (points on "
                                                      "flat ground), in the CRS's units")] = None,
    intrinsics: Annotated[Path | None, typer.Option(help="OpenCV YAML or camera JSON with K and dist")] = None,
    refine_intrinsics: Annotated[bool, typer.Option(help="refine --intrinsics instead of holding them fixed")] = False,
    focal_px: Annotated[float | None, typer.Option(help="hold the focal length at this value (px)")] = None,
    focal: Annotated[str, typer.Option(help="auto | single | separate")] = "auto",
    principal_point: Annotated[str, typer.Option(help="auto | fixed | free")] = "auto",
    distortion: Annotated[str, typer.Option(help="auto | none | terms such as k1,k2")] = "auto",
    loss: Annotated[str, typer.Option(help="robust loss: soft_l1 | huber | cauchy | linear")] = "soft_l1",
    survey_sigma: Annotated[float, typer.Option(help="standard deviation of GCP world coordinates (m); 0.3-1 for "
                                                     "points picked on a web map")] = SURVEY_SIGMA_M,
    gis: Annotated[Path | None, typer.Option(help="also write camera, GCPs with residuals and the footprint on "
                                             "the GCP plane (.gpkg / .geojson)")] = None,
    report_html: Annotated[Path | None, typer.Option(help="also write an HTML report of the calibration (built from "
                                                     "the camera JSON's folder, see 'trafficgeo report')")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="print only the summary line")] = False,
) -> None:
    """Calibrate the camera (intrinsics, distortion, pose) from GCPs and report how far it can be trusted."""
    from trafficgeo.calibration import CalibrationOptions, read_gcps, run_calibration

    size = parse_image_size(image_size)
    if gis is not None:
        from trafficgeo.cli.geo import check_gis_path

        check_gis_path(gis, "--gis")
    if report_html is not None:
        from trafficgeo.cli.report import check_html_path

        check_html_path(report_html)
    intr = _load_intrinsics(intrinsics, size) if intrinsics is not None else None
    options = CalibrationOptions(
        focal=focal, principal_point=principal_point, distortion=_distortion_option(distortion), focal_px=focal_px,
        intrinsics=intr, fix_intrinsics=intr is not None and not refine_intrinsics, loss=loss,
        survey_sigma_m=survey_sigma)
    table = read_gcps(gcps, gcp_crs=gcp_crs, crs=crs, odm_image=odm_image, ground_z=ground_z)
    if gis is not None and table.crs is None:
        raise InputError(f"--gis {gis}: the GCPs have no CRS, so nothing can be placed on a map; give --crs")
    result = run_calibration(table, size, options, camera_path=output, report_path=report)
    if gis is not None:
        _write_site_gis(gis, output)
    if quiet:
        console.print(result.report.summary)
    else:
        from trafficgeo.report.terminal import print_calibration_report

        print_calibration_report(result.report, console)
    if table.columns_note:
        console.print(f"{gcps}: columns read as {table.columns_note}")
    if table.from_lonlat and survey_sigma == SURVEY_SIGMA_M:
        console.print(f"{gcps}: longitude/latitude points are usually picked on a web map, good to a few decimetres "
                      f"or metres, not the {SURVEY_SIGMA_M:g} m of a survey; say how good with --survey-sigma (e.g. "
                      "0.5), or the fit trusts them too much and the error bars are too small")
    console.print(f"wrote {output}" + (f" and {report}" if report else ""))
    if report_html is not None:
        from trafficgeo.cli.report import write_page

        write_page(report_html, output.parent, camera=output, calibration_report=result.report)


def _write_site_gis(path: Path, camera_json: Path) -> None:
    from trafficgeo.camera.calibrated import CalibratedCamera
    from trafficgeo.io.gis import write_gis
    from trafficgeo.site.layers import site_layers, visible_footprint
    from trafficgeo.site.surface import plane_from_gcps

    calibrated = CalibratedCamera.read(camera_json)
    plane = plane_from_gcps(calibrated)
    write_gis(path, site_layers(calibrated, visible_footprint(calibrated.camera, plane)), calibrated.camera.crs)


@app.command()
def intrinsics(
    images: Annotated[list[Path], typer.Argument(help="chessboard photos taken in the video's own mode")],
    output: Annotated[Path, typer.Option("--output", "-o", help="OpenCV YAML to write")],
    pattern: Annotated[str, typer.Option(help="inner corners COLSxROWS")] = "9x6",
    square: Annotated[float, typer.Option(help="square size (m)")] = 0.025,
    fix_aspect_ratio: Annotated[bool, typer.Option(help="force fx = fy")] = False,
) -> None:
    """Intrinsics (K, distortion) from chessboard images; use with 'calibrate --intrinsics'.

    Take the photos in the same mode and resolution as the video, with stabilisation off.
    """
    from rich.progress import Progress

    from trafficgeo.calibration.chessboard import calibrate_chessboard
    from trafficgeo.camera.opencv_yaml import write_intrinsics_yaml

    pat = _parse_pattern(pattern)
    if not square > 0:
        raise InputError(f"--square {square} must be a positive size in metres, e.g. 0.025")
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("finding chessboards", total=len(images))
        result = calibrate_chessboard(images, pat, square, fix_aspect_ratio=fix_aspect_ratio,
                                      progress=lambda i, n: progress.update(task, completed=i))
    write_intrinsics_yaml(output, result.intrinsics)
    K = result.intrinsics.K
    console.print(f"boards found in {len(result.used_images)} of {len(images)} images"
                  + (f" (skipped: {', '.join(Path(s).name for s in result.skipped_images)})"
                     if result.skipped_images else ""))
    console.print(f"fx {K[0, 0]:.2f}  fy {K[1, 1]:.2f}  cx {K[0, 2]:.2f}  cy {K[1, 2]:.2f} px; dist "
                  f"{np.array2string(result.intrinsics.dist, precision=5)}; RMS {result.rms_px:.3f} px")
    console.print(f"wrote {output}")


def _parse_origin(text: str) -> tuple[float, float, float]:
    """'49.2,16.6,250' -> (lat, lon, alt)."""
    parts = [p.strip() for p in text.split(",")]
    try:
        lat, lon, alt = (float(p) for p in parts)
    except ValueError:
        raise InputError(f"--origin '{text}' is not lat,lon,alt (degrees, degrees, metres); e.g. --origin "
                         "49.2,16.6,250") from None
    return lat, lon, alt


@app.command("import-camera")
def import_camera(
    pose: Annotated[Path, typer.Argument(help="OpenCV pose file (.yml/.json): camera_matrix, dist_coeffs, R or "
                                         "rvec, t (x_cam = R X + t), image_width/height")],
    output: Annotated[Path, typer.Option("--output", "-o", help="camera JSON to write")],
    crs: Annotated[str | None, typer.Option(help="CRS of the pose's world frame, or the target CRS with --origin "
                                            "(default: the file's 'crs' key)")] = None,
    origin: Annotated[str | None, typer.Option(help="geodetic origin lat,lon,alt (deg, deg, m) of a local frame "
                                               "(default: the file's origin_lat/lon/alt)")] = None,
    frame: Annotated[str | None, typer.Option(help="axes of the local frame at --origin: enu | ned")] = None,
    image_size: Annotated[str | None, typer.Option("--image-size", help="WIDTHxHEIGHT when the file has none")]
        = None,
) -> None:
    """A camera JSON from a calibration made elsewhere (no GCPs): an OpenCV pose in a CRS or at a geodetic origin."""
    from trafficgeo.camera.io import write_camera_json
    from trafficgeo.camera.pose_file import read_pose_file

    if output.suffix.lower() != ".json":
        raise InputError(f"--output {output}: write the camera as a camera JSON (.json)")
    if output.resolve() == pose.resolve():
        raise InputError(f"--output {output} is the pose file itself; write the camera JSON to another file")
    size = parse_image_size(image_size) if image_size is not None else None
    cam = read_pose_file(pose, crs=crs, origin=_parse_origin(origin) if origin is not None else None, frame=frame,
                         image_size=size)
    write_camera_json(output, cam)
    o, pos = cam.orientation, cam.position
    console.print(f"camera {cam.width}x{cam.height} px, focal {cam.focal_px:.1f} px, at X {pos[0]:.3f} Y "
                  f"{pos[1]:.3f} Z {pos[2]:.3f} ({cam.crs_text or 'local coordinates'}); heading "
                  f"{o.heading_deg:.2f}, tilt {o.tilt_deg:.2f}, roll {o.roll_deg:.2f} deg")
    console.print(f"wrote {output}")


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="folder for the demo's files (the world is cached in OUT/world)")] =
        Path("demo-out"),
    seed: Annotated[int, typer.Option(help="world seed")] = 7,
    duration: Annotated[float, typer.Option(help="video length of the demo world (s)")] = 60.0,
    quick: Annotated[bool, typer.Option(help="a small, short world (10 s, 960x540) for a fast look")] = False,
    rebuild: Annotated[bool, typer.Option(help="rebuild the world even if a cached one matches")] = False,
    junction: Annotated[bool, typer.Option(help="the junction demo instead: turning movements at a signalised "
                                           "four-arm junction (seed 3 unless --seed is given)")] = False,
) -> None:
    """Run the pipeline on the demo world (built once, then cached) and compare every result with the truth."""
    from dataclasses import replace

    from trafficgeo.demo import DEMO_WORLD, run_demo
    from trafficgeo.io.run_manifest import check_writable_folder

    check_writable_folder(out, "--out")
    if not duration > 0:
        raise InputError(f"--duration {duration} must be positive (s)")
    if junction:
        from trafficgeo.demo import run_junction_demo

        run_junction_demo(out, seed=3 if seed == 7 else seed, duration_s=duration, console=console, rebuild=rebuild,
                          process_s=None if quick else min(20.0, duration))
        return
    world = replace(DEMO_WORLD, seed=seed, duration_s=duration)
    if quick:
        world = replace(world, duration_s=min(duration, 10.0), image_size=(960, 540), ortho_resolution=0.1)
    run_demo(out, seed=seed, console=console, world=world, rebuild=rebuild)


from trafficgeo.cli import batch as _batch  # noqa: E402, F401  (registers batch plan|run|summarize)
from trafficgeo.cli import calibrate_ortho as _calibrate_ortho  # noqa: E402, F401  (registers calibrate-ortho)
from trafficgeo.cli import geo as _geo  # noqa: E402, F401  (registers the geospatial commands)
from trafficgeo.cli import process as _process  # noqa: E402, F401  (registers process and stitch)
from trafficgeo.cli import refine as _refine  # noqa: E402, F401  (registers the refine command)
from trafficgeo.cli import report as _report  # noqa: E402, F401  (registers the report command)
from trafficgeo.cli import sumo as _sumo  # noqa: E402, F401  (registers sumo-net, sumo-demand and sumo-validate)
from trafficgeo.cli import synth as _synth  # noqa: E402, F401  (registers the synth command)
from trafficgeo.cli import traffic as _traffic  # noqa: E402, F401  (registers analyze and compare-sumo)
from trafficgeo.cli import ui as _ui  # noqa: E402, F401  (registers the gcp-ui command)
from trafficgeo.cli import video as _video  # noqa: E402, F401  (registers the frame command)

# Library parameter -> command-line flag, for InputError messages (the library names its parameters).
FLAGS = {"start_s": "--start", "end_s": "--end", "every": "--every", "checkpoint_s": "--checkpoint",
         "tiling": "--tiling", "out_dir": "--out", "interval_s": "--interval", "resolution_m": "--resolution",
         "time_offset_s": "--time-offset", "output": "--output", "annotate": "--annotate", "surface": "--surface",
         "surface_crs": "--surface-crs", "radius_m": "--radius", "backend": "--backend",
         "crs": "--crs", "gcp_crs": "--gcp-crs", "odm_image": "--odm-image", "ground_z": "--ground-z",
         "image_size": "--image-size", "pattern": "--pattern", "focal_px": "--focal-px", "intrinsics": "--intrinsics",
         "fps": "--fps", "coast_hidden_s": "--coast-hidden", "max_gap_s": "--join-gap", "pixel_sigma": "--pixel-sigma",
         "box_sigma_share": "--box-sigma-share",
         "accel_sigma": "--accel-sigma", "max_metres_per_px": "--max-metres-per-px", "camera": "--camera",
         "calibration_report": "--calibration-report", "frame": "--frame", "video": "--video", "ortho": "--ortho",
         "dem": "--dem", "cloud": "--cloud", "at_s": "--at", "gcps": "--gcps", "workdir": "--workdir",
         "port": "--port", "host": "--host", "detector": "--detector", "detector_format": "--detector-format",
         "workers": "--workers", "threads_per_worker": "--threads", "retries": "--retries", "scheduler": "--scheduler",
         "max_window_s": "--max-window", "name_pattern": "--name-pattern",
         "lanes": "--lanes", "lines": "--lines", "net": "--net", "net_crs": "--net-crs", "routes": "--routes",
         "begin_s": "--begin", "seed": "--seed", "scenario": "SCENARIO",
         "n_frames": "--frames", "duration_s": "--duration", "search_px": "--search",
         "report_path": "--report", "refine_report": "--refine-report", "origin": "--origin",
         "world_file": "--world-file", "control": "--corners", "gates": "--gates",
         "movement_interval_s": "--movement-interval", "near": "--near", "near_crs": "--near-crs",
         "max_offset_m": "--max-offset", "checks": "--checks",
         "gcps_out": "--gcps-out", "model": "--model"}


def main(argv: list[str] | None = None) -> Any:
    """Entry point of the ``trafficgeo`` console script."""
    try:
        return app(args=argv, standalone_mode=False)
    except InputError as exc:
        print(f"trafficgeo: error: {exc.in_terms_of(FLAGS)}", file=sys.stderr)
        sys.exit(2)
    except CalibrationError as exc:
        print(f"trafficgeo: calibration failed: {exc}", file=sys.stderr)
        sys.exit(1)
    except TrafficgeoError as exc:
        print(f"trafficgeo: {exc}", file=sys.stderr)
        sys.exit(1)
    except typer.Abort:
        print("trafficgeo: interrupted", file=sys.stderr)
        sys.exit(130)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.TyperException as exc:  # usage errors: bad option, missing argument
        exc.show()
        sys.exit(getattr(exc, "exit_code", 2))
    except (json.JSONDecodeError, OSError) as exc:
        print(f"trafficgeo: error: {exc}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":  # pragma: no cover
    main()
