"""Tests of trafficgeo.geo.raster: GeoRaster geometry, reading (GeoTIFF, world files, DEMs) and writing GeoTIFFs.

Real data: tests/data/autzen (see SOURCE.txt): a crop of the Autzen orthophoto (EPSG:2994, 1 ft/px) and the
co-registered Autzen lidar (per-point RGB), so the georeferencing of both readers can be checked against each other.
"""

from __future__ import annotations

import math
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from hypothesis import given, settings
from hypothesis import strategies as st
from rasterio.errors import NotGeoreferencedWarning

from trafficgeo.errors import InputError
from trafficgeo.geo import raster as raster_mod
from trafficgeo.geo.pointcloud import PointCloud, read_point_cloud
from trafficgeo.geo.raster import GeoRaster, read_dem, read_raster, write_geotiff
from trafficgeo.geo.raster_display import display_rgb

DATA = Path(__file__).parent / "data" / "autzen"
ORTHO = DATA / "autzen_ortho_trim.tif"
JPG = DATA / "autzen_crop.jpg"
LAZ = DATA / "autzen_trim.laz"
# autzen_ortho_trim.tif = window (col 385, row 3864) of autzen.wld's grid: corner = wld centre - half a pixel.
ORTHO_TRANSFORM = Affine(1.0, 0.0, 635615.9278659122 - 0.5 + 385, 0.0, -1.0, 853362.1430851521 + 0.5 - 3864)
JPG_OFFSET = (415, 256)  # (col, row) of autzen_crop.jpg inside autzen_ortho_trim.tif


@pytest.fixture(scope="module")
def ortho() -> GeoRaster:
    return read_raster(ORTHO)


@pytest.fixture(scope="module")
def cloud() -> PointCloud:
    return read_point_cloud(LAZ, crs="EPSG:2994")


def _ramp(origin: tuple[float, float] = (5.0e5, 5.0e6), res: float = 0.5, rows: int = 40, cols: int = 60) -> GeoRaster:
    """Float raster whose value at every pixel centre is the linear function 3 dx - 2 dy + 7 of the local map xy."""
    transform = Affine(res, 0.0, origin[0], 0.0, -res, origin[1])
    r, c = np.mgrid[0:rows, 0:cols]
    dx, dy = (c + 0.5) * res, -(r + 0.5) * res
    return GeoRaster((3.0 * dx - 2.0 * dy + 7.0)[None], transform, "EPSG:32617")


def _ramp_value(ras: GeoRaster, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 3.0 * (x - ras.transform.c) - 2.0 * (y - ras.transform.f) + 7.0


def _pearson(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a, b)[0, 1])


# ---------------------------------------------------------------------- reading
def test_read_geotiff_georeferencing(ortho: GeoRaster) -> None:
    assert ortho.data.shape == (3, 521, 1180) and ortho.data.dtype == np.uint8
    assert (ortho.count, ortho.rows, ortho.cols, ortho.shape) == (3, 521, 1180, (521, 1180))
    assert ortho.crs.to_epsg() == 2994
    assert ortho.transform.almost_equals(ORTHO_TRANSFORM, precision=1e-6)
    assert ortho.resolution == (1.0, 1.0)
    assert ortho.is_north_up
    np.testing.assert_allclose(
        ortho.bounds, (636000.4278659122, 848977.6430851521, 637180.4278659122, 849498.6430851521), atol=1e-6
    )
    assert ortho.path == str(ORTHO)
    assert not ortho.data.flags.writeable


def _lidar_vs_ortho(ortho: GeoRaster, cloud: PointCloud, shift_px: int) -> float:
    """Pearson r between lidar grey (mean RGB) and the ortho pixel grey at the same XY (+ a column shift)."""
    col, row = ortho.map_to_pixel(cloud.xyz[:, 0], cloud.xyz[:, 1])
    ci = np.floor(col).astype(int) + shift_px
    ri = np.floor(row).astype(int)
    ok = (ci >= 0) & (ci < ortho.cols) & (ri >= 0) & (ri < ortho.rows)
    grey_ortho = ortho.data[:, ri[ok], ci[ok]].astype(float).mean(axis=0)
    grey_lidar = cloud.rgb[ok].astype(float).mean(axis=1)
    assert ok.sum() > 90_000  # the cloud is almost all over the crop
    return _pearson(grey_ortho, grey_lidar)


def test_lidar_rgb_agrees_with_orthophoto(ortho: GeoRaster, cloud: PointCloud) -> None:
    r0 = _lidar_vs_ortho(ortho, cloud, 0)
    r40 = _lidar_vs_ortho(ortho, cloud, 40)
    assert r0 > 0.9  # measured 0.997
    assert r40 < 0.7  # measured ~0.5: a 40 ft misregistration would show
    assert _lidar_vs_ortho(ortho, cloud, 3) < r0  # and the peak is at zero shift


def test_lidar_rgb_agrees_with_bilinear_samples(ortho: GeoRaster, cloud: PointCloud) -> None:
    sel = slice(0, None, 10)
    x, y = cloud.xyz[sel, 0], cloud.xyz[sel, 1]
    grey = np.mean([ortho.sample_bilinear(x, y, band=b) for b in range(3)], axis=0)
    ok = np.isfinite(grey)
    assert 0.9 < ok.mean() < 0.97  # the southern 42 ft of the cloud lie outside the ortho
    assert _pearson(grey[ok], cloud.rgb[sel][ok].astype(float).mean(axis=1)) > 0.9


def test_world_file_equals_geotiff_georeferencing(ortho: GeoRaster) -> None:
    jpg = read_raster(JPG)
    assert jpg.crs is None  # a world file has no CRS
    assert jpg.data.shape == (3, 240, 320)
    expected = ortho.transform @ Affine.translation(*JPG_OFFSET)
    np.testing.assert_allclose(jpg.transform[:6], expected[:6], atol=1e-6, rtol=0)
    # same content at the same place (both are JPEG-recompressed copies of autzen.jpg)
    c0, r0 = JPG_OFFSET
    same = ortho.data[:, r0 : r0 + 240, c0 : c0 + 320].astype(float)
    assert np.mean(np.abs(jpg.data.astype(float) - same)) < 4.0
    assert read_raster(JPG, crs="EPSG:2994").crs.to_epsg() == 2994


def test_world_file_parsed_when_gdal_does_not(tmp_path: Path) -> None:
    # GDAL's PNM driver ignores world files, so this exercises trafficgeo's own parser (centre -> corner shift).
    img = tmp_path / "grid.pgm"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(img, "w", driver="PNM", width=4, height=3, count=1, dtype="uint8") as dst:
            dst.write(np.arange(12, dtype=np.uint8).reshape(1, 3, 4))
    with pytest.raises(InputError, match="no georeferencing; add a world file") as exc:
        read_raster(img)
    assert str(img) in str(exc.value)
    (tmp_path / "grid.wld").write_text("2\n0\n0\n-2\n636100.5\n849300.5\n")
    ras = read_raster(img, crs="EPSG:2994")
    assert ras.transform.almost_equals(Affine(2, 0, 636099.5, 0, -2, 849301.5), precision=1e-9)
    np.testing.assert_array_equal(ras.data[0], np.arange(12).reshape(3, 4))
    # pixel centre of [row 0, col 0] is the world file's (C, F)
    x, y = ras.pixel_to_map(0.5, 0.5)
    assert (float(x), float(y)) == (636100.5, 849300.5)


def test_world_file_parser_matches_gdal() -> None:
    with rasterio.open(JPG) as ds:
        gdal_transform = ds.transform
    ours = raster_mod.read_world_file(JPG.with_suffix(".wld"))
    np.testing.assert_allclose(ours[:6], gdal_transform[:6], atol=1e-9, rtol=0)


def test_bad_world_file_names_it(tmp_path: Path) -> None:
    img = tmp_path / "crop.jpg"
    shutil.copy(JPG, img)
    wld = tmp_path / "crop.wld"
    wld.write_text("1\n0\n0\n-1\n636415.9\n")  # five numbers: GDAL ignores it, trafficgeo reports it
    with pytest.raises(InputError, match="has 5 values") as exc:
        read_raster(img)
    assert str(wld) in str(exc.value)


def test_read_raster_errors(tmp_path: Path) -> None:
    missing = tmp_path / "nope.tif"
    with pytest.raises(InputError, match="does not exist") as exc:
        read_raster(missing)
    assert str(missing) in str(exc.value)
    text = tmp_path / "notes.tif"
    text.write_text("this is not a raster\n")
    with pytest.raises(InputError, match="not a raster GDAL can read") as exc:
        read_raster(text)
    assert str(text) in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(InputError, match="folder"):
        read_raster(tmp_path)


# ---------------------------------------------------------------------- pixel <-> map
finite = {"allow_nan": False, "allow_infinity": False}


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(
    res=st.floats(0.01, 20.0, **finite),
    aspect=st.floats(0.5, 2.0, **finite),
    angle=st.floats(-math.pi, math.pi, **finite),
    shear=st.floats(-0.3, 0.3, **finite),
    x0=st.floats(-5e6, 5e6, **finite),
    y0=st.floats(-5e6, 5e6, **finite),
    col=st.floats(-2e4, 2e4, **finite),
    row=st.floats(-2e4, 2e4, **finite),
)
def test_pixel_map_round_trip(res, aspect, angle, shear, x0, y0, col, row) -> None:
    shear_deg = math.degrees(math.atan(shear))
    transform = (
        Affine.translation(x0, y0)
        @ Affine.rotation(math.degrees(angle))
        @ Affine.shear(shear_deg, 0)
        @ Affine.scale(res, -res * aspect)
    )
    ras = GeoRaster(np.zeros((1, 2, 2)), transform, None)
    x, y = ras.pixel_to_map(col, row)
    # against affine's own (less careful) arithmetic
    ax, ay = transform @ (col, row)
    assert abs(x - ax) < 1e-6 and abs(y - ay) < 1e-6
    c2, r2 = ras.map_to_pixel(x, y)
    assert abs(c2 - col) < 1e-6 and abs(r2 - row) < 1e-6
    x2, y2 = ras.pixel_to_map(c2, r2)
    assert abs(x2 - x) < 1e-6 * max(res, 1.0) and abs(y2 - y) < 1e-6 * max(res, 1.0)


def test_map_to_pixel_vectorized_and_pixel_centres() -> None:
    ras = _ramp()
    cols, rows = np.meshgrid(np.arange(3) + 0.5, np.arange(2) + 0.5)
    x, y = ras.pixel_to_map(cols, rows)
    assert x.shape == (2, 3) and x.dtype == np.float64
    assert x[0, 0] == 5.0e5 + 0.25 and y[0, 0] == 5.0e6 - 0.25
    c, r = ras.map_to_pixel(x, y)
    np.testing.assert_allclose(c, cols, atol=1e-9)
    np.testing.assert_allclose(r, rows, atol=1e-9)


# ---------------------------------------------------------------------- crop
def test_crop_keeps_georeferencing(ortho: GeoRaster) -> None:
    bounds = (636200.2, 849100.7, 636500.9, 849400.1)
    sub = ortho.crop(bounds)
    # pixels intersecting the bounds: cols 199.77..500.47 -> 199..501, rows 98.54..397.94 -> 98..398
    assert sub.shape == (300, 302)
    assert sub.transform.almost_equals(ortho.transform @ Affine.translation(199, 98), precision=1e-9)
    left, bottom, right, top = sub.bounds
    assert left <= bounds[0] < left + 1 and right - 1 < bounds[2] <= right
    assert bottom <= bounds[1] < bottom + 1 and top - 1 < bounds[3] <= top
    rng = np.random.default_rng(1)
    x = rng.uniform(bounds[0], bounds[2], 500)
    y = rng.uniform(bounds[1], bounds[3], 500)
    for band in range(3):
        np.testing.assert_array_equal(sub.sample_bilinear(x, y, band), ortho.sample_bilinear(x, y, band))
    assert sub.crs == ortho.crs and sub.path == ortho.path


def test_crop_partial_overlap_is_clipped(ortho: GeoRaster) -> None:
    left, _, _, top = ortho.bounds
    sub = ortho.crop((left - 100, top - 10, left + 20, top + 100))
    assert sub.shape == (10, 20)
    assert sub.transform.almost_equals(ortho.transform, precision=1e-9)


def test_crop_errors(ortho: GeoRaster) -> None:
    with pytest.raises(InputError, match="do not overlap") as exc:
        ortho.crop((0.0, 0.0, 10.0, 10.0))
    assert str(ORTHO) in str(exc.value)
    with pytest.raises(InputError, match="left < right"):
        ortho.crop((636300.0, 849100.0, 636200.0, 849400.0))


# ---------------------------------------------------------------------- bilinear sampling
def test_sample_bilinear_reproduces_a_plane_at_large_coordinates() -> None:
    ras = _ramp()
    left, bottom, right, top = ras.bounds
    rng = np.random.default_rng(3)
    x = rng.uniform(left + 0.25, right - 0.25, 1000)  # inside the hull of the pixel centres
    y = rng.uniform(bottom + 0.25, top - 0.25, 1000)
    np.testing.assert_allclose(ras.sample_bilinear(x, y), _ramp_value(ras, x, y), atol=1e-8)
    out = ras.sample_bilinear([left - 0.01, right + 0.01, left + 1, np.nan], [top - 1, top - 1, top + 0.01, top - 1])
    assert np.all(np.isnan(out))
    # outer half-pixel ring: clamped to the edge pixel
    edge = ras.sample_bilinear(left + 0.1, top - 0.25)
    assert edge == pytest.approx(_ramp_value(ras, np.array(left + 0.25), np.array(top - 0.25)), abs=1e-9)
    with pytest.raises(InputError, match="band 1 does not exist"):
        ras.sample_bilinear(left + 1, top - 1, band=1)


def test_sample_bilinear_nan_next_to_nodata() -> None:
    data = np.ones((1, 4, 4))
    data[0, 1, 1] = -9999.0
    ras = GeoRaster(data, Affine(1, 0, 0, 0, -1, 4), None, nodata=-9999.0)
    # (1.5, 2.5) is the centre of the nodata cell; (1.2, 2.2) has it as a neighbour; (3.0, 1.0) does not
    vals = ras.sample_bilinear([1.5, 1.2, 3.0], [2.5, 2.2, 1.0])
    assert np.isnan(vals[0]) and np.isnan(vals[1]) and vals[2] == 1.0


# ---------------------------------------------------------------------- DEMs
def _dem_file(path: Path, data: np.ndarray, crs: str = "EPSG:2994", nodata: float | None = -9999.0) -> Path:
    write_geotiff(path, data, Affine(2.0, 0, 636000.0, 0, -2.0, 849500.0), crs, nodata=nodata)
    return path


def test_read_dem_sets_nodata_to_nan(tmp_path: Path) -> None:
    z = np.linspace(400.0, 420.0, 30).reshape(5, 6)
    z[2, 3] = -9999.0
    dem = read_dem(_dem_file(tmp_path / "dem.tif", z))
    assert dem.data.shape == (1, 5, 6) and dem.data.dtype == np.float64
    assert np.isnan(dem.data[0, 2, 3]) and np.isnan(dem.nodata)
    mask = np.ones_like(z, dtype=bool)
    mask[2, 3] = False
    np.testing.assert_allclose(dem.data[0][mask], z[mask], rtol=1e-6)
    assert dem.crs.to_epsg() == 2994 and dem.transform == Affine(2.0, 0, 636000.0, 0, -2.0, 849500.0)


def test_read_dem_takes_band_one(tmp_path: Path) -> None:
    data = np.stack([np.full((3, 3), 410.0), np.full((3, 3), 7.0)])
    dem = read_dem(_dem_file(tmp_path / "two.tif", data))
    assert dem.data.shape == (1, 3, 3) and np.all(dem.data == 410.0)


def test_read_dem_all_nodata(tmp_path: Path) -> None:
    path = _dem_file(tmp_path / "empty.tif", np.full((4, 4), -9999.0))
    with pytest.raises(InputError, match="every cell is nodata") as exc:
        read_dem(path)
    assert str(path) in str(exc.value)


def test_read_dem_geographic(tmp_path: Path) -> None:
    path = tmp_path / "lonlat.tif"
    write_geotiff(path, np.full((4, 4), 120.0), Affine(1e-4, 0, -123.07, 0, -1e-4, 44.06), "EPSG:4326")
    with pytest.raises(InputError, match="reproject to a projected CRS") as exc:
        read_dem(path)
    assert str(path) in str(exc.value)
    assert "gdalwarp -t_srs EPSG:32610" in str(exc.value)  # Eugene, Oregon is in UTM zone 10N


# ---------------------------------------------------------------------- writing
def test_write_geotiff_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    data = rng.normal(400.0, 10.0, (2, 300, 260))
    data[0, 5, 7] = np.nan
    transform = Affine(0.5, 0, 636000.25, 0, -0.5, 849500.75)
    path = tmp_path / "out" / "dem.tif"
    write_geotiff(path, data, transform, "EPSG:2994", nodata=-9999.0, descriptions=("elevation (foot)", None))
    assert sorted(os.listdir(path.parent)) == ["dem.tif"]
    with rasterio.open(path) as ds:
        assert ds.dtypes == ("float32", "float32")
        assert ds.block_shapes == [(256, 256), (256, 256)]
        assert ds.compression.name.lower() == "deflate"
        assert ds.nodata == -9999.0
    back = read_raster(path)
    assert back.transform == transform and back.crs.to_epsg() == 2994 and back.nodata == -9999.0
    assert back.descriptions == ("elevation (foot)", None)
    assert back.data[0, 5, 7] == -9999.0
    ok = np.isfinite(data)
    np.testing.assert_array_equal(back.data[ok], data.astype(np.float32)[ok])


def test_write_geotiff_small_keeps_integer_dtype(tmp_path: Path) -> None:
    data = np.arange(3 * 20 * 30, dtype=np.uint16).reshape(3, 20, 30)
    path = tmp_path / "rgb.tif"
    write_geotiff(path, data, Affine(1, 0, 0, 0, -1, 20), None)
    with rasterio.open(path) as ds:
        assert ds.dtypes == ("uint16",) * 3 and ds.block_shapes[0] != (256, 256) and ds.crs is None
        np.testing.assert_array_equal(ds.read(), data)


def test_write_geotiff_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "dem.tif"
    data = np.ones((2, 64, 64))

    def failing(dst, arr, descriptions) -> None:
        dst.write(arr[0], 1)
        raise OSError("disk full")

    monkeypatch.setattr(raster_mod, "_write_bands", failing)
    with pytest.raises(OSError, match="disk full"):
        write_geotiff(path, data, Affine(1, 0, 0, 0, -1, 64), "EPSG:2994")
    assert os.listdir(tmp_path) == []  # no half-written file, no temporary left behind

    monkeypatch.undo()
    write_geotiff(path, data * 5.0, Affine(1, 0, 0, 0, -1, 64), "EPSG:2994")
    monkeypatch.setattr(raster_mod, "_write_bands", failing)
    with pytest.raises(OSError, match="disk full"):
        write_geotiff(path, data, Affine(1, 0, 0, 0, -1, 64), "EPSG:2994")
    assert os.listdir(tmp_path) == ["dem.tif"]
    assert np.all(read_raster(path).data == 5.0)  # the old file is untouched


def test_an_orthophoto_given_as_dem_is_refused(ortho: GeoRaster) -> None:
    from trafficgeo.errors import InputError
    from trafficgeo.geo.raster import read_dem

    assert ortho.data.shape[0] >= 3 and ortho.data.dtype == np.uint8
    with pytest.raises(InputError, match="8-bit bands: a colour image"):
        read_dem(ortho.path)


def test_display_rgb_8bit_as_is_others_stretched_per_band_invalid_black() -> None:
    """The one colour rule of gcp-ui and the report: 8-bit bands unchanged, other types cut at 2-98 % per band."""
    rgb8 = np.arange(2 * 3 * 4, dtype=np.uint8).reshape(3, 2, 4)
    assert np.array_equal(display_rgb(rgb8), np.moveaxis(rgb8, 0, -1))
    ramp = np.linspace(0.0, 1.0, 101)
    heights = np.stack([ramp * 10.0, ramp * 1000.0, -ramp])[:, None, :]  # float bands of very different ranges
    valid = np.ones((1, 101), dtype=bool)
    valid[0, 50] = False
    heights[:, 0, 50] = np.nan
    out = display_rgb(heights, valid)
    assert out.shape == (1, 101, 3) and out.dtype == np.uint8
    assert (out[0, :3, :2] == 0).all() and (out[0, -3:, :2] == 255).all()  # below 2 % / above 98 %: clipped
    assert (out[0, :3, 2] == 255).all() and (out[0, -3:, 2] == 0).all()  # a falling band falls
    assert (out[0, 50] == 0).all()  # the invalid cell
    # one band is grey; a band of one value except a few cells is stretched over its whole range
    dem = np.full((1, 10, 10), 1000, dtype=np.uint16)
    dem[0, 0, 0] = 0
    grey = display_rgb(dem)
    assert grey.shape == (10, 10, 3) and grey[0, 0].tolist() == [0, 0, 0] and grey[5, 5].tolist() == [255] * 3
    with pytest.raises(ValueError, match="bands, rows, cols"):
        display_rgb(np.zeros((4, 4)))
