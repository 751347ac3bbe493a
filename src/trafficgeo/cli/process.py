"""Video commands: process (decode -> detect -> track -> analyze, resumable) and stitch (time chunks)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console
from trafficgeo.cli.geo import ResolutionOpt, SurfaceCrsOpt, SurfaceOpt
from trafficgeo.cli.traffic import (
    GatesOpt,
    IntervalOpt,
    LanesOpt,
    LinesOpt,
    MovementIntervalOpt,
    ReportHtmlOpt,
    check_out_dir,
)
from trafficgeo.video.detectors.names import DETECTOR_HELP
from trafficgeo.video.detectors.onnx_formats import FORMAT_HELP


@app.command()
def process(
    video: Annotated[Path, typer.Argument(help="video file (mp4/mov/...) from a fixed camera")],
    camera: Annotated[Path, typer.Option(help="camera JSON from 'trafficgeo calibrate' (on a frame of this "
                                         "video)")],
    surface: SurfaceOpt,
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    lanes: LanesOpt = None,
    lines: LinesOpt = None,
    gates: GatesOpt = None,
    interval: IntervalOpt = 60.0,
    movement_interval: MovementIntervalOpt = 900.0,
    detector: Annotated[str, typer.Option(help=DETECTOR_HELP)] = "nanodet",
    detector_format: Annotated[str, typer.Option(help=FORMAT_HELP)] = "auto",
    start: Annotated[float, typer.Option(help="start time (s)")] = 0.0,
    end: Annotated[float | None, typer.Option(help="end time (s); default: the end of the video")] = None,
    every: Annotated[int | None, typer.Option(help="detect on every n-th frame (default: every frame for background "
                                              "subtraction, about 10 a second for a learned detector)")] = None,
    tiles: Annotated[bool, typer.Option(help="with the built-in learned detector: also run it on tiles over the far "
                                        "road (planned from the camera and --lanes, else --roi, else a band of road "
                                        "around each of the --lines) so that far vehicles are large enough for it; "
                                        "warns per counting line where they stay too small")] = True,
    tiling: Annotated[str, typer.Option(help="how the tiles are planned: 'squares' (the most accurate on the demo "
                                        "world) or 'bands' (rectangles at their own input size: about 2.5x less "
                                        "detector work)")] = "squares",
    backend: Annotated[str, typer.Option(help="what runs a learned detector's network: 'auto' (the fastest installed "
                                         "runtime that agrees with onnxruntime, the built-in model's INT8 version "
                                         "included, by a short probe cached per machine and model), 'onnxruntime', "
                                         "'onnxruntime-int8' or 'openvino' (pip install "
                                         "trafficgeo[openvino])")] = "auto",
    tile_schedule: Annotated[str, typer.Option(help="when the tiles run: 'all' (every tile on every detection "
                                               "frame), 'sparse' (each tile as often as a vehicle at 100 km/h "
                                               "needs to be seen 4 times in it, at least every 0.5 s, and on the "
                                               "frame after a new vehicle appears in it; tiles whose pixels did "
                                               "not change are skipped: faster, but it counted fewer vehicles) or "
                                               "'auto' ('all' where the cost estimate keeps real time, else "
                                               "'sparse')")] = "auto",
    roi: Annotated[Path | None, typer.Option(help="region of interest: mask image or CSV polygon u,v")] = None,
    checkpoint: Annotated[float, typer.Option(help="seconds of video between checkpoints")] = 30.0,
    restart: Annotated[bool, typer.Option(help="ignore a checkpoint and start again")] = False,
    annotate: Annotated[Path | None, typer.Option(help="also write an annotated video (.mp4): boxes, ids, lanes, "
                                                  "km/h, counting lines")] = None,
    join_gap: Annotated[float, typer.Option(help="the longest time (s) a vehicle may go unseen between two pieces "
                                            "of its track that are joined into one vehicle (0: not joined)")] = 4.0,
    surface_crs: SurfaceCrsOpt = None,
    resolution: ResolutionOpt = 0.25,
    report_html: ReportHtmlOpt = None,
    strict: Annotated[bool, typer.Option(help="exit 1 (after writing the outputs) when fewer seconds of video "
                                         "could be decoded than asked: a truncated or damaged file")] = False,
) -> None:
    """Detect, track and georeference the vehicles of a video; then counts, speeds and lanes as 'analyze'.

    Interrupted runs resume from their last checkpoint when the same command is run again. A video that ends
    early (truncated or damaged) is used as far as it decodes, with a warning; process.json says what was read.
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from trafficgeo.cli.report import check_html_path
    from trafficgeo.pipeline.run import RunCallbacks, process_video
    from trafficgeo.report.traffic import print_analysis
    from trafficgeo.site.site import Site
    from trafficgeo.traffic.analyze import AnalysisOptions
    from trafficgeo.traffic.journeys import JourneyOptions
    from trafficgeo.video.pipeline import ProcessOptions

    check_out_dir(out)
    check_html_path(report_html)
    opts = ProcessOptions(detector=detector, detector_format=detector_format, start_s=start, end_s=end, every=every,
                          checkpoint_s=checkpoint, tiles=tiles, tiling=tiling, backend=backend,
                          tile_schedule=tile_schedule, restart=restart)
    analysis = AnalysisOptions(interval_s=interval, movement_interval_s=movement_interval,
                               journeys=JourneyOptions.with_gap(join_gap, at_junction=gates is not None))
    site = Site.load(camera, surface, lanes, lines, gates=gates, surface_crs=surface_crs, resolution_m=resolution)
    columns = (TextColumn("[progress.description]{task.description}"), BarColumn(),
               TextColumn("{task.completed}/{task.total} frames, {task.fields[rate]:.1f} fps, video {task.fields[t]}"),
               TimeRemainingColumn())
    t0 = time.perf_counter()
    try:
        with Progress(*columns, console=console, transient=True) as bar:
            task = bar.add_task("detect + track", total=None, rate=0.0, t="-")
            drawn = bar.add_task("annotated video", total=None, rate=0.0, t="-", visible=False)

            def tick(done: int, total: int, t: float) -> None:
                rate = done / max(time.perf_counter() - t0, 1e-9)
                bar.update(task, completed=done, total=total, rate=rate, t=f"{t:.1f} s")

            said = RunCallbacks(progress=tick, notice=lambda text: console.print(text, markup=False),
                                annotate_progress=lambda d, n: bar.update(drawn, completed=d, total=n,
                                                                          visible=True))
            run = process_video(video, site, out, options=opts, analysis=analysis, roi=roi, annotate=annotate,
                                callbacks=said)
    except KeyboardInterrupt:
        console.print(f"interrupted; run the same command again to resume from the last checkpoint in {out}")
        sys.exit(130)
    if run.warning:
        console.print(run.warning, markup=False, soft_wrap=True)
    pace = f" ({run.realtime_factor:.2f}x real time)" if run.realtime_factor else ""
    n_tracks = run.tracks.track_ids.size
    console.print(f"{run.detections.scores.size} detections, {n_tracks} tracks in {run.seconds:.1f} s{pace}")
    print_analysis(run.traffic, console)
    if annotate is not None:
        console.print(f"wrote {annotate}")
    console.print(f"wrote {', '.join(run.files)} in {out}")
    if report_html is not None:
        from trafficgeo.cli.report import write_page

        write_page(report_html, out, camera=camera)  # the video and its --start come from process.json
    if run.warning and strict:
        sys.exit(1)  # --strict: the video ended before the asked end


@app.command()
def stitch(
    chunks: Annotated[list[Path], typer.Argument(help="--out folders of 'process --start/--end' runs of one "
                                                 "video, overlapping by a few seconds (in any order)")],
    camera: Annotated[Path, typer.Option(help="camera JSON")],
    surface: SurfaceOpt,
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    lanes: LanesOpt = None,
    lines: LinesOpt = None,
    gates: GatesOpt = None,
    interval: IntervalOpt = 60.0,
    movement_interval: MovementIntervalOpt = 900.0,
    surface_crs: SurfaceCrsOpt = None,
    resolution: ResolutionOpt = 0.25,
) -> None:
    """Join the tracks of time chunks of one video (processed apart, e.g. on several machines) and analyze them."""
    from trafficgeo.pipeline.run import stitch as stitch_runs
    from trafficgeo.report.traffic import print_analysis
    from trafficgeo.site.site import Site
    from trafficgeo.traffic.analyze import AnalysisOptions

    check_out_dir(out)
    analysis = AnalysisOptions(interval_s=interval, movement_interval_s=movement_interval)
    site = Site.load(camera, surface, lanes, lines, gates=gates, surface_crs=surface_crs, resolution_m=resolution)
    result = stitch_runs(chunks, site, out, analysis=analysis,
                         notice=lambda text: console.print(text, markup=False, highlight=False))
    print_analysis(result, console)
    console.print(f"stitched {len(chunks)} chunks: {len(result.vehicles)} vehicles; wrote {out}")
