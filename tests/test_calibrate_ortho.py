"""Zero-click calibration (issue 40): ``calibrate_from_ortho`` and ``trafficgeo calibrate-ortho`` against the truth
of generated registration scenes whose orthophoto differs from the frame as real ones do (another season's grass,
shadows of trees and buildings, cars of its own, another gain and blur), with the camera's position given 5 m off
and the focal length unknown; and a clear refusal, with nothing written, for each way it cannot work."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cli_support import invoke
from trafficgeo.calibration.gcp_table import GCPTable
from trafficgeo.camera.calibrated import CalibratedCamera
from trafficgeo.geo.raster import write_geotiff
from trafficgeo.registration.from_ortho import OrthoCalibration, OrthoPoseOptions, calibrate_from_ortho
from trafficgeo.synth.registration_scene import (
    RegistrationScene,
    RegistrationSceneOptions,
    ground_errors_m,
    make_registration_scene,
)

pytestmark = pytest.mark.slow

ANOTHER_DAY = dict(ortho_season=0.5, ortho_shadows=6, ortho_vehicles=10)


def _near(scene: RegistrationScene, metres: float = 5.0, bearing_deg: float = 130.0) -> tuple[float, float]:
    """The camera's position as a user clicks it on the map: ``metres`` off towards ``bearing_deg``."""
    b = np.radians(bearing_deg)
    p = scene.camera.position[:2] + metres * np.array([np.sin(b), np.cos(b)])
    return float(p[0]), float(p[1])


@pytest.fixture(scope="module")
def scene() -> RegistrationScene:
    """A 960x540 camera 16 m up, its orthophoto flown on another day (seed 11: not one the method was tuned on)."""
    return make_registration_scene(RegistrationSceneOptions(seed=11, image_size=(960, 540), camera_height=16.0,
                                                            supersample=2, **ANOTHER_DAY))


@pytest.fixture(scope="module")
def found(scene: RegistrationScene) -> OrthoCalibration:
    checks = scene.gcps
    return calibrate_from_ortho(scene.frame, scene.ortho, scene.surface, _near(scene), checks=GCPTable(
        ids=checks.ids, world=checks.world, pixels=checks.pixels, roles=("check",) * checks.n,
        sigma_px=checks.sigma_px, crs=checks.crs, source="clicks", lines=checks.lines))


def test_the_camera_is_found_from_the_orthophoto_alone(scene: RegistrationScene, found: OrthoCalibration) -> None:
    assert found.accepted, found.reason
    cam = found.camera
    truth = scene.camera
    e = ground_errors_m(cam, truth, scene.truth_points)  # on the road, 20-110 m from the camera
    assert np.median(e) < 0.05 and e.max() < 0.25, (np.median(e), e.max())
    assert np.linalg.norm(cam.position - truth.position) < 0.15
    assert abs(cam.focal_px / truth.focal_px - 1.0) < 0.01
    o, t = cam.orientation, truth.orientation
    assert abs((o.heading_deg - t.heading_deg + 180.0) % 360.0 - 180.0) < 0.1 and abs(o.tilt_deg - t.tilt_deg) < 0.1
    assert 4.0 < found.offset_m < 6.0  # the position was given 5 m off
    assert int(found.kept.sum()) >= 100
    # the user's clicks (3 px noise), never fitted, are checked: about their own noise on the ground
    assert found.check_errors_m.shape == (scene.gcps.n,) and np.nanmedian(found.check_errors_m) < 1.0


def test_the_views_rank_the_right_focal_and_tilt_first(scene: RegistrationScene, found: OrthoCalibration) -> None:
    best = found.views[0]
    t = scene.camera.orientation.tilt_deg
    assert abs(best.tilt_deg - t) <= 6.0 and 0.6 < best.focal_px / scene.camera.focal_px < 1.6
    assert abs(best.height_m - 16.0) < 6.0 and best.agreeing >= 8


@pytest.mark.parametrize(("case", "words"), [
    ("winter", "matches the orthophoto in too few places"),
    ("wrong-pole", "or the position is not the camera's"),
    ("no-texture", "matches the orthophoto in too few places"),
    ("elsewhere", "matches the orthophoto in too few places"),
])
def test_each_failure_is_refused_with_its_reason(scene: RegistrationScene, case: str, words: str) -> None:
    frame, ortho, near = scene.frame, scene.ortho, _near(scene)
    if case == "winter":
        ortho = make_registration_scene(RegistrationSceneOptions(seed=11, image_size=(960, 540), camera_height=16.0,
                                                                 supersample=2, ortho_snow=True)).ortho
    elif case == "wrong-pole":
        near = _near(scene, 60.0, 300.0)
    elif case == "no-texture":
        frame = np.full_like(scene.frame, 120)
    else:
        ortho = make_registration_scene(RegistrationSceneOptions(seed=11, image_size=(960, 540), camera_height=16.0,
                                                                 supersample=2, wrong_place=True)).ortho
    result = calibrate_from_ortho(frame, ortho, scene.surface, near)
    assert not result.accepted and result.camera is None
    assert words in result.reason, result.reason


def test_options_and_positions_are_checked(scene: RegistrationScene) -> None:
    from trafficgeo.errors import InputError

    with pytest.raises(InputError, match="focal_px"):
        OrthoPoseOptions(focal_px=-3.0)
    with pytest.raises(InputError, match="more than 150 m from the orthophoto"):
        calibrate_from_ortho(scene.frame, scene.ortho, scene.surface, (0.0, 0.0))


# ------------------------------------------------------------------------------------------------ the command
@pytest.fixture(scope="module")
def files(scene: RegistrationScene, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("calibrate_ortho")
    cv2.imwrite(str(folder / "frame.png"), scene.frame)
    o = scene.ortho
    write_geotiff(folder / "ortho.tif", o.data, o.transform, o.crs)
    s = scene.surface
    from affine import Affine

    write_geotiff(folder / "dem.tif", s.values[None], Affine(s.xres, 0.0, s.left, 0.0, -s.yres, s.top), o.crs,
                  nodata=float("nan"))
    scene.gcps.to_csv(folder / "gcps.csv")
    return folder


def test_calibrate_ortho_writes_a_camera_json_others_read(scene: RegistrationScene, files: Path,
                                                          tmp_path: Path) -> None:
    x, y = _near(scene)
    out, report = tmp_path / "camera.json", tmp_path / "auto.json"
    code, said, err = invoke("calibrate-ortho", files / "frame.png", "--ortho", files / "ortho.tif", "--surface",
                             files / "dem.tif", "--near", f"{x},{y}", "-o", out, "--checks", files / "gcps.csv",
                             "--report", report, "--gcps-out", tmp_path / "review.csv")
    assert code == 0, said + err
    assert "calibrated" in said and "check points: ground error median" in said
    cal = CalibratedCamera.read(out)
    assert cal.gcps and all(g.source == "auto" for g in cal.gcps) and len(cal.gcps) >= 100
    assert cal.stats is not None and cal.covariance is not None
    assert np.median(ground_errors_m(cal.camera, scene.camera, scene.truth_points)) < 0.05
    doc = json.loads(report.read_text(encoding="utf-8"))
    assert doc["accepted"] is True and doc["views"]["rows"] and doc["checks"]["median_m"] < 1.0
    assert (tmp_path / doc["frame"]).is_file()
    # 40 of the correspondences, spread over the frame, open in the GCP web app for review: drop some, it recalibrates
    from fastapi.testclient import TestClient

    from trafficgeo.ui.server import create_app
    from trafficgeo.ui.startup import open_session

    session, _ = open_session(frame=files / "frame.png", ortho=files / "ortho.tif", dem=files / "dem.tif",
                              gcps=tmp_path / "review.csv")
    with TestClient(create_app(session)) as client:
        pairs = client.get("/api/state").json()["pairs"]
        assert len(pairs) == 40 and all(p["id"].startswith("auto") for p in pairs)
        for p in pairs[:5]:
            assert client.delete(f"/api/pairs/{p['id']}").status_code == 200
        assert len(client.get("/api/state").json()["pairs"]) == 35
        cal = client.get("/api/calibration").json()
        assert cal["status"] == "ok" and np.median([q["error_px"] for q in cal["points"]]) < 1.0, cal
    # refine needs the user's own points to judge by, and says so
    code, said, err = invoke("refine", out, "--ortho", files / "ortho.tif", "--surface", files / "dem.tif",
                             "--frame", files / "frame.png", "-o", tmp_path / "refined.json")
    assert code == 2 and "only the automatic correspondences of 'trafficgeo calibrate-ortho'" in err, said + err


def test_calibrate_ortho_in_lon_lat(scene: RegistrationScene, files: Path, tmp_path: Path) -> None:
    from pyproj import Transformer

    x, y = _near(scene)
    lon, lat = Transformer.from_crs(scene.ortho.crs, "EPSG:4326", always_xy=True).transform(x, y)
    out = tmp_path / "camera.json"
    code, said, err = invoke("calibrate-ortho", files / "frame.png", "--ortho", files / "ortho.tif", "--surface",
                             files / "dem.tif", "--near", f"{lon:.8f},{lat:.8f}", "--near-crs", "EPSG:4326",
                             "--focal-px", f"{scene.camera.focal_px:.2f}", "-o", out)
    assert code == 0, said + err
    cam = CalibratedCamera.read(out).camera
    assert abs(cam.focal_px - scene.camera.focal_px) < 1e-6
    assert np.median(ground_errors_m(cam, scene.camera, scene.truth_points)) < 0.05


@pytest.mark.parametrize(("args", "code", "words"), [
    (["--near", "a,b"], 2, "position 'a,b' is not two numbers X,Y (lon,lat with --near-crs EPSG:4326)"),
    (["--near", "1,2"], 2, "from the orthophoto"),
    (["--near", "WRONG"], 1, "no camera"),
])
def test_calibrate_ortho_bad_input_writes_nothing(scene: RegistrationScene, files: Path, tmp_path: Path,
                                                  args: list[str], code: int, words: str) -> None:
    if args[1] == "WRONG":
        x, y = _near(scene, 60.0, 300.0)
        args = ["--near", f"{x},{y}"]
    out = tmp_path / "camera.json"
    got, said, err = invoke("calibrate-ortho", files / "frame.png", "--ortho", files / "ortho.tif", "--surface",
                            files / "dem.tif", *args, "-o", out)
    assert got == code, said + err
    assert words in said + err and "Traceback" not in said + err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_a_real_orthophoto_in_feet() -> None:
    """The real Autzen orthophoto (1 ft cells, EPSG:2994 international feet: tests/data/autzen) draped on its lidar
    surface through a camera 35 m up: real texture (a stadium's car parks, roads, trees), not an independent photo.
    The position is given 15.6 ft (4.8 m) off; offsets and heights are reported in metres."""
    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.mapping import pixels_to_world
    from trafficgeo.geo.pointcloud import cloud_to_dem, read_point_cloud
    from trafficgeo.geo.raster import read_raster
    from trafficgeo.geo.surface import DEMSurface
    from trafficgeo.synth.registration_scene import _integrated_background

    data = Path(__file__).parent / "data" / "autzen"
    ortho = read_raster(data / "autzen_ortho_trim.tif")
    dem = DEMSurface.from_raster(cloud_to_dem(read_point_cloud(data / "autzen_trim.laz", crs="EPSG:2994"), 1.0))
    ft = 0.3048
    x, y = 636450.0, 849250.0
    truth = Camera.from_orientation((960, 540), 800.0, [x, y, float(dem.elevation(x, y)) + 35.0 / ft], 100.0, 30.0,
                                    crs="EPSG:2994")
    rng = np.random.default_rng(0)
    frame = cv2.GaussianBlur(np.clip(_integrated_background(truth, dem, ortho, 2) * 0.8 + 10, 0, 255), (0, 0), 0.6)
    frame = np.clip(np.rint(frame + rng.normal(0, 2, frame.shape)), 0, 255).astype(np.uint8)[..., ::-1].copy()
    result = calibrate_from_ortho(frame, ortho, dem, (x + 12.0, y - 10.0))
    assert result.accepted, result.reason
    assert 4.5 < result.offset_m < 5.1 and "units above" in result.reason
    cam = result.camera
    u, v = np.meshgrid(np.arange(4, 960, 8), np.arange(4, 540, 8))
    g = pixels_to_world(truth, np.column_stack([u.ravel(), v.ravel()]), dem, with_lonlat=False)
    xyz = g.xyz[g.ok]
    d = np.hypot(*(xyz[:, :2] - truth.position[:2]).T) * ft
    pts = xyz[(d >= 20) & (d <= 120)]
    e = ground_errors_m(cam, truth, pts) * ft
    assert len(pts) > 1000 and np.median(e) < 0.05, np.median(e)
    assert abs(cam.focal_px - 800.0) < 8.0


def test_a_window_of_the_orthophoto_is_read(files: Path) -> None:
    """Only the part of a district's orthophoto the search can use is read: the same cells and georeferencing as a
    crop of the whole; bounds that miss it are refused in one line."""
    from trafficgeo.errors import InputError
    from trafficgeo.geo.raster import read_raster

    whole = read_raster(files / "ortho.tif")
    left, bottom = whole.bounds[:2]
    box = (left + 13.37, bottom + 21.2, left + 60.0, bottom + 70.05)
    part = read_raster(files / "ortho.tif", bounds=box)
    crop = whole.crop(box)
    assert part.data.shape == crop.data.shape and np.array_equal(part.data, crop.data)
    np.testing.assert_allclose(np.array(part.transform)[:6], np.array(crop.transform)[:6], atol=1e-9)
    with pytest.raises(InputError, match="does not cover the area asked for"):
        read_raster(files / "ortho.tif", bounds=(0.0, 0.0, 10.0, 10.0))
