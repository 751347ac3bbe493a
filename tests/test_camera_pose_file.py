"""A calibrated camera imported without GCPs (issue 29, part 4): OpenCV pose files (K, dist, R or rvec, t) in a
CRS or in a local frame at a geodetic origin (traj-ext style), read into the one Camera and written back."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pyproj
import pytest

from cli_support import invoke
from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.camera.pose_file import read_pose_file, write_pose_file
from trafficgeo.errors import InputError

UTM = "EPSG:32633"
LAT0, LON0, ALT0 = 49.2, 16.6, 250.0  # Brno: 1.6 deg east of zone 33's central meridian (convergence ~1.2 deg)


def _camera(crs: str, x0: float, y0: float, z0: float) -> Camera:
    return Camera.from_orientation((1280, 720), 1100.0, (x0, y0, z0 + 30.0), 35.0, 20.0, 0.5,
                                   dist=[-0.08, 0.02, 0.0005, -0.0003, 0.0], crs=crs)


def _ground(camera: Camera, z: float) -> np.ndarray:
    """Ground points (N, 3) on Z = z that the camera sees, 40 to 300 m ahead (CRS units)."""
    u, v = np.meshgrid(np.linspace(60, 1220, 9), np.linspace(300, 700, 7))
    pts = camera.intersect_horizontal_plane(np.column_stack([u.ravel(), v.ravel()]), z)
    d = np.linalg.norm(pts[:, :2] - camera.position[:2], axis=1)
    return pts[np.isfinite(d) & (d > 40) & (d < 300)]


@pytest.mark.parametrize(("rotation", "suffix"), [("rvec", ".yml"), ("R", ".yml"), ("rvec", ".json")])
def test_a_camera_written_as_a_pose_file_reads_back_projecting_the_same_pixels(tmp_path: Path, rotation: str,
                                                                               suffix: str) -> None:
    cam = _camera("EPSG:2949", 245000.0, 5182600.0, 60.0)
    path = tmp_path / f"pose{suffix}"
    write_pose_file(path, cam, rotation=rotation)
    back = read_pose_file(path)
    assert back.crs == cam.crs and back.image_size == cam.image_size
    world = _ground(cam, 60.0)
    assert len(world) > 20
    # 17 significant digits are written; t of ~5e6 m carries ~1e-9 m of rounding: far below 1e-6 px
    np.testing.assert_allclose(back.project(world), cam.project(world), atol=1e-6)
    np.testing.assert_allclose(back.position, cam.position, atol=1e-6)  # m


def _topocentric(points: np.ndarray, frame: str) -> np.ndarray:
    """UTM 33N points (E, N, ellipsoidal h) -> the local frame at the origin, by PROJ's own topocentric pipeline
    (the truth; independent of trafficgeo's ENU basis)."""
    pipe = pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +inv +proj=utm +zone=33 +ellps=WGS84 +step +proj=cart +ellps=WGS84 "
        f"+step +proj=topocentric +ellps=WGS84 +lat_0={LAT0} +lon_0={LON0} +h_0={ALT0}")
    e, n, u = pipe.transform(points[:, 0], points[:, 1], points[:, 2])
    enu = np.column_stack([e, n, u])
    return enu if frame == "enu" else np.column_stack([n, e, -u])


@pytest.mark.parametrize("frame", ["enu", "ned"])
def test_a_pose_at_a_geodetic_origin_lands_where_pyproj_puts_it(tmp_path: Path, frame: str) -> None:
    x0, y0 = pyproj.Transformer.from_crs("EPSG:4326", UTM, always_xy=True).transform(LON0 + 0.001, LAT0 + 0.0005)
    truth = _camera(UTM, x0, y0, ALT0 - 2.0)
    world = _ground(truth, ALT0 - 2.0)
    pixels = truth.project(world)
    # what a local-frame calibration (traj-ext, solvePnP on local points) stores: the pose in the local frame
    local = _topocentric(world, frame)
    ok, rvec, tvec = cv2.solvePnP(local, pixels, truth.K, truth.dist, flags=cv2.SOLVEPNP_SQPNP)
    assert ok
    ok, rvec, tvec = cv2.solvePnP(local, pixels, truth.K, truth.dist, rvec, tvec, True, cv2.SOLVEPNP_ITERATIVE)
    fs = cv2.FileStorage(str(tmp_path / "pose.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("camera_matrix", truth.K)
    fs.write("dist_coeffs", truth.dist.reshape(5, 1))
    fs.write("rot_CF_F", cv2.Rodrigues(rvec)[0])  # traj-ext's names
    fs.write("trans_CF_F", tvec)
    fs.write("origin_lat", LAT0)
    fs.write("origin_lon", LON0)
    fs.write("origin_alt", ALT0)
    fs.write("frame", frame)
    fs.release()
    cam = read_pose_file(tmp_path / "pose.yml", crs=UTM)
    # A rigid camera cannot follow the projection's scale factor k (module docstring): f |k - 1| px at most
    k = pyproj.Proj(UTM).get_factors(LON0, LAT0).meridional_scale
    tol_px = truth.focal_px * abs(k - 1) + 0.05
    err = np.linalg.norm(cam.project(world) - pixels, axis=1)
    assert err.max() < tol_px, (err.max(), tol_px)
    assert np.linalg.norm(cam.position - truth.position) < 0.05  # m: exact up to the solvePnP fit
    assert cam.crs == pyproj.CRS(UTM)
    # without the grid convergence (the local axes taken as the CRS's) the pixels would be far off
    naive = Camera(image_size=cam.image_size, K=cam.K, dist=cam.dist, position=cam.position, crs=UTM,
                   R=cv2.Rodrigues(rvec)[0] @ (np.eye(3) if frame == "enu" else
                                             np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])))
    assert np.linalg.norm(naive.project(world) - pixels, axis=1).max() > 10 * tol_px


def _pose_text(**keys: str) -> str:
    base = {"image_width": "1280", "image_height": "720",
            "camera_matrix": "[1000., 0., 639.5, 0., 1000., 359.5, 0., 0., 1.]",
            "rvec": "[1.2, 0.1, 0.2]", "t": "[1., 2., 30.]"}
    base.update(keys)
    return "%YAML:1.0\n---\n" + "".join(f"{k}: {v}\n" for k, v in base.items() if v != "")


@pytest.mark.parametrize(("keys", "kwargs", "needle"), [
    ({"rvec": ""}, {}, "no rotation"),
    ({"t": ""}, {}, "no translation"),
    ({"t": "[1., 2.]"}, {}, "key 't': expected 3"),
    ({"rvec": "", "R": "[1., 0., 0., 0., 2., 0., 0., 0., 1.]"}, {}, "not a rotation matrix"),
    ({"image_width": "", "image_height": ""}, {}, "no image size"),
    ({"origin": "[49.2, 16.6, 250.]"}, {}, "needs a projected target CRS"),
    ({"origin": "[49.2, 16.6, 250.]"}, {"crs": "EPSG:4326"}, "needs a projected target CRS"),
    ({"origin": "[249.2, 16.6, 250.]"}, {"crs": UTM}, "latitude must be within"),
    ({"frame": "xyz", "origin": "[49.2, 16.6, 250.]"}, {"crs": UTM}, "'enu' (east-north-up) or 'ned'"),
    ({"camera_matrix": ""}, {}, "no camera matrix"),
    ({"rvec": "[1.2, .nan, 0.2]"}, {}, "not finite numbers"),
    ({"origin": "[49.2, 200., 250.]"}, {"crs": UTM}, "longitude within +/-180"),
    ({}, {"crs": "EPSG:4326"}, "must be a projected CRS"),
])
def test_bad_pose_files_raise_one_line(tmp_path: Path, keys: dict, kwargs: dict, needle: str) -> None:
    path = tmp_path / "pose.yml"
    path.write_text(_pose_text(**keys))
    with pytest.raises(InputError) as info:
        read_pose_file(path, **kwargs)
    text = str(info.value)
    assert needle in text and "\n" not in text and str(path) in text


def test_import_camera_writes_the_camera_json(tmp_path: Path) -> None:
    cam = _camera("EPSG:2949", 245000.0, 5182600.0, 60.0)
    write_pose_file(tmp_path / "pose.yml", cam)
    code, _stdout, stderr = invoke("import-camera", tmp_path / "pose.yml", "-o", tmp_path / "camera.json")
    assert code == 0, stderr
    back = read_camera_json(tmp_path / "camera.json")
    world = _ground(cam, 60.0)
    np.testing.assert_allclose(back.project(world), cam.project(world), atol=1e-6)
    assert json.loads((tmp_path / "camera.json").read_text())["crs"] == "EPSG:2949"
    code, _out, stderr = invoke("import-camera", tmp_path / "pose.yml", "-o", tmp_path / "c2.json",
                                "--origin", "49.2,16.6")
    assert code == 2 and "--origin" in stderr and "lat,lon,alt" in stderr
    code, _out, stderr = invoke("import-camera", tmp_path / "pose.yml", "-o", tmp_path / "pose.yml")
    assert code == 2 and "(.json)" in stderr
    assert (tmp_path / "pose.yml").read_text().startswith("%YAML")  # the pose file is left as it was


def test_a_hand_written_json_pose_at_a_geodetic_origin(tmp_path: Path) -> None:
    # a camera 30 m south of the origin, 10 m up, looking level towards true north (the local frame's y axis)
    doc = {"image_width": 1280, "image_height": 720, "K": [[1000, 0, 639.5], [0, 1000, 359.5], [0, 0, 1]],
           "dist": [-0.1, 0.01, 0, 0], "R": [[1, 0, 0], [0, 0, -1], [0, 1, 0]], "t": [0, 10, 30],
           "origin": [LAT0, LON0, ALT0], "frame": "enu", "crs": UTM}
    (tmp_path / "pose.json").write_text(json.dumps(doc))
    cam = read_pose_file(tmp_path / "pose.json")
    np.testing.assert_array_equal(cam.dist, [-0.1, 0.01, 0.0, 0.0, 0.0])  # 'dist', 4 values: k3 = 0
    back = pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +inv +proj=topocentric +ellps=WGS84 "
        f"+lat_0={LAT0} +lon_0={LON0} +h_0={ALT0} +step +inv +proj=cart +ellps=WGS84 "
        "+step +proj=utm +zone=33 +ellps=WGS84")
    truth = np.array(back.transform(0.0, -30.0, 10.0))
    np.testing.assert_allclose(cam.position, truth, atol=1e-6)  # m: the centre is transformed exactly
    # it looks at true north, which in the grid is the meridian convergence away from grid north
    conv = pyproj.Proj(UTM).get_factors(LON0, LAT0).meridian_convergence  # deg, grid north -> true north
    o = cam.orientation
    assert abs(((o.heading_deg + conv + 180) % 360) - 180) < 0.01 and abs(o.tilt_deg) < 0.01


def test_an_origin_outside_the_crs_area_is_refused() -> None:
    """Issue 43: a swapped lat/lon origin put the camera 11,000 km away with exit 0. An origin outside the target
    CRS's area of use (2 degrees of margin) is refused, and a swap is suggested when the numbers fit the other way."""
    from trafficgeo.camera.pose_file import camera_from_pose

    K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
    cam = camera_from_pose((640, 480), K, np.zeros(5), np.eye(3), [0.0, 0.0, 10.0], crs="EPSG:32633",
                           origin=(52.5, 13.4, 40.0))  # Berlin, in UTM 33N
    assert 3e5 < cam.position[0] < 5e5 and 5.8e6 < cam.position[1] < 5.9e6
    with pytest.raises(InputError, match="swapped"):
        camera_from_pose((640, 480), K, np.zeros(5), np.eye(3), [0.0, 0.0, 10.0], crs="EPSG:32633",
                         origin=(13.4, 52.5, 40.0))
    with pytest.raises(InputError, match="outside the area of"):
        camera_from_pose((640, 480), K, np.zeros(5), np.eye(3), [0.0, 0.0, 10.0], crs="EPSG:32633",
                         origin=(-33.9, 151.2, 40.0))  # Sydney
