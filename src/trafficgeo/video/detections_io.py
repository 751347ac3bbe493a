"""Detections made elsewhere (another detector, an annotation tool): read them, and write ours, as tables.

:func:`read_detections` returns a :class:`pandas.DataFrame` with one row per box and the columns
``frame`` (int), ``x1, y1, x2, y2`` (float, pixels), ``score`` (float) and ``class`` (str, ``""`` = unknown),
sorted by frame (stable: the file's order within a frame). Accepted files:

* **CSV** with a header (names are case-insensitive): ``frame`` and a box as ``x1, y1, x2, y2`` (corners) or
  ``x, y, w, h`` (top-left corner and size; also ``left, top, width, height``); optional ``score`` (or ``conf``,
  ``confidence``; default 1.0) and ``class`` (or ``label``, ``category``, ``class_name``; default ``""``).
  Frames are numbered as in the file.
* **MOT Challenge** ``det.txt`` (``.txt``, no header): ``frame, id, bb_left, bb_top, bb_width, bb_height, conf,
  ...``. Frames are **1-based** in this format and are stored as in the file (subtract 1 for 0-based video
  frames); ``conf`` is stored as given (some public detections are not in [0, 1]; :func:`detections_for_frame`
  clips); the class is ``""``.
* **COCO JSON** (``.json``): ``images`` (``id``, ``file_name``, optional ``frame_index``), ``annotations``
  (``image_id``, ``bbox`` = ``[x, y, w, h]``, ``category_id``, optional ``score``) and ``categories`` (``id``,
  ``name``). The frame of an image is its ``frame_index`` when every image has one, else its rank in the order of
  the image ids (0-based). A COCO *results* file (a bare list of annotations) is read with ``frame = image_id`` and
  the class named from the 91 COCO category ids for vehicles (3 = car, ...; others keep their number).

Coordinates are taken as written (no half-pixel or 1-based shift): tools disagree on sub-pixel conventions by at
most a pixel. With ``image_size = (W, H)`` boxes are clipped to the frame (pixel-centre convention, edges at
-0.5 and W - 0.5) and a box wholly outside it, or coordinates that all look normalised (0..1), is an error.
:func:`write_detections` writes the CSV form atomically.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from trafficgeo.errors import InputError
from trafficgeo.io.atomic import write_csv_atomic
from trafficgeo.io.json_text import loads_json
from trafficgeo.io.mot import read_mot
from trafficgeo.video.detections import Detections

COLUMNS = ["frame", "x1", "y1", "x2", "y2", "score", "class"]
HINT = ("give a CSV with a header frame,x1,y1,x2,y2 (or frame,x,y,w,h) and optional score,class; a MOT Challenge "
        "det.txt; or a COCO JSON with images, annotations and categories")
# The original (91-id) COCO category ids of road vehicles, as used in COCO results files.
COCO91_VEHICLES = {2: "bicycle", 3: "car", 4: "motorcycle", 6: "bus", 8: "truck"}
_SCORE_NAMES = ("score", "conf", "confidence")
_CLASS_NAMES = ("class", "label", "category", "class_name")


def _empty() -> pd.DataFrame:
    return pd.DataFrame({"frame": np.zeros(0, dtype=np.int64), "x1": np.zeros(0), "y1": np.zeros(0),
                         "x2": np.zeros(0), "y2": np.zeros(0), "score": np.zeros(0),
                         "class": np.zeros(0, dtype=object)})


def _numbers(values: ArrayLike, name: str, where: str, first_row: int = 2) -> np.ndarray:
    """Finite floats or an InputError naming the first bad row (file rows counted from ``first_row``)."""
    s = pd.to_numeric(pd.Series(values), errors="coerce")
    arr = s.to_numpy(dtype=np.float64)
    bad = ~np.isfinite(arr)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raw = pd.Series(values).iloc[k]
        raise InputError(f"{where}: row {k + first_row}: {name} = {raw!r} is not a finite number; {HINT}")
    return arr


def _frames(values: ArrayLike, where: str, minimum: int, first_row: int = 2) -> np.ndarray:
    f = _numbers(values, "frame", where, first_row)
    bad = (f != np.round(f)) | (f < minimum)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"{where}: row {k + first_row}: frame {f[k]:g} is not a whole number >= {minimum}; {HINT}")
    return f.astype(np.int64)


def _table(frame: np.ndarray, x1: np.ndarray, y1: np.ndarray, x2: np.ndarray, y2: np.ndarray, score: np.ndarray,
           cls: np.ndarray, where: str, first_row: int = 2) -> pd.DataFrame:
    bad = (x2 < x1) | (y2 < y1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"{where}: row {k + first_row}: box ({x1[k]:g}, {y1[k]:g}, {x2[k]:g}, {y2[k]:g}) has a "
                         "negative width or height; boxes are x1,y1 (top-left) to x2,y2 (bottom-right) or x,y,w,h")
    df = pd.DataFrame({"frame": frame, "x1": x1, "y1": y1, "x2": x2, "y2": y2, "score": score,
                       "class": np.asarray(cls, dtype=object)})
    return df


def _read_csv(p: Path) -> pd.DataFrame:
    where = str(p)
    try:
        df = pd.read_csv(p, skipinitialspace=True, comment="#", dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not a readable CSV ({' '.join(str(exc).split())}); {HINT}") from None
    cols = {str(c).strip().lower(): c for c in df.columns}
    if "frame" not in cols:
        found = ", ".join(map(str, df.columns)) or "none"
        raise InputError(f"{p}: missing column frame (found: {found}); {HINT}")

    def col(name: str) -> pd.Series:
        return df[cols[name]].astype(str).str.strip()

    if all(c in cols for c in ("x1", "y1", "x2", "y2")):
        x1, y1, x2, y2 = (_numbers(col(c), c, where) for c in ("x1", "y1", "x2", "y2"))
    else:
        for names in (("x", "y", "w", "h"), ("left", "top", "width", "height"),
                      ("bb_left", "bb_top", "bb_width", "bb_height")):
            if all(c in cols for c in names):
                x1, y1, w, h = (_numbers(col(c), c, where) for c in names)
                x2, y2 = x1 + w, y1 + h
                break
        else:
            raise InputError(f"{p}: no box columns: give x1,y1,x2,y2 or x,y,w,h (found: "
                             f"{', '.join(map(str, df.columns))}); {HINT}")
    frame = _frames(col("frame"), where, 0)
    score_col = next((c for c in _SCORE_NAMES if c in cols), None)
    score = _numbers(col(score_col), score_col, where) if score_col else np.ones(len(df))
    class_col = next((c for c in _CLASS_NAMES if c in cols), None)
    cls = col(class_col).to_numpy(dtype=object) if class_col else np.full(len(df), "", dtype=object)
    return _table(frame, x1, y1, x2, y2, score, cls, where)


def _read_mot(p: Path) -> pd.DataFrame:
    """A MOT Challenge det.txt through :func:`trafficgeo.io.mot.read_mot` (a file without ``conf``: score 1.0)."""
    mot = read_mot(p, HINT)
    if mot.empty:
        return _empty()
    x1, y1, x2, y2 = (mot[c].to_numpy(dtype=np.float64) for c in ("x1", "y1", "x2", "y2"))
    score = mot["score"].fillna(1.0).to_numpy(dtype=np.float64)
    return _table(mot["frame"].to_numpy(dtype=np.int64), x1, y1, x2, y2, score,
                  np.full(len(mot), "", dtype=object), str(p), first_row=1)


def _read_coco(p: Path) -> pd.DataFrame:
    where = str(p)
    try:
        doc = loads_json(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not valid JSON ({' '.join(str(exc).split())}); {HINT}") from None
    if isinstance(doc, list):  # COCO results: a bare list of annotations
        anns, frame_of, names = doc, None, dict(COCO91_VEHICLES)
    elif isinstance(doc, dict) and isinstance(doc.get("annotations"), list):
        anns = doc["annotations"]
        images = doc.get("images")
        if not isinstance(images, list) or not all(isinstance(i, dict) and "id" in i for i in images):
            raise InputError(f"{p}: COCO 'images' must be a list of objects with an 'id'; {HINT}")
        ids = [i["id"] for i in images]
        if len(set(map(str, ids))) != len(ids):
            raise InputError(f"{p}: COCO image ids are not unique; give each image its own id")
        if images and all("frame_index" in i for i in images):
            frame_of = {str(i["id"]): i["frame_index"] for i in images}
        else:
            try:
                order = sorted(ids)
            except TypeError:
                raise InputError(f"{p}: COCO image ids mix numbers and text; use one kind") from None
            frame_of = {str(i): k for k, i in enumerate(order)}
        cats = doc.get("categories", [])
        if not isinstance(cats, list) or not all(isinstance(c, dict) and "id" in c for c in cats):
            raise InputError(f"{p}: COCO 'categories' must be a list of objects with an 'id' and a 'name'; {HINT}")
        names = {c["id"]: str(c.get("name", c["id"])) for c in cats}
    else:
        raise InputError(f"{p}: not a COCO file (no 'annotations' list); {HINT}")
    n = len(anns)
    frame = np.zeros(n, dtype=object)
    box = np.zeros((n, 4), dtype=object)
    score = np.ones(n, dtype=object)
    cls = np.full(n, "", dtype=object)
    for k, a in enumerate(anns):
        if not isinstance(a, dict) or "image_id" not in a or "bbox" not in a:
            raise InputError(f"{p}: annotation {k}: needs 'image_id' and 'bbox' [x, y, w, h]; {HINT}")
        b = a["bbox"]
        if not isinstance(b, list | tuple) or len(b) != 4:
            raise InputError(f"{p}: annotation {k}: bbox {b!r} is not [x, y, w, h]; {HINT}")
        if frame_of is None:
            frame[k] = a["image_id"]
        else:
            if str(a["image_id"]) not in frame_of:
                raise InputError(f"{p}: annotation {k}: image_id {a['image_id']!r} is not among the images; {HINT}")
            frame[k] = frame_of[str(a["image_id"])]
        box[k] = b
        score[k] = a.get("score", 1.0)
        cat = a.get("category_id")
        cls[k] = names.get(cat, "" if cat is None else str(cat))
    where_ann = f"{where} (annotation numbers from 0)"
    frame_i = _frames(frame, where_ann, 0, first_row=0)
    x1, y1, w, h = (_numbers(box[:, j], name, where_ann, 0) for j, name in enumerate(("x", "y", "w", "h")))
    s = _numbers(score, "score", where_ann, 0)
    return _table(frame_i, x1, y1, x1 + w, y1 + h, s, cls, where_ann, first_row=0)


def _is_mot(p: Path) -> bool:
    """A .txt whose first non-empty line starts with a number (a MOT file has no header)."""
    with open(p, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.strip():
                first = line.split(",")[0].strip()
                try:
                    float(first)
                except ValueError:
                    return False
                return True
    return True


def read_detections(path: str | Path, *, image_size: tuple[int, int] | None = None) -> pd.DataFrame:
    """Detections from a CSV, MOT Challenge ``det.txt`` or COCO JSON file (see the module docstring).

    Returns a DataFrame with columns ``frame, x1, y1, x2, y2, score, class`` sorted by frame. ``image_size``
    ``(W, H)`` in pixels clips the boxes to the frame and rejects boxes outside it.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: detections file not found; {HINT}")
    suffix = p.suffix.lower()
    if suffix == ".json":
        df = _read_coco(p)
    elif suffix == ".txt" and _is_mot(p):
        df = _read_mot(p)
    else:
        df = _read_csv(p)
    if image_size is not None:
        df = _check_frame(df, image_size, str(p))
    df = df.sort_values("frame", kind="stable").reset_index(drop=True)
    return df[COLUMNS]


def _check_frame(df: pd.DataFrame, image_size: tuple[int, int], where: str) -> pd.DataFrame:
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise InputError(f"image_size {image_size!r} must be (width, height) in pixels") from None
    if w < 1 or h < 1:
        raise InputError(f"image_size {image_size!r} must be (width, height) in pixels, both >= 1")
    if df.empty:
        return df
    b = df[["x1", "y1", "x2", "y2"]].to_numpy()
    if w > 2 and h > 2 and np.nanmax(np.abs(b)) <= 1.0:
        raise InputError(f"{where}: every box coordinate is within 0..1: the boxes look normalised; multiply them "
                         f"by the image size ({w}x{h}) to give pixels")
    outside = (b[:, 2] < -0.5) | (b[:, 0] > w - 0.5) | (b[:, 3] < -0.5) | (b[:, 1] > h - 0.5)
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        raise InputError(f"{where}: the box of frame {df['frame'].iloc[k]} ({', '.join(f'{v:g}' for v in b[k])}) "
                         f"lies outside the {w}x{h} frame; check the image size and the box format")
    out = df.copy()
    out[["x1", "x2"]] = np.clip(b[:, [0, 2]], -0.5, w - 0.5)
    out[["y1", "y2"]] = np.clip(b[:, [1, 3]], -0.5, h - 0.5)
    return out


def iter_detections(table: pd.DataFrame) -> Iterator[tuple[int, Detections]]:
    """``(frame, Detections)`` for each frame present in ``table`` (columns of :func:`read_detections`), in frame
    order. Scores are clipped to [0, 1] (NaN -> 1); missing classes become ``""``."""
    missing = [c for c in ("frame", "x1", "y1", "x2", "y2") if c not in table.columns]
    if missing:
        raise InputError(f"detections table: missing column(s) {', '.join(missing)}; use read_detections")
    if table.empty:
        return
    df = table.sort_values("frame", kind="stable")
    frame = df["frame"].to_numpy(dtype=np.int64)
    boxes = df[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    score = df["score"].to_numpy(dtype=np.float64) if "score" in df.columns else np.ones(len(df))
    score = np.clip(np.nan_to_num(score, nan=1.0), 0.0, 1.0)
    if "class" in df.columns:
        cls = df["class"].where(df["class"].notna(), "").astype(str).to_numpy(dtype=object)
    else:
        cls = np.full(len(df), "", dtype=object)
    uniq, start = np.unique(frame, return_index=True)
    ends = np.append(start[1:], len(frame))
    for f, a, b in zip(uniq, start, ends, strict=True):
        yield int(f), Detections(boxes[a:b], score[a:b], cls[a:b])


def detections_for_frame(table: pd.DataFrame) -> dict[int, Detections]:
    """Per frame number, its :class:`~trafficgeo.video.detections.Detections` (frames without boxes are absent)."""
    return dict(iter_detections(table))


def detections_table(frames: dict[int, Detections] | Iterator[tuple[int, Detections]]) -> pd.DataFrame:
    """The table form (columns of :func:`read_detections`) of per-frame detections."""
    items = frames.items() if isinstance(frames, dict) else frames
    parts = [(f, d) for f, d in items if len(d)]
    if not parts:
        return _empty()
    frame = np.concatenate([np.full(len(d), f, dtype=np.int64) for f, d in parts])
    det = Detections.concatenate(d for _, d in parts)
    return pd.DataFrame({"frame": frame, "x1": det.boxes[:, 0], "y1": det.boxes[:, 1], "x2": det.boxes[:, 2],
                         "y2": det.boxes[:, 3], "score": det.scores, "class": det.classes})


def write_detections(path: str | Path, table: pd.DataFrame) -> None:
    """Write ``table`` (columns of :func:`read_detections`; ``score`` and ``class`` optional) as CSV atomically
    (pixels and scores to 1e-4)."""
    missing = [c for c in ("frame", "x1", "y1", "x2", "y2") if c not in table.columns]
    if missing:
        raise InputError(f"{path}: cannot write detections without column(s) {', '.join(missing)}")
    out = pd.DataFrame({c: table[c] for c in ("frame", "x1", "y1", "x2", "y2")})
    out["frame"] = out["frame"].astype(np.int64)
    out["score"] = table["score"] if "score" in table.columns else 1.0
    out["class"] = table["class"].where(table["class"].notna(), "").astype(str) if "class" in table.columns else ""
    p = Path(path)
    write_csv_atomic(p, out, float_format="%.4f")
