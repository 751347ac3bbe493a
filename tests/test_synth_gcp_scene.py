"""Tests of the synthetic GCP scene generator (trafficgeo.synth)."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trafficgeo.synth import GCPScene, RoadSurface, make_gcp_scene

ORIGIN = np.array([245000.0, 5182600.0, 90.0])


def _scene_arrays(sc: GCPScene) -> list[np.ndarray]:
    cam = sc.camera
    return [sc.true_world, sc.true_pixels, sc.gcps.world, sc.gcps.pixels, sc.outlier, cam.K, cam.R, cam.position,
            cam.dist, sc.gcps.sigma_px]


def _height_above_road(sc: GCPScene, world: np.ndarray | None = None) -> np.ndarray:
    w = sc.true_world if world is None else world
    return w[:, 2] - sc.road.z(w[:, 0], w[:, 1])


# ---------------------------------------------------------------------------------------------------- determinism
def test_same_seed_gives_identical_scene() -> None:
    kw = {"n_control": 14, "n_check": 4, "n_outliers": 3}
    a, b = make_gcp_scene(7, **kw), make_gcp_scene(7, **kw)
    for x, y in zip(_scene_arrays(a), _scene_arrays(b), strict=True):
        np.testing.assert_array_equal(x, y)
    assert a.gcps.ids == b.gcps.ids and a.gcps.roles == b.gcps.roles and a.outlier_kind == b.outlier_kind
    assert a.road.azimuth_deg == b.road.azimuth_deg


def test_different_seed_gives_different_scene() -> None:
    a, b = make_gcp_scene(1), make_gcp_scene(2)
    assert not np.allclose(a.camera.position, b.camera.position)
    assert a.true_world.shape == b.true_world.shape
    assert not np.allclose(a.true_world, b.true_world)
    assert not np.allclose(a.gcps.pixels, b.gcps.pixels)


# ---------------------------------------------------------------------------------------------------- table
def test_table_fields_roles_and_crs() -> None:
    sc = make_gcp_scene(3, n_control=10, n_check=5, pixel_sigma=0.7)
    t = sc.gcps
    n = 15
    assert t.ids == tuple(f"G{i:02d}" for i in range(1, n + 1))
    assert t.roles == ("control",) * 10 + ("check",) * 5
    assert t.world.shape == (n, 3) and t.world.dtype == np.float64
    assert t.pixels.shape == (n, 2) and sc.true_world.shape == (n, 3) and sc.true_pixels.shape == (n, 2)
    np.testing.assert_array_equal(t.sigma_px, np.full(n, 0.7))
    assert t.source == "synthetic" and t.lines == tuple(range(2, n + 2))
    assert t.crs == pyproj.CRS.from_epsg(2949)
    assert sc.camera.crs == "EPSG:2949"
    # Large coordinates on purpose, near the requested origin.
    assert np.all(np.abs(sc.true_world[:, :2] - ORIGIN[:2]) < 300.0)
    assert sc.pixel_sigma == 0.7 and sc.survey_sigma == 0.025
    # Observed pixels are rounded to 0.01 px.
    np.testing.assert_allclose(t.pixels * 100, np.round(t.pixels * 100), atol=1e-6)


def test_no_crs() -> None:
    sc = make_gcp_scene(3, crs=None, origin=(0.0, 0.0, 0.0))
    assert sc.gcps.crs is None and sc.camera.crs is None


# ---------------------------------------------------------------------------------------------------- pixels
def test_true_pixels_are_projections_inside_image() -> None:
    for seed in range(10):
        sc = make_gcp_scene(seed, n_control=16, n_check=4, n_elevated=3)
        np.testing.assert_allclose(sc.true_pixels, sc.camera.project(sc.true_world), rtol=0, atol=1e-9)
        w, h = sc.camera.image_size
        assert np.all(sc.true_pixels[:, 0] >= 0.02 * w - 0.5) and np.all(sc.true_pixels[:, 0] <= 0.98 * w - 0.5)
        assert np.all(sc.true_pixels[:, 1] >= 0.02 * h - 0.5) and np.all(sc.true_pixels[:, 1] <= 0.98 * h - 0.5)
        depth = sc.camera.world_to_camera(sc.true_world)[:, 2]
        assert np.all((depth >= 10.0) & (depth <= 120.0))


def test_pixel_noise_has_requested_sigma() -> None:
    sigma = 1.5
    diffs = []
    for seed in range(10):
        sc = make_gcp_scene(seed, n_control=20, pixel_sigma=sigma)
        diffs.append(sc.gcps.pixels - sc.true_pixels)
    d = np.concatenate(diffs)
    assert d.shape[0] == 200
    assert abs(d.std() / sigma - 1.0) < 0.2
    assert abs(d.mean()) < 0.3


def test_zero_noise_is_exact() -> None:
    sc = make_gcp_scene(5, n_control=12, n_check=3, pixel_sigma=0.0, survey_sigma=0.0)
    np.testing.assert_array_equal(sc.gcps.world, sc.true_world)
    assert np.max(np.abs(sc.gcps.pixels - sc.true_pixels)) <= 0.005 + 1e-9  # rounding to 0.01 px only
    np.testing.assert_array_equal(sc.gcps.sigma_px, 0.01)  # a table's sigma must be > 0: the rounding step


def test_crs_must_be_projected_metres() -> None:
    with pytest.raises(ValueError, match="projected CRS in metres"):
        make_gcp_scene(0, crs="EPSG:4326")
    with pytest.raises(ValueError, match="projected CRS in metres"):
        make_gcp_scene(0, crs="EPSG:2227")  # California zone 3, US survey feet


def test_survey_noise_has_requested_sigma() -> None:
    d = np.concatenate([make_gcp_scene(s, n_control=20, survey_sigma=0.05).gcps.world
                        - make_gcp_scene(s, n_control=20, survey_sigma=0.05).true_world for s in range(5)])
    std = d.std(axis=0)
    assert np.all(np.abs(std / 0.05 - 1.0) < 0.25), std


def test_points_cover_near_and_far() -> None:
    spreads = []
    for seed in range(20):
        sc = make_gcp_scene(seed, n_control=12)
        spreads.append(np.ptp(sc.true_pixels[:, 1]) / sc.camera.height)
        depth = sc.camera.world_to_camera(sc.true_world)[:, 2]
        assert depth.max() / depth.min() > 1.3
    assert min(spreads) > 0.25 and np.mean(spreads) > 0.5


# ---------------------------------------------------------------------------------------------------- geometry
def test_elevated_points_and_road_points() -> None:
    for seed in range(5):
        sc = make_gcp_scene(seed, n_control=12, n_check=4, n_elevated=3, survey_sigma=0.0)
        hgt = _height_above_road(sc)
        elevated = hgt > 1e-6
        assert elevated.sum() == 3
        assert np.all((hgt[elevated] >= 0.5) & (hgt[elevated] <= 6.0))
        np.testing.assert_allclose(hgt[~elevated], 0.0, atol=1e-9)  # on the road surface exactly
        assert all(r == "control" for r in np.array(sc.gcps.roles)[elevated])
        s, off = sc.road.station_offset(sc.true_world[:, 0], sc.true_world[:, 1])
        # Road points: lane-marking corners at lane boundaries (3 lanes of 3.5 m), stations every 3 m.
        np.testing.assert_allclose(np.abs(off[~elevated]) % 3.5, 1.75, atol=1e-6)
        assert np.all(np.abs(off[~elevated]) <= 5.25 + 1e-6)
        np.testing.assert_allclose((s[~elevated] / 3.0) - np.round(s[~elevated] / 3.0), 0.0, atol=1e-6)
        # Poles stand at the verge, beyond the road edges.
        assert np.all((np.abs(off[elevated]) >= 5.25 + 0.5 - 1e-6) & (np.abs(off[elevated]) <= 5.25 + 3 + 1e-6))
        # The camera stands 3-10 m beyond an edge, camera_height above that edge.
        cs, co = sc.road.station_offset(*sc.camera.position[:2])
        assert 5.25 + 3.0 - 1e-6 <= abs(co) <= 5.25 + 10.0 + 1e-6
        edge = sc.road.points(cs, np.sign(co) * 5.25)[0]
        assert sc.camera.position[2] - edge[2] == pytest.approx(8.0, abs=1e-9)


def test_road_points_within_survey_noise() -> None:
    sc = make_gcp_scene(11, n_control=20, n_elevated=0, survey_sigma=0.02)
    resid = _height_above_road(sc, sc.gcps.world)
    assert np.all(np.abs(resid) < 5 * 0.02 + 0.02 * 5 * 0.02)  # Z noise plus the crossfall effect of XY noise


def test_road_surface_crossfall_grade_and_crest() -> None:
    road = RoadSurface(ORIGIN, 30.0, crossfall=0.02)
    p = road.points(0.0, [-5.0, -2.0, 0.0, 2.0, 5.0])
    np.testing.assert_allclose(p[:, 2] - 90.0, [-0.1, -0.04, 0.0, -0.04, -0.1], atol=1e-12)
    np.testing.assert_allclose(road.z(p[:, 0], p[:, 1]), p[:, 2], atol=1e-12)
    # Right of the axis is azimuth + 90 deg: for an axis heading east, offset +1 is to the south.
    east = RoadSurface(ORIGIN, 90.0)
    np.testing.assert_allclose(east.points(10.0, 1.0)[0], ORIGIN + np.array([10.0, -1.0, 0.0]), atol=1e-9)

    graded = RoadSurface(ORIGIN, 200.0, grade=0.03, crossfall=0.02)
    a, b = graded.points([10.0, 35.0], 3.0)
    assert b[2] - a[2] == pytest.approx(0.03 * 25.0, abs=1e-9)
    assert np.hypot(*(b[:2] - a[:2])) == pytest.approx(25.0, abs=1e-9)

    crest = RoadSurface(ORIGIN, 0.0, crest_radius=1500.0)
    z = crest.points([-60.0, 0.0, 40.0], 0.0)[:, 2]
    np.testing.assert_allclose(z - 90.0, [-3600 / 3000, 0.0, -1600 / 3000], atol=1e-12)
    # z() is vectorized and broadcasts.
    xs, ys = np.meshgrid(ORIGIN[0] + np.arange(3.0), ORIGIN[1] + np.arange(4.0))
    assert crest.z(xs, ys).shape == (4, 3)


def test_road_surface_validation() -> None:
    with pytest.raises(ValueError, match="crest_radius"):
        RoadSurface(ORIGIN, 0.0, crest_radius=-10.0)
    with pytest.raises(ValueError, match="origin"):
        RoadSurface(np.array([1.0, 2.0]), 0.0)


def test_explicit_camera_parameters_are_used() -> None:
    sc = make_gcp_scene(4, focal_px=1500.0, dist=[-0.1, 0.02], heading_deg=123.0, tilt_deg=15.0, roll_deg=1.0,
                        camera_height=10.0, crest_radius=2000.0)
    o = sc.camera.orientation
    assert o.heading_deg == pytest.approx(123.0) and o.tilt_deg == pytest.approx(15.0)
    assert o.roll_deg == pytest.approx(1.0)
    assert sc.camera.focal_px == 1500.0
    np.testing.assert_array_equal(sc.camera.dist, [-0.1, 0.02, 0.0, 0.0, 0.0])
    assert sc.road.crest_radius == 2000.0


def test_random_camera_parameters_in_realistic_ranges() -> None:
    for seed in range(30):
        cam = make_gcp_scene(seed).camera
        o = cam.orientation
        assert 0.7 * 1920 <= cam.focal_px <= 1.3 * 1920
        assert 8.0 <= o.tilt_deg <= 25.0 and abs(o.roll_deg) <= 2.0
        assert -0.15 <= cam.dist[0] <= 0.05 and -0.05 <= cam.dist[1] <= 0.05
        assert np.all(cam.dist[2:] == 0)


def test_low_tripod_camera() -> None:
    sc = make_gcp_scene(2, camera_height=1.5, n_control=10)
    assert sc.camera.orientation.tilt_deg < 8.0
    assert sc.true_world.shape == (10, 3)


# ---------------------------------------------------------------------------------------------------- outliers
@pytest.mark.parametrize("pixel_sigma", [0.5, 1.0, 2.5])
def test_planted_outliers(pixel_sigma: float) -> None:
    n_out = 5
    for seed in range(6):
        sc = make_gcp_scene(seed, n_control=15, n_check=5, n_outliers=n_out, pixel_sigma=pixel_sigma,
                            survey_sigma=0.0)
        roles = np.array(sc.gcps.roles)
        kinds = np.array(sc.outlier_kind)
        assert sc.outlier.sum() == n_out
        assert np.all(roles[sc.outlier] == "control")
        assert np.all((kinds != "") == sc.outlier)
        assert sorted(kinds[sc.outlier].tolist()) == ["elevation", "elevation", "ortho", "pixel", "pixel"]
        threshold = max(12 * pixel_sigma, 8.0)
        cam = sc.camera
        for i in np.nonzero(sc.outlier)[0]:
            dw = sc.gcps.world[i] - sc.true_world[i]
            if kinds[i] == "pixel":
                np.testing.assert_array_equal(dw, 0.0)
                shift = sc.gcps.pixels[i] - sc.true_pixels[i]
                assert 15.0 - 5 * pixel_sigma <= np.hypot(*shift) <= 60.0 + 5 * pixel_sigma
                uv = sc.gcps.pixels[i]
            else:
                if kinds[i] == "elevation":
                    np.testing.assert_array_equal(dw[:2], 0.0)
                    assert 3.0 <= dw[2] <= 10.0
                else:
                    assert dw[2] == 0.0 and 1.5 <= np.hypot(dw[0], dw[1]) <= 5.0
                uv = cam.project(sc.gcps.world[i][None])[0]
                assert np.hypot(*(sc.gcps.pixels[i] - sc.true_pixels[i])) < 6 * pixel_sigma + 0.01
            assert np.hypot(*(uv - sc.true_pixels[i])) >= threshold - 0.01  # 0.01: rounding of observed pixels
            assert cam.in_image(uv[None])[0]
        # Inliers are only noisy.
        ok = ~sc.outlier
        np.testing.assert_array_equal(sc.gcps.world[ok], sc.true_world[ok])
        assert np.all(np.hypot(*(sc.gcps.pixels[ok] - sc.true_pixels[ok]).T) < 6 * pixel_sigma + 0.01)


def test_outlier_kinds_cycle() -> None:
    sc = make_gcp_scene(8, n_control=12, n_outliers=1)
    assert [k for k in sc.outlier_kind if k] == ["pixel"]
    sc = make_gcp_scene(8, n_control=12, n_outliers=3)
    assert sorted(k for k in sc.outlier_kind if k) == ["elevation", "ortho", "pixel"]


def test_impossible_outliers_raise() -> None:
    # 12 sigma = 120 px cannot be reached by a wrong click of 15-60 px.
    with pytest.raises(ValueError, match="outlier"):
        make_gcp_scene(0, n_outliers=1, pixel_sigma=10.0)


# ---------------------------------------------------------------------------------------------------- errors
def test_camera_looking_at_sky_raises() -> None:
    with pytest.raises(ValueError, match="cannot place"):
        make_gcp_scene(0, tilt_deg=-30.0, focal_px=2000.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"n_elevated": 5, "n_control": 4}, "n_elevated"), ({"n_outliers": 13}, "n_outliers"),
     ({"n_control": 0}, "n_control"), ({"pixel_sigma": -1.0}, "pixel_sigma"), ({"camera_height": 0.0}, "height"),
     ({"image_size": (0, 1080)}, "image_size")],
)
def test_bad_arguments_raise(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make_gcp_scene(0, **kwargs)


# ---------------------------------------------------------------------------------------------------- hypothesis
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 100_000), size=st.sampled_from([(1920, 1080), (3840, 2160)]),
       n_control=st.integers(8, 20), n_check=st.integers(0, 5))
def test_generation_succeeds(seed: int, size: tuple[int, int], n_control: int, n_check: int) -> None:
    sc = make_gcp_scene(seed, image_size=size, n_control=n_control, n_check=n_check, n_outliers=min(3, n_control - 6))
    n = n_control + n_check
    assert sc.camera.image_size == size
    assert sc.gcps.world.shape == (n, 3) and sc.gcps.roles.count("check") == n_check
    assert np.all(sc.camera.in_image(sc.true_pixels)) and np.all(sc.camera.in_image(sc.gcps.pixels))
    assert np.all(np.isfinite(sc.gcps.world)) and np.all(np.isfinite(sc.gcps.pixels))
    # Distinct features.
    assert len({tuple(np.round(p, 3)) for p in sc.true_world}) == n


@settings(max_examples=80, deadline=None)
@given(radius=st.sampled_from([-2000.0, -300.0, -60.0, 60.0, 250.0, 1500.0]), s=st.floats(-50, 50),
       o=st.floats(-15, 15), az=st.floats(0, 360))
def test_curved_road_points_and_station_offset_are_inverse(radius, s, o, az):
    road = RoadSurface(origin=[245000.0, 5182600.0, 90.0], azimuth_deg=az, grade=0.01, crossfall=0.02,
                       curve_radius=radius)
    p = road.points([s], [o])
    s2, o2 = road.station_offset(p[:, 0], p[:, 1])
    assert s2[0] == pytest.approx(s, abs=1e-6) and o2[0] == pytest.approx(o, abs=1e-6)
    # The axis leaves the origin along the azimuth and turns right for a positive radius.
    a = road.points([0.0, 1e-3], [0.0, 0.0])
    heading = np.degrees(np.arctan2(*(a[1, :2] - a[0, :2]))) % 360
    assert min(abs(heading - az % 360), 360 - abs(heading - az % 360)) < 1e-3
    h = road.heading_at(np.array([10.0]))[0]
    b = road.points([10.0, 10.001], [0.0, 0.0])
    h_num = np.degrees(np.arctan2(*(b[1, :2] - b[0, :2]))) % 360
    assert min(abs(h - h_num), 360 - abs(h - h_num)) < 1e-3
    assert (h - az) % 360 == pytest.approx(np.degrees(10.0 / radius) % 360, abs=1e-6)
    # Offsets are lateral: a point at (s, o) lies |o| from the axis point at s.
    axis_pt = road.points([s], [0.0])
    assert np.hypot(*(p[0, :2] - axis_pt[0, :2])) == pytest.approx(abs(o), abs=1e-6)
