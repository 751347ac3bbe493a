"""Camera intrinsics from photos of a printed chessboard (OpenCV ``calibrateCamera``, 5-term distortion).

Pre-calibrate a phone once: take 10-20 sharp photos of a flat chessboard filling much of the frame at varied
tilts and positions (corners of the frame included), *in the same camera mode, resolution and zoom as the
traffic video* (photo and video modes of a phone usually crop the sensor differently; digital stabilisation
changes the intrinsics from frame to frame, switch it off).

``pattern`` counts the INNER corners (where four squares meet): a board of 10 x 7 squares has 9 x 6 inner
corners. Detection: ``cv2.findChessboardCorners`` (adaptive threshold + normalised image),
``cv2.findChessboardCornersSB`` as a fallback, then ``cv2.cornerSubPix`` on the full-resolution image.
Large photos are searched on a copy reduced to at most :data:`DETECT_MAX_SIDE` pixels (much faster), the
corners are refined at full resolution.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from trafficgeo.camera.opencv_yaml import Intrinsics
from trafficgeo.errors import CalibrationError, InputError

DETECT_MAX_SIDE = 1600
"""Images larger than this (longest side, px) are searched for the board on a reduced copy."""
MIN_VIEWS = 3
_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
_SUBPIX_MAX_HALF_WINDOW = 11  # OpenCV's calibration sample uses an 11 px half window (23 x 23)


@dataclass(frozen=True, eq=False)
class ChessboardCalibration:
    """Result of :func:`calibrate_chessboard`.

    Attributes:
        intrinsics: K, dist, image_size and rms_px of the calibration.
        used_images: the images where the board was found, in the order given.
        skipped_images: the images where it was not.
        per_view_rms_px: (n_used,) reprojection RMS of each used image [px], same order as ``used_images``.
        rms_px: reprojection RMS over all corners of all used images [px].
    """

    intrinsics: Intrinsics
    used_images: tuple[str, ...]
    skipped_images: tuple[str, ...]
    per_view_rms_px: np.ndarray
    rms_px: float


def _read_gray(path: Path) -> np.ndarray:
    """The image as 8-bit grayscale (EXIF orientation applied, like cv2.imread); InputError if unreadable."""
    try:
        data = np.fromfile(path, dtype=np.uint8)  # not cv2.imread: clear errors, non-ASCII paths on Windows
    except FileNotFoundError:
        raise InputError(f"{path}: image not found; check the path") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not an image; give image files (e.g. folder/*.jpg)") from None
    except OSError as exc:
        raise InputError(
            f"{path}: cannot be read ({exc.strerror or exc}); check the file permissions"
        ) from None
    img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
    if img is None or img.size == 0:
        raise InputError(
            f"{path}: not a readable image (OpenCV cannot decode it); give JPEG or PNG photos of the "
            f"chessboard"
        )
    return img


def _subpix_half_window(corners: np.ndarray, pattern: tuple[int, int]) -> int:
    """A cornerSubPix half window of a third of the closest corner spacing (at most 11 px, at least 2 px).

    A window reaching towards the neighbouring corners sees edges that do not pass through its corner and
    biases it: on OpenCV's 13 sample images a fixed 11 px half window (OpenCV's sample) gives 0.41 px RMS
    with 1.2 px on the most foreshortened view (22 px squares); a third of the spacing gives 0.18 px and
    0.24 px.
    """
    cols, rows = pattern
    grid = corners.reshape(rows, cols, 2)
    spacing = min(
        float(np.linalg.norm(np.diff(grid, axis=1), axis=2).min()),
        float(np.linalg.norm(np.diff(grid, axis=0), axis=2).min()),
    )
    return int(max(2, min(_SUBPIX_MAX_HALF_WINDOW, math.floor(spacing / 3))))


def _is_checkerboard(gray: np.ndarray, corners: np.ndarray, pattern: tuple[int, int]) -> bool:
    """True if the corners are X-junctions of alternating dark/light squares, in checkerboard parity.

    Guards against shifted detections: for a wrong pattern, findChessboardCornersSB can return a grid whose
    last row lies on the outer edge of the board, where the "corners" are L-shaped and poorly located. A few
    isolated failing corners (glare on a glossy print) are tolerated, a failing outer row or column is not.
    """
    cols, rows = pattern
    grid = corners.reshape(rows, cols, 2).astype(np.float64)
    du = np.gradient(grid, axis=1)  # local step to the next column
    dv = np.gradient(grid, axis=0)  # local step to the next row
    offsets = [(1, 1), (1, -1), (-1, -1), (-1, 1)]  # quadrant centres, going round the corner
    pts = np.stack([grid + 0.35 * (a * du + b * dv) for a, b in offsets], axis=2).reshape(-1, 4, 2)
    smooth = cv2.GaussianBlur(gray, (0, 0), 1.0).astype(np.float32)
    map_xy = pts.astype(np.float32)
    vals = cv2.remap(
        smooth, map_xy[..., 0], map_xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    vals = vals.astype(np.float64)
    q1, q2, q3, q4 = vals[:, 0], vals[:, 1], vals[:, 2], vals[:, 3]
    contrast = (q1 + q3 - q2 - q4) / 2  # > 0 when the (+,+) and (-,-) squares are the light ones
    separation = np.maximum(np.minimum(q1, q3) - np.maximum(q2, q4), np.minimum(q2, q4) - np.maximum(q1, q3))
    typical = float(np.median(np.abs(contrast)))
    if typical < 5.0:  # gray levels: no visible board
        return False
    good = separation >= 0.25 * typical
    bad = ~good.reshape(rows, cols)
    edges = (bad[0, :], bad[-1, :], bad[:, 0], bad[:, -1])
    if bad.mean() > 0.1 or any(edge.mean() >= 0.5 for edge in edges):
        return False
    parity = np.where((np.add.outer(np.arange(rows), np.arange(cols)) % 2).ravel() == 0, 1.0, -1.0)
    signs = (np.sign(contrast) * parity)[good]
    return bool(np.all(signs == signs[0]))


def _find_corners(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel inner corners (N, 2) float32 in full-resolution pixels, or None if the board is not found."""
    h, w = gray.shape
    scale = min(1.0, DETECT_MAX_SIDE / max(h, w))
    small = gray
    if scale < 1.0:
        small = cv2.resize(gray, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
    found, corners = cv2.findChessboardCorners(small, pattern, flags=_FIND_FLAGS)
    if not found:
        found, corners = cv2.findChessboardCornersSB(small, pattern)
    if not found or corners is None:
        return None
    corners = np.asarray(corners, dtype=np.float32).reshape(-1, 2)  # OpenCV 5: (N, 2); OpenCV 4: (N, 1, 2)
    if corners.shape[0] != pattern[0] * pattern[1]:
        return None
    if scale < 1.0:  # pixel centres: x_small = (x + 0.5) * s - 0.5
        sx, sy = small.shape[1] / w, small.shape[0] / h
        corners = np.column_stack([(corners[:, 0] + 0.5) / sx - 0.5, (corners[:, 1] + 0.5) / sy - 0.5])
        corners = corners.astype(np.float32)
    half = _subpix_half_window(corners, pattern)
    refined = cv2.cornerSubPix(
        gray, corners.reshape(-1, 1, 2).copy(), (half, half), (-1, -1), _SUBPIX_CRITERIA
    )
    refined = np.asarray(refined, dtype=np.float32).reshape(-1, 2)
    if not np.all(np.isfinite(refined)) or not _is_checkerboard(gray, refined, pattern):
        return None
    return refined


def _board_points(pattern: tuple[int, int], square_size: float) -> np.ndarray:
    """(N, 3) float32 board coordinates in the order OpenCV returns the corners (row by row)."""
    cols, rows = pattern
    xy = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(np.float64) * square_size
    return np.column_stack([xy, np.zeros(len(xy))]).astype(np.float32)


def _check_pattern(pattern: tuple[int, int]) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in pattern)
        ok = len(tuple(pattern)) == 2 and all(float(v) == int(v) for v in pattern)
    except (TypeError, ValueError):
        ok = False
    if not ok or cols < 3 or rows < 3:
        raise InputError(
            f"chessboard pattern {pattern!r} is invalid; give the INNER corners as (columns, rows), "
            f"both >= 3, e.g. 9x6 for a board of 10 x 7 squares"
        )
    return cols, rows


def calibrate_chessboard(
    images: Sequence[str | os.PathLike[str]],
    pattern: tuple[int, int] = (9, 6),
    square_size: float = 0.025,
    *,
    fix_aspect_ratio: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ChessboardCalibration:
    """Calibrate pinhole intrinsics + 5-term distortion from chessboard photos.

    Args:
        images: image files (all the same size).
        pattern: inner corners (columns, rows); 9x6 for a board of 10 x 7 squares.
        square_size: side of a square (any unit; it scales only the board poses, not the intrinsics).
        fix_aspect_ratio: force fx == fy (CALIB_FIX_ASPECT_RATIO with ratio 1), for square pixels.
        progress: called as ``progress(i, n)`` after each image is searched, i = 1..n.

    Raises:
        InputError: no images, a missing/unreadable image, images of different sizes, a bad pattern or square
            size, or the board found in fewer than 3 images.
        CalibrationError: OpenCV's calibration failed or gave a non-physical camera.
    """
    paths = [Path(p) for p in images]
    if not paths:
        raise InputError(
            "no chessboard images given; give at least 3 (10-20 recommended) photos of the board"
        )
    pattern = _check_pattern(pattern)
    try:
        square = float(square_size)
    except (TypeError, ValueError):
        square = math.nan
    if not (math.isfinite(square) and square > 0):
        raise InputError(
            f"chessboard square size {square_size!r} is invalid; give the side of one square as a "
            f"positive number (e.g. 0.025 for 25 mm in metres)"
        )

    n = len(paths)
    image_size: tuple[int, int] | None = None
    first: Path | None = None
    used: list[str] = []
    skipped: list[str] = []
    image_points: list[np.ndarray] = []
    for i, path in enumerate(paths, start=1):
        gray = _read_gray(path)
        size = (int(gray.shape[1]), int(gray.shape[0]))
        if image_size is None:
            image_size, first = size, path
        elif size != image_size:
            rotated = " (rotated: portrait vs landscape?)" if size == image_size[::-1] else ""
            raise InputError(
                f"{path}: image is {size[0]}x{size[1]} but {first} is {image_size[0]}x{image_size[1]}"
                f"{rotated}; all chessboard images must come from the same camera mode and "
                f"resolution, remove or re-take the odd ones"
            )
        corners = _find_corners(gray, pattern)
        if corners is None:
            skipped.append(str(path))
        else:
            used.append(str(path))
            image_points.append(corners)
        if progress is not None:
            progress(i, n)

    cols, rows = pattern
    if len(used) < MIN_VIEWS:
        raise InputError(
            f"the {cols}x{rows} chessboard was found in {len(used)} of {n} images, at least "
            f"{MIN_VIEWS} are needed; the whole board must be visible and sharp, and the pattern must "
            f"count INNER corners (a board of {cols + 1} x {rows + 1} squares has {cols}x{rows}): "
            f"check `pattern`",
            parameters=("pattern",),
        )
    assert image_size is not None

    obj = _board_points(pattern, square)
    object_points = [obj] * len(image_points)
    flags = cv2.CALIB_FIX_ASPECT_RATIO if fix_aspect_ratio else 0
    # With CALIB_FIX_ASPECT_RATIO, OpenCV keeps fx/fy of the initial matrix: the identity gives fx == fy.
    K0 = np.eye(3)
    d0 = np.zeros(5)
    try:
        rms, K, dist, _rvecs, _tvecs, _std_in, _std_ex, per_view = cv2.calibrateCameraExtended(
            object_points, image_points, image_size, K0, d0, flags=flags
        )
    except cv2.error as exc:
        raise CalibrationError(
            f"OpenCV calibrateCamera failed on {len(used)} views "
            f"({' '.join(str(exc).split())[:200]}); add views at more varied tilts"
        ) from None
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).reshape(-1)
    per_view = np.asarray(per_view, dtype=np.float64).reshape(-1)
    if dist.size != 5:
        raise CalibrationError(f"OpenCV returned {dist.size} distortion coefficients, expected 5")
    if not (
        math.isfinite(rms)
        and np.all(np.isfinite(K))
        and np.all(np.isfinite(dist))
        and K[0, 0] > 0
        and K[1, 1] > 0
    ):
        raise CalibrationError(
            f"chessboard calibration gave a non-physical camera (fx={K[0, 0]:g}, "
            f"fy={K[1, 1]:g}, rms={rms:g} px) from {len(used)} views; add views with the board "
            f"tilted in different directions"
        )
    intrinsics = Intrinsics(K=K, dist=dist, image_size=image_size, rms_px=float(rms))
    return ChessboardCalibration(
        intrinsics=intrinsics,
        used_images=tuple(used),
        skipped_images=tuple(skipped),
        per_view_rms_px=per_view,
        rms_px=float(rms),
    )
