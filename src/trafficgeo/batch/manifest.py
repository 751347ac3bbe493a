"""The manifest of a batch (``trafficgeo batch plan``): the cameras of ``cameras.csv``, the video files found for
them, and the tasks of the two stages, written as ``tasks.csv``.

* :func:`read_cameras` reads and checks ``cameras.csv`` (columns
  ``camera_id,camera,surface,timezone,lanes,lines,detector,options``; paths relative to the CSV's folder).
* :func:`plan_batch` finds the video files (globs; ``{camera}`` in a glob stands for each camera id), dates them
  from their names (:mod:`trafficgeo.batch.names`: a local time in the camera's time zone, DST rule there) or the
  container's ``creation_time`` tag (UTC), and builds the tasks (:func:`build_tasks`): a detect task per file or
  per window of at most ``max_window_s`` of it, a track task per camera and local day.
* :func:`write_tasks` / :func:`read_tasks` write and read ``tasks.csv``; :func:`plan_summary` describes a plan.

A file that cannot be used (unreadable, no start time, no camera, overlapping another file of its camera) is a
*problem*: one line in :attr:`BatchPlan.problems`, never an exception.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from datetime import UTC, date, datetime, timedelta
from pathlib import Path
from typing import Any

from trafficgeo.batch.model import BATCH_OPTIONS, STAGES, CameraEntry, Task, VideoFile, parse_utc, utc_text
from trafficgeo.batch.names import DEFAULT_NAME_PATTERN, compile_pattern, local_to_utc, zone
from trafficgeo.batch.videos import find_videos, probe_video
from trafficgeo.errors import InputError

__all__ = ["CAMERA_COLUMNS", "DEFAULT_NAME_PATTERN", "MAX_WINDOW_S", "TASK_COLUMNS", "BatchPlan", "build_tasks",
           "find_videos", "plan_batch", "plan_summary", "read_cameras", "read_tasks", "write_tasks"]

#: the longest stretch of video (s) one detect task covers; a longer file is split into equal windows
MAX_WINDOW_S = 3600.0
#: the columns of ``cameras.csv`` (the first four are required)
CAMERA_COLUMNS = ("camera_id", "camera", "surface", "timezone", "lanes", "lines", "detector", "options")
#: the columns of ``tasks.csv``
TASK_COLUMNS = ("task_id", "stage", "camera_id", "day", "start_utc", "end_utc", "video", "video_start_s",
                "video_end_s", "depends", "cameras", "crs")
_REQUIRED = CAMERA_COLUMNS[:4]
# ProcessOptions fields cameras.csv may not set: the detector has its own column, the window sets the times, and
# the tracker options are not plain JSON values
_NOT_OPTIONS = {"detector": "use the detector column", "start_s": "the plan's windows set it",
                "end_s": "the plan's windows set it", "tracker": "it cannot be set in cameras.csv"}


@dataclass(frozen=True)
class BatchPlan:
    """Cameras, video files and tasks of a batch. ``tasks``: detect tasks (per camera, in time order), then track
    tasks (per camera, per day); ``crs`` the dataset CRS (``"EPSG:2949"``); ``problems`` one line each."""

    cameras: dict[str, CameraEntry]
    videos: tuple[VideoFile, ...]
    tasks: tuple[Task, ...]
    crs: str
    cameras_csv: Path
    problems: tuple[str, ...] = ()


# ------------------------------------------------------------------------------------------------ cameras.csv
def _read_table(path: Path, what: str, required: Sequence[str], known: Sequence[str]
                ) -> list[tuple[int, dict[str, str]]]:
    """(line number, row) of a UTF-8 CSV with a header holding ``required`` and no column outside ``known``."""
    if not path.is_file():
        raise InputError(f"{what} {path}: not found; check the path")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{what} {path}: cannot be read ({exc}); save it as UTF-8 CSV") from None
    reader = csv.reader(io.StringIO(text, newline=""))
    header = [h.strip() for h in next(reader, [])]
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(f"{path}, line 1: missing column(s) {', '.join(missing)}; the header must be "
                         f"{','.join(known)}")
    unknown = [c for c in header if c not in known]
    if unknown or len(set(header)) != len(header):
        bad = unknown or sorted({c for c in header if header.count(c) > 1})
        raise InputError(f"{path}, line 1: column(s) {', '.join(bad)} unknown or repeated; the columns are "
                         f"{','.join(known)}")
    rows = []
    for cells in reader:
        if not any(c.strip() for c in cells):
            continue
        if len(cells) != len(header):
            raise InputError(f"{path}, line {reader.line_num}: {len(cells)} values for {len(header)} columns; "
                             "quote values holding commas (a JSON object in options: \"{...}\")")
        rows.append((reader.line_num, {h: c.strip() for h, c in zip(header, cells, strict=True)}))
    return rows


def _file(where: str, column: str, text: str, folder: Path, fix: str) -> Path:
    p = Path(text).expanduser()
    p = p if p.is_absolute() else folder / p
    if not p.is_file():
        raise InputError(f"{where}, column {column}: file {text!r} not found (looked for {p}); {fix}")
    return p.resolve()


def _check_options(where: str, text: str, detector: str) -> dict[str, Any]:
    """The options JSON object of a row, checked by building ProcessOptions from it."""
    from trafficgeo.video.pipeline import ProcessOptions

    if not text:
        options: Any = {}
    else:
        try:
            options = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"{where}, column options: not JSON ({exc.msg}); write a JSON object such as "
                             '{"every": 2, "interval_s": 300}') from None
    if not isinstance(options, dict):
        raise InputError(f"{where}, column options: {text!r} is not a JSON object; write one such as "
                         '{"every": 2} or leave it empty')
    allowed = sorted({f.name for f in fields(ProcessOptions)} - set(_NOT_OPTIONS) | set(BATCH_OPTIONS))
    for key in options:
        if key in _NOT_OPTIONS:
            raise InputError(f"{where}, column options: key {key!r} cannot be given here ({_NOT_OPTIONS[key]})")
        if key not in allowed:
            raise InputError(f"{where}, column options: unknown key {key!r}; the keys are {', '.join(allowed)}")
    interval = options.get("interval_s", 60.0)
    if isinstance(interval, bool) or not isinstance(interval, int | float) or not 0 < interval < math.inf:
        raise InputError(f"{where}, column options: interval_s {interval!r} must be a positive number of seconds")
    if not isinstance(options.get("report", True), bool):
        raise InputError(f"{where}, column options: report {options['report']!r} must be true or false")
    try:
        ProcessOptions(detector=detector, **{k: v for k, v in options.items() if k not in BATCH_OPTIONS})
    except InputError as exc:
        raise InputError(f"{where}, column options: {exc}") from None
    except TypeError as exc:
        raise InputError(f"{where}, column options: {exc}") from None
    return options


def read_cameras(path: str | os.PathLike[str]) -> dict[str, CameraEntry]:
    """The cameras of ``cameras.csv`` by id, in file order; an InputError naming the file, line and column of the
    first bad value and how to fix it."""
    from trafficgeo.site.site import load_camera
    from trafficgeo.video.detectors.names import DETECTOR_NAMES

    csv_path = Path(path)
    folder = csv_path.parent
    rows = _read_table(csv_path, "cameras.csv", _REQUIRED, CAMERA_COLUMNS)
    if not rows:
        raise InputError(f"{csv_path}: no cameras; add a row per camera under the header {','.join(CAMERA_COLUMNS)}")
    out: dict[str, CameraEntry] = {}
    lines: dict[str, int] = {}
    for line, row in rows:
        where = f"{csv_path}, line {line}"
        cid = row["camera_id"]
        if not cid or any(not (ch.isascii() and (ch.isalnum() or ch in "-_")) for ch in cid):
            raise InputError(f"{where}, column camera_id: {cid!r} is not an id; use letters, digits, - and _ only")
        if cid in out:
            raise InputError(f"{where}, column camera_id: duplicate camera_id {cid!r} (also on line {lines[cid]}); "
                             "give each camera its own id")
        for col in _REQUIRED[1:]:
            if not row[col]:
                raise InputError(f"{where}, column {col}: empty; every camera needs a {col}")
        camera = _file(where, "camera", row["camera"], folder, "give the camera JSON from trafficgeo calibrate")
        try:
            load_camera(camera)
        except InputError as exc:
            raise InputError(f"{where}, column camera: {exc}") from None
        surface = row["surface"]
        try:
            float(surface)
        except ValueError:
            if surface.lower() != "plane":
                surface = str(_file(where, "surface", surface, folder,
                                    "give a number (m), plane, a DEM (.tif) or a LAS/LAZ file"))
        try:
            zone(row["timezone"])
        except InputError as exc:
            raise InputError(f"{where}, column timezone: {exc}") from None
        lanes, lns = ((_file(where, col, row[col], folder, "give a GIS file or leave it empty") if row.get(col)
                       else None) for col in ("lanes", "lines"))
        detector = row.get("detector") or "nanodet"
        if detector.lower() not in DETECTOR_NAMES:
            detector = str(_file(where, "detector", detector, folder,
                                 f"give one of {', '.join(sorted(DETECTOR_NAMES))} or the path of an .onnx model"))
        options = _check_options(where, row.get("options", ""), detector)
        out[cid] = CameraEntry(cid, camera, surface, row["timezone"], lanes, lns, detector, options)
        lines[cid] = line
    return out


def _dataset_crs(cameras: Mapping[str, CameraEntry], crs: str | None, csv_path: Path) -> str:
    """The dataset CRS text (given, else the first camera's), having checked every camera can be transformed to
    it."""
    import numpy as np
    import pyproj

    from trafficgeo.camera.model import crs_to_text
    from trafficgeo.crs import parse_crs
    from trafficgeo.site.site import load_camera

    cams = {cid: load_camera(e.camera).camera for cid, e in cameras.items()}
    if crs is not None:
        target = parse_crs(crs)
    else:
        cid, cam = next(iter(cams.items()))
        if cam.crs is None:
            raise InputError(f"{csv_path}: camera {cid} ({cameras[cid].camera}) has no CRS, so the dataset has none; "
                             "calibrate it with a CRS or give the dataset's `crs`", parameters=("crs",))
        target = cam.crs
    assert target is not None
    for cid, cam in cams.items():
        if cam.crs is None:
            raise InputError(f"{csv_path}: camera {cid} ({cameras[cid].camera}) has no CRS; calibrate it with a "
                             "CRS so that its results can join the dataset's")
        try:
            t = pyproj.Transformer.from_crs(cam.crs, target, always_xy=True)
            x, y = t.transform(float(cam.position[0]), float(cam.position[1]), errcheck=True)
            ok = bool(np.isfinite(x) and np.isfinite(y))
        except pyproj.exceptions.ProjError:
            ok = False
        if not ok:
            raise InputError(f"{csv_path}: camera {cid}'s CRS ({cam.crs.name}) cannot be transformed to the dataset "
                             f"CRS ({target.name}); give a `crs` that covers every camera", parameters=("crs",))
    return str(crs_to_text(target))


# ------------------------------------------------------------------------------------------------ tasks
def windows(duration_s: float, max_window_s: float = MAX_WINDOW_S) -> list[tuple[float, float]]:
    """``[start_s, end_s)`` windows (s of the file) covering ``duration_s`` exactly in the fewest equal parts of
    at most ``max_window_s``."""
    if not max_window_s > 0:
        raise InputError(f"max_window_s {max_window_s}: must be a positive number of seconds",
                         parameters=("max_window_s",))
    n = max(1, math.ceil(duration_s / max_window_s - 1e-9))
    edges = [duration_s * k / n for k in range(n)] + [duration_s]
    return list(itertools.pairwise(edges))


def _day_bounds(day: date, timezone: str) -> tuple[datetime, datetime]:
    """UTC instants of local midnight starting ``day`` and the next one."""
    start = local_to_utc(datetime(day.year, day.month, day.day), timezone)
    nxt = day + timedelta(days=1)
    return start, local_to_utc(datetime(nxt.year, nxt.month, nxt.day), timezone)


def _local_day(t: datetime, timezone: str) -> date:
    return t.astimezone(zone(timezone)).date()


def build_tasks(videos: Sequence[VideoFile], cameras: Mapping[str, CameraEntry], *,
                max_window_s: float = MAX_WINDOW_S) -> tuple[Task, ...]:
    """Detect tasks (a file, or windows of at most ``max_window_s`` of it; per camera in time order), then a track
    task per camera and local day depending on every detect task overlapping that day, spanning the day clipped to
    the video coverage. Ids: ``detect/<camera>/<UTC start as YYYYmmddTHHMMSSZ>`` (``+<offset_s>`` added only to
    keep an id unique) and ``track/<camera>/<YYYY-MM-DD>``. The files of a camera must not overlap (half a frame of
    slack; ValueError otherwise): :func:`plan_batch` drops overlapping files as problems first."""
    detect: list[Task] = []
    track: list[Task] = []
    for cid, entry in cameras.items():
        mine: list[Task] = []
        files = sorted((v for v in videos if v.camera_id == cid), key=lambda v: (v.start_utc, str(v.path)))
        for a, b in itertools.pairwise(files):
            if b.start_utc < a.end_utc - timedelta(seconds=0.5 / b.fps):
                raise ValueError(f"files {a.path} and {b.path} of camera {cid} overlap; drop one first")
        for v in files:
            for a, b in windows(v.duration_s, max_window_s):
                start = v.start_utc + timedelta(seconds=a)
                mine.append(Task("", "detect", cid, _local_day(start, entry.timezone).isoformat(), start,
                                 v.start_utc + timedelta(seconds=b), v.path, a, b))
        ids = [f"detect/{cid}/{t.start_utc.astimezone(UTC):%Y%m%dT%H%M%SZ}" for t in mine]
        mine = [replace(t, task_id=tid if ids.count(tid) == 1 else f"{tid}+{_seconds_text(t.video_start_s)}")
                for tid, t in zip(ids, mine, strict=True)]
        detect += mine
        days: set[date] = set()
        for t in mine:
            first, last = (_local_day(x, entry.timezone) for x in (t.start_utc, t.end_utc - timedelta(microseconds=1)))
            days |= {first + timedelta(days=k) for k in range((last - first).days + 1)}
        for day in sorted(days):
            lo, hi = _day_bounds(day, entry.timezone)
            deps = [t for t in mine if t.start_utc < hi and t.end_utc > lo]
            if deps:
                track.append(Task(f"track/{cid}/{day.isoformat()}", "track", cid, day.isoformat(),
                                  max(lo, min(t.start_utc for t in deps)), min(hi, max(t.end_utc for t in deps)),
                                  depends=tuple(t.task_id for t in deps)))
    return tuple(detect + track)


def _seconds_text(seconds: float) -> str:
    """``1800``, ``0.5``: seconds without trailing zeros (microsecond resolution)."""
    return f"{seconds:.6f}".rstrip("0").rstrip(".")


def plan_batch(cameras_csv: str | os.PathLike[str], videos: Sequence[str], *,
               name_pattern: str = DEFAULT_NAME_PATTERN, crs: str | None = None,
               max_window_s: float = MAX_WINDOW_S) -> BatchPlan:
    """The plan of a batch: the cameras of ``cameras_csv``, the files the globs ``videos`` find, their tasks and the
    dataset CRS (``crs``, default the first camera's); problems with files are lines of the plan, bad cameras or
    options an InputError."""
    if isinstance(videos, str):
        videos = [videos]
    compile_pattern(name_pattern)
    windows(1.0, max_window_s)  # checks max_window_s
    csv_path = Path(cameras_csv).resolve()
    cameras = read_cameras(csv_path)
    dataset_crs = _dataset_crs(cameras, crs, csv_path)
    files, problems = find_videos(cameras, list(videos), name_pattern=name_pattern)
    return BatchPlan(cameras, tuple(files), build_tasks(files, cameras, max_window_s=max_window_s), dataset_crs,
                     csv_path, tuple(problems))


# ------------------------------------------------------------------------------------------------ tasks.csv
def _relative(path: Path, folder: Path) -> str:
    return Path(os.path.relpath(path.resolve(), folder.resolve())).as_posix()


def write_tasks(path: str | os.PathLike[str], plan: BatchPlan) -> Path:
    """Write the plan's tasks as ``tasks.csv`` (atomically; paths relative to its folder); returns its path."""
    from trafficgeo.io.atomic import atomic_open

    out = Path(path)
    if not plan.tasks:
        raise InputError(f"{out}: the plan has no tasks (no usable video file); check the video globs and the "
                         "problems of the plan")
    folder = out.resolve().parent
    cams = _relative(plan.cameras_csv, folder)
    with atomic_open(out, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(TASK_COLUMNS)
        for t in plan.tasks:
            w.writerow([t.task_id, t.stage, t.camera_id, t.day, utc_text(t.start_utc), utc_text(t.end_utc),
                        "" if t.video is None else _relative(t.video, folder),
                        repr(float(t.video_start_s)), repr(float(t.video_end_s)), ";".join(t.depends), cams, plan.crs])
    return out


def read_tasks(path: str | os.PathLike[str]) -> BatchPlan:
    """The plan written by :func:`write_tasks`: tasks from the file, cameras re-read from the ``cameras.csv`` it
    names, videos probed again (a missing or unreadable one is a problem line); an InputError naming the line and
    column of a bad value."""
    p = Path(path)
    rows = _read_table(p, "tasks.csv", TASK_COLUMNS, TASK_COLUMNS)
    if not rows:
        raise InputError(f"{p}: no tasks; write it with trafficgeo batch plan")
    folder = p.resolve().parent
    tasks: list[Task] = []
    seen: dict[str, int] = {}
    for line, row in rows:
        tasks.append(_task_of_row(f"{p}, line {line}", row, folder, seen))
        seen[tasks[-1].task_id] = line
    first = rows[0][1]
    for line, row in rows:
        for col in ("cameras", "crs"):
            if row[col] != first[col]:
                raise InputError(f"{p}, line {line}, column {col}: {row[col]!r} differs from line {rows[0][0]} "
                                 f"({first[col]!r}); one plan has one {col}")
    detect = {t.task_id for t in tasks if t.stage == "detect"}
    for (line, _), t in zip(rows, tasks, strict=True):
        missing = [d for d in t.depends if d not in detect]
        if missing:
            raise InputError(f"{p}, line {line}, column depends: {missing[0]!r} is not a detect task of this file; "
                             "plan again with trafficgeo batch plan")
    cameras_csv = (folder / first["cameras"]).resolve()
    cameras = read_cameras(cameras_csv)
    for (line, _), t in zip(rows, tasks, strict=True):
        if t.camera_id not in cameras:
            raise InputError(f"{p}, line {line}, column camera_id: {t.camera_id!r} is not a camera of "
                             f"{cameras_csv}; plan again with trafficgeo batch plan")
    from trafficgeo.crs import parse_crs

    try:
        parse_crs(first["crs"])
    except InputError as exc:
        raise InputError(f"{p}, line {rows[0][0]}, column crs: {exc}") from None
    videos, problems = [], []
    for t in tasks:
        if t.stage != "detect" or t.video is None or t.video_start_s > 0 or any(v.path == t.video for v in videos):
            continue
        try:
            videos.append(probe_video(t.video, t.camera_id, t.start_utc))
        except (InputError, OSError) as exc:
            problems.append(f"{t.video}: unreadable: {str(exc).removeprefix(f'video {t.video}: ')}")
    return BatchPlan(cameras, tuple(videos), tuple(tasks), first["crs"], cameras_csv, tuple(problems))


def _task_of_row(where: str, row: dict[str, str], folder: Path, seen: Mapping[str, int]) -> Task:
    def bad(col: str, why: str) -> InputError:
        return InputError(f"{where}, column {col}: {row[col]!r} {why}; plan again with trafficgeo batch plan or "
                          "fix the value")

    tid, stage = row["task_id"], row["stage"]
    if not tid:
        raise bad("task_id", "is empty")
    if tid in seen:
        raise bad("task_id", f"repeats the task of line {seen[tid]}")
    if stage not in STAGES:
        raise bad("stage", f"is not a stage ({', '.join(STAGES)})")
    try:
        date.fromisoformat(row["day"])
    except ValueError:
        raise bad("day", "is not a date YYYY-MM-DD") from None
    times = []
    for col in ("start_utc", "end_utc"):
        try:
            times.append(parse_utc(row[col]))
        except ValueError:
            raise bad(col, "is not a UTC time like 2026-05-04T07:30:00Z") from None
    if not times[1] > times[0]:
        raise bad("end_utc", f"is not after start_utc {row['start_utc']}")
    secs = []
    for col in ("video_start_s", "video_end_s"):
        try:
            secs.append(float(row[col] or 0.0))
        except ValueError:
            raise bad(col, "is not a number of seconds") from None
        if not 0 <= secs[-1] < math.inf:
            raise bad(col, "must be a time >= 0 (s)")
    video = None
    if stage == "detect":
        if not row["video"]:
            raise bad("video", "is empty; a detect task needs its video file")
        video = (folder / row["video"]).resolve()
        if not secs[1] > secs[0]:
            raise bad("video_end_s", f"is not after video_start_s {row['video_start_s']}")
    depends = tuple(d for d in row["depends"].split(";") if d)
    if stage == "track" and not depends:
        raise bad("depends", "is empty; a track task depends on detect tasks")
    return Task(tid, stage, row["camera_id"], row["day"], times[0], times[1], video, secs[0], secs[1], depends)


# ------------------------------------------------------------------------------------------------ summary
def _when(t: datetime, timezone: str) -> str:
    local = t.astimezone(zone(timezone))
    return f"{local:%Y-%m-%d %H:%M:%S %Z} ({utc_text(t.replace(microsecond=0))})"


def _duration(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _hours(seconds: float) -> str:
    return f"{seconds / 3600.0:.2f} h ({_duration(seconds)})"


def plan_summary(plan: BatchPlan, *, max_gaps: int = 10) -> list[str]:
    """Lines for a user: totals, then per camera the files, hours of video, first and last time (local and UTC) and
    the gaps longer than 1 s between consecutive files (at most ``max_gaps`` listed), then the problems."""
    n_detect = sum(t.stage == "detect" for t in plan.tasks)
    lines = [f"{len(plan.cameras)} camera(s), {len(plan.videos)} video file(s), "
             f"{_hours(sum(v.duration_s for v in plan.videos))} of video; "
             f"{len(plan.tasks)} tasks ({n_detect} detect, {len(plan.tasks) - n_detect} track); CRS {plan.crs}"]
    for cid, entry in plan.cameras.items():
        files = sorted((v for v in plan.videos if v.camera_id == cid), key=lambda v: v.start_utc)
        if not files:
            lines.append(f"camera {cid} ({entry.timezone}): no video files")
            continue
        days = sum(t.stage == "track" and t.camera_id == cid for t in plan.tasks)
        lines.append(f"camera {cid} ({entry.timezone}): {len(files)} file(s), "
                     f"{_hours(sum(v.duration_s for v in files))}, {days} day(s), from "
                     f"{_when(files[0].start_utc, entry.timezone)} to {_when(files[-1].end_utc, entry.timezone)}")
        gaps = [(a, b) for a, b in itertools.pairwise(files)
                if (b.start_utc - a.end_utc).total_seconds() > 1.0]
        for a, b in gaps[:max_gaps]:
            lines.append(f"  gap of {_duration((b.start_utc - a.end_utc).total_seconds())} from "
                         f"{_when(a.end_utc, entry.timezone)} to {_when(b.start_utc, entry.timezone)}")
        if len(gaps) > max_gaps:
            lines.append(f"  ... and {len(gaps) - max_gaps} more gap(s)")
    if plan.problems:
        lines.append(f"{len(plan.problems)} problem(s):")
        lines += [f"  {p}" for p in plan.problems]
    return lines
