"""Running one task of a batch into the dataset (:mod:`trafficgeo.batch.dataset`), idempotently.

* **detect** runs the pipeline's :func:`~trafficgeo.pipeline.stages.detect` stage over its window of the video in
  ``DATASET/_work/<task>/`` (a retried task resumes from its checkpoint), then writes the window's detection boxes
  and the frames read (``detections`` and ``frames`` tables, full precision, from the stage's
  :class:`~trafficgeo.video.detections.DetectionFrames`) and removes the work folder.
* **track** reads the frames and detections of the detect tasks it depends on, keeps those of its camera-day (local
  midnight to midnight), cuts them into *segments* where consecutive frames are more than ``max(1 s, 3 frame
  steps)`` apart (or the frame rate changes), tracks each segment with the
  :func:`~trafficgeo.pipeline.stages.track` stage set up as the pipeline sets it up (``fps / every``; frame times
  only for variable-frame-rate video), so that a vehicle crossing from one file into the next stays one vehicle, and
  analyses each segment with the :func:`~trafficgeo.pipeline.stages.analyze` stage (boxes rounded to 1/1000 px as
  ``process`` writes them in ``tracks.csv``, so that one file gives exactly ``process``'s results). Track ids are
  ``<segment>-<tracker id>``, unique in the day. The analysis of a segment runs on seconds from an origin a whole
  number of counting intervals after local midnight, so count intervals start on the clock (whole minutes for 60 s);
  a segment gets counts of its own, so an interval a gap cuts in two appears twice, each with its observed part.

A task's key (:func:`task_key`) is a SHA-256 over everything its outputs depend on; ``_SUCCESS.json``, written last,
holds it with the outputs' SHA-256 (:func:`is_done`). Bad input (:class:`~trafficgeo.errors.InputError`) gives a
``failed`` outcome and leaves nothing behind; any other exception propagates (the runner retries the task).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from datetime import UTC, datetime, timedelta
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.batch.dataset import (
    camera_position,
    check_dataset,
    day_tables,
    ensure_dataset,
    merge_day,
    table_metadata,
    table_path,
    write_day_tables,
    write_table,
)
from trafficgeo.batch.day_report import report_path, write_day_report
from trafficgeo.batch.model import BATCH_OPTIONS, CameraEntry, Task, TaskOutcome, task_folder, utc_text
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import write_json_atomic
from trafficgeo.io.json_text import loads_json
from trafficgeo.pipeline.stages import analyze, detect, track
from trafficgeo.site.site import Site
from trafficgeo.video.pipeline import ProcessOptions, settled_options

__all__ = ["BatchContext", "is_done", "run_task", "task_key"]

SUCCESS_FILE = "_SUCCESS.json"
BOX = ["x1", "y1", "x2", "y2"]


@dataclass(frozen=True)
class BatchContext:
    """What every task of a batch shares: the ``dataset`` folder, the camera entries by id and the dataset ``crs``;
    ``tasks`` (by id, optional) lets a track task's key include its dependencies' keys computed from their inputs
    (without it they are read from the dependencies' ``_SUCCESS.json``)."""

    dataset: Path
    cameras: Mapping[str, CameraEntry]
    crs: str
    tasks: Mapping[str, Task] = field(default_factory=dict)

    @classmethod
    def from_plan(cls, plan: Any, dataset: str | os.PathLike) -> BatchContext:
        """The context of a plan (any object with ``cameras``, ``crs`` and ``tasks``) writing into ``dataset``."""
        tasks = {t.task_id: t for t in getattr(plan, "tasks", ())}
        return cls(Path(dataset), dict(plan.cameras), str(plan.crs), tasks)


# ------------------------------------------------------------------------------------------------ keys
@lru_cache(maxsize=256)
def _file_sha256(path: str, size: int, mtime_ns: int) -> str:
    """SHA-256 of a whole file, remembered per (path, size, mtime) within a worker."""
    from trafficgeo.video.checkpoint import sha256_file

    return sha256_file(Path(path))


def _sha256(path: Path) -> str:
    st = path.stat()
    return _file_sha256(str(path.resolve()), st.st_size, st.st_mtime_ns)


def _input_id(path: str | os.PathLike | None) -> str | None:
    """A file's content hash; a spec that is no file (a number, ``plane``) as its text; None as None."""
    if path is None:
        return None
    p = Path(path)
    if p.is_file():
        return "sha256:" + _sha256(p)
    return "text:" + str(path)


def _video_fingerprint(path: Path | None) -> str:
    """The plan's fingerprint of the video (:func:`trafficgeo.batch.videos.fingerprint`: its size and the hash of
    its first and last MiB, cheap for hour-long files); ``missing`` when not a file."""
    from trafficgeo.batch.videos import fingerprint

    if path is None or not Path(path).is_file():
        return "missing"
    return fingerprint(Path(path), Path(path).stat().st_size)


def _entry(task: Task, ctx: BatchContext) -> CameraEntry:
    entry = ctx.cameras.get(task.camera_id)
    if entry is None:
        raise InputError(f"task {task.task_id}: camera {task.camera_id} is not in cameras.csv")
    return entry


def task_key(task: Task, ctx: BatchContext) -> str:
    """SHA-256 (hex) of what the task's outputs depend on. detect: the video fingerprint and window (and its start
    time), the camera, surface and lanes (the detector's size filter and tiles), the detector, the options (but the
    counting interval) and the trafficgeo version, and the counting lines when no lanes are given (they plan the
    detector's tiles then); track: the keys of its dependencies, the camera, surface, lanes, lines, time zone and day,
    the detector, the options, the dataset CRS and the version. With lanes, counting lines and the interval do not
    enter a detect key, so changing them re-does only the track tasks."""
    from trafficgeo.version import __version__

    entry = _entry(task, ctx)
    detector = entry.detector or "nanodet"
    doc: dict[str, Any] = {"stage": task.stage, "trafficgeo": __version__, "camera_id": entry.camera_id,
                           "camera": _input_id(entry.camera), "surface": _input_id(entry.surface),
                           "lanes": _input_id(entry.lanes),
                           "detector": _input_id(detector) if Path(detector).is_file() else detector}
    options = dict(entry.options)
    if task.stage == "detect":
        for name in BATCH_OPTIONS:
            options.pop(name, None)
        doc.update(video=_video_fingerprint(task.video), window=[task.video_start_s, task.video_end_s],
                   start_utc=utc_text(task.start_utc))
        if entry.lanes is None:
            doc["lines"] = _input_id(entry.lines)
    elif task.stage == "track":
        doc.update(lines=_input_id(entry.lines), day=task.day, timezone=entry.timezone, crs=ctx.crs,
                   depends=[_dependency_key(d, ctx) for d in task.depends])
    else:
        raise InputError(f"task {task.task_id}: stage {task.stage!r} is not detect or track")
    doc["options"] = options
    text = json.dumps(doc, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _dependency_key(task_id: str, ctx: BatchContext) -> str:
    dep = ctx.tasks.get(task_id)
    if dep is not None:
        return task_key(dep, ctx)
    doc = _success(ctx.dataset, task_id)
    return str(doc.get("key")) if doc else f"not done: {task_id}"


# ------------------------------------------------------------------------------------------------ done
def _success_path(dataset: Path, task_id: str) -> Path:
    return Path(dataset) / "_tasks" / task_folder(task_id) / SUCCESS_FILE


def _success(dataset: Path, task_id: str) -> dict[str, Any] | None:
    path = _success_path(dataset, task_id)
    try:
        doc = loads_json(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("outputs"), dict) else None


def _done(task: Task, ctx: BatchContext, key: str) -> dict[str, Any] | None:
    doc = _success(ctx.dataset, task.task_id)
    if doc is None or doc.get("key") != key:
        return None
    for rel, digest in doc["outputs"].items():
        path = Path(ctx.dataset) / rel
        if not path.is_file() or _sha256(path) != digest:
            return None
    return doc


def is_done(task: Task, ctx: BatchContext) -> bool:
    """Whether ``task`` has run with its current key and its outputs are unchanged since."""
    try:
        return _done(task, ctx, task_key(task, ctx)) is not None
    except InputError:  # a task of an unknown camera or stage is never done
        return False


# ------------------------------------------------------------------------------------------------ running
def run_task(task: Task, ctx: BatchContext) -> TaskOutcome:
    """Run ``task`` into ``ctx.dataset`` unless it is done (``skipped``, nothing touched). Bad input gives a
    ``failed`` outcome with a one-line reason and leaves nothing of the task behind; other errors propagate."""
    t0 = time.perf_counter()
    try:
        key = task_key(task, ctx)
    except InputError as exc:  # a task of an unknown camera or stage
        return TaskOutcome(task.task_id, "failed", reason=" ".join(str(exc).split()))
    doc = _done(task, ctx, key)
    if doc is not None:
        return TaskOutcome(task.task_id, "skipped", key=key, seconds=time.perf_counter() - t0,
                           outputs=tuple(doc["outputs"]))
    dataset = Path(ctx.dataset)
    existed = dataset.exists()
    work = dataset / "_work" / task_folder(task.task_id)
    try:
        check_dataset(dataset, ctx.crs)
        entry = _entry(task, ctx)
        if task.stage == "detect":
            written, extra, video_s = _run_detect(task, ctx, entry, work)
        else:
            written, extra, video_s = _run_track(task, ctx, entry)
    except InputError as exc:
        _remove_work(work, dataset, existed)
        reason = " ".join(str(exc).split())
        return TaskOutcome(task.task_id, "failed", key=key, reason=reason, seconds=time.perf_counter() - t0)
    outputs = {p.relative_to(dataset).as_posix(): _sha256(p) for p in written}
    seconds = time.perf_counter() - t0
    from trafficgeo.version import __version__

    write_json_atomic(_success_path(dataset, task.task_id),
                      {"task_id": task.task_id, "stage": task.stage, "camera_id": task.camera_id, "key": key,
                       "outputs": outputs, "seconds": seconds, "finished_utc": utc_text(datetime.now(UTC)),
                       "trafficgeo": __version__, **extra})
    if task.stage == "detect":
        _remove_work(work, dataset, True)
    return TaskOutcome(task.task_id, "done", key=key, seconds=seconds, video_s=video_s, outputs=tuple(outputs))


def _remove_work(work: Path, dataset: Path, existed: bool) -> None:
    """Remove a task's work folder, ``_work`` when that leaves it empty, and the dataset folder when this task made
    it and it is empty (never another task's files: only empty folders go)."""
    if work.exists():
        shutil.rmtree(work, ignore_errors=True)
    for folder in (work.parent, *(() if existed else (dataset,))):
        with contextlib.suppress(OSError):  # not empty (another task writes there) or gone
            folder.rmdir()


def process_options(entry: CameraEntry, **window: float) -> ProcessOptions:
    """The :class:`ProcessOptions` of a camera entry (its detector and options; ``window``: ``start_s``,
    ``end_s``); :class:`InputError` naming an unknown option."""
    from trafficgeo.video.track import TrackerOptions

    known = {f.name for f in fields(ProcessOptions)} - {"detector", "start_s", "end_s"}
    unknown = sorted(set(entry.options) - known - set(BATCH_OPTIONS))
    if unknown:
        raise InputError(f"camera {entry.camera_id}: options {', '.join(unknown)} unknown; use "
                         f"{', '.join(sorted(known | set(BATCH_OPTIONS)))}")
    kw = {k: v for k, v in entry.options.items() if k in known}
    try:
        if isinstance(kw.get("tracker"), dict):
            kw["tracker"] = TrackerOptions(**kw["tracker"])
        return ProcessOptions(detector=entry.detector or "nanodet", **kw, **window)
    except TypeError as exc:
        raise InputError(f"camera {entry.camera_id}: options: {exc}") from None


@lru_cache(maxsize=4)
def _surface(spec: str, camera: str, identity: tuple[str | None, str | None]) -> Any:
    """The surface of a camera, built once per worker process for the same files (``identity``: their hashes): a
    point cloud is gridded once, not by every task of the camera (read only: tasks never change a surface)."""
    from trafficgeo.site.surface import load_surface

    return load_surface(spec, camera)


def _site(entry: CameraEntry, *, lines: bool) -> Site:
    """The camera's site (its surface from the worker's cache); ``lines``: with its counting lines."""
    from trafficgeo.camera.calibrated import CalibratedCamera

    surface = _surface(str(entry.surface), str(entry.camera), (_input_id(entry.surface), _input_id(entry.camera)))
    return Site.load(CalibratedCamera.read(entry.camera), surface, entry.lanes, entry.lines if lines else None)


# ------------------------------------------------------------------------------------------------ detect
def _run_detect(task: Task, ctx: BatchContext, entry: CameraEntry, work: Path):
    from trafficgeo.video.reader import video_info

    if task.video is None or not Path(task.video).is_file():
        raise InputError(f"task {task.task_id}: video {task.video} not found; check the path or plan again")
    video = Path(task.video)
    opts = process_options(entry, start_s=task.video_start_s, end_s=task.video_end_s)
    site = _site(entry, lines=entry.lanes is None)  # no lanes: lines plan the tiles
    info = video_info(video)
    opts = settled_options(opts, info.fps)
    found = detect(video, site, work, opts)
    index, times, row = found.frame_index, found.time_s, found.row
    file_start = task.start_utc - timedelta(seconds=task.video_start_s)
    frames = pd.DataFrame({"frame": index, "time_s": times, "time_utc": _utc(file_start, times),
                           "detections": np.bincount(row, minlength=index.size).astype(np.int32)})
    boxes = pd.DataFrame({"frame": index[row], "time_s": times[row], "time_utc": _utc(file_start, times[row]),
                          **dict(zip(BOX, found.boxes.T, strict=True)), "score": found.scores,
                          "class": found.classes.astype(object)})
    meta = {"fps": info.fps, "every": opts.every, "variable_frame_rate": bool(info.variable_frame_rate),
            "video": str(video), "file_start_utc": utc_text(file_start),
            "window_s": [task.video_start_s, task.video_end_s]}
    ensure_dataset(ctx.dataset, ctx.crs)
    name = task_folder(task.task_id)
    written = [write_table(table_path(ctx.dataset, "detections", task.camera_id, name), boxes, meta),
               write_table(table_path(ctx.dataset, "frames", task.camera_id, name), frames, meta)]
    extra = {"frames": int(index.size), "detections": len(boxes)}
    return written, extra, float(task.video_end_s - task.video_start_s)


def _utc(start: datetime, seconds: np.ndarray) -> pd.Series:
    micro = np.round(np.asarray(seconds, dtype=np.float64) * 1e6).astype(np.int64)
    return pd.Series(pd.Timestamp(start).as_unit("us") + pd.to_timedelta(micro, unit="us"),
                     dtype="datetime64[us, UTC]")


# ------------------------------------------------------------------------------------------------ track
def day_bounds(day: str, timezone: str) -> tuple[datetime, datetime]:
    """Local midnight of ``day`` and of the next day in ``timezone``, as UTC times."""
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

    try:
        tz = ZoneInfo(timezone)
        date = datetime.strptime(day, "%Y-%m-%d")
    except (ZoneInfoNotFoundError, ValueError):
        raise InputError(f"day {day!r} in time zone {timezone!r}: give a YYYY-MM-DD day and an IANA time zone "
                         "(Europe/Berlin, UTC)") from None
    start = date.replace(tzinfo=tz)
    end = (date + timedelta(days=1)).replace(tzinfo=tz)
    return start.astimezone(UTC), end.astimezone(UTC)


def _day_frames(task: Task, ctx: BatchContext, lo: datetime, hi: datetime):
    """The frames (with their file's fps, every and variable-rate flag) and detections of the camera-day, in time
    order; a file overlapping the one before it in time gives only its frames after that one's last."""
    blocks = []
    for dep in task.depends:
        name = task_folder(dep)
        fpath = table_path(ctx.dataset, "frames", task.camera_id, name)
        dpath = table_path(ctx.dataset, "detections", task.camera_id, name)
        done = _success(ctx.dataset, dep)
        dep_task = ctx.tasks.get(dep)
        if done is None or (dep_task is not None and not is_done(dep_task, ctx)) or not fpath.is_file():
            raise InputError(f"task {task.task_id}: the detect task {dep} it depends on has not finished; see its "
                             "status and run the batch again")
        frames = pd.read_parquet(fpath)
        dets = pd.read_parquet(dpath)
        meta = table_metadata(fpath)
        frames = frames.assign(fps=float(meta["fps"]), every=int(meta["every"]),
                               vfr=bool(meta["variable_frame_rate"]), block=len(blocks))
        dets = dets.assign(block=len(blocks))
        blocks.append((frames, dets))
    lo_ts, hi_ts = pd.Timestamp(lo), pd.Timestamp(hi)
    order = sorted(range(len(blocks)), key=lambda k: blocks[k][0]["time_utc"].min() if len(blocks[k][0]) else hi_ts)
    kept_f, kept_d, last = [], [], None
    for k in order:
        f, d = blocks[k]
        keep = (f["time_utc"] >= lo_ts) & (f["time_utc"] < hi_ts)
        if last is not None:
            keep &= f["time_utc"] > last
        f = f[keep]
        if len(f):
            last = f["time_utc"].max()
            kept_f.append(f)
            kept_d.append(d[d["frame"].isin(f["frame"])])
    if not kept_f:
        return None, None
    frames = pd.concat(kept_f, ignore_index=True)
    frames["row"] = np.arange(len(frames))
    dets = pd.concat(kept_d, ignore_index=True)
    dets = dets.merge(frames[["block", "frame", "row"]], on=["block", "frame"], how="inner", sort=False)
    dets = dets.sort_values("row", kind="stable").reset_index(drop=True)  # boxes of a frame stay in their order
    return frames, dets


def _micros(times: pd.Series) -> np.ndarray:
    """Microseconds since 1970 (int64) of a UTC time column."""
    return ((times - pd.Timestamp(0, tz="UTC")) // pd.Timedelta(microseconds=1)).to_numpy(dtype=np.int64)


def _segments(frames: pd.DataFrame) -> list[np.ndarray]:
    """Row ranges of the frames between gaps: more than ``max(1 s, 3 frame steps)`` between consecutive frames, or
    another frame rate, frame step or kind of video."""
    t = _micros(frames["time_utc"]) / 1e6
    step = frames["every"].to_numpy() / frames["fps"].to_numpy()
    breaks = np.diff(t) > np.maximum(1.0, 3.0 * step[:-1])
    for c in ("fps", "every", "vfr"):
        breaks |= frames[c].to_numpy()[1:] != frames[c].to_numpy()[:-1]
    cuts = np.flatnonzero(breaks) + 1
    return np.split(np.arange(len(frames)), cuts)


def _track_segment(frames: pd.DataFrame, dets: pd.DataFrame, rows: np.ndarray, entry: CameraEntry,
                   segment: int) -> pd.DataFrame:
    """Track one segment as the pipeline does; the tracked boxes (``frame``: a frame number unique in the
    segment, ``file_frame``: the frame in its file, ``time_utc``)."""
    from trafficgeo.video.detections import DetectionFrames

    first = frames.iloc[rows[0]]
    fps, every, vfr = float(first["fps"]), int(first["every"]), bool(first["vfr"])
    opts = settled_options(process_options(entry), fps)
    t_us = _micros(frames["time_utc"])[rows]
    seconds = (t_us - t_us[0]) / 1e6
    file_frame = frames["frame"].to_numpy()[rows]
    guess = file_frame[0] + np.round(seconds * fps).astype(np.int64)
    ramp = np.arange(rows.size)
    number = np.maximum.accumulate(guess - ramp) + ramp  # strictly increasing; the file's frames for one file
    det_rows = dets["row"].to_numpy()
    lo, hi = np.searchsorted(det_rows, [rows[0], rows[-1] + 1], side="left")  # rows: one contiguous range
    segment_frames = DetectionFrames(frame_index=number, time_s=seconds, row=det_rows[lo:hi] - rows[0],
                                     boxes=dets[BOX].to_numpy(dtype=np.float64)[lo:hi],
                                     scores=dets["score"].to_numpy(dtype=np.float64)[lo:hi],
                                     classes=dets["class"].fillna("").astype(str).to_numpy(dtype=object)[lo:hi])
    table = track(segment_frames, fps / every, opts.tracker, variable_rate=vfr).to_table()  # in time order
    if table.empty:
        return pd.DataFrame()
    j = np.searchsorted(number, table["frame"].to_numpy())  # the frames' positions in the segment
    return pd.DataFrame({"frame": number[j], "file_frame": file_frame[j], "time_us": t_us[j],
                         "track_id": [f"{segment}-{i}" for i in table["track_id"]],
                         **{c: np.round(table[c].to_numpy(dtype=np.float64), 3) for c in BOX},
                         "score": np.round(table["score"].to_numpy(dtype=np.float64), 3),
                         "class": table["class"].to_numpy(dtype=object)})


def analysis_origin(first: datetime, midnight: datetime, interval_s: float) -> datetime:
    """The time origin of a segment's analysis: the latest whole number of counting intervals after local
    ``midnight`` not after ``first``, so that count intervals start on the clock."""
    k = math.floor((first - midnight).total_seconds() / interval_s + 1e-9)
    return midnight + timedelta(seconds=k * interval_s)


def _run_track(task: Task, ctx: BatchContext, entry: CameraEntry):
    from trafficgeo.traffic.analyze import AnalysisOptions
    from trafficgeo.traffic.counts import check_interval
    from trafficgeo.traffic.tracks import tracks_from_table

    process_options(entry)  # checks the options
    interval_s = float(entry.options.get("interval_s", BATCH_OPTIONS["interval_s"]))
    check_interval(interval_s)
    midnight, next_midnight = day_bounds(task.day, entry.timezone)
    site = _site(entry, lines=True)
    cam, lane_set, count_lines = site.camera.camera, site.lanes, site.count_lines
    frames, dets = _day_frames(task, ctx, midnight, next_midnight)
    results = []
    for k, rows in enumerate(_segments(frames) if frames is not None else []):
        tracks = _track_segment(frames, dets, rows, entry, k)
        if not len(tracks):
            continue
        first = pd.Timestamp(int(tracks["time_us"].min()), unit="us", tz="UTC").to_pydatetime()
        origin = analysis_origin(first, midnight, interval_s)
        origin_us = (origin - datetime(1970, 1, 1, tzinfo=UTC)) // timedelta(microseconds=1)
        tracks["time"] = (tracks["time_us"].to_numpy() - origin_us) / 1e6
        result = analyze(tracks_from_table(tracks), site, analysis=AnalysisOptions(interval_s=interval_s))
        results.append((result, origin, tracks))
    day = merge_day(results, midnight, lane_set, count_lines)
    tables = day_tables(day, cam, ctx.crs, midnight, task.camera_id)
    ensure_dataset(ctx.dataset, ctx.crs)
    written = write_day_tables(ctx.dataset, task.camera_id, task.day, tables)
    if entry.options.get("report", BATCH_OPTIONS["report"]):
        written.append(write_day_report(ctx.dataset, task.camera_id, task.day, entry.timezone, day, cam,
                                        entry.camera))
    else:  # not asked for: no page of an earlier run stays beside this run's tables
        report_path(ctx.dataset, task.camera_id, task.day).unlink(missing_ok=True)
    extra = {"segments": len(results), "vehicles": len(tables["vehicles"]),
             "camera_position": camera_position(cam, ctx.crs, task.camera_id)}
    return written, extra, 0.0
