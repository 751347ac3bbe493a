"""The camera model: conventions, projection, undistortion accuracy, precision at large coordinates, JSON io."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from trafficgeo.camera import Camera, read_camera_json, rotation_from_orientation, write_camera_json
from trafficgeo.camera.distortion import distort_normalized, max_monotonic_radius, undistort_normalized
from trafficgeo.errors import InputError

ORIGIN = np.array([245000.0, 5182600.0, 90.0])


def phone_camera(**kw) -> Camera:
    args = dict(image_size=(3840, 2160), focal_px=2800.0, position=ORIGIN + [0, 0, 8.0], heading_deg=30.0,
                tilt_deg=15.0, roll_deg=1.0, dist=[-0.25, 0.08, 0.001, -0.0005, -0.01], crs="EPSG:2949")
    args.update(kw)
    return Camera.from_orientation(args.pop("image_size"), args.pop("focal_px"), args.pop("position"),
                                   args.pop("heading_deg"), args.pop("tilt_deg"), args.pop("roll_deg"), **args)


def frame_grid(w: int, h: int, n: int = 25) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(-0.5, w - 0.5, n), np.linspace(-0.5, h - 0.5, n))
    return np.stack([u.ravel(), v.ravel()], axis=1)


# ------------------------------------------------------------------ conventions
def test_heading_zero_looks_north_and_right_is_east():
    R = rotation_from_orientation(0.0, 0.0, 0.0)
    np.testing.assert_allclose(R[2], [0, 1, 0], atol=1e-15)  # optical axis north
    np.testing.assert_allclose(R[0], [1, 0, 0], atol=1e-15)  # image right = east
    np.testing.assert_allclose(R[1], [0, 0, -1], atol=1e-15)  # image down = world down


def test_heading_90_looks_east_and_tilt_looks_down():
    cam = Camera.from_orientation((100, 100), 50.0, [0, 0, 10], 90.0, 30.0)
    np.testing.assert_allclose(cam.optical_axis, [np.cos(np.radians(30)), 0, -np.sin(np.radians(30))], atol=1e-12)
    # A point straight ahead along the optical axis lands on the principal point.
    uv = cam.project(cam.position + 20 * cam.optical_axis)
    np.testing.assert_allclose(uv[0], cam.principal_point, atol=1e-9)
    # A point below the optical axis appears lower in the image (v larger).
    assert cam.project(cam.position + 20 * cam.optical_axis + [0, 0, -1])[0, 1] > cam.principal_point[1]
    # A point to the right of the view (south when looking east) appears at larger u.
    assert cam.project(cam.position + 20 * cam.optical_axis + [0, -1, 0])[0, 0] > cam.principal_point[0]


def test_positive_roll_dips_image_right_below_horizon():
    cam = Camera.from_orientation((100, 100), 50.0, [0, 0, 10], 0.0, 0.0, 10.0)
    assert cam.R[0][2] < 0  # the image's right axis points down in the world


@settings(max_examples=60, deadline=None)
@given(h=st.floats(0, 359.99), t=st.floats(-80, 89), r=st.floats(-60, 60))
def test_orientation_round_trip(h, t, r):
    cam = Camera.from_orientation((640, 480), 500.0, [0, 0, 0], h, t, r)
    o = cam.orientation
    assert abs((o.heading_deg - h + 180) % 360 - 180) < 1e-7
    assert o.tilt_deg == pytest.approx(t, abs=1e-7)
    assert o.roll_deg == pytest.approx(r, abs=1e-7)
    np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(cam.R) == pytest.approx(1.0)


def test_pixel_centre_convention_principal_point_default():
    cam = Camera.from_orientation((1920, 1080), 1000.0, [0, 0, 0], 0, 0)
    assert cam.principal_point == (959.5, 539.5)
    assert cam.in_image(np.array([[-0.5, -0.5], [1919.5, 1079.5]])).all()
    assert not cam.in_image(np.array([[-0.6, 0.0], [0.0, 1079.6]])).any()


# ------------------------------------------------------------------ projection
def test_projection_matches_opencv_project_points():
    cam = phone_camera()
    rng = np.random.default_rng(0)
    pts = cam.position + rng.uniform([-40, 5, -10], [40, 100, -6], (2000, 3))
    uv = cam.project(pts)
    inside = cam.in_image(uv)
    assert inside.sum() > 100
    rvec, tvec = cam.rvec_tvec(origin=cam.position)
    uv_cv, _ = cv2.projectPoints(pts - cam.position, rvec, tvec, cam.K, cam.dist)
    np.testing.assert_allclose(uv[inside], uv_cv[inside, 0], atol=1e-8)


def test_points_behind_the_camera_are_nan():
    cam = phone_camera()
    behind = cam.position - 10 * cam.optical_axis
    assert np.isnan(cam.project(behind)).all()


def test_large_coordinates_keep_float64_precision():
    """At 5e6 m a 1 mm move still moves the projection by the expected amount."""
    cam = phone_camera(position=np.array([4999000.0, 4999000.0, 120.0]))
    p = cam.position + 30 * cam.optical_axis
    d = cam.project(p + [0.001, 0, 0]) - cam.project(p)
    local = Camera.from_orientation((3840, 2160), 2800.0, [0, 0, 0], 30.0, 15.0, 1.0,
                                    dist=cam.dist)
    d_local = local.project(30 * local.optical_axis + [0.001, 0, 0]) - local.project(30 * local.optical_axis)
    np.testing.assert_allclose(d, d_local, rtol=1e-6)


# ------------------------------------------------------------------ undistortion
def test_undistortion_is_exact_over_the_whole_frame_including_corners():
    cam = phone_camera()
    grid = frame_grid(*cam.image_size)
    xn = cam.pixels_to_normalized(grid)
    assert np.all(np.isfinite(xn))
    back = cam.normalized_to_pixels(distort_normalized(xn, cam.dist))
    assert np.max(np.abs(back - grid)) < 1e-3


def test_opencv_default_undistort_points_is_not_accurate_enough():
    """The reason we do not use cv2.undistortPoints' default 5 iterations (README claim: 0.44 px)."""
    cam = phone_camera()
    corners = np.array([[-0.5, -0.5], [3839.5, -0.5], [-0.5, 2159.5], [3839.5, 2159.5]])
    xcv = cv2.undistortPoints(corners[:, None, :], cam.K, cam.dist)[:, 0]
    err_cv = np.max(np.abs(cam.normalized_to_pixels(distort_normalized(xcv, cam.dist)) - corners))
    assert err_cv > 0.1
    assert err_cv == pytest.approx(0.44, abs=0.01)


@settings(max_examples=40, deadline=None)
@example(k1=0.1875, k2=-0.0625, p1=0.0, p2=0.0, f=700.0)  # pincushion: Newton from xd overshot into the fold
@given(k1=st.floats(-0.35, 0.2), k2=st.floats(-0.1, 0.1), p1=st.floats(-0.003, 0.003),
       p2=st.floats(-0.003, 0.003), f=st.floats(700, 4000))
def test_project_then_ray_round_trip(k1, k2, p1, p2, f):
    """project -> rays -> intersect: a world point comes back onto itself (where the lens model is invertible)."""
    dist = np.array([k1, k2, p1, p2, 0.0])
    cam = Camera.from_orientation((1920, 1080), f, ORIGIN + [0, 0, 10], 45.0, 20.0, 0.5, dist=dist)
    r_max = max_monotonic_radius(dist)
    rng = np.random.default_rng(1)
    pts = cam.position + rng.uniform([-30, -30, -10.5], [30, 30, -9.5], (300, 3))
    xc = cam.world_to_camera(pts)
    ok = (xc[:, 2] > 1) & (np.hypot(xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2]) < 0.95 * r_max)
    ok[ok] &= cam.in_image(cam.project(pts[ok]), margin=-200)  # pixels come from the frame (plus a margin)
    uv = cam.project(pts[ok])
    back = cam.intersect_horizontal_plane(uv, pts[ok, 2])
    np.testing.assert_allclose(back, pts[ok], atol=1e-6)


def test_undistort_marks_folded_region_nan():
    dist = np.array([-0.6, 0.0, 0.0, 0.0, 0.0])  # folds back at r = 1/sqrt(1.8) ~ 0.745
    r_fold = max_monotonic_radius(dist)
    assert r_fold == pytest.approx(1 / np.sqrt(1.8), abs=2e-3)
    too_far = np.array([[0.6, 0.0]])  # distorted radius above the fold's maximum (0.497)
    assert np.isnan(undistort_normalized(too_far, dist)).all()


# ------------------------------------------------------------------ JSON
def test_camera_json_round_trip_is_exact(tmp_path):
    cam = phone_camera()
    path = tmp_path / "camera.json"
    write_camera_json(path, cam, {"stats": {"rmse_px": 1.0}})
    back = read_camera_json(path)
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_array_equal(back.R, cam.R)
    np.testing.assert_array_equal(back.position, cam.position)
    np.testing.assert_array_equal(back.dist, cam.dist)
    assert back.crs == "EPSG:2949" and back.image_size == (3840, 2160)
    doc = json.loads(path.read_text())
    assert doc["format"] == "trafficgeo.camera/1" and doc["stats"]["rmse_px"] == 1.0
    # rvec/tvec are OpenCV's: they reproduce the projection of absolute coordinates.
    pts = cam.position + 30 * cam.optical_axis + np.array([[1.0, 2.0, -3.0]])
    uv_cv, _ = cv2.projectPoints(pts, np.array(doc["rvec"]), np.array(doc["tvec"]), cam.K, cam.dist)
    np.testing.assert_allclose(uv_cv[:, 0], cam.project(pts), atol=1e-4)
    assert doc["orientation"]["heading_deg"] == pytest.approx(30.0)


@pytest.mark.parametrize("content, needle", [
    ("not json", "not valid JSON"),
    ('{"image_size": [10, 10], "K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}',
     "position"),
    ('{"image_size": [10, 10], "K": [[1, 0], [0, 1]], "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "position": [0, 0, 0]}',
     "shape"),
    ('{"image_size": [10, 10], "K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "R": [[2, 0, 0], [0, 1, 0], [0, 0, 1]], '
     '"position": [0, 0, 0]}', "rotation"),
    ('{"format": "other/9", "image_size": [10, 10]}', "format"),
])
def test_bad_camera_json_is_refused_with_a_clear_message(tmp_path, content, needle):
    path = tmp_path / "c.json"
    path.write_text(content)
    with pytest.raises(InputError, match=needle):
        read_camera_json(path)


def test_missing_camera_json(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_camera_json(tmp_path / "nope.json")
