"""Tests of the geospatial commands (trafficgeo.cli.geo): georef, project, dem, gcp-z, accuracy, calibrate --gis.

Inputs are generated scenes with known truth (trafficgeo.synth.make_gcp_scene: a road surface with grade, crowned
crossfall and optionally a crest, in EPSG:2949 metres) and the Autzen lidar sample (tests/data/autzen, EPSG:2994
international feet). Commands run in-process through ``trafficgeo.cli.main``; exit code 2 means bad input with one
line on stderr and nothing written.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import geopandas as gpd
import laspy
import numpy as np
import pandas as pd
import pyogrio
import pyproj
import pytest
import rasterio
import shapely
from affine import Affine

from cli_support import invoke
from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.geo.raster import read_dem, write_geotiff
from trafficgeo.geo.surface import DEMSurface
from trafficgeo.synth.gcp_scene import make_gcp_scene

AUTZEN = Path(__file__).parent / "data" / "autzen" / "autzen_trim.laz"
FT = 0.3048
SIZE = (1920, 1080)
SIZE_TEXT = "1920x1080"
SCENE_SEED = 7
DEM_RES = 0.25  # m, synthetic road DEM cells
DEM_CELLS = 800  # 200 m x 200 m
WALL = (24.0, 27.0)  # m ahead of the camera: where the 'wall' DEM stands 6 m above the road
BAND_NAMES = ("radial_m", "major_m", "minor_m", "calibration_m", "pixel_m", "gsd_m")
TO_LONLAT_2949 = pyproj.Transformer.from_crs("EPSG:2949", "EPSG:4326", always_xy=True)


# ------------------------------------------------------------------------------------------------ helpers




def ok(*args: object) -> str:
    """Run a command that must succeed; returns its stdout."""
    code, stdout, stderr = invoke(*args)
    assert code == 0, (stdout, stderr)
    assert "Traceback" not in stderr
    return stdout


def temp_leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".") and ".tmp" in p.name)


def assert_bad_input(code: int, stdout: str, stderr: str, outputs: list[Path], word: str) -> None:
    """Exit 2, one line on stderr naming ``word``, no traceback, none of ``outputs`` and no temporary files."""
    assert code == 2, (stdout, stderr)
    assert "Traceback" not in stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("trafficgeo: error:"), stderr
    assert word in lines[0], stderr
    for out in outputs:
        assert not out.exists(), out
        assert temp_leftovers(out.parent) == []


def write_csv(path: Path, frame: pd.DataFrame) -> Path:
    frame.to_csv(path, index=False)
    return path


def raw_rows(path: Path) -> list[dict[str, str]]:
    """A CSV's rows as the text written (to see empty cells as empty)."""
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def road_points_in_view(sc, stations=tuple(range(5, 61, 5)), offsets=tuple(range(-6, 7, 2))) -> np.ndarray:
    """World points on the road surface at ``stations`` metres ahead of the camera (along its look direction) and
    ``offsets`` metres across the axis, that the TRUE camera sees inside the image."""
    cam, road = sc.camera, sc.road
    s0, _ = road.station_offset(cam.position[0], cam.position[1])
    look = np.sign(cam.optical_axis[:2] @ road.axis)
    ss, oo = np.meshgrid(s0 + look * np.asarray(stations, float), np.asarray(offsets, float), indexing="ij")
    pts = road.points(ss.ravel(), oo.ravel())
    uv = cam.project(pts)
    inside = cam.in_image(np.nan_to_num(uv, nan=-1e9), margin=2.0)
    return pts[inside]


def dem_grid(sc, z_of=None) -> tuple[np.ndarray, Affine]:
    """The road surface sampled at cell centres of a 200 m x 200 m grid in front of the camera (heading ~108 deg)."""
    cam = sc.camera
    left = float(np.floor(cam.position[0])) - 60.0
    top = float(np.floor(cam.position[1])) + 60.0
    xc = left + (np.arange(DEM_CELLS) + 0.5) * DEM_RES
    yc = top - (np.arange(DEM_CELLS) + 0.5) * DEM_RES
    xx, yy = np.meshgrid(xc, yc)
    z = (z_of or sc.road.z)(xx, yy)
    return z, Affine(DEM_RES, 0.0, left, 0.0, -DEM_RES, top)


# ------------------------------------------------------------------------------------------------ fixtures


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("geo")


@pytest.fixture(scope="module")
def scene():
    sc = make_gcp_scene(SCENE_SEED, image_size=SIZE, n_control=14, n_check=4)
    assert sc.camera.crs == "EPSG:2949"
    return sc


@pytest.fixture(scope="module")
def true_cam(scene, work: Path) -> Path:
    path = work / "true_camera.json"
    write_camera_json(path, scene.camera)
    return path


@pytest.fixture(scope="module")
def gcps_csv(scene, work: Path) -> Path:
    path = work / "gcps.csv"
    scene.gcps.to_csv(path)
    return path


@pytest.fixture(scope="module")
def cal_cam(gcps_csv: Path, work: Path) -> Path:
    """The scene's camera calibrated from its GCPs by 'trafficgeo calibrate' (with a covariance block)."""
    path = work / "calibrated.json"
    ok("calibrate", gcps_csv, "--image-size", SIZE_TEXT, "-o", path, "--crs", "EPSG:2949", "-q")
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert "covariance" in doc and len(doc["gcps"]) == 18
    return path


@pytest.fixture(scope="module")
def road_dem(scene, work: Path) -> Path:
    z, transform = dem_grid(scene)
    path = work / "road.tif"
    write_geotiff(path, z[None], transform, "EPSG:2949")
    return path


@pytest.fixture(scope="module")
def wall_dem(scene, work: Path) -> Path:
    """The road DEM with a 6 m high wall across the road 24-27 m ahead of the camera."""
    cam, road = scene.camera, scene.road
    s0, _ = road.station_offset(cam.position[0], cam.position[1])
    look = float(np.sign(cam.optical_axis[:2] @ road.axis))

    def z_of(x, y):
        s, _o = road.station_offset(x, y)
        ahead = (s - s0) * look
        return road.z(x, y) + np.where((ahead >= WALL[0]) & (ahead <= WALL[1]), 6.0, 0.0)

    z, transform = dem_grid(scene, z_of)
    path = work / "wall.tif"
    write_geotiff(path, z[None], transform, "EPSG:2949")
    return path


@pytest.fixture(scope="module")
def road_pixels(scene, work: Path) -> tuple[Path, np.ndarray]:
    """Pixel CSV: true projections of road points (with pass-through columns), then a sky and an off-image pixel."""
    pts = road_points_in_view(scene)
    assert len(pts) >= 40
    uv = scene.camera.project(pts)
    n = len(pts)
    frame = pd.DataFrame({
        "track_id": [f"T{i:03d}" for i in range(n)] + ["sky", "off"],
        "u": np.r_[uv[:, 0], 960.0, 2100.0],
        "v": np.r_[uv[:, 1], 0.0, 500.0],
        "frame": np.arange(n + 2) * 3,
        "x": np.full(n + 2, -1.0),  # clashes with the output's x: kept as x_in
    })
    return write_csv(work / "road_pixels.csv", frame), pts


@pytest.fixture(scope="module")
def autzen_dem(work: Path) -> Path:
    """'trafficgeo dem' of the Autzen cloud at 1 m (3.2808 ft) cells."""
    path = work / "autzen_dem.tif"
    ok("dem", AUTZEN, "-o", path, "--resolution", "1", "--crs", "EPSG:2994")
    return path


@pytest.fixture(scope="module")
def feet_cam(autzen_dem: Path, work: Path) -> tuple[Path, Camera]:
    """A camera in EPSG:2994 (feet) 30 ft above the middle of the Autzen cloud, looking east and down 30 deg."""
    dem = DEMSurface.from_raster(read_dem(autzen_dem))
    zg = float(dem.elevation(636600.0, 849200.0))
    assert 420 < zg < 435
    cam = Camera.from_orientation(SIZE, 1200.0, [636600.0, 849200.0, zg + 30.0], 90.0, 30.0, crs="EPSG:2994")
    path = work / "feet_camera.json"
    write_camera_json(path, cam)
    return path, cam


@pytest.fixture(scope="module")
def feet_pixels(work: Path) -> Path:
    u, v = np.meshgrid(np.linspace(100, 1800, 5), np.linspace(600, 1070, 4))
    frame = pd.DataFrame({"u": u.ravel(), "v": v.ravel(), "name": [f"p{i}" for i in range(u.size)]})
    return write_csv(work / "feet_pixels.csv", frame)


# ------------------------------------------------------------------------------------------------ 1. georef


@pytest.fixture(scope="module")
def georef_true_dem(true_cam: Path, road_pixels, road_dem: Path, work: Path) -> tuple[Path, str]:
    out = work / "georef_true_dem.csv"
    stdout = ok("georef", true_cam, road_pixels[0], "--surface", road_dem, "-o", out)
    return out, stdout


def test_georef_true_camera_on_dem_recovers_the_road(georef_true_dem, road_pixels, scene) -> None:
    out, stdout = georef_true_dem
    _csv, pts = road_pixels
    n = len(pts)
    res = pd.read_csv(out)
    assert len(res) == n + 2
    assert "wrote" in stdout and "road.tif" in stdout
    road = res.iloc[:n]
    assert (road["status"] == "ok").all()
    err = road[["x", "y", "z"]].to_numpy() - pts
    assert np.abs(err).max() < 0.02, np.abs(err).max(axis=0)
    assert np.median(np.linalg.norm(err, axis=1)) < 0.005
    # distance from the camera in metres, incidence between 0 and 90 deg
    expected_d = np.linalg.norm(pts - scene.camera.position, axis=1)
    np.testing.assert_allclose(road["distance_m"], expected_d, atol=0.02)
    assert ((road["incidence_deg"] > 0) & (road["incidence_deg"] <= 90)).all()
    # the sky gets no ground point; a pixel beyond the frame is outside the image
    sky, off = res.iloc[n], res.iloc[n + 1]
    assert sky["status"] == "above_horizon"
    assert off["status"] == "outside_image"
    for row in (sky, off):
        assert np.isnan(row["x"]) and np.isnan(row["y"]) and np.isnan(row["z"]) and np.isnan(row["lon"])
    text_rows = raw_rows(out)
    assert text_rows[n]["x"] == "" and text_rows[n]["lat"] == "" and text_rows[n]["distance_m"] == ""


def test_georef_passes_columns_through_and_adds_lonlat(georef_true_dem, road_pixels) -> None:
    out, _stdout = georef_true_dem
    csv_path, pts = road_pixels
    inp = pd.read_csv(csv_path)
    res = pd.read_csv(out)
    for col in ("track_id", "u", "v", "frame"):
        assert res[col].tolist() == inp[col].tolist() or np.allclose(res[col], inp[col], atol=1e-4), col
    assert (res["x_in"] == -1.0).all()  # the input's own x is kept, renamed
    assert list(res.columns[:5]) == ["track_id", "u", "v", "frame", "x_in"]
    for col in ("x", "y", "z", "lon", "lat", "distance_m", "incidence_deg", "status"):
        assert col in res.columns, col
    n = len(pts)
    lon, lat = TO_LONLAT_2949.transform(res["x"].to_numpy()[:n], res["y"].to_numpy()[:n])
    np.testing.assert_allclose(res["lon"].to_numpy()[:n], lon, atol=2e-9)
    np.testing.assert_allclose(res["lat"].to_numpy()[:n], lat, atol=2e-9)
    # and close to the lon/lat of the true points (2 cm ~ 3e-7 deg)
    tlon, tlat = TO_LONLAT_2949.transform(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(res["lon"].to_numpy()[:n], tlon, atol=3e-7)
    np.testing.assert_allclose(res["lat"].to_numpy()[:n], tlat, atol=3e-7)
    assert -72 < lon.mean() < -70 and 46 < lat.mean() < 47.5  # MTM zone 7, Quebec


def test_georef_constant_surface_matches_horizontal_plane(true_cam: Path, road_pixels, scene, tmp_path) -> None:
    out = tmp_path / "flat.csv"
    ok("georef", true_cam, road_pixels[0], "--surface", "90.5", "-o", out)
    res = pd.read_csv(out)
    uv = res[["u", "v"]].to_numpy()
    expected = scene.camera.intersect_horizontal_plane(uv, 90.5)
    good = res["status"] == "ok"
    assert good.sum() == len(road_pixels[1])
    np.testing.assert_allclose(res.loc[good, ["x", "y", "z"]].to_numpy(), expected[good.to_numpy()], atol=2e-4)


def test_georef_min_incidence_marks_grazing_rays(true_cam: Path, road_pixels, road_dem: Path, georef_true_dem,
                                                 tmp_path: Path) -> None:
    base = pd.read_csv(georef_true_dem[0])
    out = tmp_path / "grazing.csv"
    ok("georef", true_cam, road_pixels[0], "--surface", road_dem, "-o", out, "--min-incidence", "10")
    res = pd.read_csv(out)
    low = (base["status"] == "ok") & (base["incidence_deg"] < 10)
    high = (base["status"] == "ok") & (base["incidence_deg"] >= 10)
    assert low.sum() > 0 and high.sum() > 0
    assert (res.loc[low, "status"] == "grazing").all()
    assert (res.loc[high, "status"] == "ok").all()
    assert res.loc[low, "x"].isna().all()


# ------------------------------------------------------------------------------------------------ 2. plane, crest


def test_georef_plane_on_calibrated_camera(cal_cam: Path, road_pixels, scene, tmp_path: Path) -> None:
    out = tmp_path / "plane.csv"
    stdout = ok("georef", cal_cam, road_pixels[0], "--surface", "plane", "-o", out)
    assert "plane through" in stdout
    res = pd.read_csv(out)
    pts = road_pixels[1]
    n = len(pts)
    assert (res["status"].iloc[:n] == "ok").all()
    assert res["status"].iloc[n] == "above_horizon"
    assert res["status"].iloc[n + 1] == "outside_image"
    xyz = res[["x", "y", "z"]].to_numpy()[:n]
    # the points are coplanar ...
    A = np.column_stack([xyz[:, 0] - xyz[:, 0].mean(), xyz[:, 1] - xyz[:, 1].mean(), np.ones(n)])
    coef, *_ = np.linalg.lstsq(A, xyz[:, 2], rcond=None)
    assert np.abs(A @ coef - xyz[:, 2]).max() < 2e-4
    # ... on a plane close to the one through the GCPs on the road (the pole tops are not on the road)
    doc = json.loads(cal_cam.read_text(encoding="utf-8"))
    g = np.array([[r["x"], r["y"], r["z"]] for r in doc["gcps"] if r["inlier"] and r["role"] == "control"])
    on_road = np.abs(g[:, 2] - scene.road.z(g[:, 0], g[:, 1])) < 0.5
    assert (~on_road).sum() == 2
    gr = g[on_road]
    B = np.column_stack([gr[:, 0] - xyz[:, 0].mean(), gr[:, 1] - xyz[:, 1].mean(), np.ones(len(gr))])
    ref, *_ = np.linalg.lstsq(B, gr[:, 2], rcond=None)
    assert np.abs(A @ ref - xyz[:, 2]).max() < 0.1


def test_georef_plane_ignores_elevated_gcps(cal_cam: Path, road_pixels, tmp_path: Path) -> None:
    out = tmp_path / "plane.csv"
    ok("georef", cal_cam, road_pixels[0], "--surface", "plane", "-o", out)
    pts = road_pixels[1]
    res = pd.read_csv(out).iloc[: len(pts)]
    err = np.linalg.norm(res[["x", "y", "z"]].to_numpy() - pts, axis=1)
    # the calibration's check points are 0.12 m RMS; a plane through the pole tops too gives a 3 m median error
    assert np.median(err) < 0.5, np.median(err)


@pytest.mark.slow
def test_plane_error_grows_on_a_crest_but_dem_does_not(tmp_path: Path) -> None:
    sc = make_gcp_scene(SCENE_SEED, image_size=SIZE, n_control=14, n_check=4, crest_radius=500.0)
    sc.gcps.to_csv(tmp_path / "gcps.csv")
    cam = tmp_path / "cam.json"
    ok("calibrate", tmp_path / "gcps.csv", "--image-size", SIZE_TEXT, "-o", cam, "--crs", "EPSG:2949", "-q")
    z, transform = dem_grid(sc)
    write_geotiff(tmp_path / "crest.tif", z[None], transform, "EPSG:2949")
    pts = road_points_in_view(sc)
    uv = sc.camera.project(pts)
    write_csv(tmp_path / "px.csv", pd.DataFrame({"u": uv[:, 0], "v": uv[:, 1]}))
    errs = {}
    for name, surface in (("dem", tmp_path / "crest.tif"), ("plane", "plane")):
        ok("georef", cam, tmp_path / "px.csv", "--surface", surface, "-o", tmp_path / f"{name}.csv")
        res = pd.read_csv(tmp_path / f"{name}.csv")
        assert (res["status"] == "ok").all(), (name, res["status"].value_counts())
        errs[name] = np.linalg.norm(res[["x", "y", "z"]].to_numpy() - pts, axis=1)
    dist = np.hypot(*(pts[:, :2] - sc.camera.position[:2]).T)
    near, far = dist < 25, dist > 45
    assert near.sum() >= 5 and far.sum() >= 5
    assert np.median(errs["dem"]) < 0.15  # only the calibration's error
    assert np.median(errs["plane"]) > 5 * np.median(errs["dem"])
    assert np.median(errs["plane"][far]) > 2 * np.median(errs["plane"][near])
    assert np.median(errs["dem"][far]) < 0.3


# ------------------------------------------------------------------------------------------------ 3. GIS output


@pytest.mark.slow
def test_georef_gpkg_geojson_parquet(true_cam: Path, road_pixels, road_dem: Path, georef_true_dem,
                                     tmp_path: Path) -> None:
    base = pd.read_csv(georef_true_dem[0])
    n_in = len(base)
    ok_rows = (base["status"] == "ok").to_numpy()
    for suffix in (".gpkg", ".geojson", ".parquet"):
        ok("georef", true_cam, road_pixels[0], "--surface", road_dem, "-o", tmp_path / f"pts{suffix}")

    gdf = gpd.read_file(tmp_path / "pts.gpkg")
    assert pyogrio.list_layers(tmp_path / "pts.gpkg")[:, 0].tolist() == ["points"]
    assert gdf.crs.to_epsg() == 2949
    assert len(gdf) == n_in
    assert gdf.geometry.isna().to_numpy()[~ok_rows].all() or gdf.geometry.is_empty.to_numpy()[~ok_rows].all()
    assert gdf["track_id"].tolist() == base["track_id"].tolist()
    assert gdf["status"].tolist() == base["status"].tolist()
    xyz = shapely.get_coordinates(gdf.geometry[ok_rows], include_z=True)
    np.testing.assert_allclose(xyz, base.loc[ok_rows, ["x", "y", "z"]].to_numpy(), atol=1e-6)

    pq = gpd.read_parquet(tmp_path / "pts.parquet")
    assert pq.crs.to_epsg() == 2949 and len(pq) == n_in
    np.testing.assert_allclose(shapely.get_coordinates(pq.geometry[ok_rows], include_z=True), xyz, atol=1e-6)

    doc = json.loads((tmp_path / "pts.geojson").read_text(encoding="utf-8"))
    assert doc["type"] == "FeatureCollection" and "crs" not in doc
    feats = doc["features"]
    assert len(feats) == n_in
    assert all(f["properties"]["layer"] == "points" for f in feats)
    coords = np.array([f["geometry"]["coordinates"] for f, good in zip(feats, ok_rows, strict=True) if good])
    np.testing.assert_allclose(coords[:, 0], base.loc[ok_rows, "lon"], atol=2e-8)
    np.testing.assert_allclose(coords[:, 1], base.loc[ok_rows, "lat"], atol=2e-8)
    np.testing.assert_allclose(coords[:, 2], base.loc[ok_rows, "z"], atol=1e-3)  # metres already
    missing = [f for f, good in zip(feats, ok_rows, strict=True) if not good]
    assert [f["geometry"] for f in missing] == [None, None]
    assert [f["properties"]["track_id"] for f in missing] == ["sky", "off"]
    assert [f["properties"]["x"] for f in missing] == [None, None]
    back = gpd.read_file(tmp_path / "pts.geojson")
    assert back.crs.to_epsg() in (4326, 4979) and len(back) == n_in  # GDAL: WGS 84 (3D when there is z)


# ------------------------------------------------------------------------------------------------ 4. height


def test_georef_height_lifts_the_surface(true_cam: Path, road_pixels, road_dem: Path, georef_true_dem, scene,
                                         tmp_path: Path) -> None:
    out = tmp_path / "roof.csv"
    ok("georef", true_cam, road_pixels[0], "--surface", road_dem, "-o", out, "--height", "1.5")
    res = pd.read_csv(out)
    n = len(road_pixels[1])
    good = res["status"] == "ok"
    assert good.iloc[:n].all() and not good.iloc[n:].any()
    x, y, z = (res.loc[good, c].to_numpy() for c in ("x", "y", "z"))
    np.testing.assert_allclose(z - scene.road.z(x, y), 1.5, atol=0.005)
    # a lifted point lies on the pixel's ray, closer to the camera than the ground point of the same pixel
    uv = scene.camera.project(np.column_stack([x, y, z]))
    np.testing.assert_allclose(uv, res.loc[good, ["u", "v"]].to_numpy(), atol=0.02)
    base = pd.read_csv(georef_true_dem[0])
    assert (res.loc[good, "distance_m"] < base.loc[good, "distance_m"] - 1.5).all()


@pytest.mark.slow
def test_georef_height_is_in_metres_for_a_feet_camera(feet_cam, feet_pixels: Path, autzen_dem: Path,
                                                      tmp_path: Path) -> None:
    cam_path, _cam = feet_cam
    out = tmp_path / "roof_ft.csv"
    ok("georef", cam_path, feet_pixels, "--surface", autzen_dem, "-o", out, "--height", "1.5")
    res = pd.read_csv(out)
    assert (res["status"] == "ok").all()
    dem = DEMSurface.from_raster(read_dem(autzen_dem))
    ground = dem.elevation(res["x"].to_numpy(), res["y"].to_numpy())
    np.testing.assert_allclose(res["z"].to_numpy() - ground, 1.5 / FT, atol=0.01)


# ------------------------------------------------------------------------------------------------ 5. project


def test_project_round_trip(true_cam: Path, georef_true_dem, tmp_path: Path) -> None:
    out = tmp_path / "back.csv"
    stdout = ok("project", true_cam, georef_true_dem[0], "-o", out)
    assert "wrote" in stdout
    res = pd.read_csv(out)
    good = (res["status_in"] == "ok").to_numpy()
    assert (res.loc[good, "status"] == "ok").all()
    duv = res.loc[good, ["u", "v"]].to_numpy() - res.loc[good, ["u_in", "v_in"]].to_numpy()
    # x, y, z are written to 0.1 mm: a few thousandths of a pixel at 12 m with f = 1350 px
    assert np.abs(duv).max() < 0.02, np.abs(duv).max()
    assert np.median(np.abs(duv)) < 5e-3
    # depth along the optical axis, metres
    assert (res.loc[good, "depth_m"] > 5).all() and (res.loc[good, "depth_m"] < 70).all()
    assert res["track_id"].tolist() == pd.read_csv(georef_true_dem[0])["track_id"].tolist()
    for col in ("x_in", "lon", "distance_m"):
        assert col in res.columns


def test_project_statuses_and_occlusion(true_cam: Path, scene, wall_dem: Path, tmp_path: Path) -> None:
    cam, road = scene.camera, scene.road
    s0, _ = road.station_offset(cam.position[0], cam.position[1])
    look = float(np.sign(cam.optical_axis[:2] @ road.axis))
    front = road.points(s0 + look * np.array([12.0, 15.0]), [0.0, 2.0])  # before the wall
    hidden = road.points(s0 + look * np.array([40.0, 55.0]), [0.0, 2.0])  # behind the wall
    on_wall = road.points(s0 + look * sum(WALL) / 2, 0.0)
    on_wall[:, 2] += 6.0
    behind = (cam.position - 10.0 * cam.optical_axis)[None]
    side = (cam.position + 30.0 * cam.R[0] + 10 * cam.optical_axis)[None]  # far right of the frame
    pts = np.vstack([front, hidden, on_wall, behind, side])
    assert cam.in_image(cam.project(hidden)).all()
    names = ["front1", "front2", "hidden1", "hidden2", "wall_top", "behind", "side"]
    frame = pd.DataFrame({"name": names, "x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]})
    write_csv(tmp_path / "world.csv", frame)

    ok("project", true_cam, tmp_path / "world.csv", "-o", tmp_path / "plain.csv")
    plain = pd.read_csv(tmp_path / "plain.csv").set_index("name")
    assert plain["status"].to_dict() == {"front1": "ok", "front2": "ok", "hidden1": "ok", "hidden2": "ok",
                                         "wall_top": "ok", "behind": "behind_camera", "side": "outside_image"}
    assert np.isnan(plain.loc["behind", "u"]) and np.isnan(plain.loc["behind", "v"])
    assert plain.loc["behind", "depth_m"] == pytest.approx(-10.0, abs=1e-3)
    expected = cam.project(pts[:5])
    np.testing.assert_allclose(plain[["u", "v"]].to_numpy()[:5], expected, atol=1e-4)

    ok("project", true_cam, tmp_path / "world.csv", "-o", tmp_path / "occl.csv", "--surface", wall_dem)
    occl = pd.read_csv(tmp_path / "occl.csv").set_index("name")
    assert occl["status"].to_dict() == {"front1": "ok", "front2": "ok", "hidden1": "occluded", "hidden2": "occluded",
                                        "wall_top": "ok", "behind": "behind_camera", "side": "outside_image"}
    np.testing.assert_allclose(occl[["u", "v"]].to_numpy()[:5], expected, atol=1e-4)  # pixels still given


# ------------------------------------------------------------------------------------------------ 6. dem, feet


@pytest.mark.slow
def test_dem_from_autzen_in_feet(autzen_dem: Path) -> None:
    las = laspy.read(AUTZEN)
    z = np.asarray(las.z)
    ground = np.asarray(las.classification) == 2
    with rasterio.open(autzen_dem) as ds:
        assert pyproj.CRS.from_wkt(ds.crs.to_wkt()).equals(pyproj.CRS.from_epsg(2994))
        assert ds.res == pytest.approx((1 / FT, 1 / FT), abs=1e-9)
        assert ds.count == 1
        assert "foot" in (ds.descriptions[0] or "")
        data = ds.read(1)
        b = ds.bounds
    valid = np.isfinite(data)
    assert 0.7 < valid.mean() < 1.0
    assert z[ground].min() - 1e-3 <= np.nanmin(data) and np.nanmax(data) <= z[ground].max() + 1e-3
    assert z.min() <= np.nanmin(data) and np.nanmax(data) < z.max()
    # the grid covers the ground points and its edges lie on multiples of the cell size
    x, y = np.asarray(las.x)[ground], np.asarray(las.y)[ground]
    assert b.left <= x.min() and x.max() < b.right and b.bottom <= y.min() and y.max() < b.top
    assert b.left / (1 / FT) == pytest.approx(round(b.left / (1 / FT)), abs=1e-6)
    # cells holding ground points lie close to their points (a local plane, not their median; checked on a few)
    col = np.floor((x - b.left) / (1 / FT)).astype(int)
    row = np.floor((b.top - y) / (1 / FT)).astype(int)
    diff = []
    for k in np.linspace(0, len(x) - 1, 25).astype(int):
        same = (col == col[k]) & (row == row[k])
        diff.append(data[row[k], col[k]] - np.median(np.asarray(las.z)[ground][same]))
    assert np.median(np.abs(diff)) < 0.1 and np.max(np.abs(diff)) < 1.0  # feet


@pytest.mark.slow
def test_georef_on_laz_in_feet(feet_cam, feet_pixels: Path, autzen_dem: Path, tmp_path: Path) -> None:
    cam_path, cam = feet_cam
    # the header's Oregon Lambert WKT is accepted as the camera's EPSG:2994; --surface-crs overrides it
    ok("georef", cam_path, feet_pixels, "--surface", AUTZEN, "-o", tmp_path / "laz.csv", "--resolution", "1")
    ok("georef", cam_path, feet_pixels, "--surface", AUTZEN, "-o", tmp_path / "laz2.csv", "--resolution", "1",
       "--surface-crs", "EPSG:2994")
    ok("georef", cam_path, feet_pixels, "--surface", autzen_dem, "-o", tmp_path / "dem.csv")
    laz, laz2, dem = (pd.read_csv(tmp_path / f"{n}.csv") for n in ("laz", "laz2", "dem"))
    for res in (laz, laz2, dem):
        assert (res["status"] == "ok").all()
        assert res["name"].tolist() == [f"p{i}" for i in range(20)]
    np.testing.assert_allclose(laz[["x", "y", "z"]], dem[["x", "y", "z"]], atol=2e-4)
    np.testing.assert_allclose(laz2[["x", "y", "z"]], dem[["x", "y", "z"]], atol=2e-4)
    # distance_m is metres: the feet distance times 0.3048
    d_ft = np.linalg.norm(laz[["x", "y", "z"]].to_numpy() - cam.position, axis=1)
    np.testing.assert_allclose(laz["distance_m"], d_ft * FT, atol=1e-4)
    assert 3 < laz["distance_m"].min() and laz["distance_m"].max() < 40
    # the points are on the ground of the cloud, below the camera
    assert (laz["z"] < cam.position[2] - 5).all()
    # lon/lat from the feet coordinates
    lon, lat = pyproj.Transformer.from_crs("EPSG:2994", "EPSG:4326", always_xy=True).transform(laz["x"], laz["y"])
    np.testing.assert_allclose(laz["lon"], lon, atol=2e-9)
    np.testing.assert_allclose(laz["lat"], lat, atol=2e-9)
    assert -123.08 < lon.mean() < -123.06 and 44.04 < lat.mean() < 44.06


@pytest.mark.slow
def test_georef_on_crs_less_las_needs_surface_crs(true_cam: Path, road_pixels, scene, tmp_path: Path) -> None:
    pts = road_points_in_view(scene)
    lo, hi = pts[:, :2].min(axis=0) - 5, pts[:, :2].max(axis=0) + 5
    step = 0.5  # points at the centres of 0.5 m cells (cells start at multiples of 0.5 m)
    xs = np.arange(np.floor(lo[0] / step), np.ceil(hi[0] / step)) * step + step / 2
    ys = np.arange(np.floor(lo[1] / step), np.ceil(hi[1] / step)) * step + step / 2
    xx, yy = np.meshgrid(xs, ys)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets = [float(xs.min()), float(ys.min()), 0.0]
    header.scales = [0.0001, 0.0001, 0.0001]
    las = laspy.LasData(header)
    las.x, las.y, las.z = xx.ravel(), yy.ravel(), scene.road.z(xx, yy).ravel()
    las.classification = np.full(xx.size, 2, dtype=np.uint8)
    las.write(tmp_path / "nocrs.las")
    assert laspy.read(tmp_path / "nocrs.las").header.parse_crs() is None

    out = tmp_path / "out.csv"
    code, stdout, stderr = invoke("georef", true_cam, road_pixels[0], "--surface", tmp_path / "nocrs.las", "-o", out,
                                  "--resolution", "0.5")
    assert_bad_input(code, stdout, stderr, [out], "--surface-crs")
    ok("georef", true_cam, road_pixels[0], "--surface", tmp_path / "nocrs.las", "-o", out, "--resolution", "0.5",
       "--surface-crs", "EPSG:2949")
    res = pd.read_csv(out).iloc[: len(pts)]
    assert (res["status"] == "ok").all()
    err = np.linalg.norm(res[["x", "y", "z"]].to_numpy() - pts, axis=1)
    assert err.max() < 0.05, err.max()


# ------------------------------------------------------------------------------------------------ 7. gcp-z


def _ground_median(x: float, y: float, radius_ft: float) -> float:
    las = laspy.read(AUTZEN)
    g = np.asarray(las.classification) == 2
    gx, gy, gz = np.asarray(las.x)[g], np.asarray(las.y)[g], np.asarray(las.z)[g]
    near = np.hypot(gx - x, gy - y) <= radius_ft
    return float(np.median(gz[near])) if near.any() else float("nan")


@pytest.fixture(scope="module")
def autzen_gcps(work: Path) -> tuple[Path, dict[str, float]]:
    radius_ft = 2.0 / FT
    where = {"A": (636600.0, 849200.0), "B": (636620.0, 849150.0), "C": (636500.0, 849100.0),
             "D": (636800.0, 849100.0), "E": (640000.0, 849200.0), "F": (636700.0, 849250.0)}
    truth = {k: _ground_median(x, y, radius_ft) for k, (x, y) in where.items()}
    assert np.isnan(truth["F"]) and np.isnan(truth["E"])  # no ground points within 2 m (a building) / outside
    z = {"A": "", "B": "", "C": f"{truth['C']:.3f}", "D": f"{truth['D'] + 8.0 / FT:.3f}", "E": "420.0", "F": ""}
    lines = ["id,x,y,z,u,v,note"] + [f"{k},{x},{y},{z[k]},{100 + i},{200 + i},n{k}"
                                     for i, (k, (x, y)) in enumerate(where.items())]
    path = work / "autzen_gcps.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path, truth


@pytest.mark.slow
def test_gcp_z_with_cloud(autzen_gcps, tmp_path: Path) -> None:
    path, truth = autzen_gcps
    out = tmp_path / "gcps_z.csv"
    stdout = ok("gcp-z", path, "--cloud", AUTZEN, "--crs", "EPSG:2994", "--radius", "2", "-o", out)
    assert "GCP D: disagrees" in stdout.replace("\n", " ")
    res = pd.read_csv(out).set_index("id")
    assert res["z_check"].to_dict() == {"A": "filled", "B": "filled", "C": "ok", "D": "disagrees", "E": "outside",
                                        "F": "empty"}
    for k in "ABCD":
        assert res.loc[k, "z_ground"] == pytest.approx(truth[k], abs=1e-6)
    assert res.loc["A", "z"] == pytest.approx(truth["A"], abs=1e-4)
    assert res.loc["B", "z"] == pytest.approx(truth["B"], abs=1e-4)
    assert res.loc["D", "dz_m"] == pytest.approx(8.0, abs=0.01)  # metres, not feet
    assert abs(res.loc["C", "dz_m"]) < 0.01
    assert res.loc["D", "z"] == pytest.approx(truth["D"] + 8.0 / FT, abs=1e-3)  # a given z is kept
    assert res.loc["E", "z"] == pytest.approx(420.0) and np.isnan(res.loc["E", "z_ground"])
    assert np.isnan(res.loc["F", "z"]) and res.loc["F", "ground_points"] == 0
    assert (res.loc[list("ABCD"), "ground_points"] >= 3).all()
    assert (res.loc[list("ABCD"), "ground_spread_m"] < 0.15).all()
    # the other columns pass through
    assert res["note"].tolist() == [f"n{k}" for k in "ABCDEF"]
    assert res["u"].tolist() == [100, 101, 102, 103, 104, 105]
    lon, lat = pyproj.Transformer.from_crs("EPSG:2994", "EPSG:4326", always_xy=True).transform(res["x"], res["y"])
    np.testing.assert_allclose(res["lon"], lon, atol=2e-9)
    np.testing.assert_allclose(res["lat"], lat, atol=2e-9)

    ok("gcp-z", path, "--cloud", AUTZEN, "--radius", "2", "--replace", "-o", tmp_path / "replaced.csv")
    rep = pd.read_csv(tmp_path / "replaced.csv").set_index("id")
    assert rep.loc["C", "z_check"] == "replaced"
    assert rep.loc["D", "z"] == pytest.approx(truth["D"], abs=1e-4)  # replaced by the ground


@pytest.mark.slow
def test_gcp_z_with_dem(autzen_gcps, autzen_dem: Path, tmp_path: Path) -> None:
    path, truth = autzen_gcps
    out = tmp_path / "gcps_dem.csv"
    ok("gcp-z", path, "--dem", autzen_dem, "-o", out)
    res = pd.read_csv(out).set_index("id")
    assert "ground_points" not in res.columns
    assert res.loc["A", "z_check"] in ("filled", "rough")
    assert res.loc["B", "z_check"] in ("filled", "rough")
    assert res.loc["D", "z_check"] == "disagrees" and res.loc["E", "z_check"] == "outside"
    dem = DEMSurface.from_raster(read_dem(autzen_dem))
    for k in "ABCD":
        x, y = res.loc[k, "x"], res.loc[k, "y"]
        assert res.loc[k, "z_ground"] == pytest.approx(float(dem.elevation(x, y)), abs=1e-9)
        assert res.loc[k, "z_ground"] == pytest.approx(truth[k], abs=0.5)  # DEM vs the local median, feet
    assert res.loc["D", "dz_m"] == pytest.approx(8.0, abs=0.2)
    assert res.loc["A", "z"] == pytest.approx(res.loc["A", "z_ground"], abs=1e-4)
    assert res["note"].tolist() == [f"n{k}" for k in "ABCDEF"]


# ------------------------------------------------------------------------------------------------ 8. accuracy


@pytest.fixture(scope="module")
def accuracy_run(cal_cam: Path, road_dem: Path, work: Path) -> tuple[Path, Path, str]:
    tif, gpkg = work / "acc.tif", work / "site.gpkg"
    stdout = ok("accuracy", cal_cam, "--surface", road_dem, "-o", tif, "--gis", gpkg, "--cell", "1")
    return tif, gpkg, stdout


@pytest.mark.slow
def test_accuracy_geotiff(accuracy_run, cal_cam: Path, scene) -> None:
    tif, _gpkg, stdout = accuracy_run
    assert "expected error" in stdout
    with rasterio.open(tif) as ds:
        assert ds.count == 6
        assert ds.descriptions == BAND_NAMES
        assert ds.crs.to_epsg() == 2949
        assert ds.res == pytest.approx((1.0, 1.0))
        bands = ds.read().astype(np.float64)
        transform = ds.transform
    finite = np.isfinite(bands)
    assert (finite == finite[0]).all()  # every band has data on the same cells
    vis = finite[0]
    assert 0.2 < vis.mean() < 0.95
    radial, major, minor, cal, pix, gsd = bands[:, vis]
    assert (radial > 0).all() and (minor > 0).all() and (minor <= major + 1e-6).all()
    np.testing.assert_allclose(radial**2, major**2 + minor**2, rtol=1e-4)
    np.testing.assert_allclose(radial**2, cal**2 + pix**2, rtol=1e-4)
    assert (gsd <= pix * (1 + 1e-5)).all()  # worst direction of one pixel vs the radial 1 px noise

    # visible = in front, inside the frame (on this smooth road nothing is occluded)
    cam = read_camera_json(cal_cam)
    rows, cols = np.indices(vis.shape)
    xc = transform.c + (cols.ravel() + 0.5) * transform.a
    yc = transform.f + (rows.ravel() + 0.5) * transform.e
    zc = scene.road.z(xc, yc)
    uv = cam.project(np.column_stack([xc, yc, zc]))
    inside = cam.in_image(np.nan_to_num(uv, nan=-1e9))
    clear = cam.in_image(np.nan_to_num(uv, nan=-1e9), margin=3.0) | ~cam.in_image(np.nan_to_num(uv, nan=-1e9),
                                                                                    margin=-3.0)
    dist = np.hypot(xc - cam.position[0], yc - cam.position[1])
    clear &= np.abs(dist - 250.0) > 2
    assert (vis.ravel()[clear] == (inside & (dist <= 250.0))[clear]).all()

    # the error grows with the distance from the camera
    d = dist.reshape(vis.shape)[vis]
    near, far = d < 30, d > 80
    assert near.sum() > 100 and far.sum() > 100
    assert np.median(radial[far]) > 3 * np.median(radial[near])
    assert np.median(pix[far]) > 3 * np.median(pix[near])


@pytest.mark.slow
def test_accuracy_pixel_sigma_scales_pixel_noise_only(cal_cam: Path, road_dem: Path, tmp_path: Path) -> None:
    for s in ("1", "2"):
        ok("accuracy", cal_cam, "--surface", road_dem, "-o", tmp_path / f"s{s}.tif", "--cell", "2",
           "--pixel-sigma", s)
    with rasterio.open(tmp_path / "s1.tif") as a, rasterio.open(tmp_path / "s2.tif") as b:
        one, two = a.read().astype(np.float64), b.read().astype(np.float64)
        assert a.transform == b.transform
    vis = np.isfinite(one[0])
    np.testing.assert_allclose(two[4][vis], 2 * one[4][vis], rtol=1e-4)  # pixel_m
    np.testing.assert_allclose(two[3][vis], one[3][vis], rtol=1e-5)  # calibration_m
    np.testing.assert_allclose(two[5][vis], one[5][vis], rtol=1e-5)  # gsd_m


def test_accuracy_site_gpkg(accuracy_run, cal_cam: Path, road_dem: Path, tmp_path: Path) -> None:
    _tif, gpkg, _stdout = accuracy_run
    assert sorted(pyogrio.list_layers(gpkg)[:, 0].tolist()) == ["camera", "footprint", "gcps"]
    cam, doc = read_camera_json(cal_cam), json.loads(cal_cam.read_text(encoding="utf-8"))
    camera = gpd.read_file(gpkg, layer="camera")
    assert camera.crs.to_epsg() == 2949 and len(camera) == 1
    np.testing.assert_allclose(shapely.get_coordinates(camera.geometry, include_z=True)[0], cam.position, atol=1e-6)
    gcps = gpd.read_file(gpkg, layer="gcps")
    assert len(gcps) == len(doc["gcps"]) == 18
    for col in ("id", "du", "dv", "error_px", "inlier"):
        assert col in gcps.columns, col
    np.testing.assert_allclose(np.hypot(gcps["du"], gcps["dv"]), gcps["error_px"], atol=1e-6)
    foot = gpd.read_file(gpkg, layer="footprint")
    assert len(foot) == 1 and foot.crs.to_epsg() == 2949
    poly = foot.geometry.iloc[0]
    assert poly.is_valid and poly.area > 1000
    assert foot["area_m2"].iloc[0] == pytest.approx(poly.area, rel=1e-6)
    # ground seen near the bottom centre of the image is inside; ground behind the camera is not
    px = write_csv(tmp_path / "px.csv", pd.DataFrame({"u": [960.0, 700.0, 1300.0], "v": [1060.0, 1000.0, 950.0]}))
    ok("georef", cal_cam, px, "--surface", road_dem, "-o", tmp_path / "g.csv")
    g = pd.read_csv(tmp_path / "g.csv")
    assert (g["status"] == "ok").all()
    for x, y in g[["x", "y"]].to_numpy():
        assert poly.contains(shapely.Point(x, y)), (x, y)
    axis = cam.optical_axis[:2] / np.linalg.norm(cam.optical_axis[:2])
    behind = cam.position[:2] - 10.0 * axis
    assert not poly.contains(shapely.Point(*behind))
    assert not poly.contains(shapely.Point(*cam.position[:2]))


def test_accuracy_units_feet_camera_equals_metre_camera(tmp_path: Path) -> None:
    """The same geometry in metres (EPSG:2949) and in feet (EPSG:2994): the error maps agree in metres."""
    common = {"heading_deg": 40.0, "tilt_deg": 25.0}
    m_cam = Camera.from_orientation((1280, 720), 1000.0, [245000.0, 5182600.0, 10.0], crs="EPSG:2949", **common)
    f_cam = Camera.from_orientation((1280, 720), 1000.0, [636600.0, 849200.0, 10.0 / FT], crs="EPSG:2994", **common)
    write_camera_json(tmp_path / "m.json", m_cam)
    write_camera_json(tmp_path / "f.json", f_cam)
    stats = {}
    for name in ("m", "f"):
        stdout = ok("accuracy", tmp_path / f"{name}.json", "--surface", "0", "-o", tmp_path / f"{name}.tif",
                    "--cell", "0.5", "--max-distance", "60")
        assert "no calibration covariance" in stdout
        with rasterio.open(tmp_path / f"{name}.tif") as ds:
            bands = ds.read().astype(np.float64)
            res = ds.res[0]
        vis = np.isfinite(bands[0])
        assert np.isnan(bands[3]).all()  # no covariance: no calibration part
        np.testing.assert_allclose(bands[0][vis], bands[4][vis], rtol=1e-5)
        stats[name] = (res, vis.sum(), np.median(bands[4][vis]), np.percentile(bands[4][vis], 90))
    assert stats["m"][0] == pytest.approx(0.5)
    assert stats["f"][0] == pytest.approx(0.5 / FT)
    assert stats["f"][1] == pytest.approx(stats["m"][1], rel=0.02)  # same visible area in cells of 0.25 m2
    assert stats["f"][2] == pytest.approx(stats["m"][2], rel=0.02)  # pixel noise on the ground, metres
    assert stats["f"][3] == pytest.approx(stats["m"][3], rel=0.02)
    # 1 px at 10 m height, 25 deg tilt: the image centre's ground distance is 10 / tan(25) = 21.4 m
    assert 0.005 < stats["m"][2] < 0.5


# ------------------------------------------------------------------------------------------------ 9. calibrate --gis


def test_calibrate_gis_geojson(gcps_csv: Path, scene, tmp_path: Path) -> None:
    cam_path, site = tmp_path / "cam.json", tmp_path / "site.geojson"
    stdout = ok("calibrate", gcps_csv, "--image-size", SIZE_TEXT, "-o", cam_path, "--crs", "EPSG:2949", "-q",
                "--gis", site)
    assert str(site) in stdout.replace("\n", "") or site.is_file()
    doc = json.loads(site.read_text(encoding="utf-8"))
    assert doc["type"] == "FeatureCollection" and "crs" not in doc
    layers = [f["properties"]["layer"] for f in doc["features"]]
    assert set(layers) == {"camera", "gcps", "footprint"}
    assert layers.count("camera") == 1 and layers.count("gcps") == 18 and layers.count("footprint") == 1
    cam, cam_doc = read_camera_json(cam_path), json.loads(cam_path.read_text(encoding="utf-8"))
    (camera,) = [f for f in doc["features"] if f["properties"]["layer"] == "camera"]
    lon, lat = TO_LONLAT_2949.transform(cam.position[0], cam.position[1])
    assert camera["geometry"]["coordinates"][:2] == pytest.approx([lon, lat], abs=2e-8)
    assert camera["geometry"]["coordinates"][2] == pytest.approx(cam.position[2], abs=1e-4)  # metres, 4 decimals
    assert camera["properties"]["focal_px"] == pytest.approx(cam.focal_px)
    gcps = [f for f in doc["features"] if f["properties"]["layer"] == "gcps"]
    by_id = {g["id"]: g for g in cam_doc["gcps"]}
    for f in gcps:
        p = f["properties"]
        ref = by_id[p["id"]]
        assert p["du"] == pytest.approx(ref["u_proj"] - ref["u"], abs=1e-9)
        assert p["dv"] == pytest.approx(ref["v_proj"] - ref["v"], abs=1e-9)
        assert p["error_px"] == pytest.approx(np.hypot(p["du"], p["dv"]), abs=1e-9)
        glon, glat = TO_LONLAT_2949.transform(ref["x"], ref["y"])
        assert f["geometry"]["coordinates"][:2] == pytest.approx([glon, glat], abs=2e-8)
    (foot,) = [f for f in doc["features"] if f["properties"]["layer"] == "footprint"]
    geom = shapely.geometry.shape(foot["geometry"])
    assert geom.is_valid and not geom.is_empty
    polys = list(geom.geoms) if geom.geom_type == "MultiPolygon" else [geom]
    assert all(p.exterior.is_ccw for p in polys)  # RFC 7946 right-hand rule
    lons, lats = np.array(geom.exterior.coords if geom.geom_type == "Polygon" else polys[0].exterior.coords).T[:2]
    assert (-72 < lons).all() and (lons < -70).all() and (46 < lats).all() and (lats < 47.5).all()
    # ground in front of the camera is in the footprint, the camera's own position is not
    pts = road_points_in_view(scene, stations=(10, 15, 20), offsets=(0,))
    for x, y in pts[:, :2]:
        assert geom.contains(shapely.Point(*TO_LONLAT_2949.transform(x, y)))
    assert not geom.contains(shapely.Point(lon, lat))


# ------------------------------------------------------------------------------------------------ 10. bad input


@pytest.fixture(scope="module")
def bad_files(work: Path, scene, true_cam: Path, road_dem: Path) -> dict[str, Path]:
    folder = work / "bad"
    folder.mkdir()
    files = {"cam": true_cam, "dem": road_dem}
    files["px"] = write_csv(folder / "px.csv", pd.DataFrame({"u": [960.0, 500.0], "v": [1000.0, 900.0]}))
    files["no_v"] = write_csv(folder / "no_v.csv", pd.DataFrame({"u": [960.0], "vv": [1000.0]}))
    (folder / "abc.csv").write_text("u,v\n960,1000\nabc,900\n", encoding="utf-8")
    files["abc"] = folder / "abc.csv"
    files["world_no_z"] = write_csv(folder / "w.csv", pd.DataFrame({"x": [245000.0], "y": [5182600.0]}))
    files["world"] = write_csv(folder / "world.csv", pd.DataFrame({"x": [245000.0], "y": [5182600.0], "z": [90.0]}))
    z, transform = dem_grid(scene)
    write_geotiff(folder / "utm.tif", z[None, ::20, ::20], transform @ Affine.scale(20), "EPSG:32610")
    files["utm_dem"] = folder / "utm.tif"
    write_geotiff(folder / "far.tif", np.full((1, 10, 10), 90.0), transform @ Affine.translation(0, -50000),
                  "EPSG:2949")
    files["far_dem"] = folder / "far.tif"
    write_geotiff(folder / "lonlat.tif", np.full((1, 4, 4), 90.0), Affine(1e-4, 0, -71.3, 0, -1e-4, 46.8),
                  "EPSG:4326")
    files["lonlat_dem"] = folder / "lonlat.tif"
    (folder / "garbage.tif").write_text("not a raster\n", encoding="utf-8")
    files["garbage_tif"] = folder / "garbage.tif"
    (folder / "garbage.laz").write_text("not a point cloud\n", encoding="utf-8")
    files["garbage_laz"] = folder / "garbage.laz"
    (folder / "cam_bad.json").write_text("{not json", encoding="utf-8")
    files["cam_bad"] = folder / "cam_bad.json"
    nocrs = scene.camera.replace(crs=None)
    write_camera_json(folder / "cam_nocrs.json", nocrs)
    files["cam_nocrs"] = folder / "cam_nocrs.json"
    files["gcps"] = write_csv(folder / "g.csv", pd.DataFrame({"id": ["a"], "x": [636600.0], "y": [849200.0]}))
    return files


BAD = {
    # name: (argv with {key} placeholders for bad_files / OUT, word in the message)
    "missing camera": (["georef", "{folder}/nocam.json", "{px}", "--surface", "90", "-o", "{OUT}.csv"],
                       "camera file not found"),
    "camera not JSON": (["georef", "{cam_bad}", "{px}", "--surface", "90", "-o", "{OUT}.csv"], "not valid JSON"),
    "missing pixels": (["georef", "{cam}", "{folder}/nopx.csv", "--surface", "90", "-o", "{OUT}.csv"],
                       "pixels file not found"),
    "pixels without v": (["georef", "{cam}", "{no_v}", "--surface", "90", "-o", "{OUT}.csv"], "missing column(s) v"),
    "non-numeric u": (["georef", "{cam}", "{abc}", "--surface", "90", "-o", "{OUT}.csv"],
                      "row 3: column u = 'abc' is not a number"),
    "surface nonsense": (["georef", "{cam}", "{px}", "--surface", "nonsense", "-o", "{OUT}.csv"],
                         "'nonsense' is not a number"),
    "surface missing.tif": (["georef", "{cam}", "{px}", "--surface", "{folder}/missing.tif", "-o", "{OUT}.csv"],
                            "does not exist"),
    "surface garbage.tif": (["georef", "{cam}", "{px}", "--surface", "{garbage_tif}", "-o", "{OUT}.csv"],
                            "not a raster"),
    "surface garbage.laz": (["georef", "{cam}", "{px}", "--surface", "{garbage_laz}", "-o", "{OUT}.csv"],
                            "not a LAS/LAZ file"),
    "surface unknown type": (["georef", "{cam}", "{px}", "--surface", "{no_v}", "-o", "{OUT}.csv"],
                             "unknown surface type '.csv'"),
    "DEM in another CRS": (["georef", "{cam}", "{px}", "--surface", "{utm_dem}", "-o", "{OUT}.csv"],
                           "differs from the camera's"),
    "DEM in lon/lat": (["georef", "{cam}", "{px}", "--surface", "{lonlat_dem}", "-o", "{OUT}.csv"], "geographic"),
    "plane without GCPs": (["georef", "{cam}", "{px}", "--surface", "plane", "-o", "{OUT}.csv"],
                           "--surface plane needs the GCPs"),
    "resolution 0": (["georef", "{cam}", "{px}", "--surface", "{dem}", "-o", "{OUT}.csv", "--resolution", "0"],
                     "--resolution"),
    "output .xyz": (["georef", "{cam}", "{px}", "--surface", "90", "-o", "{OUT}.xyz"], "unknown output format"),
    "gpkg without CRS": (["georef", "{cam_nocrs}", "{px}", "--surface", "90", "-o", "{OUT}.gpkg"], "needs a CRS"),
    "project without z": (["project", "{cam}", "{world_no_z}", "-o", "{OUT}.csv"], "missing column(s) z"),
    "project surface nonsense": (["project", "{cam}", "{world}", "-o", "{OUT}.csv", "--surface", "nonsense"],
                                 "'nonsense' is not a number"),
    "dem resolution 0": (["dem", str(AUTZEN), "-o", "{OUT}.tif", "--resolution", "0"], "--resolution"),
    "dem missing cloud": (["dem", "{folder}/none.laz", "-o", "{OUT}.tif"], "does not exist"),
    "dem garbage cloud": (["dem", "{garbage_laz}", "-o", "{OUT}.tif"], "not a LAS/LAZ file"),
    "gcp-z cloud and dem": (["gcp-z", "{gcps}", "--cloud", str(AUTZEN), "--dem", "{dem}", "-o", "{OUT}.csv"],
                            "exactly one"),
    "gcp-z neither": (["gcp-z", "{gcps}", "-o", "{OUT}.csv"], "exactly one"),
    "gcp-z radius 0": (["gcp-z", "{gcps}", "--cloud", str(AUTZEN), "-o", "{OUT}.csv", "--radius", "0"], "--radius"),
    "gcp-z without y": (["gcp-z", "{no_v}", "--cloud", str(AUTZEN), "-o", "{OUT}.csv"], "missing column(s) x, y"),
    "accuracy png": (["accuracy", "{cam}", "--surface", "{dem}", "-o", "{OUT}.png"], "name it .tif"),
    "accuracy no CRS": (["accuracy", "{cam_nocrs}", "--surface", "90", "-o", "{OUT}.tif"], "has no CRS"),
    "accuracy sigma -1": (["accuracy", "{cam}", "--surface", "{dem}", "-o", "{OUT}.tif", "--pixel-sigma", "-1"],
                          "--pixel-sigma"),
    "accuracy cell 0": (["accuracy", "{cam}", "--surface", "{dem}", "-o", "{OUT}.tif", "--cell", "0"], "--cell"),
    "accuracy sees no ground": (["accuracy", "{cam}", "--surface", "{far_dem}", "-o", "{OUT}.tif"], "sees no ground"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_exits_2_one_line_nothing_written(case: str, bad_files: dict[str, Path], tmp_path: Path) -> None:
    argv, word = BAD[case]
    out_stem = tmp_path / "out" / "result"
    subst = {k: str(v) for k, v in bad_files.items()} | {"folder": str(bad_files["px"].parent), "OUT": str(out_stem)}
    args = [a.format(**subst) for a in argv]
    outputs = [Path(a) for a in args if a.startswith(str(out_stem))]
    assert len(outputs) == 1
    (tmp_path / "out").mkdir()
    code, stdout, stderr = invoke(*args)
    assert_bad_input(code, stdout, stderr, outputs, word)


def test_failed_write_keeps_an_existing_output(true_cam: Path, bad_files: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "keep.csv"
    out.write_text("old\n", encoding="utf-8")
    code, _stdout, stderr = invoke("georef", true_cam, bad_files["no_v"], "--surface", "90", "-o", out)
    assert code == 2, stderr
    assert out.read_text(encoding="utf-8") == "old\n"
    assert temp_leftovers(tmp_path) == []


def test_excel_csv_with_bom_and_upper_case_columns(true_cam: Path, tmp_path: Path) -> None:
    px = tmp_path / "excel.csv"
    px.write_text("U, V ,Label\n960,1000,a\n", encoding="utf-8-sig")
    ok("georef", true_cam, px, "--surface", "90", "-o", tmp_path / "o.csv")
    res = pd.read_csv(tmp_path / "o.csv")
    assert res["status"].tolist() == ["ok"] and res["Label"].tolist() == ["a"]
    assert res["z"].iloc[0] == pytest.approx(90.0)


# ------------------------------------------------------------------------------------------------ fixed bugs


@pytest.mark.parametrize("value", ["nan", "inf"])
def test_surface_not_finite_is_bad_input(value: str, true_cam: Path, bad_files: dict[str, Path],
                                         tmp_path: Path) -> None:
    out = tmp_path / "o.csv"
    code, stdout, stderr = invoke("georef", true_cam, bad_files["px"], "--surface", value, "-o", out)
    assert_bad_input(code, stdout, stderr, [out], value)


def test_height_not_finite_is_bad_input(true_cam: Path, bad_files: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "o.csv"
    code, stdout, stderr = invoke("georef", true_cam, bad_files["px"], "--surface", "90", "-o", out,
                                  "--height", "nan")
    assert_bad_input(code, stdout, stderr, [out], "--height")


def test_accuracy_bad_gis_suffix_writes_nothing(cal_cam: Path, road_dem: Path, tmp_path: Path) -> None:
    out, site = tmp_path / "acc.tif", tmp_path / "site.shp"
    code, stdout, stderr = invoke("accuracy", cal_cam, "--surface", road_dem, "-o", out, "--gis", site,
                                  "--cell", "4")
    assert_bad_input(code, stdout, stderr, [out, site], ".shp")


def test_calibrate_bad_gis_suffix_writes_nothing(gcps_csv: Path, tmp_path: Path) -> None:
    out, site = tmp_path / "cam.json", tmp_path / "site.shp"
    code, stdout, stderr = invoke("calibrate", gcps_csv, "--image-size", SIZE_TEXT, "-o", out, "--crs", "EPSG:2949",
                                  "-q", "--gis", site)
    assert_bad_input(code, stdout, stderr, [out, site], ".shp")


def test_project_to_gpkg_does_not_blame_the_camera_crs(true_cam: Path, georef_true_dem, tmp_path: Path) -> None:
    out = tmp_path / "p.gpkg"
    code, _stdout, stderr = invoke("project", true_cam, georef_true_dem[0], "-o", out)
    assert code == 0, stderr
    import geopandas as gpd

    assert gpd.read_file(out).crs.to_epsg() == 2949


@pytest.mark.slow
def test_gcp_z_to_gpkg_uses_the_data_crs_and_rejects_a_non_numeric_z(autzen_gcps, tmp_path: Path) -> None:
    path, _ = autzen_gcps
    out = tmp_path / "g.gpkg"
    ok("gcp-z", path, "--cloud", AUTZEN, "--crs", "EPSG:2994", "--radius", "2", "-o", out)
    import geopandas as gpd

    assert gpd.read_file(out).crs.to_epsg() == 2994
    bad = tmp_path / "bad.csv"
    bad.write_text("id,x,y,z\nA,636600,849200,91.2m\n")
    code, stdout, stderr = invoke("gcp-z", bad, "--cloud", AUTZEN, "--crs", "EPSG:2994", "-o", tmp_path / "b.csv")
    assert_bad_input(code, stdout, stderr, [tmp_path / "b.csv"], "91.2m")


def test_dem_output_must_be_a_geotiff(tmp_path: Path) -> None:
    out = tmp_path / "dem.png"
    code, stdout, stderr = invoke("dem", AUTZEN, "--crs", "EPSG:2994", "-o", out)
    assert_bad_input(code, stdout, stderr, [out], ".tif")
