"""The stages a run is composed of, public so that :func:`~trafficgeo.pipeline.run.process_video`,
:func:`~trafficgeo.pipeline.run.stitch`, batch and the demo build on the same calls:

* :func:`detect_and_track` - decode a time window of a video, detect and track the vehicles on the site
  (resumable, in a work folder), giving the detections and the tracks (what ``process_video`` runs);
* :func:`detect` - the same, giving the detections over time (:class:`~trafficgeo.video.detections.DetectionFrames`:
  what a batch task keeps, to track a whole camera-day at once);
* :func:`track` - the tracker over stored detections (e.g. the frames of several files of one camera-day);
* :func:`analyze` - image tracks on the site -> world trajectories, speeds (km/h), lanes and counts.

Inputs are a :class:`~trafficgeo.site.site.Site` (loaded once) and the detections and tracks over time
(:class:`~trafficgeo.video.detections.DetectionFrames`, :class:`~trafficgeo.run.tracks.ImageTracks`); times in seconds.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from trafficgeo.run.tracks import ImageTracks
from trafficgeo.site.site import Site
from trafficgeo.traffic.analyze import AnalysisOptions, TrafficResult
from trafficgeo.traffic.analyze import analyze as analyze_world
from trafficgeo.traffic.speed import ScaleKnowledge
from trafficgeo.traffic.tracks import load_tracks
from trafficgeo.video.detections import DetectionFrames
from trafficgeo.video.pipeline import ProcessOptions
from trafficgeo.video.track import TrackerOptions, track_frames

__all__ = ["analyze", "detect", "detect_and_track", "track"]


def detect_and_track(video: str | os.PathLike, site: Site, work_dir: str | os.PathLike, options: ProcessOptions, *,
                     roi: np.ndarray | None = None, restart: bool = False,
                     progress: Callable[[int, int, float], None] | None = None,
                     notice: Callable[[str], None] | None = None,
                     detector_info: Callable[[dict], None] | None = None) -> tuple[DetectionFrames, ImageTracks]:
    """Decode, detect and track the vehicles of ``video`` (the time window and detector of ``options``, settled for
    the video with :func:`~trafficgeo.video.pipeline.settled_options`) on ``site`` (its camera and surface size the
    boxes, its lanes, else its counting lines, else its gates, plan the tiles), resumably in ``work_dir``, where
    ``detections.csv`` and ``tracks.csv`` are written; returns the detections over time (full precision) and the
    tracks as ``tracks.csv`` holds them.
    ``detector_info(doc)`` gets the detector's record (tile plan, backend, estimate) for ``process.json``."""
    from trafficgeo.video.pipeline import detect_and_track as run_video

    return run_video(video, site.camera.camera, site.surface, work_dir, options, roi=roi, restart=restart,
                     lanes=site.lanes, lines=site.tiling_lines, progress=progress, notice=notice,
                     detector_info=detector_info)


def detect(video: str | os.PathLike, site: Site, work_dir: str | os.PathLike, options: ProcessOptions, *,
           roi: np.ndarray | None = None, restart: bool = False,
           progress: Callable[[int, int, float], None] | None = None,
           notice: Callable[[str], None] | None = None) -> DetectionFrames:
    """:func:`detect_and_track`, giving the detections over time of the window (a batch task's: its tracks are
    made again over the whole camera-day by :func:`track`)."""
    return detect_and_track(video, site, work_dir, options, roi=roi, restart=restart, progress=progress,
                            notice=notice)[0]


def track(frames: DetectionFrames, fps: float, options: TrackerOptions | None = None, *,
          variable_rate: bool = False) -> ImageTracks:
    """The tracks of ``frames`` (detected at ``fps`` frames per second; ``variable_rate``: the frames' times drive
    the motion model): ``frame`` the frames' ``frame_index``, ``time`` their ``time_s``, ``track_id`` the tracker's
    integer id as text, boxes in px at full precision."""
    return track_frames(frames, fps, options, variable_rate=variable_rate)


def analyze(tracks: ImageTracks | pd.DataFrame | str | os.PathLike, site: Site, *,
            analysis: AnalysisOptions | None = None, fps: float | None = None, progress: Any = None,
            knowledge: ScaleKnowledge | None = None) -> TrafficResult:
    """Image tracks (a table or file, see :func:`~trafficgeo.traffic.tracks.load_tracks`) on ``site`` -> world
    trajectories, fragments joined into vehicles, speeds (km/h), lanes and counts (with the site's gates: turning
    movements), as ``analysis`` says (:class:`~trafficgeo.traffic.analyze.AnalysisOptions`: intervals, smoother,
    journeys); the headline speeds placed by what the site's calibrated camera knows of its ground scale
    (``knowledge`` overrides it)."""
    how = analysis or AnalysisOptions()
    return analyze_world(site.camera.camera, site.surface, load_tracks(tracks, fps=fps), lanes=site.lanes,
                         lines=site.count_lines, interval_s=how.interval_s, options=how.trajectory,
                         progress=progress,
                         knowledge=knowledge if knowledge is not None else ScaleKnowledge.from_camera(site.camera),
                         journeys=how.journeys, gates=list(site.gates) if site.gates else None,
                         movement_interval_s=how.movement_interval_s)
