"""MOT Challenge text files (``gt.txt``, ``det.txt``, tracker output): one box per line, no header.

A line is ``frame, id, bb_left, bb_top, bb_width, bb_height[, conf, ...]`` (comma-separated, further columns
ignored): frames are **1-based**, the box is its top-left corner and size in pixels, ``id`` is the track (-1 for
plain detections). :func:`read_mot` returns them checked, with the box as corners, for
:func:`trafficgeo.traffic.tracks.read_tracks` and the detections readers.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError

__all__ = ["MOT_COLUMNS", "read_mot"]

#: Columns of :func:`read_mot`'s table.
MOT_COLUMNS = ["frame", "track_id", "x1", "y1", "x2", "y2", "score"]
_FIELDS = ((0, "frame"), (2, "bb_left"), (3, "bb_top"), (4, "bb_width"), (5, "bb_height"), (6, "conf"))


def _empty() -> pd.DataFrame:
    return pd.DataFrame({"frame": np.zeros(0, dtype=np.int64), "track_id": pd.Series([], dtype=object),
                         **{c: np.zeros(0) for c in ("x1", "y1", "x2", "y2", "score")}})


def read_mot(path: str | os.PathLike[str], hint: str) -> pd.DataFrame:
    """Read a MOT Challenge text file: one row per line with :data:`MOT_COLUMNS`.

    ``frame`` (int, 1-based as in the file), ``track_id`` (str, as written), ``x1, y1, x2, y2`` (float px:
    ``bb_left``, ``bb_top`` and those plus ``bb_width``, ``bb_height``), ``score`` (float ``conf`` as written, NaN
    when the file has no such column). An empty file gives an empty table. ``hint`` ends every error message (how
    to fix the file).

    Raises:
        InputError: an unreadable file, fewer than 6 columns, a field that is not a finite number or a frame that is
            not a whole number >= 1 (naming the line).
    """
    p = Path(path)
    try:
        raw = pd.read_csv(p, header=None, skipinitialspace=True, dtype=str, keep_default_na=False)
    except pd.errors.EmptyDataError:
        return _empty()
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not a readable MOT file ({' '.join(str(exc).split())}); {hint}") from None
    if raw.shape[1] < 6:
        raise InputError(f"{p}: a MOT line needs at least frame,id,left,top,width,height; found {raw.shape[1]} "
                         f"column(s); {hint}")
    num = {}
    for k, name in _FIELDS:
        if k >= raw.shape[1]:
            num[name] = np.full(len(raw), np.nan)
            continue
        values = pd.to_numeric(raw[k], errors="coerce").to_numpy(dtype=np.float64)
        bad = ~np.isfinite(values)
        if name == "frame":
            with np.errstate(invalid="ignore"):
                bad |= (values != np.round(values)) | (values < 1)
        if bad.any():
            line = int(np.flatnonzero(bad)[0])
            what = "a whole number >= 1" if name == "frame" else "a finite number"
            raise InputError(f"{p}: line {line + 1}: {name} = {raw[k].iloc[line]!r} is not {what}; {hint}")
        num[name] = values
    return pd.DataFrame({
        "frame": num["frame"].astype(np.int64), "track_id": raw[1].str.strip().to_numpy(dtype=object),
        "x1": num["bb_left"], "y1": num["bb_top"], "x2": num["bb_left"] + num["bb_width"],
        "y2": num["bb_top"] + num["bb_height"], "score": num["conf"]})
