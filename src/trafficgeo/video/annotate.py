"""An annotated copy of a processed video: each tracked vehicle's box, id, lane and speed (km/h) drawn on its frames,
and the counting lines. Written with PyAV (H.264), atomically."""

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


def _label_rows(tracks: pd.DataFrame, points: pd.DataFrame) -> pd.DataFrame:
    """Track boxes with the analysis' lane and speed at the same frame (by the tracker's id)."""
    info = points[["source_track", "frame", "lane", "speed_kmh"]].rename(columns={"source_track": "track_id"})
    t = tracks.assign(track_id=tracks["track_id"].astype(str))
    return t.merge(info.assign(track_id=info["track_id"].astype(str)), on=["track_id", "frame"], how="left")


def _colour(track_id: str) -> tuple[int, int, int]:
    h = zlib.crc32(track_id.encode()) % 180  # stable across runs, unlike hash()
    hsv = np.uint8([[[h, 200, 255]]])
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0])


def annotate_video(video: str | Path, output: str | Path, tracks: pd.DataFrame, points: pd.DataFrame, *,
                   camera: Camera | None = None, lines: list | None = None, surface=None,
                   progress: Callable[[int, int], None] | None = None) -> None:
    """Draw ``tracks`` (``tracks.csv``) labelled with ``points`` (``trajectories.csv``: lane, km/h) on the frames
    of ``video`` into ``output`` (.mp4). With ``camera`` and ``surface``, the counting ``lines`` are drawn too."""
    import av

    from trafficgeo.video.reader import iter_frames, video_info

    out = Path(output)
    if out.suffix.lower() not in (".mp4", ".mov", ".mkv"):
        raise InputError(f"annotate {out}: write the annotated video as .mp4", parameters=("annotate",))
    info = video_info(video)
    rows = _label_rows(tracks, points)
    by_frame = rows.groupby("frame").indices
    polylines = []
    if camera is not None and surface is not None and lines:
        for ln in lines:
            xy = np.asarray(ln.geometry.coords, dtype=np.float64)[:, :2]
            uv = camera.project(np.column_stack([xy, surface.elevation(xy[:, 0], xy[:, 1])]))
            if np.all(np.isfinite(uv)):
                polylines.append((ln.name, np.round(uv).astype(np.int32)))
    start = float(tracks["time"].min()) if len(tracks) else 0.0
    end = float(tracks["time"].max()) + 1e-3 if len(tracks) else info.duration_s
    total = max(1, round((end - start) * info.fps))
    with atomic_path(out) as tmp:
        container = av.open(str(tmp), mode="w", format="mp4")
        stream = container.add_stream("libx264", rate=max(1, round(info.fps)))
        stream.width, stream.height, stream.pix_fmt = info.width, info.height, "yuv420p"
        stream.options = {"crf": "23", "preset": "veryfast"}
        for k, frame in enumerate(iter_frames(video, start_s=start, end_s=end), start=1):
            img = frame.image.copy()
            for name, uv in polylines:
                cv2.polylines(img, [uv], False, (0, 255, 255), 2, cv2.LINE_AA)
                cv2.putText(img, f"line {name}", tuple(int(c) for c in uv[0]), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                            (0, 255, 255), 2, cv2.LINE_AA)
            for i in by_frame.get(frame.index, []):
                r = rows.iloc[i]
                p1, p2 = (int(r["x1"]), int(r["y1"])), (int(r["x2"]), int(r["y2"]))
                col = _colour(str(r["track_id"]))
                cv2.rectangle(img, p1, p2, col, 2)
                speed = "" if pd.isna(r["speed_kmh"]) else f" {r['speed_kmh']:.0f} km/h"
                lane = "" if pd.isna(r["lane"]) or r["lane"] == "" else f" {r['lane']}"
                cv2.putText(img, f"{r['track_id']}{lane}{speed}", (p1[0], max(12, p1[1] - 4)),
                            cv2.FONT_HERSHEY_SIMPLEX, 0.5, col, 1, cv2.LINE_AA)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                container.mux(packet)
            if progress is not None:
                progress(k, total)
        for packet in stream.encode():
            container.mux(packet)
        container.close()
