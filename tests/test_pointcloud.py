"""Tests of trafficgeo.geo.pointcloud: LAS/LAZ reading, ground selection, ground z lookups and DEMs from clouds.

Real data: tests/data/autzen/autzen_trim.laz (EPSG:2994, international feet, classes 1 and 2; see SOURCE.txt).
Synthetic data: a tilted plane with noise and "trees" (class 5, 3-15 m above it) at UTM-sized coordinates.
"""

from __future__ import annotations

import math
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.pointcloud import (
    GroundIndex,
    PointCloud,
    cloud_to_dem,
    ground_mask,
    read_point_cloud,
)
from trafficgeo.geo.raster import read_dem, write_geotiff

DATA = Path(__file__).parent / "data" / "autzen"
LAZ = DATA / "autzen_trim.laz"
FT = 0.3048

# synthetic scene: ground plane z = Z0 + GX dx + GY dy (+ noise SIGMA), 100 m x 100 m, at UTM-like coordinates
ORIGIN = (512_346.0, 4_987_654.0)
Z0, GX, GY, SIGMA = 150.0, 0.03, -0.02, 0.05
TREES = ((25.0, 30.0), (70.0, 60.0), (40.0, 80.0))  # centres (dx, dy), radius 8 m


def _plane(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return Z0 + GX * (x - ORIGIN[0]) + GY * (y - ORIGIN[1])


def _synthetic(classes: bool = True, hole: bool = False, seed: int = 0, crs: str = "EPSG:32617",
               path: str | None = None) -> PointCloud:
    """Ground plane + noise (class 2) and tree crowns above it (class 5); all class 1 when ``classes`` is False."""
    rng = np.random.default_rng(seed)
    gxy = rng.uniform(0.0, 100.0, (20_000, 2))
    if hole:  # a 10 m radius gap at the centre: inside the ground hull, but no ground points
        gxy = gxy[np.hypot(gxy[:, 0] - 50.0, gxy[:, 1] - 50.0) > 10.0]
    centres = np.array(TREES)[rng.integers(0, len(TREES), 3_000)]
    ang = rng.uniform(0, 2 * np.pi, 3_000)
    rad = 8.0 * np.sqrt(rng.uniform(0, 1, 3_000))
    txy = centres + np.column_stack((rad * np.cos(ang), rad * np.sin(ang)))
    xy = np.vstack((gxy, txy)) + ORIGIN
    z = _plane(xy[:, 0], xy[:, 1])
    z[: len(gxy)] += rng.normal(0.0, SIGMA, len(gxy))
    z[len(gxy) :] += rng.uniform(3.0, 15.0, len(txy))
    cls = np.r_[np.full(len(gxy), 2), np.full(len(txy), 5)] if classes else np.ones(len(xy))
    return PointCloud(np.column_stack((xy, z)), cls, None, crs, path)


def _write_las(path: Path, cloud: PointCloud, crs: pyproj.CRS | None = None) -> Path:
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets = np.floor(cloud.xyz.min(axis=0)) if len(cloud) else np.zeros(3)
    header.scales = np.full(3, 0.001)
    if crs is not None:
        header.add_crs(crs)
    las = laspy.LasData(header)
    if len(cloud):
        las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]
        las.classification = cloud.classification
    las.write(path)
    return path


@pytest.fixture(scope="module")
def autzen() -> PointCloud:
    return read_point_cloud(LAZ, crs="EPSG:2994")


@pytest.fixture(scope="module")
def autzen_index(autzen: PointCloud) -> GroundIndex:
    return GroundIndex.from_cloud(autzen)


# ---------------------------------------------------------------------- reading
def test_read_laz(autzen: PointCloud) -> None:
    assert len(autzen) == 110_000 and autzen.xyz.dtype == np.float64
    np.testing.assert_allclose(autzen.xyz[:, 0].min(), 636001.8, atol=0.06)
    np.testing.assert_allclose(autzen.xyz[:, 0].max(), 637179.2, atol=0.06)
    np.testing.assert_allclose(autzen.xyz[:, 1].min(), 848935.2, atol=0.06)
    np.testing.assert_allclose(autzen.xyz[:, 1].max(), 849497.9, atol=0.06)
    np.testing.assert_allclose([autzen.xyz[:, 2].min(), autzen.xyz[:, 2].max()], [406.3, 520.5], atol=0.06)
    assert autzen.classification.dtype == np.uint8
    assert np.count_nonzero(autzen.classification == 2) == 26_107
    assert autzen.rgb.dtype == np.uint16 and autzen.rgb.shape == (110_000, 3) and autzen.rgb.max() == 236
    assert autzen.crs.to_epsg() == 2994 and autzen.path == str(LAZ)
    assert not autzen.xyz.flags.writeable


def test_read_laz_header_crs_is_in_feet() -> None:
    cloud = read_point_cloud(LAZ)
    assert cloud.crs is not None and metres_per_unit(cloud.crs) == FT
    assert cloud.crs.is_projected


def test_read_las_round_trip(tmp_path: Path) -> None:
    syn = _synthetic()
    back = read_point_cloud(_write_las(tmp_path / "syn.las", syn, pyproj.CRS.from_epsg(32617)))
    assert back.crs.to_epsg() == 32617 and back.rgb is not None  # point format 3 has RGB fields
    np.testing.assert_allclose(back.xyz, syn.xyz, atol=0.0006)  # 1 mm scale
    np.testing.assert_array_equal(back.classification, syn.classification)


def test_read_point_cloud_errors(tmp_path: Path) -> None:
    missing = tmp_path / "missing.laz"
    with pytest.raises(InputError, match="does not exist") as exc:
        read_point_cloud(missing)
    assert str(missing) in str(exc.value)

    text = tmp_path / "notes.las"
    text.write_text("x,y,z\n1,2,3\n")
    with pytest.raises(InputError, match="not a LAS/LAZ file") as exc:
        read_point_cloud(text)
    assert str(text) in str(exc.value) and "\n" not in str(exc.value)

    empty = _write_las(tmp_path / "empty.las", PointCloud(np.zeros((0, 3)), np.zeros(0), None, None))
    with pytest.raises(InputError, match="has no points") as exc:
        read_point_cloud(empty)
    assert str(empty) in str(exc.value)

    with pytest.raises(InputError, match="geographic") as exc:
        read_point_cloud(LAZ, crs="EPSG:4326")
    assert str(LAZ) in str(exc.value)


def test_read_point_cloud_geographic_header(tmp_path: Path) -> None:
    lonlat = PointCloud([[-123.07, 44.05, 120.0], [-123.06, 44.06, 121.0]], [2, 2], None, None)
    path = _write_las(tmp_path / "lonlat.las", lonlat, pyproj.CRS.from_epsg(4326))
    with pytest.raises(InputError, match="reproject it to a projected CRS") as exc:
        read_point_cloud(path)
    assert str(path) in str(exc.value) and "EPSG:32610" in str(exc.value)


# ---------------------------------------------------------------------- ground selection
def test_ground_mask_uses_class_2(autzen: PointCloud) -> None:
    np.testing.assert_array_equal(ground_mask(autzen), autzen.classification == 2)


def test_ground_mask_percentile_filter_rejects_trees() -> None:
    cloud = _synthetic(classes=False)
    truth = np.r_[np.ones(20_000, bool), np.zeros(3_000, bool)]
    mask = ground_mask(cloud)
    # almost no tree point is taken as ground (a cell with 1-2 ground points under a crown can fail)
    assert np.count_nonzero(mask & ~truth) < 0.005 * 3_000
    assert np.count_nonzero(mask & truth) > 0.85 * 20_000  # most ground is kept
    # a stricter tolerance keeps fewer ground points; the percentile filter works in metres
    assert np.count_nonzero(ground_mask(cloud, tolerance_m=0.05)) < np.count_nonzero(mask) * 0.7


def test_ground_mask_converts_metres_to_feet() -> None:
    metres = _synthetic(classes=False)
    feet = PointCloud(metres.xyz / FT, metres.classification, None, "EPSG:2994")  # the same scene in feet
    agree = ground_mask(feet) == ground_mask(metres)
    assert agree.mean() > 0.999  # only float rounding at cell edges may differ


# ---------------------------------------------------------------------- ground index
@pytest.mark.parametrize("classes", [True, False])
def test_ground_index_recovers_plane(classes: bool) -> None:
    cloud = _synthetic(classes=classes)
    index = GroundIndex.from_cloud(cloud)
    rng = np.random.default_rng(5)
    qx = rng.uniform(5.0, 95.0, 400) + ORIGIN[0]
    qy = rng.uniform(5.0, 95.0, 400) + ORIGIN[1]
    res = index.lookup(qx, qy, radius_m=1.5)
    assert res.z.shape == res.spread.shape == res.count.shape == res.inside.shape == (400,)
    assert res.inside.all() and res.count.min() >= 3
    err = res.z - _plane(qx, qy)
    # median of ~14 points: sigma / sqrt(14) * 1.25 ~ 0.017 m
    assert np.median(np.abs(err)) < 0.025 and np.max(np.abs(err)) < 0.1
    # under the trees too: the lookup sees ground, not crowns
    tx = np.array([c[0] for c in TREES]) + ORIGIN[0]
    ty = np.array([c[1] for c in TREES]) + ORIGIN[1]
    np.testing.assert_allclose(index.z_at(tx, ty, radius_m=1.5), _plane(tx, ty), atol=0.1)
    # spread ~ the noise sigma (plus the plane's slope within the radius)
    assert 0.7 * SIGMA < np.median(res.spread) < 1.4 * SIGMA


def test_ground_index_counts_match_brute_force_in_feet() -> None:
    rng = np.random.default_rng(6)
    n = 400  # ~5 points per 1 m (3.28 ft) radius: some queries have fewer than 3
    xyz = np.column_stack((rng.uniform(0, 50, n) + 636000.0, rng.uniform(0, 50, n) + 849000.0,
                           rng.normal(410.0, 0.2, n)))
    index = GroundIndex(xyz, "EPSG:2994")
    qx = rng.uniform(2, 48, 200) + 636000.0
    qy = rng.uniform(2, 48, 200) + 849000.0
    res = index.lookup(qx, qy, radius_m=1.0)  # 1 m = 3.2808 ft
    d = np.hypot(xyz[None, :, 0] - qx[:, None], xyz[None, :, 1] - qy[:, None])
    near = d <= 1.0 / FT
    np.testing.assert_array_equal(res.count, near.sum(axis=1))
    expected = np.array([np.median(xyz[row, 2]) if row.any() else np.nan for row in near])
    np.testing.assert_allclose(res.z, expected, rtol=0, atol=1e-9)
    few = res.count < 3
    assert few.any() and np.all(np.isnan(res.spread[few])) and np.all(np.isfinite(res.spread[~few]))
    i = int(np.argmax(~few))
    zz = xyz[near[i], 2]
    assert res.spread[i] == pytest.approx(1.4826 * np.median(np.abs(zz - np.median(zz))), abs=1e-12)


def test_z_at_errors_name_the_point_and_file(tmp_path: Path) -> None:
    path = _write_las(tmp_path / "syn.las", _synthetic(hole=True), pyproj.CRS.from_epsg(32617))
    index = GroundIndex.from_cloud(read_point_cloud(path))
    ok_x, ok_y = ORIGIN[0] + 20.0, ORIGIN[1] + 20.0
    z = index.z_at([ok_x, ok_x + 1], [ok_y, ok_y + 1])
    assert z.shape == (2,) and np.all(np.abs(z - _plane(np.array([ok_x, ok_x + 1]), np.array([ok_y, ok_y + 1]))) < 0.1)

    outside = ORIGIN[0] + 150.0, ORIGIN[1] + 20.0
    with pytest.raises(InputError, match=r"point 1 at \(512496\.000, 4987674\.000\) lies outside the point cloud") as e:
        index.z_at([ok_x, outside[0], ok_x], [ok_y, outside[1], ok_y])
    assert str(path) in str(e.value)

    centre = ORIGIN[0] + 50.0, ORIGIN[1] + 50.0  # in the hole: inside the hull, no ground within 1 m
    with pytest.raises(InputError, match=r"point 0 at .*no ground points within 1 m.*increase radius_m") as e:
        index.z_at(centre[0], centre[1], radius_m=1.0)
    assert str(path) in str(e.value)
    assert index.z_at(centre[0], centre[1], radius_m=12.0)[0] == pytest.approx(_plane(*map(np.array, centre)), abs=0.05)
    res = index.lookup([centre[0], np.nan], [centre[1], 0.0])
    assert res.count.tolist() == [0, 0] and res.inside.tolist() == [True, False] and np.isnan(res.z).all()


def test_inside_is_the_convex_hull_not_the_bbox() -> None:
    rng = np.random.default_rng(8)
    xy = rng.uniform(0.0, 100.0, (6000, 2))
    xy = xy[xy.sum(axis=1) <= 100.0]  # a triangle: its bbox is twice as large
    index = GroundIndex(np.column_stack((xy + ORIGIN, np.full(len(xy), 150.0))), "EPSG:32617", "triangle.laz")
    qx = np.array([10.0, 45.0, 55.0, 60.0]) + ORIGIN[0]
    qy = np.array([10.0, 45.0, 55.0, 45.0]) + ORIGIN[1]
    res = index.lookup(qx, qy, radius_m=30.0)
    assert res.inside.tolist() == [True, True, False, False]
    assert res.count[2] > 0  # near enough to points, but outside the footprint
    with pytest.raises(InputError, match=r"point 2 at .* lies outside the point cloud triangle\.laz"):
        index.z_at(qx, qy, radius_m=30.0)


def test_z_at_message_in_feet(autzen_index: GroundIndex) -> None:
    with pytest.raises(InputError, match=r"within 0\.01 m \(0\.03281 foot\)"):
        autzen_index.z_at(636500.0, 849200.0, radius_m=0.01)


# ---------------------------------------------------------------------- DEM from a cloud
@pytest.fixture(scope="module")
def autzen_dem(autzen: PointCloud):
    return cloud_to_dem(autzen, resolution_m=2.0)


@pytest.mark.slow
def test_dem_from_autzen_grid(autzen: PointCloud, autzen_dem) -> None:
    dem = autzen_dem
    res = 2.0 / FT  # 6.5617 ft
    assert dem.resolution == pytest.approx((res, res), rel=1e-12)
    assert dem.is_north_up and dem.crs == autzen.crs and dem.descriptions == ("ground elevation (foot)",)
    assert dem.data.shape[0] == 1 and dem.data.dtype == np.float64 and math.isnan(dem.nodata)
    ground = autzen.xyz[autzen.classification == 2]
    left, bottom, right, top = dem.bounds
    # edges on multiples of the cell size, enclosing the ground points with less than a cell to spare
    for edge in (left, bottom, right, top):
        assert abs(edge / res - round(edge / res)) < 1e-6
    assert 0 <= ground[:, 0].min() - left < res and 0 < right - ground[:, 0].max() <= res
    assert 0 <= ground[:, 1].min() - bottom < res and 0 < top - ground[:, 1].max() <= res
    cols = math.floor(ground[:, 0].max() / res) - math.floor(ground[:, 0].min() / res) + 1
    rows = math.floor(ground[:, 1].max() / res) - math.floor(ground[:, 1].min() / res) + 1
    assert dem.shape == (rows, cols) == (87, 181)  # 562.7 ft x 1177.4 ft in 6.56 ft cells
    z = dem.data[0]
    assert ground[:, 2].min() <= np.nanmin(z) and np.nanmax(z) <= ground[:, 2].max()
    assert 0.75 < np.isfinite(z).mean() < 0.95  # NaN outside the convex hull of the ground points


@pytest.mark.slow
def test_dem_cells_follow_their_points(autzen: PointCloud, autzen_dem) -> None:
    """Cells hold a local plane's value (tests/test_cloud_surface.py), close to the median of their own points."""
    ground = autzen.xyz[autzen.classification == 2]
    col, row = autzen_dem.map_to_pixel(ground[:, 0], ground[:, 1])
    ci, ri = np.floor(col).astype(int), np.floor(row).astype(int)
    cells = ri * autzen_dem.cols + ci
    uniq, counts = np.unique(cells, return_counts=True)
    diff = []
    for cell in uniq[counts >= 4][:300]:
        r, c = divmod(int(cell), autzen_dem.cols)
        diff.append(autzen_dem.data[0, r, c] - np.median(ground[cells == cell, 2]))
    diff = np.abs(np.array(diff))
    assert np.isfinite(diff).all() and np.median(diff) < 0.1 and np.percentile(diff, 90) < 0.5  # feet


@pytest.mark.slow
def test_dem_one_metre_cells_are_feet() -> None:
    cloud = _synthetic(crs="EPSG:2994")  # the same numbers read as feet
    dem = cloud_to_dem(cloud, resolution_m=1.0)
    assert dem.resolution[0] == pytest.approx(3.2808398950, abs=1e-9)
    assert dem.descriptions == ("ground elevation (foot)",)


@pytest.mark.slow
def test_dem_agrees_with_ground_index(autzen: PointCloud, autzen_index: GroundIndex, autzen_dem) -> None:
    rng = np.random.default_rng(7)
    pick = rng.choice(len(autzen_index), 1000, replace=False)
    x, y = autzen_index.xyz[pick, 0], autzen_index.xyz[pick, 1]
    look = autzen_index.lookup(x, y, radius_m=3.0)
    flat = (look.spread < 0.3) & (look.count >= 5)
    assert flat.sum() > 300
    diff = autzen_dem.sample_bilinear(x[flat], y[flat]) - look.z[flat]
    assert np.isfinite(diff).mean() > 0.95  # NaN only next to the NaN cells at the footprint's edge
    diff = diff[np.isfinite(diff)]
    assert np.median(np.abs(diff)) < 0.15 and np.percentile(np.abs(diff), 90) < 0.4  # feet


@pytest.mark.slow
def test_dem_fills_holes_by_tin_and_keeps_nan_outside() -> None:
    cloud = _synthetic(hole=True)
    pad = 20.0
    bounds = (ORIGIN[0] - pad, ORIGIN[1] - pad, ORIGIN[0] + 100 + pad, ORIGIN[1] + 100 + pad)
    dem = cloud_to_dem(cloud, resolution_m=2.0, bounds=bounds)
    assert dem.shape == (70, 70) and dem.bounds == pytest.approx(bounds)
    z = dem.data[0]
    c, r = np.meshgrid(np.arange(dem.cols) + 0.5, np.arange(dem.rows) + 0.5)
    x, y = dem.pixel_to_map(c, r)
    in_hole = np.hypot(x - ORIGIN[0] - 50, y - ORIGIN[1] - 50) < 8.0
    assert in_hole.sum() > 40
    # linear TIN across the hole between edge cells whose medians have ~0.02 m noise
    hole_err = z[in_hole] - _plane(x[in_hole], y[in_hole])
    assert np.max(np.abs(hole_err)) < 0.1 and np.mean(np.abs(hole_err)) < 0.04
    outside = (x < ORIGIN[0] - 1) | (x > ORIGIN[0] + 101) | (y < ORIGIN[1] - 1) | (y > ORIGIN[1] + 101)
    assert np.all(np.isnan(z[outside]))
    inner = (np.abs(x - ORIGIN[0] - 50) < 48) & (np.abs(y - ORIGIN[1] - 50) < 48)
    assert np.all(np.isfinite(z[inner]))
    ok = np.isfinite(z)
    assert np.max(np.abs(z[ok] - _plane(x[ok], y[ok]))) < 0.15  # the trees (class 5) are not in the DEM


@pytest.mark.slow
def test_dem_explicit_ground_mask_and_errors() -> None:
    cloud = _synthetic()
    everything = cloud_to_dem(cloud, resolution_m=4.0, ground=np.ones(len(cloud), bool))
    assert np.nanmax(everything.data) > _plane(np.array(ORIGIN[0] + 100.0), np.array(ORIGIN[1])) + 2.0  # crowns
    with pytest.raises(InputError, match="no ground points inside the bounds"):
        cloud_to_dem(cloud, 2.0, bounds=(0.0, 0.0, 10.0, 10.0))
    with pytest.raises(InputError, match="coarser resolution"):
        cloud_to_dem(cloud, 0.001)
    with pytest.raises(InputError, match="positive number of metres"):
        cloud_to_dem(cloud, 0.0)


@pytest.mark.slow
def test_dem_write_read_round_trip(tmp_path: Path, autzen_dem) -> None:
    path = tmp_path / "autzen_dem.tif"
    write_geotiff(path, autzen_dem.data, autzen_dem.transform, autzen_dem.crs, nodata=-9999.0,
                  descriptions=autzen_dem.descriptions)
    back = read_dem(path)
    assert back.transform.almost_equals(autzen_dem.transform, precision=1e-9)
    assert back.crs.to_epsg() == 2994 and back.descriptions == autzen_dem.descriptions
    np.testing.assert_array_equal(np.isnan(back.data), np.isnan(autzen_dem.data))
    np.testing.assert_allclose(back.data, autzen_dem.data, atol=1e-4)  # float32 storage
