"""The one "read a raster decimated for display" path (``geo.raster_display.read_display``) and the one pixel <-> map
conversion (``geo.raster.pixel_to_map`` / ``map_to_pixel``), on rasters with known geotransforms and values."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pyproj
import pytest
from affine import Affine

from trafficgeo.errors import InputError
from trafficgeo.geo.raster import map_to_pixel, pixel_size, pixel_to_map, write_geotiff
from trafficgeo.geo.raster_display import read_display

CRS = "EPSG:32633"
X0, Y0 = 500_000.0, 5_000_000.0
XRES, YRES = 0.5, 0.25  # non-square pixels (m)


@pytest.fixture(scope="module")
def grid(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """300 x 90 px, 0.5 m wide and 0.25 m tall; band 1 holds the column index, band 2 the row index, band 3 0."""
    path = tmp_path_factory.mktemp("display") / "grid.tif"
    rows, cols = np.mgrid[0:90, 0:300].astype(np.float32)
    write_geotiff(path, np.stack([cols, rows, 0 * rows]), Affine(XRES, 0.0, X0, 0.0, -YRES, Y0), CRS)
    return path


def test_pixel_map_round_trip_on_a_rotated_non_square_grid() -> None:
    t = Affine.translation(X0, Y0) @ Affine.rotation(30.0) @ Affine.scale(0.5, -0.25)
    col, row = np.array([0.5, 10.5, 299.5]), np.array([0.5, 3.5, 89.5])
    x, y = pixel_to_map(t, col, row)
    c30, s30 = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    np.testing.assert_allclose(x, X0 + c30 * 0.5 * col + s30 * 0.25 * row, rtol=0, atol=1e-9)
    np.testing.assert_allclose(y, Y0 + s30 * 0.5 * col - c30 * 0.25 * row, rtol=0, atol=1e-9)
    back_c, back_r = map_to_pixel(t, x, y)
    np.testing.assert_allclose(back_c, col, atol=1e-9)
    np.testing.assert_allclose(back_r, row, atol=1e-9)
    assert pixel_size(t) == pytest.approx((0.5, 0.25), abs=1e-12)


def test_small_raster_is_read_whole_at_full_resolution(grid: Path) -> None:
    d = read_display(grid, 300)
    assert d is not None and d.factor == 1 and d.data.shape == (3, 90, 300) and d.valid.all()
    assert d.transform == d.grid_transform == Affine(XRES, 0.0, X0, 0.0, -YRES, Y0)
    assert d.window == (0, 0, 300, 90) and d.bounds == (X0, Y0 - 90 * YRES, X0 + 300 * XRES, Y0)
    np.testing.assert_array_equal(d.data[0, 7], np.arange(300))
    assert d.crs is not None and d.crs.to_epsg() == 32633


def test_decimated_by_an_integer_factor_with_block_means_and_centres_in_place(grid: Path) -> None:
    d = read_display(grid, 100)  # 300 px > 100: factor 3, 100 x 30 display pixels
    assert d is not None and d.factor == 3 and d.data.shape == (3, 30, 100)
    i, j = np.mgrid[0:30, 0:100]
    # each display pixel is the mean of a 3 x 3 block: columns 3j..3j+2, rows 3i..3i+2
    np.testing.assert_allclose(d.data[0], 3 * j + 1, atol=1e-4)
    np.testing.assert_allclose(d.data[1], 3 * i + 1, atol=1e-4)
    # the centre of display pixel (i, j) is the centre of its block on the map
    x, y = pixel_to_map(d.transform, j + 0.5, i + 0.5)
    np.testing.assert_allclose(x, X0 + XRES * (3 * j + 1.5), rtol=0, atol=1e-6)
    np.testing.assert_allclose(y, Y0 - YRES * (3 * i + 1.5), rtol=0, atol=1e-6)
    assert d.grid_transform == Affine(XRES, 0.0, X0, 0.0, -YRES, Y0)  # full-resolution coordinates stay
    assert read_display(grid, 150).factor == 2 and read_display(grid, 99).factor == 4


def test_a_part_within_bounds(grid: Path) -> None:
    """Columns 40..139 and rows 20..59: (100 x 40 px), read with factor 2."""
    bounds = (X0 + 40 * XRES, Y0 - 60 * YRES, X0 + 140 * XRES, Y0 - 20 * YRES)
    d = read_display(grid, 50, bounds=bounds, crs=pyproj.CRS(CRS), north_up=True)
    assert d is not None and d.window == (40, 20, 100, 40) and d.factor == 2 and d.data.shape == (3, 20, 50)
    assert d.bounds == pytest.approx(bounds, abs=1e-9)
    i, j = np.mgrid[0:20, 0:50]
    np.testing.assert_allclose(d.data[0], 40 + 2 * j + 0.5, atol=1e-4)
    np.testing.assert_allclose(d.data[1], 20 + 2 * i + 0.5, atol=1e-4)
    x, y = pixel_to_map(d.transform, j + 0.5, i + 0.5)
    np.testing.assert_allclose(x, X0 + XRES * (40 + 2 * j + 1.0), atol=1e-6)
    np.testing.assert_allclose(y, Y0 - YRES * (20 + 2 * i + 1.0), atol=1e-6)
    assert read_display(grid, 50, bounds=(X0 - 100, Y0 + 10, X0 - 50, Y0 + 20)) is None  # no overlap


def test_world_file_and_bad_files(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "img.png"), np.full((10, 20, 3), 128, np.uint8))
    (tmp_path / "img.pgw").write_text("0.5\n0\n0\n-0.25\n1000.25\n2000.125\n")  # C, F: centre of pixel (0, 0)
    d = read_display(tmp_path / "img.png", 100)
    assert d is not None and d.transform == Affine(0.5, 0.0, 1000.0, 0.0, -0.25, 2000.25)
    (tmp_path / "bad.tif").write_text("not a raster")
    with pytest.raises(InputError, match=r"--ortho .*bad\.tif is not a raster GDAL can read"):
        read_display(tmp_path / "bad.tif", 100, what="--ortho")
    cv2.imwrite(str(tmp_path / "plain.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(InputError, match="no georeferencing"):
        read_display(tmp_path / "plain.png", 100)
