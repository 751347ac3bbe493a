"""The run entry points of the Python API, composed of the stages of :mod:`trafficgeo.pipeline.stages`:
:func:`process_video` (``trafficgeo process``: decode -> detect -> track -> analyze, streaming and resumable, into a
run folder) and :func:`stitch` (``trafficgeo stitch``: the runs of time chunks of one video joined and analysed).

Both write a :class:`~trafficgeo.run.folder.RunFolder` and return what they computed. Inputs are objects or
paths (:class:`trafficgeo.site.Site`). Times are seconds of video from its start.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.io.json_text import loads_json
from trafficgeo.pipeline.stages import analyze, detect_and_track
from trafficgeo.run.folder import RunFolder
from trafficgeo.run.records import ProcessRecord
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.site.site import Site
from trafficgeo.traffic.analyze import AnalysisOptions, TrafficResult
from trafficgeo.video.detections import DetectionFrames
from trafficgeo.video.pipeline import ProcessOptions

__all__ = ["SITE_WITHOUT_CALIBRATION", "ProcessResult", "RunCallbacks", "process_video", "run_info", "stitch"]

PathLike = str | os.PathLike


@dataclass(frozen=True)
class ProcessResult:
    """What :func:`process_video` did.

    Attributes:
        traffic: the analysis of the tracks (vehicles, crossings, counts, trajectories).
        detections: the detections over time (full precision; written as ``detections.csv``).
        tracks: the tracks as ``tracks.csv`` holds them (what was analysed).
        folder: the run folder written.
        options: the options as run (``every`` and the tracker settled for the video).
        read: what was decoded: ``start_s``, ``end_s`` (s, the end of the last frame used), ``frames``,
            ``complete`` (False when the video ended before the asked end, e.g. a truncated file).
        seconds: wall-clock time of detection and tracking (s).
        warning: one line when less video was read than asked, else None.
        tiling: the built-in learned detector's tile plan (``TilePlan.to_dict()``), or None.
        files: the files written in the folder.
        schedule: what the tile schedule did (``TileSchedule.to_dict()``), or None (no tiles, or all run).
    """

    traffic: TrafficResult
    detections: DetectionFrames
    tracks: ImageTracks
    folder: RunFolder
    options: ProcessOptions
    read: dict[str, Any]
    seconds: float
    warning: str | None
    tiling: dict[str, Any] | None
    files: tuple[str, ...]
    schedule: dict[str, Any] | None = None

    @property
    def realtime_factor(self) -> float | None:
        """Seconds of video processed per second of wall clock (None if nothing was read)."""
        end, start = self.read.get("end_s"), self.read.get("start_s")
        if end is None or start is None or not self.seconds > 0:
            return None
        return (end - start) / self.seconds


READ_RECORD = "read.json"  # in the checkpoint folder: what the detection read, for a run resumed after it finished


def _reader_said(caught: list) -> list[str]:
    """The reader's warnings (:class:`VideoReadWarning`) among ``caught``, once each; others are shown as usual."""
    from trafficgeo.video.reader import VideoReadWarning

    for w in caught:
        if not issubclass(w.category, VideoReadWarning):
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return list(dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, VideoReadWarning)))


def _keep_what_was_read(checkpoint: Path, read: dict, said: list[str]) -> tuple[dict, list[str]]:
    """``read`` and ``said`` as this run saw them, kept in the checkpoint folder once the detection has finished;
    or, for a run resumed after its detection had finished (no frame decoded now), those kept by the run that
    did the detection (a kept record that is not one is ignored)."""
    from trafficgeo.io.atomic import write_json_atomic

    path = checkpoint / READ_RECORD
    if read["frames"] == 0 and not said and path.is_file() and path.stat().st_size < 1 << 20:
        try:
            doc = loads_json(path.read_text(encoding="utf-8"))
            kept, told = doc["read"], doc["said"]
            numbers = [kept["first"], kept["last"]]
            if (set(kept) == {"first", "last", "frames"} and isinstance(kept["frames"], int)
                    and all(v is None or isinstance(v, int | float) for v in numbers)
                    and isinstance(told, list) and all(isinstance(t, str) for t in told)):
                return kept, told
        except (OSError, ValueError, KeyError, TypeError):
            pass
    if checkpoint.is_dir():
        write_json_atomic(path, {"read": read, "said": said})
    return read, said


def _what_was_read(video: Path, opts: ProcessOptions, read: dict, said: list[str]) -> tuple[dict, str | None]:
    """What the frames seen (``read``: first/last frame time (s) and frames) and the reader's warnings (``said``)
    say about the time range read: ``process.json``'s ``read`` and a one-line warning when fewer seconds were decoded
    than asked (or than the file says it holds), else None."""
    from trafficgeo.video.reader import video_info

    info = video_info(video)
    asked = opts.end_s if opts.end_s is not None else info.duration_s
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


@dataclass(frozen=True)
class RunCallbacks:
    """What a long run tells its caller as it goes (each None: nothing): ``progress(frames_done, frames_total,
    video_time_s)`` per frame, ``notice(line)`` with the tile plan, the cost and the checkpoint news (and a stitch's
    gaps), ``annotate_progress(done, total)`` while the annotated video is written."""

    progress: Callable[[int, int, float], None] | None = None
    notice: Callable[[str], None] | None = None
    annotate_progress: Callable[[int, int], None] | None = None


SITE_WITHOUT_CALIBRATION = (
    "site: it was loaded from a bare Camera, which carries no record of its calibration (no GCPs, no covariance), so "
    "each vehicle's speed_kmh is measured over the middle half of the time it is seen, not where the calibration "
    "knows the ground scale; load the site from the camera JSON or the CalibratedCamera (tg.load_camera(path), "
    "Calibration.calibrated_camera())")


def _check_site(site: object) -> Site:
    """``site`` as the :class:`Site` it must be (an InputError naming the fix otherwise), having warned when it was
    loaded from a bare Camera, dropping what a calibration knows (:data:`SITE_WITHOUT_CALIBRATION`)."""
    if not isinstance(site, Site):
        raise InputError(f"site: {type(site).__name__} is not a Site; load it once with tg.Site.load(camera, "
                         "surface, lanes=..., lines=..., gates=...)", parameters=("site",))
    if site.bare_camera:
        warnings.warn(SITE_WITHOUT_CALIBRATION, UserWarning, stacklevel=3)
    return site


def process_video(video: PathLike, site: Site, out_dir: PathLike, *, options: ProcessOptions | None = None,
                  analysis: AnalysisOptions | None = None, roi: np.ndarray | PathLike | None = None,
                  annotate: PathLike | None = None, callbacks: RunCallbacks | None = None) -> ProcessResult:
    """Detect, track and georeference the vehicles of ``video`` on ``site``, then count them (``trafficgeo
    process``), writing the run folder ``out_dir`` (:mod:`trafficgeo.run.folder`). Resumes from the folder's
    checkpoint when run again with the same inputs (``options.restart`` to start over).

    ``site``: the camera, surface, lanes, counting lines and gates, loaded once (:class:`trafficgeo.site.Site`;
    with gates the learned detector's tracks follow the junction's tracker, :func:`~trafficgeo.video.pipeline.
    settled_options`);
    ``options``: the detector, time range, frame step and checkpoints (:class:`~trafficgeo.video.pipeline.
    ProcessOptions`); ``analysis``: counting intervals, the smoother and journeys
    (:class:`~trafficgeo.traffic.analyze.AnalysisOptions`); ``roi``: a bool mask (H, W) or a mask image / CSV polygon;
    ``annotate``: also write an annotated ``.mp4``; ``callbacks``: progress and news (:class:`RunCallbacks`).

    >>> import trafficgeo as tg
    >>> site = tg.Site.load(world / "camera_truth.json", world / "cloud.laz", lanes=world / "lanes.gpkg",
    ...                     lines=world / "count_lines.gpkg")
    >>> run = tg.process_video(world / "video.mp4", site, out / "run", options=tg.ProcessOptions(end_s=4.0))
    >>> run.read["complete"], sorted(run.folder.counts().columns)[:2]
    (True, ['count', 'count_car'])
    """
    from trafficgeo.io.run_manifest import check_writable_folder
    from trafficgeo.traffic.outputs import write_traffic
    from trafficgeo.video.pipeline import finish_run, settled_options
    from trafficgeo.video.reader import video_info

    out = Path(out_dir)
    check_writable_folder(out, "out_dir")
    if annotate is not None and Path(annotate).suffix.lower() != ".mp4":
        raise InputError(f"annotate {annotate}: write the annotated video as .mp4", parameters=("annotate",))
    video = Path(video)
    site = _check_site(site)
    calls = callbacks or RunCallbacks()
    opts = settled_options(options or ProcessOptions(), video_info(video).fps, junction=bool(site.gates))
    mask = roi
    if roi is not None and not isinstance(roi, np.ndarray):
        from trafficgeo.video.roi import read_roi

        mask = read_roi(Path(roi), site.camera.camera.image_size)
    folder = RunFolder(out)
    with folder.writing("process") as run:  # one run in a folder at a time; readers refuse it until it ends
        seen = _detect(video, site, out, opts, mask, calls)  # detections.csv, tracks.csv (resumable)
        result = analyze(seen.tracks, site, analysis=analysis)
        if seen.line_warnings:  # the counting lines too far for the detector: in summary.json too
            result = replace(result, warnings=[*seen.line_warnings, *result.warnings])
        run.adopt("detections.csv", "tracks.csv")  # written as the video was read (checked: RunFolder.write_table)
        write_traffic(run, result, site.camera.camera)
        if annotate is not None:
            from trafficgeo.video.annotate import annotate_video

            annotate_video(video, annotate, seen.tracks, result.points, camera=site.camera.camera,
                           lines=site.count_lines, surface=site.surface, start_s=opts.start_s, end_s=opts.end_s,
                           progress=calls.annotate_progress)
        run.process(run_info(video=str(video), camera=site.camera.source, options=opts, seconds=seen.seconds,
                             detections=seen.detections.scores.size, track_rows=len(seen.tracks), read=seen.read,
                             detector=seen.detector or None))
        finish_run(out)  # the checkpoint goes once the run is written
    return ProcessResult(result, seen.detections, seen.tracks, folder, opts, seen.read, seen.seconds, seen.short,
                         seen.detector.get("tiling"), tuple(p.name for p in run.written), seen.detector.get("schedule"))


@dataclass(frozen=True)
class _Seen:
    """What detection and tracking of a video gave (:func:`_detect`): the detections and tracks, what was read
    (``read``: process.json's; ``short``: the warning when less was read than asked), the detector's record, the
    seconds of wall clock, and the counting lines too far for the detector (warnings)."""

    detections: DetectionFrames
    tracks: ImageTracks
    read: dict
    short: str | None
    detector: dict
    seconds: float
    line_warnings: list[str]


def _detect(video: Path, site: Site, out: Path, opts: ProcessOptions, mask: np.ndarray | None,
            calls: RunCallbacks) -> _Seen:
    """Decode, detect and track ``video`` on ``site`` into the run folder ``out`` (resumably: its checkpoint), as
    ``opts`` say; what was read is kept with the checkpoint so that a resumed run still says it."""
    from trafficgeo.video.checkpoint import CHECKPOINT_DIR
    from trafficgeo.video.reader import VideoReadWarning

    t0 = time.perf_counter()
    read: dict = {"first": None, "last": None, "frames": 0}
    detector: dict = {}

    def tick(done: int, total: int, t: float) -> None:
        read.update(first=read["first"] if read["first"] is not None else t if done == 1 else opts.start_s,
                    last=t, frames=done)
        if calls.progress is not None:
            calls.progress(done, total, t)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", VideoReadWarning)
        detections, tracks = detect_and_track(video, site, out, opts, roi=mask, restart=opts.restart, progress=tick,
                                              notice=calls.notice, detector_info=detector.update)
    elapsed = time.perf_counter() - t0
    read, said = _keep_what_was_read(out / CHECKPOINT_DIR, read, _reader_said(caught))
    read_doc, short = _what_was_read(video, opts, read, said)
    if not len(tracks):
        raise InputError(f"{video}: no vehicle was tracked; check the ROI, the time range and the detector")
    plan = detector.get("tiling") or {}
    return _Seen(detections, tracks, read_doc, short, detector, elapsed, list(plan.get("line_warnings") or []))


def _chunk(folder: Path) -> tuple[pd.DataFrame, tuple[float, float], str | None]:
    """A finished chunk run's tracks, its time range (s of video: start/end of its process.json, else its track
    times) and video name."""
    run = RunFolder(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder; give the output folders of finished 'trafficgeo process' runs")
    table = run.tracks()
    info = run.process()
    times = pd.to_numeric(table["time"], errors="coerce")
    start, end = (info.options.start_s, info.options.end_s) if info is not None else (None, None)
    start = start if start is not None else float(times.min()) if times.notna().any() else 0.0
    end = end if end is not None else float(times.max()) if times.notna().any() else start
    video = Path(info.video).name if info is not None else None
    return table, (start, end), video


def stitch(chunks: Sequence[PathLike], site: Site, out_dir: PathLike, *, analysis: AnalysisOptions | None = None,
           notice: Callable[[str], None] | None = None) -> TrafficResult:
    """Join the tracks of the runs of overlapping time chunks of one video (``process_video`` with ``start_s`` /
    ``end_s``, e.g. on several machines; folders in any order) and analyse them on ``site`` into the run folder
    ``out_dir`` (``trafficgeo stitch``), as ``analysis`` says (the pieces of one vehicle's track are joined across the
    chunks as within one). ``notice(line)`` gets a warning per gap or unequal overlap between chunks."""
    from trafficgeo.io.folder_lock import hold_folder
    from trafficgeo.io.run_manifest import check_writable_folder
    from trafficgeo.traffic.outputs import write_traffic
    from trafficgeo.video.stitch import plan_chunks, stitch_tracks

    out = Path(out_dir)
    check_writable_folder(out, "out_dir")
    site = _check_site(site)
    how = analysis or AnalysisOptions()
    seen: dict[Path, Path] = {}
    for folder in map(Path, chunks):
        key = folder.resolve()
        if key in seen:
            raise InputError(f"{folder}: given twice (as {seen[key]} too); give each chunk once")
        if out.resolve() == key:
            raise InputError(f"out_dir {out}: is one of the chunks; write the stitched run to a folder of its own",
                             parameters=("out_dir",))
        seen[key] = folder
    with hold_folder(out):  # one run at a time in a folder; a run there stays until the new one is written
        read = [_chunk(Path(folder)) for folder in chunks]
        order, problems = plan_chunks([r[1] for r in read], [str(c) for c in chunks], [r[2] for r in read])
        for text in problems:
            if notice is not None:
                notice(f"warning: {text}")
        joined = stitch_tracks([read[k][0] for k in order])
        joined["class"] = joined["class"].fillna("")
        from trafficgeo.traffic.tracks import tracks_from_table

        result = analyze(tracks_from_table(joined), site, analysis=how)
        with RunFolder(out).writing("stitch") as run:
            write_traffic(run, result, site.camera.camera)
            run.table("tracks.csv", joined, float_format="%.3f")
    return result


def run_info(*, video: str, camera: str, options: ProcessOptions, seconds: float, detections: int,
             track_rows: int, read: dict | None = None, detector: dict | None = None) -> ProcessRecord:
    """The record of ``process.json``: what was processed (``video``, ``camera``: paths as given, or relative to
    the run folder), how (the detector and time range asked for in ``options``, and the tracker they settled
    on: pass options settled by :func:`~trafficgeo.video.pipeline.settled_options`), what was read (``read``:
    ``start_s``/``end_s`` of the frames decoded (s, the end of the last frame), ``frames``, and ``complete``: false
    when the video ended before the asked end, e.g. a truncated file), and how fast (``seconds`` of wall clock)."""
    from trafficgeo.run.records import ProcessSettings, VideoRead
    from trafficgeo.video.detectors.names import detector_name

    settings = ProcessSettings(detector=detector_name(options.detector), detector_format=options.detector_format,
                               start_s=options.start_s, end_s=options.end_s, every=options.every,
                               tiles=options.tiles, tiling=options.tiling, backend=options.backend,
                               tile_schedule=options.tile_schedule,
                               tracker=asdict(options.tracker) if options.tracker is not None else None)
    return ProcessRecord(
        video=video, camera=camera, options=settings, detector=detector,
        read=VideoRead(read["start_s"], read["end_s"], read["frames"], read["complete"]) if read is not None else None,
        seconds=seconds, detections=detections, track_rows=track_rows)
