"""``trafficgeo calibrate-ortho``: calibrate a camera from the orthophoto alone (no clicks); a thin wrapper over
:func:`trafficgeo.registration.run.calibrate_ortho_files`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console
from trafficgeo.errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


def parse_position(text: str, near_crs: str | None, target_crs: object) -> tuple[float, float]:
    """``"X,Y"`` in ``near_crs`` (the target CRS when None; for EPSG:4326 the order is lon,lat) -> X, Y in
    ``target_crs``."""
    parts = [p.strip() for p in text.split(",")]
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise InputError(f"position {text!r} is not two numbers X,Y (lon,lat with near_crs EPSG:4326)",
                         parameters=("near", "near_crs")) from None
    if near_crs is None:
        return x, y
    from pyproj import Transformer

    from trafficgeo.crs import parse_crs

    src = parse_crs(near_crs)
    tx, ty = Transformer.from_crs(src, target_crs, always_xy=True).transform(x, y)
    if not (abs(tx) < 1e12 and abs(ty) < 1e12):
        raise InputError(f"position {text!r} in {near_crs} has no place in the orthophoto's CRS; check the order "
                         "(lon,lat for EPSG:4326)", parameters=("near",))
    return float(tx), float(ty)


@app.command("calibrate-ortho")
def calibrate_ortho(
    video: Annotated[Path, typer.Argument(help="the video (its traffic is removed: temporal mode of --frames "
                                               "frames) or a still without traffic (PNG, JPEG, TIFF)")],
    ortho: Annotated[Path, typer.Option("--ortho", help="orthophoto GeoTIFF (projected CRS) of the site")],
    surface: Annotated[str, typer.Option("--surface", help="DEM (.tif), point cloud (.las/.laz) or a constant "
                                                          "elevation, in the orthophoto's CRS")],
    near: Annotated[str, typer.Option("--near", help="the camera's pole on the map: X,Y in the orthophoto's CRS "
                                                     "(or in --near-crs; lon,lat for EPSG:4326), within "
                                                     "--max-offset of it")],
    output: Annotated[Path, typer.Option("--output", "-o", help="camera JSON to write")],
    near_crs: Annotated[str | None, typer.Option("--near-crs", help="CRS of --near, e.g. EPSG:4326")] = None,
    focal_px: Annotated[float | None, typer.Option("--focal-px", help="the focal length in pixels when known "
                                                                      "(else it is found)")] = None,
    checks: Annotated[Path | None, typer.Option("--checks", help="GCP file whose points are only checked, never "
                                                                 "fitted: their ground error is printed")] = None,
    report: Annotated[Path | None, typer.Option("--report", help="report JSON to write (ground views tried, "
                                                                 "passes, every correspondence; the frame beside "
                                                                 "it)")] = None,
    gcps_out: Annotated[Path | None, typer.Option("--gcps-out", help="write 40 of the automatic correspondences, "
                                                                     "spread over the frame, as a GCP file to review "
                                                                     "in 'trafficgeo gcp-ui --gcps FILE'")] = None,
    max_offset: Annotated[float, typer.Option("--max-offset", help="how far (m) the camera may stand from "
                                                                   "--near")] = 20.0,
    start: Annotated[float, typer.Option("--start", help="video: first second of the stretch")] = 0.0,
    duration: Annotated[float, typer.Option("--duration", help="video: seconds of the stretch")] = 30.0,
    frames: Annotated[int, typer.Option("--frames", help="video: frames whose temporal mode is the still")] = 25,
    surface_crs: Annotated[str | None, typer.Option(help="CRS of the surface file if it lacks one")] = None,
    resolution: Annotated[float, typer.Option(help="grid cell (m) when the surface is a point cloud")] = 0.25,
) -> None:
    """Calibrate the camera from the orthophoto alone: the frame is warped onto the ground for a sweep of focal
    lengths and tilts and matched to the orthophoto around the pole, the best matches start a calibration, and the
    orthophoto draped on the surface is registered to the frame until the camera stops moving (as 'refine' does).
    Heading, tilt, height, focal length and distortion are found; the camera JSON is the one 'calibrate' writes,
    its GCPs the automatic correspondences. When no camera passes every test, the reason is printed, nothing is
    written and the exit code is 1."""
    from trafficgeo.crs import metres_per_unit
    from trafficgeo.geo.raster import open_raster, read_raster, to_pyproj_crs
    from trafficgeo.registration.from_ortho import OrthoPoseOptions
    from trafficgeo.registration.run import calibrate_ortho_files, read_frame_image

    options = OrthoPoseOptions(max_offset_m=max_offset, focal_px=focal_px)
    ds, _ = open_raster(ortho, "ortho")
    with ds:
        crs = to_pyproj_crs(ds.crs)
        left, bottom, right, top = ds.bounds
    if crs is None:
        raise InputError(f"{ortho}: the orthophoto has no CRS; give a GeoTIFF georeferenced in a projected CRS",
                         parameters=("ortho",))
    position = parse_position(near, near_crs, crs)
    reach = (options.radius_m + options.max_offset_m + 50.0) / metres_per_unit(crs)  # all the search can use
    if not (left - reach < position[0] < right + reach and bottom - reach < position[1] < top + reach):
        raise InputError(f"the camera position ({position[0]:.2f}, {position[1]:.2f}) is more than "
                         f"{options.radius_m:g} m from the orthophoto ({left:.1f}..{right:.1f}, {bottom:.1f}.."
                         f"{top:.1f}); give it in the orthophoto's CRS (or lon,lat with near_crs EPSG:4326)",
                         parameters=("near", "near_crs"))
    raster = read_raster(ortho, bounds=(position[0] - reach, position[1] - reach, position[0] + reach,
                                        position[1] + reach))
    if video.suffix.lower() in IMAGE_SUFFIXES:
        still = read_frame_image(video)
    else:
        from trafficgeo.video.background_frame import background_frame

        with console.status(f"the scene without traffic: temporal mode of {frames} frames of {video.name}"):
            still = background_frame(video, start_s=start, duration_s=duration, n_frames=frames)
    with console.status("searching the orthophoto for the camera's view") as status:
        result = calibrate_ortho_files(still, raster, surface, position, output, checks=checks, report_path=report,
                                       gcps_out=gcps_out, options=options, surface_crs=surface_crs,
                                       resolution_m=resolution, progress=lambda line: status.update(line))
    if not result.accepted:
        console.print(f"[yellow]no camera[/yellow]: {result.reason}; nothing written to {output}")
        raise SystemExit(1)  # exit code 1: the job ran, no trustworthy camera came out of it
    cam = result.calibration.camera
    o = cam.orientation
    console.print(f"[green]calibrated[/green]: {result.reason}")
    console.print(f"heading {o.heading_deg:.2f} deg, tilt {o.tilt_deg:.2f} deg, roll {o.roll_deg:.2f} deg, focal "
                  f"{cam.focal_px:.1f} px; wrote {output}")
    if gcps_out is not None:
        console.print(f"wrote {gcps_out}: review it with 'trafficgeo gcp-ui --gcps {gcps_out}' (drop or move pairs, "
                      "then save the camera)")
    e = result.check_errors_m
    if e.size:
        import numpy as np

        finite = e[np.isfinite(e)]
        console.print(f"check points: ground error median {np.median(finite):.3f} m, max {finite.max():.3f} m over "
                      f"{finite.size} points" if finite.size else "check points: no ray reaches them")
