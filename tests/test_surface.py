"""Surfaces and ray intersection: analytic planes, DEMs of non-planar roads against their truth, first hits,
statuses for rays without a hit, lifted surfaces, and a brute-force oracle on random terrain."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trafficgeo.camera.model import Camera
from trafficgeo.geo.mapping import pixels_to_world, world_to_pixels
from trafficgeo.geo.surface import (
    ABOVE_HORIZON,
    BEHIND_CAMERA,
    GRAZING,
    MISS,
    NO_DATA,
    OK,
    ConstantSurface,
    DEMSurface,
    PlaneSurface,
)
from trafficgeo.synth.gcp_scene import RoadSurface

E0, N0, Z0 = 245000.0, 5182600.0, 90.0


def grid_dem(fn, left: float, top: float, res: float, cols: int, rows: int) -> DEMSurface:
    """DEM sampling ``fn(x, y)`` at cell centres."""
    x = left + (np.arange(cols) + 0.5) * res
    y = top - (np.arange(rows) + 0.5) * res
    X, Y = np.meshgrid(x, y)
    return DEMSurface(fn(X, Y), left, top, res, res)


def road_camera(**kw) -> Camera:
    args = dict(position=[E0 - 15.0, N0 - 25.0, Z0 + 10.0], heading_deg=30.0, tilt_deg=14.0, roll_deg=0.4,
                dist=[-0.12, 0.03, 0, 0, 0], crs="EPSG:2949")
    args.update(kw)
    return Camera.from_orientation((1920, 1080), 1500.0, **args)


# --- planes -----------------------------------------------------------------------------------------------------

@settings(max_examples=60, deadline=None)
@given(heading=st.floats(0, 360), tilt=st.floats(5, 85), roll=st.floats(-10, 10), height=st.floats(2, 60),
       gx=st.floats(-0.1, 0.1), gy=st.floats(-0.1, 0.1), u=st.floats(0, 1919), v=st.floats(540, 1079))
def test_plane_hit_projects_back_to_its_pixel(heading, tilt, roll, height, gx, gy, u, v):
    cam = Camera.from_orientation((1920, 1080), 1400.0, [E0, N0, Z0 + height], heading, tilt, roll, crs="EPSG:2949")
    plane = PlaneSurface(np.array([E0 + 7.0, N0 - 3.0, Z0]), gx, gy)
    g = pixels_to_world(cam, [[u, v]], plane, min_incidence_deg=0.0, with_lonlat=False)
    if g.status[0] == "ok":
        p = g.xyz[0]
        assert p[2] == pytest.approx(float(plane.elevation(p[0], p[1])), abs=1e-6)
        np.testing.assert_allclose(cam.project(g.xyz), [[u, v]], atol=1e-6)
    else:
        # Only rays that do not come down to the plane may fail: pointing up relative to the plane.
        d = cam.rays([[u, v]])[0]
        assert d @ np.array([-gx, -gy, 1.0]) >= -1e-9


def test_plane_fit_recovers_gradients():
    rng = np.random.default_rng(1)
    xy = rng.uniform(-50, 50, (40, 2))
    z = Z0 + 0.03 * xy[:, 0] - 0.01 * xy[:, 1] + rng.normal(0, 0.002, 40)
    plane = PlaneSurface.fit(np.column_stack([xy[:, 0] + E0, xy[:, 1] + N0, z]))
    assert plane.gx == pytest.approx(0.03, abs=2e-4)
    assert plane.gy == pytest.approx(-0.01, abs=2e-4)
    assert plane.rms == pytest.approx(0.002, rel=0.3)
    with pytest.raises(ValueError, match="collinear"):
        PlaneSurface.fit([[0, 0, 0], [1, 1, 0], [2, 2, 0]])


def test_plane_statuses_above_horizon_and_behind_camera():
    cam = road_camera()
    flat = ConstantSurface(Z0)
    uv = np.array([[960, 0], [960, 1079]])
    codes = flat.intersect(cam.position, cam.rays(uv)).code
    assert codes.tolist() == [ABOVE_HORIZON, OK]
    above = ConstantSurface(Z0 + 30.0)  # a "surface" above the camera: downward rays meet it behind the camera
    assert above.intersect(cam.position, cam.rays(uv)).code.tolist() == [OK, BEHIND_CAMERA]


def test_grazing_rays_get_a_status_not_a_number():
    cam = Camera.from_orientation((1920, 1080), 1500.0, [E0, N0, Z0 + 1.0], 0.0, 0.2, 0.0)
    g = pixels_to_world(cam, [[960, 545], [960, 1079]], ConstantSurface(Z0), min_incidence_deg=0.5)
    assert g.status.tolist() == ["grazing", "ok"]
    assert np.isnan(g.xyz[0]).all() and np.isfinite(g.xyz[1]).all()


# --- DEMs of non-planar roads -----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def crowned_road():
    road = RoadSurface(origin=[E0, N0, Z0], azimuth_deg=30.0, grade=0.03, crossfall=0.02, crest_radius=600.0)
    dem = grid_dem(road.z, E0 - 120, N0 + 120, 0.1, 2400, 2400)
    return road, dem


@pytest.mark.slow
def test_dem_maps_check_pixels_to_the_true_ground(crowned_road):
    road, dem = crowned_road
    cam = road_camera()
    rng = np.random.default_rng(3)
    s = rng.uniform(5, 90, 300)
    o = rng.uniform(-9, 9, 300)
    truth = road.points(s, o)
    uv = cam.project(truth)
    keep = cam.in_image(uv)
    g = pixels_to_world(cam, uv[keep], dem, min_incidence_deg=0.0)
    assert (g.status == "ok").all()
    err = np.linalg.norm(g.xyz - truth[keep], axis=1)
    # Beyond the crest some road is hidden by the road itself: those rays stop at the crest, in front of the point.
    seen = world_to_pixels(cam, truth[keep], dem, occlusion_tolerance_m=0.005).status
    hidden = seen == "occluded"
    assert set(seen) <= {"ok", "occluded"}
    assert 0 < hidden.sum() < 0.2 * hidden.size
    dist = np.linalg.norm(truth[keep] - cam.position, axis=1)
    assert np.all(g.distance_m[hidden] < dist[hidden] - 0.5)
    # Bilinear DEM of 0.1 m cells vs the exact crowned/crested road: millimetres (the crown is a kink), except
    # where the ray skims the road at under a degree and any height error is stretched 60-fold or more.
    clear = ~hidden & (g.incidence_deg > 1.0)
    assert clear.sum() > 0.8 * clear.size
    assert np.max(err[clear]) < 0.02
    assert np.median(err[clear]) < 0.003
    # ... while the plane through the same area is metres off far down the road.
    plane = PlaneSurface.fit(road.points(rng.uniform(0, 40, 50), rng.uniform(-8, 8, 50)))
    gp = pixels_to_world(cam, uv[keep], plane)
    far = s[keep] > 70
    assert np.median(np.linalg.norm(gp.xyz[far] - truth[keep][far], axis=1)) > 0.5


@pytest.mark.slow
def test_dem_hit_equals_surface_and_round_trips(crowned_road):
    _, dem = crowned_road
    cam = road_camera()
    u, v = np.meshgrid(np.linspace(0, 1919, 60), np.linspace(400, 1079, 40))
    uv = np.column_stack([u.ravel(), v.ravel()])
    g = pixels_to_world(cam, uv, dem)
    ok = g.ok
    assert ok.sum() > 1500
    np.testing.assert_allclose(g.xyz[ok, 2], dem.elevation(g.xyz[ok, 0], g.xyz[ok, 1]), atol=1e-5)
    np.testing.assert_allclose(cam.project(g.xyz[ok]), uv[ok], atol=1e-4)


@pytest.mark.slow
def test_lifted_surface_equals_a_raised_dem(crowned_road):
    road, dem = crowned_road
    raised = grid_dem(lambda x, y: road.z(x, y) + 1.5, E0 - 120, N0 + 120, 0.1, 2400, 2400)
    cam = road_camera()
    uv = np.array([[900.0, 800.0], [300.0, 1000.0], [1700.0, 700.0]])
    a = pixels_to_world(cam, uv, dem, height=1.5).xyz
    b = pixels_to_world(cam, uv, raised).xyz
    np.testing.assert_allclose(a, b, atol=1e-5)
    flat_a = pixels_to_world(cam, uv, ConstantSurface(Z0), height=1.5).xyz
    np.testing.assert_allclose(flat_a, pixels_to_world(cam, uv, ConstantSurface(Z0 + 1.5)).xyz, atol=1e-9)


def test_first_hit_is_the_obstacle_not_the_ground_behind_it():
    # Flat ground with a 4 m high block 30-34 m north of the camera.
    def terrain(x, y):
        block = (np.abs(x - E0) < 5) & (y - N0 > 30) & (y - N0 < 34)
        return np.where(block, Z0 + 4.0, Z0)

    dem = grid_dem(terrain, E0 - 50, N0 + 100, 0.25, 400, 600)
    cam = Camera.from_orientation((1920, 1080), 1500.0, [E0, N0, Z0 + 6.0], 0.0, 5.0, 0.0, crs="EPSG:2949")
    behind = np.array([[E0, N0 + 40.0, Z0]])  # ground behind the block, on the same line of sight
    uv = cam.project(behind)
    g = pixels_to_world(cam, uv, dem)
    assert g.status[0] == "ok"
    assert 29.7 <= g.xyz[0, 1] - N0 <= 34.0 and g.xyz[0, 2] > Z0 + 0.5  # on the block (its bilinear edge)
    assert world_to_pixels(cam, behind, dem).status[0] == "occluded"
    assert world_to_pixels(cam, np.array([[E0, N0 + 20.0, Z0]]), dem).status[0] == "ok"
    assert world_to_pixels(cam, behind).status[0] == "ok"  # without a surface there is no occlusion test


def test_dem_statuses_miss_no_data_above_horizon_and_behind():
    dem = grid_dem(lambda x, y: np.full_like(x, Z0), E0 - 20, N0 + 60, 0.5, 80, 80)  # 40 m x 40 m patch
    cam = Camera.from_orientation((1920, 1080), 1500.0, [E0, N0, Z0 + 8.0], 0.0, 10.0, 0.0, crs="EPSG:2949")
    far = cam.project(np.array([[E0, N0 + 100.0, Z0]]))  # ground beyond the patch
    near = cam.project(np.array([[E0, N0 + 45.0, Z0]]))
    sky = np.array([[960.0, 0.0]])
    g = pixels_to_world(cam, np.vstack([far, near, sky]), dem)
    assert g.status.tolist() == ["miss", "ok", "above_horizon"]
    holes = dem.values.copy()
    holes[20:40, :] = np.nan  # a band without data at 20-30 m north of the patch's top edge
    dem_h = DEMSurface(holes, E0 - 20, N0 + 60, 0.5, 0.5)
    in_hole = cam.project(np.array([[E0, N0 + 45.0, Z0]]))
    assert dem_h.intersect(cam.position, cam.rays(in_hole)).code[0] == NO_DATA
    below = Camera.from_orientation((1920, 1080), 1500.0, [E0, N0 + 40, Z0 - 3.0], 0.0, 10.0, 0.0)
    assert dem.intersect(below.position, below.rays(near)).code[0] == BEHIND_CAMERA
    assert MISS != NO_DATA != GRAZING


def test_dem_outside_and_nan_elevation_queries():
    dem = grid_dem(lambda x, y: x - E0, E0, N0 + 10, 1.0, 10, 10)
    z = dem.elevation([E0 + 0.5, E0 + 5.0, E0 + 9.75, E0 - 1.0], [N0 + 5, N0 + 5, N0 + 5, N0 + 5])
    np.testing.assert_allclose(z[:3], [0.5, 5.0, 9.5])  # clamped in the outer half cell
    assert np.isnan(z[3])


# --- brute-force oracle -----------------------------------------------------------------------------------------

def _oracle_first_hit(dem: DEMSurface, o: np.ndarray, d: np.ndarray, t_max: float, step: float) -> float:
    t = np.arange(0.0, t_max, step)
    p = o + t[:, None] * d
    gap = p[:, 2] - dem.elevation(p[:, 0], p[:, 1])
    below = np.flatnonzero(np.isfinite(gap) & (gap <= 0))
    if below.size == 0:
        return np.nan
    k = below[0]
    if k == 0:
        return np.nan
    # Linear interpolation of the crossing inside the sampling step.
    return t[k - 1] + step * gap[k - 1] / (gap[k - 1] - gap[k])


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dem_first_hit_matches_dense_sampling_on_rough_terrain(seed):
    rng = np.random.default_rng(seed)
    res, n = 0.5, 160
    base = rng.normal(0, 1.0, (n, n))
    from scipy.ndimage import gaussian_filter

    z = Z0 + 6.0 * gaussian_filter(base, 3.0) / gaussian_filter(base, 3.0).std()
    z[40:44, 60:120] += 5.0  # a wall
    dem = DEMSurface(z, E0, N0 + n * res, res, res)
    o = np.array([E0 + 10.0, N0 + 10.0, Z0 + 15.0])
    dirs = rng.normal(0, 1, (300, 3))
    dirs[:, 2] = -np.abs(dirs[:, 2]) * rng.uniform(0.05, 1.0, 300)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = dem.intersect(o, dirs, min_incidence_deg=0.0)
    step = 0.01
    for i in range(len(dirs)):
        t_ref = _oracle_first_hit(dem, o, dirs[i], 200.0, step)
        if np.isnan(t_ref):
            if hits.code[i] == OK:  # only a crossing within a sampling step of the DEM's edge may escape the oracle
                beyond = o + (hits.distance[i] + 2 * step) * dirs[i]
                assert np.isnan(dem.elevation(beyond[0], beyond[1]))
        else:
            assert hits.code[i] == OK
            # Agreement to the oracle's sampling step (a sub-step bump could be crossed twice within it).
            assert hits.distance[i] == pytest.approx(t_ref, abs=2 * step)


@pytest.mark.slow
def test_point_cloud_surface_maps_check_pixels_to_the_true_ground(tmp_path):
    """Lidar of a crowned, crested road (ground + trees + poles) -> LAZ -> ground DEM -> pixels on the ground."""
    from trafficgeo.geo.pointcloud import write_point_cloud
    from trafficgeo.site.surface import load_surface
    from trafficgeo.synth.terrain import road_point_cloud

    road = RoadSurface(origin=[E0, N0, Z0], azimuth_deg=30.0, grade=0.03, crossfall=0.02, crest_radius=600.0)
    cam = road_camera()
    cloud = road_point_cloud(road, [E0, N0], 90.0, density=8.0, noise=0.02, seed=1, crs="EPSG:2949")
    write_point_cloud(tmp_path / "site.laz", cloud)
    surf = load_surface(str(tmp_path / "site.laz"), cam, resolution_m=0.5)
    rng = np.random.default_rng(4)
    truth = road.points(rng.uniform(5, 60, 200), rng.uniform(-7, 7, 200))
    uv = cam.project(truth)
    keep = cam.in_image(uv) & (world_to_pixels(cam, truth, surf).status == "ok")
    g = pixels_to_world(cam, uv[keep], surf)
    ok = g.ok
    assert ok.mean() > 0.95
    err = np.linalg.norm(g.xyz[ok] - truth[keep][ok], axis=1)
    # 2 cm lidar noise, 0.5 m cells of medians: about a centimetre in Z, stretched 5-10x along rays that meet the
    # road at 6-12 deg.
    dz = np.abs(g.xyz[ok, 2] - truth[keep][ok, 2])
    assert np.median(dz) < 0.015
    assert np.median(err) < 0.1
    assert np.percentile(err, 95) < 0.4


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 10_000), level=st.integers(1, 4), gc=st.floats(0, 37), gr=st.floats(0, 23))
def test_max_pyramid_bounds_the_surface_within_its_reach(seed, level, gc, gr):
    """The invariant the ray march relies on: no surface point within the level's reach is above the stored max."""
    from trafficgeo.geo.surface import _MaxPyramid

    rng = np.random.default_rng(seed)
    values = rng.normal(0, 1, (23, 37))
    values[rng.random(values.shape) < 0.05] = np.nan
    dem = DEMSurface(values, 0.0, 23.0, 1.0, 1.0)
    pyr = _MaxPyramid(values)
    stored = pyr.lookup(np.array([level]), np.array([min(int(gr), 22)]), np.array([min(int(gc), 36)]))[0]
    reach = pyr.reach[level]
    s = np.linspace(-reach, reach, 4 * int(reach) + 1)
    C, R = np.meshgrid(gc + s, gr + s)
    z = dem.elevation(C.ravel(), 23.0 - R.ravel())
    if np.isfinite(z).any():
        assert np.nanmax(z) <= stored
