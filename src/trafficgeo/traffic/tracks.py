"""Image-space tracks in: from any tracker, as CSV or in the MOT Challenge text format.

A track point is a vehicle's ground contact point in the image (pixels, OpenCV pixel-centre convention) at a
frame, with the time of that frame in seconds. Accepted inputs:

* **CSV** with a header: ``frame, track_id`` and either ``u, v`` (the ground contact point) or a box
  ``x1, y1, x2, y2`` (its bottom centre is taken as the ground point); optional ``class``, ``score`` and ``time``
  (seconds; otherwise ``time = frame / fps``). Frames are numbered as in the file.
* **MOT Challenge** ``.txt`` (no header): ``frame, id, bb_left, bb_top, bb_width, bb_height, conf, ...`` with
  1-based frames: ``time = (frame - 1) / fps``.

Each (frame, track) pair may appear once. Rows are returned sorted by track (in number order when every id is
a whole number: :func:`~trafficgeo.run.tracks.track_order`), then time.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.io.mot import read_mot
from trafficgeo.run.tracks import ImageTracks, track_order

CSV_HINT = ("give a CSV with columns frame,track_id and u,v (ground point, px) or x1,y1,x2,y2 (box, px), optionally "
            "class,score,time, or a MOT Challenge .txt")


def _numeric(df: pd.DataFrame, col: str, where: str) -> np.ndarray:
    values = pd.to_numeric(df[col], errors="coerce")
    bad = values.isna()
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        raise InputError(f"{where}: row {row + 2}: column {col} = {df[col].iloc[row]!r} is not a number; {CSV_HINT}")
    return values.to_numpy(dtype=np.float64)


MIN_FPS, MAX_FPS = 0.1, 1000.0  # frames per second a track file's frame numbers may be timed with


def read_tracks(path: str | Path, *, fps: float | None = None) -> ImageTracks:
    """Read tracks from a CSV or a MOT Challenge ``.txt`` (see the module docstring).

    ``fps`` gives the time of each frame when the file has no ``time`` column.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: tracks file not found; {CSV_HINT}")
    if fps is not None and not (np.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise InputError(f"fps {fps:g} is not a video frame rate; give one from {MIN_FPS:g} to {MAX_FPS:g} "
                         "frames per second, e.g. 25", parameters=("fps",))
    mot = p.suffix.lower() == ".txt"
    if mot:
        df = read_mot(p, CSV_HINT)
    else:
        try:
            df = pd.read_csv(p, skipinitialspace=True)
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
            raise InputError(f"{p}: not a readable CSV ({' '.join(str(exc).split())}); {CSV_HINT}") from None
        df.columns = [str(c).strip().lower() for c in df.columns]
    if df.empty:
        raise InputError(f"{p}: no track rows; {CSV_HINT}")
    for col in ("frame", "track_id"):
        if col not in df.columns:
            raise InputError(f"{p}: missing column {col} (found: {', '.join(map(str, df.columns))}); {CSV_HINT}")
    frame_f = _numeric(df, "frame", str(p))
    if np.any(frame_f != np.round(frame_f)) or np.any(frame_f < (1 if mot else 0)):
        raise InputError(f"{p}: frame numbers must be whole numbers >= {1 if mot else 0}; {CSV_HINT}")
    frame = frame_f.astype(np.int64)
    track = df["track_id"].astype(str).str.strip().to_numpy()
    has_box = all(c in df.columns for c in ("x1", "y1", "x2", "y2"))
    n = len(df)
    if has_box:
        box = np.column_stack([_numeric(df, c, str(p)) for c in ("x1", "y1", "x2", "y2")])
        if np.any(box[:, 2] < box[:, 0]) or np.any(box[:, 3] < box[:, 1]):
            raise InputError(f"{p}: a box has x2 < x1 or y2 < y1; boxes are x1,y1 (top-left) to x2,y2 (bottom-right)")
    else:
        box = np.full((n, 4), np.nan)
    if "u" in df.columns and "v" in df.columns:
        u, v = _numeric(df, "u", str(p)), _numeric(df, "v", str(p))
    elif has_box:
        u, v = 0.5 * (box[:, 0] + box[:, 2]), box[:, 3]  # bottom centre of the box
    else:
        raise InputError(f"{p}: no ground point: give columns u,v or a box x1,y1,x2,y2; {CSV_HINT}")
    if "time" in df.columns:
        time = _numeric(df, "time", str(p))
    elif fps is not None:
        time = (frame - (1 if mot else 0)) / fps
    else:
        raise InputError(f"{p}: the file has no time column; give the frame rate as `fps` (e.g. 25)",
                         parameters=("fps",))
    dup = pd.Series(list(zip(track, frame, strict=True))).duplicated()
    if dup.any():
        row = int(np.flatnonzero(dup.to_numpy())[0])
        raise InputError(f"{p}: row {row + 2}: track {track[row]} appears twice in frame {frame[row]}; one point per "
                         "track and frame")
    vclass = df["class"].fillna("").astype(str).to_numpy() if "class" in df.columns else np.full(n, "", dtype=object)
    score = pd.to_numeric(df["score"], errors="coerce").to_numpy(dtype=np.float64) if "score" in df.columns \
        else np.full(n, np.nan)
    order = track_order(track, time)
    return ImageTracks(track_id=track[order], frame=frame[order], time=time[order], u=u[order], v=v[order],
                       box=box[order], vclass=np.asarray(vclass, dtype=object)[order], score=score[order])


def tracks_from_table(table: pd.DataFrame) -> ImageTracks:
    """Tracks from a table with ``track_id, frame, time, x1, y1, x2, y2`` and optional ``class, score`` (the
    ``tracks.csv`` that ``process`` writes): ground point = box bottom centre, rows sorted by track and time."""
    return ImageTracks.from_boxes(track_id=table["track_id"].to_numpy(), frame=table["frame"].to_numpy(),
                                  time=table["time"].to_numpy(), boxes=table[["x1", "y1", "x2", "y2"]].to_numpy(),
                                  scores=table["score"].to_numpy() if "score" in table.columns else None,
                                  classes=table["class"].to_numpy() if "class" in table.columns else None)


def load_tracks(tracks: ImageTracks | pd.DataFrame | str | os.PathLike, *, fps: float | None = None) -> ImageTracks:
    """Image tracks as they are, from a table (``frame, time, track_id`` and boxes ``x1, y1, x2, y2`` or points
    ``u, v``; ``tracks.csv`` of ``process``), or read from a tracks CSV or MOT file (``fps`` when it has no time)."""
    if isinstance(tracks, ImageTracks):
        return tracks
    if isinstance(tracks, pd.DataFrame):
        table = tracks.copy()
        if "class" in table.columns:
            table["class"] = table["class"].fillna("").astype(str)
        return tracks_from_table(table)
    if isinstance(tracks, str | os.PathLike):
        return read_tracks(Path(tracks), fps=fps)
    raise InputError(f"tracks: {type(tracks).__name__} is not ImageTracks, a table or the path of a tracks file",
                     parameters=("tracks",))
