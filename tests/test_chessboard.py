"""Chessboard intrinsics calibration on OpenCV's 13 real left*.jpg sample images (640x480, 9x6 corners)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from trafficgeo.calibration.chessboard import (
    ChessboardCalibration,
    _find_corners,
    _is_checkerboard,
    calibrate_chessboard,
)
from trafficgeo.camera.opencv_yaml import Intrinsics, read_intrinsics_yaml, write_intrinsics_yaml
from trafficgeo.errors import InputError

DATA = Path(__file__).parent / "data" / "opencv-chessboard"
IMAGES = sorted(DATA.glob("left*.jpg"))


@pytest.fixture(scope="module")
def reference() -> Intrinsics:
    return read_intrinsics_yaml(DATA / "left_intrinsics.yml")


@pytest.fixture(scope="module")
def calib() -> tuple[ChessboardCalibration, list[tuple[int, int]]]:
    calls: list[tuple[int, int]] = []
    result = calibrate_chessboard(IMAGES, (9, 6), 0.025, progress=lambda i, n: calls.append((i, n)))
    return result, calls


@pytest.fixture(scope="module")
def calib_square() -> ChessboardCalibration:
    return calibrate_chessboard(IMAGES, fix_aspect_ratio=True)


def test_sample_images_present() -> None:
    assert len(IMAGES) == 13


def test_calibration_matches_known_intrinsics(
    calib: tuple[ChessboardCalibration, list], reference: Intrinsics
) -> None:
    result, _ = calib
    intr = result.intrinsics
    fx, fy, cx, cy = intr.K[0, 0], intr.K[1, 1], intr.K[0, 2], intr.K[1, 2]
    assert fx == pytest.approx(536, rel=0.01)
    assert fy == pytest.approx(536, rel=0.01)
    assert cx == pytest.approx(342, abs=5)
    assert cy == pytest.approx(236, abs=5)
    assert result.rms_px < 0.6
    # OpenCV's own calibration of the same images (left_intrinsics.yml)
    assert fx == pytest.approx(reference.fx, rel=0.01)
    assert fy == pytest.approx(reference.fy, rel=0.01)
    assert cx == pytest.approx(reference.cx, rel=0.01)
    assert cy == pytest.approx(reference.cy, rel=0.01)
    assert intr.K[0, 1] == 0.0
    np.testing.assert_array_equal(intr.K[2], [0, 0, 1])
    # the dominant radial term agrees; k2/k3 trade off against each other and are not compared
    assert intr.dist[0] == pytest.approx(reference.dist[0], abs=0.03)
    assert intr.dist.shape == (5,) and intr.dist.dtype == np.float64


def test_calibration_bookkeeping(calib: tuple[ChessboardCalibration, list]) -> None:
    result, calls = calib
    assert result.used_images == tuple(str(p) for p in IMAGES)
    assert result.skipped_images == ()
    assert result.per_view_rms_px.shape == (13,)
    assert np.all(result.per_view_rms_px > 0) and np.all(result.per_view_rms_px < 1.0)
    # the overall RMS is the corner-weighted mean of the per-view RMS (54 corners per view)
    assert result.rms_px == pytest.approx(float(np.sqrt(np.mean(result.per_view_rms_px**2))), rel=1e-6)
    assert result.intrinsics.image_size == (640, 480)
    assert result.intrinsics.rms_px == result.rms_px
    assert calls == [(i, 13) for i in range(1, 14)]


def test_fix_aspect_ratio(calib_square: ChessboardCalibration, reference: Intrinsics) -> None:
    intr = calib_square.intrinsics
    assert intr.K[0, 0] == intr.K[1, 1]
    assert intr.K[0, 0] == pytest.approx(536, rel=0.01)
    assert intr.K[0, 0] == pytest.approx(reference.fx, rel=0.01)
    assert intr.K[0, 2] == pytest.approx(342, abs=5)
    assert intr.K[1, 2] == pytest.approx(236, abs=5)
    assert calib_square.rms_px < 0.6


def test_result_writes_to_yaml(calib: tuple[ChessboardCalibration, list], tmp_path: Path) -> None:
    intr = calib[0].intrinsics
    write_intrinsics_yaml(tmp_path / "phone.yml", intr)
    back = read_intrinsics_yaml(tmp_path / "phone.yml")
    np.testing.assert_array_equal(back.K, intr.K)
    np.testing.assert_array_equal(back.dist, intr.dist)
    assert back.image_size == (640, 480) and back.rms_px == intr.rms_px


def test_skipped_image_is_reported(tmp_path: Path) -> None:
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    result = calibrate_chessboard([*IMAGES[:4], blank])
    assert result.skipped_images == (str(blank),)
    assert len(result.used_images) == 4 and result.per_view_rms_px.shape == (4,)


def test_large_images_are_searched_reduced_and_refined_at_full_size(tmp_path: Path) -> None:
    gray = cv2.imread(str(IMAGES[0]), cv2.IMREAD_GRAYSCALE)
    big = cv2.resize(gray, None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)  # 1920x1440 > DETECT_MAX_SIDE
    small_corners = _find_corners(gray, (9, 6))
    big_corners = _find_corners(big, (9, 6))
    assert small_corners is not None and big_corners is not None
    expected = (small_corners + 0.5) * 3 - 0.5  # pixel (0, 0) is the centre of the top-left pixel
    err = np.linalg.norm(big_corners - expected, axis=1)
    assert np.median(err) < 0.3 and err.max() < 1.0


@pytest.mark.slow
def test_detection_on_the_board_edge_is_rejected() -> None:
    # findChessboardCornersSB "finds" a 7x7 grid on the 9x6 board of left03 whose last row is the board's
    # outer edge (L-shaped corners); the X-junction check must reject it.
    gray = cv2.imread(str(DATA / "left03.jpg"), cv2.IMREAD_GRAYSCALE)
    found, corners = cv2.findChessboardCornersSB(gray, (7, 7))
    if not found:
        pytest.skip("this OpenCV's findChessboardCornersSB no longer returns the 7x7 edge detection")
    assert not _is_checkerboard(gray, np.asarray(corners, np.float32).reshape(-1, 2), (7, 7))
    assert _find_corners(gray, (7, 7)) is None


def test_checkerboard_check_tolerates_one_washed_out_square() -> None:
    gray = cv2.imread(str(IMAGES[0]), cv2.IMREAD_GRAYSCALE)
    corners = _find_corners(gray, (9, 6))
    assert corners is not None and _is_checkerboard(gray, corners, (9, 6))
    grid = corners.reshape(6, 9, 2)
    r, c = 2, 4
    square = np.array([grid[r, c], grid[r, c + 1], grid[r + 1, c + 1], grid[r + 1, c]])
    centre = square.mean(axis=0)
    glare = gray.copy()
    # fill the square's inside with white (glare); its 4 corners stop being X-junctions
    cv2.fillConvexPoly(glare, np.round(centre + 0.8 * (square - centre)).astype(np.int32), 255)
    if float(gray[int(centre[1]), int(centre[0])]) > 128:  # the square was white: make it black instead
        cv2.fillConvexPoly(glare, np.round(centre + 0.8 * (square - centre)).astype(np.int32), 0)
    assert _is_checkerboard(glare, corners, (9, 6))
    shifted = corners.reshape(6, 9, 2)[:, :, :] + (grid[0, 1] - grid[0, 0]) / 2  # half a square off
    assert not _is_checkerboard(gray, shifted.reshape(-1, 2).astype(np.float32), (9, 6))


# ---------------------------------------------------------------------------------------------- errors
@pytest.mark.slow
@pytest.mark.parametrize("pattern", [(7, 7), (10, 7)])
def test_wrong_pattern(pattern: tuple[int, int]) -> None:
    with pytest.raises(InputError) as info:
        calibrate_chessboard(IMAGES[:3], pattern)
    msg = str(info.value)
    assert "\n" not in msg
    assert f"{pattern[0]}x{pattern[1]}" in msg and "found in 0 of 3" in msg
    assert "INNER" in msg and "visible" in msg


def test_missing_image(tmp_path: Path) -> None:
    missing = tmp_path / "nope.jpg"
    with pytest.raises(InputError, match="not found") as info:
        calibrate_chessboard([*IMAGES[:3], missing])
    assert str(missing) in str(info.value)


def test_non_image_file(tmp_path: Path) -> None:
    fake = tmp_path / "notes.jpg"
    fake.write_text("this is not a JPEG\n")
    with pytest.raises(InputError, match="not a readable image") as info:
        calibrate_chessboard([fake, *IMAGES[:3]])
    assert str(fake) in str(info.value)


def test_empty_file(tmp_path: Path) -> None:
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match=r"empty\.png"):
        calibrate_chessboard([empty])


def test_images_of_different_sizes(tmp_path: Path) -> None:
    gray = cv2.imread(str(IMAGES[3]), cv2.IMREAD_GRAYSCALE)
    resized = tmp_path / "left04_small.png"
    cv2.imwrite(str(resized), cv2.resize(gray, (320, 240), interpolation=cv2.INTER_AREA))
    with pytest.raises(InputError) as info:
        calibrate_chessboard([*IMAGES[:3], resized])
    msg = str(info.value)
    assert str(resized) in msg and "320x240" in msg and "640x480" in msg


def test_no_images() -> None:
    with pytest.raises(InputError):
        calibrate_chessboard([])


@pytest.mark.parametrize("pattern", [(2, 6), (9,), (9, 6, 1), ("a", 6), (9.5, 6)])
def test_bad_pattern_argument(pattern: tuple) -> None:
    with pytest.raises(InputError, match="INNER"):
        calibrate_chessboard(IMAGES[:3], pattern)


@pytest.mark.parametrize("square", [0.0, -1.0, float("nan"), float("inf"), "big"])
def test_bad_square_size(square: object) -> None:
    with pytest.raises(InputError, match="square size"):
        calibrate_chessboard(IMAGES[:3], (9, 6), square)  # type: ignore[arg-type]
