"""The scene without its traffic: one clean frame from a stretch of fixed-camera video.

Used where a still of the road itself is wanted (orthophoto registration, ``trafficgeo refine``): passing vehicles
would be matched against the orthophoto's road texture. Each pixel takes its temporal mode over frames spread
evenly over the stretch (:func:`trafficgeo.video.detectors.background.temporal_mode`: the colour seen most often,
which is the road's even where vehicles cover it more than half of the time, when a median would show them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.video.detectors.background import temporal_mode
from trafficgeo.video.reader import iter_frames, video_info

DEFAULT_FRAMES = 25


def background_frame(video: str | Path, *, start_s: float = 0.0, duration_s: float = 30.0,
                     n_frames: int = DEFAULT_FRAMES) -> np.ndarray:
    """(H, W, 3) BGR uint8: the per-pixel temporal mode of ``n_frames`` frames spread evenly over
    ``[start_s, start_s + duration_s)`` seconds of ``video`` (cut at its end).

    Raises :class:`InputError` (naming the parameter) for a stretch outside the video or fewer than 3 frames.
    """
    if not (isinstance(n_frames, int | np.integer) and n_frames >= 3):
        raise InputError(f"n_frames = {n_frames!r} must be a whole number >= 3", parameters=("n_frames",))
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise InputError(f"duration_s = {duration_s} must be a positive number of seconds",
                         parameters=("duration_s",))
    info = video_info(video)
    if not (np.isfinite(start_s) and 0.0 <= start_s < info.duration_s):
        raise InputError(f"start_s = {start_s} s is outside {video} ({info.duration_s:.1f} s long)",
                         parameters=("start_s",))
    end_s = min(start_s + duration_s, info.duration_s)
    available = max(int((end_s - start_s) * info.fps), 1)
    every = max(available // int(n_frames), 1)
    frames = [f.image for _, f in zip(range(int(n_frames)), iter_frames(video, start_s=start_s, end_s=end_s,
                                                                          every=every), strict=False)]
    if len(frames) < 3:
        raise InputError(f"{video}: only {len(frames)} frame(s) between {start_s:g} and {end_s:g} s; give a longer "
                         "stretch (duration_s)", parameters=("duration_s",))
    return temporal_mode(frames)
