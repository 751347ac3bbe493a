"""Multi-object tracking of vehicle detections: ByteTrack from the ``trackers`` library (Apache-2.0).

ByteTrack associates boxes frame to frame with a Kalman-predicted IoU, first with the confident detections, then
with the weak ones (a partly hidden vehicle keeps its identity), and keeps a lost track alive for
``lost_track_s`` seconds so that identities survive short occlusions. The boxes it returns are the detector's
(not the tracker's prediction): trafficgeo smooths positions later, in world coordinates, where the motion is
simple (:mod:`trafficgeo.traffic.trajectories`).

A tracker's state is a function of the detections fed to it (and their frame times) only: no counter or cache is
shared between trackers, so a resumed run restores it by feeding the stored detections to a fresh one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.video.detections import DetectionFrames, Detections


@dataclass(frozen=True)
class TrackerOptions:
    """ByteTrack settings (scores are the detector's, 0..1)."""

    lost_track_s: float = 1.5  # a track survives this long without a detection
    activation_score: float = 0.4  # a detection must score this much to start a track
    high_score: float = 0.5  # detections scoring this much are matched first
    min_consecutive_frames: int = 2  # frames before a new track gets an id
    min_iou: float = 0.1  # least overlap between a track's predicted box and a detection to match them

    def __post_init__(self) -> None:
        ok = (self.lost_track_s > 0 and 0 <= self.activation_score <= 1 and 0 <= self.high_score <= 1
              and self.min_consecutive_frames >= 1 and 0 <= self.min_iou < 1)
        if not ok:
            raise InputError(f"tracker options out of range: {self}; times > 0, scores and IoU in [0, 1]")


class VehicleTracker:
    """Frame-by-frame ByteTrack over :class:`~trafficgeo.video.detections.Detections` at ``fps`` frames per second."""

    def __init__(self, fps: float, options: TrackerOptions | None = None) -> None:
        import trackers

        if not (np.isfinite(fps) and fps > 0):
            raise InputError(f"frame rate {fps!r} must be positive")
        self.options = options or TrackerOptions()
        o = self.options
        self._classes: list[str] = []
        self._tracker = trackers.ByteTrackTracker(
            lost_track_buffer=max(1, round(o.lost_track_s * fps)), frame_rate=float(fps),
            track_activation_threshold=o.activation_score, minimum_consecutive_frames=o.min_consecutive_frames,
            minimum_iou_threshold=o.min_iou, high_conf_det_threshold=o.high_score)

    def _class_ids(self, classes: np.ndarray) -> np.ndarray:
        ids = []
        for c in classes:
            name = str(c)
            if name not in self._classes:
                self._classes.append(name)
            ids.append(self._classes.index(name))
        return np.asarray(ids, dtype=int)

    def live_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """The boxes (N, 4) px of the tracks alive after the last update (their filtered state) and (N,) bool: the
        track is young (seen, not yet confirmed: it needs a detection on the next frame to get an id)."""
        tracks = list(self._tracker.tracks)
        if not tracks:
            return np.zeros((0, 4)), np.zeros(0, dtype=bool)
        boxes = np.array([np.asarray(t.get_state_bbox(), dtype=np.float64).reshape(4) for t in tracks])
        return boxes, np.array([t.tracker_id == -1 for t in tracks], dtype=bool)

    def update(self, detections: Detections, time_s: float | None = None) -> Detections:
        """Feed one frame's detections; returns the detections that belong to confirmed tracks, with their
        ``track_ids``.
        ``time_s`` (the frame's timestamp) lets variable-frame-rate video keep the motion model right."""
        import supervision as sv

        det = sv.Detections(xyxy=np.asarray(detections.boxes, dtype=np.float64).reshape(-1, 4),
                            confidence=np.asarray(detections.scores, dtype=np.float64),
                            class_id=self._class_ids(detections.classes))
        out = self._tracker.update(det, timestamp=time_s) if time_s is not None else self._tracker.update(det)
        keep = np.asarray(out.tracker_id) >= 0
        names = np.asarray(self._classes + [""], dtype=object)
        cls = np.asarray(out.class_id if out.class_id is not None else np.full(len(out), -1))[keep]
        return Detections(boxes=out.xyxy[keep],
                          scores=(np.asarray(out.confidence)[keep] if out.confidence is not None
                                  else np.ones(int(keep.sum()))),
                          classes=names[np.where(cls >= 0, cls, len(self._classes))],
                          track_ids=np.asarray(out.tracker_id)[keep].astype(np.int64))


def track_frames(frames: DetectionFrames, fps: float, options: TrackerOptions | None = None, *,
                 variable_rate: bool = False) -> ImageTracks:
    """Track stored detections over time with a fresh tracker, frame by frame as the pipeline does: ``fps`` is the
    rate of the frames given (the video's fps / its frame step); with ``variable_rate`` the frames' ``time_s``
    drive the motion model. Returns the tracked boxes, ``frame`` the frames' ``frame_index``, ``time`` their
    ``time_s``, at full precision."""
    tracker = VehicleTracker(fps, options)
    bounds = frames.frame_bounds()
    rows, tracked = [], []
    for j in range(len(frames)):
        out = tracker.update(frames.on_frame(j, bounds), float(frames.time_s[j]) if variable_rate else None)
        if len(out):
            rows.append(np.full(len(out), j))
            tracked.append(out)
    return tracks_of(frames.frame_index, frames.time_s, np.concatenate(rows) if rows else np.zeros(0, dtype=int),
                     Detections.concatenate(tracked) if tracked else Detections.empty())


def tracks_of(frame_index: np.ndarray, time_s: np.ndarray, row: np.ndarray, tracked: Detections) -> ImageTracks:
    """:class:`~trafficgeo.run.tracks.ImageTracks` of tracked detections: ``row`` (N,) the position of each
    detection's frame in ``frame_index`` (frame numbers) and ``time_s`` (s)."""
    row = np.asarray(row, dtype=np.int64)
    ids = tracked.track_ids if tracked.track_ids is not None else np.zeros(0, dtype=np.int64)
    if ids.size != len(tracked):
        raise ValueError("tracks_of: the detections have no track ids; track them first")
    return ImageTracks.from_boxes(track_id=ids, frame=np.asarray(frame_index, dtype=np.int64)[row],
                                  time=np.asarray(time_s, dtype=np.float64)[row], boxes=tracked.boxes,
                                  scores=tracked.scores, classes=tracked.classes)
