"""``trafficgeo refine``: refine a rough GCP calibration by registering the orthophoto to the video; a thin wrapper
over :func:`trafficgeo.registration.run.refine_camera_files`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console
from trafficgeo.errors import InputError


@app.command()
def refine(
    camera: Annotated[Path, typer.Argument(help="camera JSON from 'trafficgeo calibrate' (the rough camera)")],
    ortho: Annotated[Path, typer.Option("--ortho", help="orthophoto GeoTIFF in the camera's CRS")],
    surface: Annotated[str, typer.Option("--surface", help="DEM (.tif), point cloud (.las/.laz), 'plane' or a "
                                                          "constant elevation")],
    output: Annotated[Path, typer.Option("--output", "-o", help="refined camera JSON to write")],
    video: Annotated[Path | None, typer.Option("--video", help="the calibrated video (its traffic is removed: "
                                                               "temporal mode of --frames frames)")] = None,
    frame: Annotated[Path | None, typer.Option("--frame", help="a still without traffic instead of --video")] = None,
    gcps: Annotated[Path | None, typer.Option("--gcps", help="the GCP file the camera was calibrated from "
                                                             "(default: the GCPs in the camera JSON)")] = None,
    report: Annotated[Path | None, typer.Option("--report", help="refinement report JSON to write (with the frame "
                                                                 "matched on beside it)")] = None,
    start: Annotated[float, typer.Option("--start", help="video: first second of the stretch")] = 0.0,
    duration: Annotated[float, typer.Option("--duration", help="video: seconds of the stretch")] = 30.0,
    frames: Annotated[int, typer.Option("--frames", help="video: frames whose temporal mode is the still")] = 25,
    search: Annotated[float, typer.Option("--search", help="how far (px) the rough camera may be off")] = 60.0,
    surface_crs: Annotated[str | None, typer.Option(help="CRS of the surface file if it lacks one")] = None,
    resolution: Annotated[float, typer.Option(help="grid cell (m) when the surface is a point cloud")] = 0.25,
) -> None:
    """Refine CAMERA by matching the orthophoto, draped on the surface, to the video: hundreds of automatic
    correspondences, a robust re-fit, repeated until the camera stops moving. The user's own GCPs judge it by their
    check-point / leave-one-out error in pixels, where every click's noise weighs the same (on the ground a click's
    noise grows with its distance, so the farthest clicks would decide): the refined camera is written when it
    misses them less, or no worse than their noise can tell; the ground errors before and after are printed beside.
    Otherwise the original camera is written unchanged, the reason printed, and the exit code is 1. A camera from
    'calibrate-ortho' has no clicks of the user's: give them with --gcps."""
    from trafficgeo.cli.geo import camera_argument, surface_argument
    from trafficgeo.registration.refine import RefineOptions
    from trafficgeo.registration.run import read_frame_image, refine_camera_files

    if (video is None) == (frame is None):
        raise InputError("give the video (--video) or a still without traffic (--frame), one of them",
                         parameters=("video", "frame"))
    options = RefineOptions(search_px=search)
    calibrated = camera_argument(camera)
    ground = surface_argument(surface, calibrated, surface_crs, resolution)
    if video is not None:
        from trafficgeo.video.background_frame import background_frame

        with console.status(f"the scene without traffic: temporal mode of {frames} frames of {video.name}"):
            still = background_frame(video, start_s=start, duration_s=duration, n_frames=frames)
    else:
        still = read_frame_image(frame)
    table = None
    if gcps is not None:
        from trafficgeo.calibration.gcp_read import read_gcps

        table = read_gcps(gcps, crs=calibrated.camera.crs)
        if table.columns_note:
            console.print(f"{gcps}: columns read as {table.columns_note}")
    result = refine_camera_files(calibrated, still, ortho, ground, output, gcps=table, report_path=report,
                                 options=options, progress=console.print)
    b, a = result.before, result.after
    console.print(f"user's points, held-out error RMS: before {b.rmse_px:.2f} px ({b.rmse_m:.3f} m on the ground)"
                  + (f", after {a.rmse_px:.2f} px ({a.rmse_m:.3f} m)" if a is not None else ""))
    if result.accepted:
        console.print(f"[green]refined[/green]: {result.reason}; wrote {output}")
        return
    console.print(f"[yellow]refinement refused[/yellow]: {result.reason}; {output} is the original camera")
    raise SystemExit(1)  # exit code 1: the job ran, its result is not trustworthy (explained above)
