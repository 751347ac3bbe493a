"""Region of interest: the part of the frame where traffic is analysed.

Either a mask image of the frame's size (PNG/BMP/TIFF: non-zero pixels are inside; JPEG, being lossy: pixels
brighter than 127 are inside) or a CSV polygon with columns ``u,v``: vertices in pixels, OpenCV's convention
(origin at the centre of the top-left pixel, u to the right, v down). An optional ``polygon`` column splits
the vertices into several polygons (all inside). Draw the mask or pick the vertices on a frame written by
``trafficgeo frame``.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import cv2
import numpy as np

from trafficgeo.errors import InputError

MASK_SUFFIXES = (".png", ".bmp", ".tif", ".tiff", ".jpg", ".jpeg")
_LOSSY_SUFFIXES = (".jpg", ".jpeg")
_SHIFT = 8  # fractional bits of the polygon vertices given to cv2.fillPoly (1/256 px)


def read_roi(path: str | Path, image_size: tuple[int, int]) -> np.ndarray:
    """Boolean mask (H, W), True inside the region, for frames of ``image_size`` = (width, height) pixels."""
    p = Path(path)
    w, h = (int(v) for v in image_size)
    if w <= 0 or h <= 0:
        raise InputError(f"ROI {p}: image size {w}x{h} must be positive")
    if not p.is_file():
        raise InputError(f"ROI {p}: {'is a folder, not a file' if p.is_dir() else 'not found'}; check the path")
    suffix = p.suffix.lower()
    if suffix == ".csv":
        mask = _polygon_mask(p, w, h)
    elif suffix in MASK_SUFFIXES:
        mask = _image_mask(p, w, h)
    else:
        raise InputError(f"ROI {p}: unknown format '{p.suffix}'; give a mask image (.png) or a CSV polygon "
                         "with columns u,v (pixels)")
    if not mask.any():
        raise InputError(f"ROI {p}: no pixel of the {w}x{h} frame is inside the region; check that it was "
                         "drawn on a frame of this video")
    return mask


def _image_mask(p: Path, w: int, h: int) -> np.ndarray:
    data = np.fromfile(p, dtype=np.uint8)  # cv2.imread cannot open non-ASCII paths on Windows
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None:
        raise InputError(f"ROI {p}: not a readable image; save the mask as PNG")
    if image.shape[:2] != (h, w):
        raise InputError(f"ROI {p}: the mask is {image.shape[1]}x{image.shape[0]} px but the video frames are "
                         f"{w}x{h}; draw the mask on a frame of this video (trafficgeo frame VIDEO -o frame.png)")
    if image.ndim == 3:
        channels = image[..., :3] if image.shape[2] >= 3 else image[..., :1]
        image = channels.max(axis=2)
    threshold = 127 if p.suffix.lower() in _LOSSY_SUFFIXES else 0
    return np.asarray(image > threshold)


def _polygon_mask(p: Path, w: int, h: int) -> np.ndarray:
    polygons = _read_polygons(p)
    mask = np.zeros((h, w), dtype=np.uint8)
    scale = 1 << _SHIFT
    scaled = [np.round(np.asarray(poly, dtype=float) * scale) for poly in polygons]
    if any(np.abs(a).max() >= 2**31 - 1 for a in scaled):
        raise InputError(f"ROI {p}: vertices lie absurdly far outside the frame; check the u,v columns (pixels)")
    pts = [a.astype(np.int32).reshape(-1, 1, 2) for a in scaled]
    cv2.fillPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=_SHIFT)
    return mask.astype(bool)


def _read_polygons(p: Path) -> list[list[tuple[float, float]]]:
    """Vertices per polygon, in file order; polygons keyed by the optional 'polygon' column."""
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:
            rows = [r for r in csv.reader(fh) if r and any(c.strip() for c in r)]
    except UnicodeDecodeError:
        raise InputError(f"ROI {p}: not a text CSV; give columns u,v (pixels)") from None
    if not rows:
        raise InputError(f"ROI {p}: empty; give a CSV with columns u,v (pixels), one vertex per line")
    header = [c.strip().lower() for c in rows[0]]
    if "u" in header and "v" in header:
        iu, iv = header.index("u"), header.index("v")
        ig = header.index("polygon") if "polygon" in header else None
        body, first_line = rows[1:], 2
    else:
        iu, iv, ig, body, first_line = 0, 1, None, rows, 1
    polygons: dict[str, list[tuple[float, float]]] = {}
    for line, row in enumerate(body, start=first_line):
        try:
            u, v = float(row[iu]), float(row[iv])
        except (ValueError, IndexError):
            raise InputError(f"ROI {p} line {line}: '{','.join(row)}' is not a vertex u,v in pixels; the file "
                             "needs columns u,v (a header line 'u,v' is optional)") from None
        if not (math.isfinite(u) and math.isfinite(v)):
            raise InputError(f"ROI {p} line {line}: vertex ({u}, {v}) is not finite")
        key = row[ig].strip() if ig is not None and ig < len(row) else ""
        polygons.setdefault(key, []).append((u, v))
    for key, poly in polygons.items():
        if len(poly) < 3:
            name = f"polygon '{key}'" if key else "the polygon"
            raise InputError(f"ROI {p}: {name} has {len(poly)} vertices; a region needs at least 3")
    return list(polygons.values())
