"""An annotated copy of a processed video: each tracked vehicle's box, id, lane and speed (km/h) drawn on every
frame it is tracked through, and the counting lines. Written with PyAV (H.264), atomically.

Every decoded frame of the processed time range is written (``start_s``/``end_s``, default the whole video), not
only the frames the detector ran on: between two detection frames of a track its box is interpolated linearly in
the frame index (pixels), and a track is drawn from its first to its last tracked frame, never beyond. Labels read
``#<track id> <lane> <speed> km/h`` (the ``#`` keeps the id from reading as the first digits of the speed); lane and
speed are those of the track's last analysed point at or before the frame.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_path
from trafficgeo.run.tracks import ImageTracks

_BOX = ("x1", "y1", "x2", "y2")


def _label_rows(tracks: ImageTracks | pd.DataFrame, points: pd.DataFrame) -> pd.DataFrame:
    """Track boxes with the analysis' lane and speed at the same frame (by the tracker's id)."""
    tracks = tracks.to_table() if isinstance(tracks, ImageTracks) else tracks
    info = points[["source_track", "frame", "lane", "speed_kmh"]].rename(columns={"source_track": "track_id"})
    t = tracks.assign(track_id=tracks["track_id"].astype(str))
    return t.merge(info.assign(track_id=info["track_id"].astype(str)), on=["track_id", "frame"], how="left")


def box_label(track_id: str, lane: object, speed_kmh: float) -> str:
    """The text drawn above a box: ``"#0 L1 47 km/h"`` (lane and speed left out when unknown)."""
    speed = "" if pd.isna(speed_kmh) else f" {speed_kmh:.0f} km/h"
    lane_text = "" if lane is None or pd.isna(lane) or lane == "" else f" {lane}"
    return f"#{track_id}{lane_text}{speed}"


def frame_boxes(tracks: ImageTracks | pd.DataFrame, points: pd.DataFrame) -> pd.DataFrame:
    """One row per track and video frame from its first to its last tracked frame.

    Columns ``frame``, ``track_id`` (text), ``x1 y1 x2 y2`` (pixels: the tracked box on the tracker's frames,
    linear interpolation in the frame index between them) and ``label`` (:func:`box_label` with the lane and
    speed of the track's last analysed row at or before the frame; the first one before that).
    """
    rows = _label_rows(tracks, points).sort_values(["track_id", "frame"], kind="stable")
    rows = rows.drop_duplicates(["track_id", "frame"], keep="last")
    parts = []
    for tid, g in rows.groupby("track_id", sort=False):
        known = g["frame"].to_numpy(np.int64)
        frames = np.arange(known[0], known[-1] + 1, dtype=np.int64)
        boxes = {c: np.interp(frames, known, g[c].to_numpy(np.float64)) for c in _BOX}
        labelled = g["speed_kmh"].notna().to_numpy() | g["lane"].notna().to_numpy()
        texts = np.array([box_label(str(tid), ln, sp) for ln, sp in zip(g["lane"], g["speed_kmh"], strict=True)],
                         dtype=object)
        if labelled.any():  # carry the last analysed label forward (and the first one back)
            idx = np.where(labelled, np.arange(len(g)), -1)
            idx = np.maximum.accumulate(idx)
            idx[idx < 0] = int(np.argmax(labelled))
            texts = texts[idx]
        at = np.searchsorted(known, frames, side="right") - 1
        parts.append(pd.DataFrame({"frame": frames, "track_id": str(tid), **boxes, "label": texts[at]}))
    if not parts:
        return pd.DataFrame({"frame": np.zeros(0, np.int64), "track_id": [], **{c: [] for c in _BOX}, "label": []})
    return pd.concat(parts, ignore_index=True)


def _colour(track_id: str) -> tuple[int, int, int]:
    h = zlib.crc32(track_id.encode()) % 180  # stable across runs, unlike hash()
    hsv = np.uint8([[[h, 200, 255]]])
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0])


def annotate_video(video: str | Path, output: str | Path, tracks: ImageTracks | pd.DataFrame, points: pd.DataFrame, *,
                   camera: Camera | None = None, lines: list | None = None, surface=None,
                   start_s: float = 0.0, end_s: float | None = None,
                   progress: Callable[[int, int], None] | None = None) -> None:
    """Draw ``tracks`` (or the ``tracks.csv`` table) labelled with ``points`` (``trajectories.csv``: lane, km/h)
    on every frame of ``video`` from ``start_s`` to ``end_s`` (s; default the whole video) into ``output`` (.mp4);
    see the module docstring. With ``camera`` and ``surface``, the counting ``lines`` are drawn too."""
    import av

    from trafficgeo.video.reader import iter_frames, video_info

    out = Path(output)
    if out.suffix.lower() not in (".mp4", ".mov", ".mkv"):
        raise InputError(f"annotate {out}: write the annotated video as .mp4", parameters=("annotate",))
    info = video_info(video)
    boxes = frame_boxes(tracks, points)
    by_frame = boxes.groupby("frame").indices
    coords = boxes[list(_BOX)].to_numpy(np.float64)
    labels = boxes["label"].to_numpy()
    colour_of = {t: _colour(t) for t in boxes["track_id"].unique()}  # once per track, not per box and frame
    colours = [colour_of[t] for t in boxes["track_id"]]
    polylines = []
    if camera is not None and surface is not None and lines:
        for ln in lines:
            xy = np.asarray(ln.geometry.coords, dtype=np.float64)[:, :2]
            uv = camera.project(np.column_stack([xy, surface.elevation(xy[:, 0], xy[:, 1])]))
            if np.all(np.isfinite(uv)):
                polylines.append((ln.name, np.round(uv).astype(np.int32)))
    end = min(end_s, info.duration_s) if end_s is not None else info.duration_s
    total = max(1, round((end - start_s) * info.fps))
    with atomic_path(out) as tmp:
        container = av.open(str(tmp), mode="w", format="mp4")
        stream = container.add_stream("libx264", rate=max(1, round(info.fps)))
        stream.width, stream.height, stream.pix_fmt = info.width, info.height, "yuv420p"
        stream.options = {"crf": "23", "preset": "veryfast"}
        for k, frame in enumerate(iter_frames(video, start_s=start_s, end_s=end_s), start=1):
            img = frame.image.copy()
            for name, uv in polylines:
                cv2.polylines(img, [uv], False, (0, 255, 255), 2, cv2.LINE_AA)
                cv2.putText(img, f"line {name}", tuple(int(c) for c in uv[0]), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                            (0, 255, 255), 2, cv2.LINE_AA)
            for i in by_frame.get(frame.index, []):
                x1, y1, x2, y2 = (int(c) for c in np.rint(coords[i]))
                col = colours[i]
                cv2.rectangle(img, (x1, y1), (x2, y2), col, 2)
                cv2.putText(img, labels[i], (x1, max(12, y1 - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.5, col,
                            1, cv2.LINE_AA)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                container.mux(packet)
            if progress is not None:
                progress(k, max(k, total))
        for packet in stream.encode():
            container.mux(packet)
        container.close()
