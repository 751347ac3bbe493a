"""Video commands: process (decode -> detect -> track -> analyze, resumable) and stitch (time chunks)."""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli import app, console
from trafficgeo.cli.geo import ResolutionOpt, SurfaceCrsOpt, SurfaceOpt, _camera, _surface
from trafficgeo.cli.traffic import IntervalOpt, LanesOpt, LinesOpt, ReportHtmlOpt, _check_out_dir, _layout
from trafficgeo.errors import InputError
from trafficgeo.video.detector_names import DETECTOR_HELP
from trafficgeo.video.onnx_formats import FORMAT_HELP


def _analyze_and_write(cam, surf, image_tracks, lane_set, count_lines, interval: float, out: Path):
    """Analyze and write the outputs, without publishing the run (the caller adds its files and publishes)."""
    from trafficgeo.report.traffic import print_analysis
    from trafficgeo.traffic.analyze import analyze as run_analysis
    from trafficgeo.traffic.analyze import write_analysis

    result = run_analysis(cam, surf, image_tracks, lanes=lane_set, lines=count_lines, interval_s=interval)
    written = write_analysis(out, result, cam, publish=False)
    print_analysis(result, console)
    return result, written


def _what_was_read(video: Path, opts, read: dict, caught: list) -> tuple[dict, str | None]:
    """What the frames seen (``read``: first/last frame time (s) and frames, from the progress ticks) and the
    reader's warnings (``caught``) say about the time range read: ``process.json``'s ``read`` and a one-line
    warning when fewer seconds were decoded than asked (or than the file says it holds), else None."""
    from trafficgeo.video.reader import VideoReadWarning, video_info

    for w in caught:  # other warnings are shown as usual
        if not issubclass(w.category, VideoReadWarning):
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    info = video_info(video)
    asked = opts.end_s if opts.end_s is not None else info.duration_s
    said = list(dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, VideoReadWarning)))
    step = opts.every / info.fps if info.fps > 0 else 0.0
    end = None if read["last"] is None else read["last"] + step  # the end of the last frame used
    doc = {"start_s": read["first"], "end_s": end, "frames": read["frames"]}
    short = end is not None and asked - end > 0.5 * step + 1e-6
    if not (short or said):
        return {**doc, "complete": True}, None
    got = f"{read['first']:.2f}-{end:.2f} s ({read['frames']} frames)" if end is not None else "no frame"
    why = said[-1] if said else f"the video is {info.duration_s:.2f} s long"  # the main pass: the last
    return ({**doc, "complete": False},
            f"warning: read {got} of the asked {opts.start_s:g}-{asked:.2f} s; {why}")


@app.command()
def process(
    ctx: typer.Context,
    video: Annotated[Path, typer.Argument(help="video file (mp4/mov/...) from a fixed camera")],
    camera: Annotated[Path, typer.Option(help="camera JSON from 'trafficgeo calibrate' (on a frame of this "
                                         "video)")],
    surface: SurfaceOpt,
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    lanes: LanesOpt = None,
    lines: LinesOpt = None,
    interval: IntervalOpt = 60.0,
    detector: Annotated[str, typer.Option(help=DETECTOR_HELP)] = "nanodet",
    detector_format: Annotated[str, typer.Option(help=FORMAT_HELP)] = "auto",
    start: Annotated[float, typer.Option(help="start time (s)")] = 0.0,
    end: Annotated[float | None, typer.Option(help="end time (s); default: the end of the video")] = None,
    every: Annotated[int | None, typer.Option(help="detect on every n-th frame (default: every frame for background "
                                              "subtraction, about 10 a second for a learned detector)")] = None,
    tiles: Annotated[bool, typer.Option(help="with the built-in learned detector: also run it on tiles over the far "
                                        "road (planned from the camera and --lanes or --roi) so that far vehicles "
                                        "are large enough for it")] = True,
    roi: Annotated[Path | None, typer.Option(help="region of interest: mask image or CSV polygon u,v")] = None,
    checkpoint: Annotated[float, typer.Option(help="seconds of video between checkpoints")] = 30.0,
    restart: Annotated[bool, typer.Option(help="ignore a checkpoint and start again")] = False,
    annotate: Annotated[Path | None, typer.Option(help="also write an annotated video (.mp4): boxes, ids, lanes, "
                                                  "km/h, counting lines")] = None,
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
    from trafficgeo.traffic.lines import check_interval
    from trafficgeo.traffic.tracks import tracks_from_table
    from trafficgeo.video.pipeline import (
        ProcessOptions,
        detect_and_track,
        finish_run,
        hold_folder,
        settled_options,
        write_run_info,
    )
    from trafficgeo.video.reader import VideoReadWarning, video_info

    _check_out_dir(out)
    check_html_path(report_html)
    check_interval(interval)
    if annotate is not None and annotate.suffix.lower() != ".mp4":
        raise InputError(f"--annotate {annotate}: write the annotated video as .mp4")
    opts = ProcessOptions(detector=detector, detector_format=detector_format, start_s=start, end_s=end, every=every,
                          checkpoint_s=checkpoint, tiles=tiles)
    cam, doc = _camera(camera)
    surf = _surface(surface, cam, doc, surface_crs, resolution, str(camera))
    lane_set, count_lines = _layout(cam, surf, lanes, lines)
    opts = settled_options(opts, video_info(video).fps)  # settled here too, for process.json
    mask = None
    if roi is not None:
        from trafficgeo.video.roi import read_roi

        mask = read_roi(roi, cam.image_size)
    from trafficgeo.io.run_manifest import begin_outputs, publish_outputs

    ctx.with_resource(hold_folder(out))  # one run in a folder until the command ends
    begin_outputs(out)  # from here until the end, readers refuse the folder
    t0 = time.perf_counter()
    read: dict = {"first": None, "last": None, "frames": 0}  # frame times (s) and frames seen
    detector_doc: dict = {}  # the detector's tile plan, for process.json
    columns = (TextColumn("[progress.description]{task.description}"), BarColumn(),
               TextColumn("{task.completed}/{task.total} frames, {task.fields[rate]:.1f} fps, video {task.fields[t]}"),
               TimeRemainingColumn())
    try:
        with Progress(*columns, console=console, transient=True) as bar:
            task = bar.add_task("detect + track", total=None, rate=0.0, t="-")

            def tick(done: int, total: int, t: float) -> None:
                rate = done / max(time.perf_counter() - t0, 1e-9)
                bar.update(task, completed=done, total=total, rate=rate, t=f"{t:.1f} s")
                read.update(first=read["first"] if read["first"] is not None else t if done == 1 else start,
                            last=t, frames=done)

            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", VideoReadWarning)
                detections, tracks = detect_and_track(video, cam, surf, out, opts, roi=mask, restart=restart,
                                                      lanes=lane_set, progress=tick,
                                                      notice=lambda text: console.print(text, markup=False),
                                                      detector_info=detector_doc.update)
    except KeyboardInterrupt:
        console.print(f"interrupted; run the same command again to resume from the last checkpoint in {out}")
        sys.exit(130)
    elapsed = time.perf_counter() - t0
    read_doc, short = _what_was_read(video, opts, read, caught)
    if short:
        console.print(short, markup=False, soft_wrap=True)
    seen_s = (read_doc["end_s"] - read_doc["start_s"]) if read_doc.get("end_s") is not None else 0.0
    pace = f" ({seen_s / elapsed:.2f}x real time)" if seen_s > 0 and elapsed > 0 else ""
    console.print(f"{len(detections)} detections, {tracks['track_id'].nunique() if len(tracks) else 0} tracks "
                  f"in {elapsed:.1f} s{pace}")
    if not len(tracks):
        raise InputError(f"{video}: no vehicle was tracked; check --roi, --start/--end and the detector")
    result, written = _analyze_and_write(cam, surf, tracks_from_table(tracks), lane_set, count_lines,
                                         interval, out)
    if annotate is not None:
        from trafficgeo.video.annotate import annotate_video

        with Progress(*columns[:2], TextColumn("{task.completed}/{task.total} frames"), console=console,
                      transient=True) as bar:
            task = bar.add_task("annotated video", total=None)
            annotate_video(video, annotate, tracks, result.points, camera=cam, lines=count_lines, surface=surf,
                           progress=lambda d, n: bar.update(task, completed=d, total=n))
        console.print(f"wrote {annotate}")
    write_run_info(out, video=str(video), camera=str(camera), options=opts, seconds=elapsed,
                   detections=len(detections), track_rows=len(tracks), read=read_doc, detector=detector_doc or None)
    finish_run(out)
    publish_outputs(out, ["detections.csv", "tracks.csv", *written, "process.json"], command="process")
    console.print(f"wrote detections.csv, tracks.csv, {', '.join(p.name for p in written)}, process.json in {out}")
    if report_html is not None:
        from trafficgeo.cli.report import write_page

        write_page(report_html, out, camera=camera)  # the video and its --start come from process.json
    if short and strict:
        sys.exit(1)  # --strict: the video ended before the asked end


def _read_chunk(folder: Path):
    """A chunk's tracks and its time range (s of video: --start/--end of its process.json, else its track times)
    and video name; the folder must be a finished run."""
    import json

    import pandas as pd

    from trafficgeo.io.run_manifest import verify_outputs

    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder; give the --out folders of finished 'trafficgeo process' runs")
    manifest = verify_outputs(folder, require=("tracks.csv",))
    table = pd.read_csv(folder / "tracks.csv", dtype={"class": str}, keep_default_na=False, na_values=[""])
    info = json.loads((folder / "process.json").read_text()) if manifest.has("process.json") else {}
    options = info.get("options") or {}
    times = pd.to_numeric(table["time"], errors="coerce") if "time" in table.columns else pd.Series([], dtype=float)
    start = options.get("start_s")
    end = options.get("end_s")
    start = float(start) if isinstance(start, int | float) else float(times.min()) if times.notna().any() else 0.0
    end = float(end) if isinstance(end, int | float) else float(times.max()) if times.notna().any() else start
    video = Path(str(info["video"])).name if isinstance(info.get("video"), str) else None
    return table, (start, end), video


@app.command()
def stitch(
    chunks: Annotated[list[Path], typer.Argument(help="--out folders of 'process --start/--end' runs of one "
                                                 "video, overlapping by a few seconds (in any order)")],
    camera: Annotated[Path, typer.Option(help="camera JSON")],
    surface: SurfaceOpt,
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    lanes: LanesOpt = None,
    lines: LinesOpt = None,
    interval: IntervalOpt = 60.0,
    surface_crs: SurfaceCrsOpt = None,
    resolution: ResolutionOpt = 0.25,
) -> None:
    """Join the tracks of time chunks of one video (processed apart, e.g. on several machines) and analyze them."""
    from trafficgeo.io.atomic import write_csv_atomic
    from trafficgeo.io.run_manifest import publish_outputs
    from trafficgeo.traffic.lines import check_interval
    from trafficgeo.traffic.tracks import tracks_from_table
    from trafficgeo.video.stitch import plan_chunks, stitch_tracks

    _check_out_dir(out)
    check_interval(interval)
    seen: dict[Path, Path] = {}
    for folder in chunks:
        key = folder.resolve()
        if key in seen:
            raise InputError(f"{folder}: given twice (as {seen[key]} too); give each chunk once")
        if out.resolve() == key:
            raise InputError(f"--out {out}: is one of the chunks; write the stitched run to a folder of its own")
        seen[key] = folder
    read = [_read_chunk(folder) for folder in chunks]
    order, warnings = plan_chunks([r[1] for r in read], [str(c) for c in chunks], [r[2] for r in read])
    for text in warnings:
        console.print(f"warning: {text}", markup=False, highlight=False)
    cam, doc = _camera(camera)
    surf = _surface(surface, cam, doc, surface_crs, resolution, str(camera))
    lane_set, count_lines = _layout(cam, surf, lanes, lines)
    joined = stitch_tracks([read[k][0] for k in order])
    joined["class"] = joined["class"].fillna("")
    _, written = _analyze_and_write(cam, surf, tracks_from_table(joined), lane_set, count_lines, interval, out)
    write_csv_atomic(out / "tracks.csv", joined, float_format="%.3f")
    publish_outputs(out, [*written, "tracks.csv"], command="stitch")
    console.print(f"stitched {len(chunks)} chunks: {joined['track_id'].nunique()} tracks; wrote {out}")
