"""The plain data of a batch over many cameras: a camera's entry in ``cameras.csv``, a video file found for it, a
task of the two stages, and what running a task gave.

Times are timezone-aware :class:`datetime.datetime` in UTC inside the library and ISO 8601 with ``Z`` in files
(``2026-05-04T07:30:00Z``); a camera's *day* is the local date in its time zone (``YYYY-MM-DD``). Stage ``detect``
runs the detector over one video file (or a window of at most an hour of it); stage ``track`` tracks and analyses
one camera-day over the detections of the detect tasks it depends on, in time order.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

#: the two stages, in the order they run
STAGES = ("detect", "track")

#: options of a camera that are the batch's, not the pipeline's, with their defaults: ``interval_s`` the counting
#: interval (s), ``report`` whether each camera-day also gets its HTML report
BATCH_OPTIONS: dict[str, Any] = {"interval_s": 60.0, "report": True}

#: the states a task can end a run in (``status.csv``)
OUTCOMES = ("done", "skipped", "failed")


@dataclass(frozen=True)
class CameraEntry:
    """One row of ``cameras.csv`` (paths resolved against the CSV's folder).

    ``surface`` is a surface spec as the command line takes it (a number, ``plane``, a DEM or a LAS/LAZ file);
    ``timezone`` an IANA name (``Europe/Berlin``) for the local times in file names and the camera-days;
    ``options`` the processing options: :class:`~trafficgeo.video.pipeline.ProcessOptions` fields (``every``,
    ``tiling``, ...) and the options of the batch itself (:data:`BATCH_OPTIONS`).
    """

    camera_id: str
    camera: Path
    surface: str
    timezone: str
    lanes: Path | None = None
    lines: Path | None = None
    detector: str = "nanodet"
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class VideoFile:
    """A video file of a camera: its start (UTC), length, frame rate and a cheap content fingerprint (size and
    hashes of its first and last MiB)."""

    camera_id: str
    path: Path
    start_utc: datetime
    duration_s: float
    fps: float
    size_bytes: int
    fingerprint: str

    @property
    def end_utc(self) -> datetime:
        from datetime import timedelta

        return self.start_utc + timedelta(seconds=self.duration_s)


@dataclass(frozen=True)
class Task:
    """One task of the manifest (a row of ``tasks.csv``).

    ``detect``: ``video`` from ``video_start_s`` to ``video_end_s`` (seconds of the file), covering ``start_utc`` to
    ``end_utc``. ``track``: the camera-day ``day``, over the detections of the ``depends`` tasks (detect task ids).
    """

    task_id: str
    stage: str
    camera_id: str
    day: str
    start_utc: datetime
    end_utc: datetime
    video: Path | None = None
    video_start_s: float = 0.0
    video_end_s: float = 0.0
    depends: tuple[str, ...] = ()

    @property
    def hours_of_video(self) -> float:
        """Hours of video the task covers."""
        return (self.end_utc - self.start_utc).total_seconds() / 3600.0


@dataclass(frozen=True)
class TaskOutcome:
    """What running a task gave: ``status`` one of :data:`OUTCOMES`, ``reason`` a one-line message for a failed
    task, ``seconds`` of wall time, ``key`` the hash of its inputs, ``outputs`` the files it wrote (relative to the
    dataset)."""

    task_id: str
    status: str
    key: str = ""
    reason: str = ""
    seconds: float = 0.0
    video_s: float = 0.0
    outputs: tuple[str, ...] = ()


def utc_text(t: datetime) -> str:
    """``t`` as ISO 8601 UTC with ``Z`` and whole seconds, or microseconds when it has them."""
    u = t.astimezone(UTC)
    text = u.strftime("%Y-%m-%dT%H:%M:%S") + (f".{u.microsecond:06d}" if u.microsecond else "")
    return text + "Z"


def parse_utc(text: str) -> datetime:
    """The UTC time written by :func:`utc_text` (any ISO 8601 with an offset or ``Z``), timezone-aware."""
    t = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    if t.tzinfo is None:
        raise ValueError(f"time {text!r} has no time zone; write it in UTC with a trailing Z")
    return t.astimezone(UTC)


def task_folder(task_id: str) -> str:
    """A folder name for ``task_id``, safe on every file system (``detect/cam 1/...`` -> ``detect--cam_1--...``)."""
    return re.sub(r"[^A-Za-z0-9._=+-]", "_", task_id.replace("/", "--"))
