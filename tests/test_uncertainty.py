"""Ground uncertainty: analytic nadir case, Monte Carlo agreement of the propagated calibration covariance, the
accuracy grid and the visible-ground footprint, and units in feet."""

from __future__ import annotations

import json

import numpy as np
import pytest

from trafficgeo.calibration.camera_record import camera_covariance
from trafficgeo.calibration.gcp_table import GCPTable
from trafficgeo.calibration.pipeline import CalibrationOptions
from trafficgeo.calibration.run import run_calibration
from trafficgeo.camera.calibrated import CalibratedCamera, CameraCovariance
from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import pixels_to_world
from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.geo.uncertainty import accuracy_grid, footprint_polygon, ground_uncertainty
from trafficgeo.synth.gcp_scene import make_gcp_scene

E0, N0, Z0 = 245000.0, 5182600.0, 90.0


def test_pixel_noise_on_a_nadir_camera_is_height_over_focal():
    H, f = 20.0, 1000.0
    cam = Camera.from_orientation((1000, 800), f, [E0, N0, Z0 + H], 0.0, 90.0, 0.0, crs="EPSG:2949")
    u = ground_uncertainty(cam, [[499.5, 399.5]], ConstantSurface(Z0), None, pixel_sigma=2.0)
    sigma = 2.0 * H / f  # per axis, metres
    assert u.major_m[0] == pytest.approx(sigma, rel=1e-4)
    assert u.minor_m[0] == pytest.approx(sigma, rel=1e-4)
    assert u.radial_m[0] == pytest.approx(np.sqrt(2) * sigma, rel=1e-4)
    assert np.isnan(u.calibration_m[0])


def test_feet_crs_reports_metres():
    H_ft, f = 60.0, 1000.0
    cam = Camera.from_orientation((1000, 800), f, [636600.0, 849200.0, 400.0 + H_ft], 0.0, 90.0, 0.0,
                                  crs="EPSG:2994")
    u = ground_uncertainty(cam, [[499.5, 399.5]], ConstantSurface(400.0), None, pixel_sigma=1.0)
    assert u.major_m[0] == pytest.approx(H_ft * 0.3048 / f, rel=1e-4)
    g = pixels_to_world(cam, [[499.5, 399.5]], ConstantSurface(400.0))
    assert g.distance_m[0] == pytest.approx(H_ft * 0.3048, rel=1e-9)
    assert g.lon[0] == pytest.approx(-123.07, abs=0.05) and g.lat[0] == pytest.approx(44.05, abs=0.05)


def test_ellipse_is_elongated_along_the_line_of_sight():
    cam = Camera.from_orientation((1920, 1080), 1500.0, [E0, N0, Z0 + 8.0], 0.0, 8.0, 0.0, crs="EPSG:2949")
    far = cam.project([[E0, N0 + 80.0, Z0]])
    u = ground_uncertainty(cam, far, ConstantSurface(Z0), None, pixel_sigma=1.0)
    assert u.major_m[0] > 5 * u.minor_m[0]
    assert min(u.azimuth_deg[0], 180 - u.azimuth_deg[0]) < 1.0  # looking north: the long axis runs north-south


def _calibrate(gcps: GCPTable, size: tuple[int, int]):
    return run_calibration(gcps, size, CalibrationOptions(distortion="none"))


@pytest.mark.slow
def test_propagated_calibration_error_matches_monte_carlo():
    """The mean predicted ground sigma over noisy calibrations agrees with the spread of their ground points."""
    sc = make_gcp_scene(3, n_control=12, grade=0.0, crossfall=0.0, dist=[0, 0, 0, 0, 0])
    surf = ConstantSurface(float(sc.road.origin[2]))
    truth = sc.road.points([0.0, 30.0, 60.0], [0.0, 0.0, 0.0])
    uv = sc.camera.project(truth)
    rng = np.random.default_rng(0)
    errors, predicted = [], []
    for _ in range(25):
        pix = sc.true_pixels + rng.normal(0, sc.pixel_sigma, sc.true_pixels.shape)
        world = sc.true_world + rng.normal(0, sc.survey_sigma, sc.true_world.shape)
        gcps = GCPTable.from_arrays(list(sc.gcps.ids), world, pix, roles=sc.gcps.roles, sigma_px=sc.gcps.sigma_px,
                                    crs=sc.gcps.crs)
        cal = _calibrate(gcps, sc.camera.image_size).calibration
        cov = camera_covariance(cal)
        predicted.append(ground_uncertainty(cal.camera, uv, surf, cov, pixel_sigma=0.0).radial_m)
        errors.append(pixels_to_world(cal.camera, uv, surf).xyz[:, :2] - truth[:, :2])
    mc = np.sqrt((np.array(errors) ** 2).sum(axis=2).mean(axis=0))
    pred = np.sqrt((np.array(predicted) ** 2).mean(axis=0))
    assert np.all(np.diff(mc) > 0)  # farther is worse
    np.testing.assert_allclose(pred, mc, rtol=0.35)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    sc = make_gcp_scene(7, n_control=14)
    path = tmp_path_factory.mktemp("cal") / "camera.json"
    run_calibration(sc.gcps, sc.camera.image_size, camera_path=path)
    calibrated = CalibratedCamera.read(path)
    return sc, calibrated.camera, json.loads(path.read_text(encoding="utf-8")), path


def test_covariance_block_round_trips_and_guards_the_camera(calibrated, tmp_path):
    _, cam, doc, path = calibrated
    cov = CameraCovariance.from_dict(doc["covariance"], cam, str(path))
    assert cov.matrix.shape == (15, 15)
    np.testing.assert_array_equal(cov.matrix, np.array(doc["covariance"]["matrix"]))  # kept as written
    L = cov.factor()
    symmetric = 0.5 * (cov.matrix + cov.matrix.T)
    np.testing.assert_allclose(L @ L.T, symmetric, atol=1e-12 * np.abs(cov.matrix).max())
    np.testing.assert_allclose(cov.camera(cov.values, cam).position, cam.position, atol=1e-6)
    other = Camera.from_orientation(cam.image_size, 1000.0, cam.position + 5.0, 10.0, 20.0, 0.0, crs=cam.crs)
    with pytest.raises(InputError, match="does not belong to this camera"):
        CameraCovariance.from_dict(doc["covariance"], other)
    write_camera_json(tmp_path / "plain.json", cam)
    assert CalibratedCamera.read(tmp_path / "plain.json").covariance is None
    np.testing.assert_array_equal(CalibratedCamera.read(path).covariance.values, cov.values)


def test_accuracy_grid_and_footprint(calibrated):
    sc, cam, _, path = calibrated
    cov = CalibratedCamera.read(path).covariance
    surf = ConstantSurface(float(np.median(sc.true_world[:, 2])))
    grid = accuracy_grid(cam, surf, cov, pixel_sigma=1.0, max_distance_m=120.0, max_cells=40_000)
    assert grid.bands.shape[0] == len(grid.band_names) == 6
    radial = grid.bands[0]
    assert np.all(np.isfinite(radial[grid.visible])) and np.all(np.isnan(radial[~grid.visible]))
    # Every visible cell centre projects into the frame; error grows with distance.
    rows, cols = np.nonzero(grid.visible)
    x, y = grid.transform @ (cols + 0.5, rows + 0.5)
    uv = cam.project(np.column_stack([x, y, np.full(x.shape, surf.z)]))
    assert cam.in_image(uv, margin=-1.0).all()
    dist = np.hypot(x - cam.position[0], y - cam.position[1])
    near, far = dist < np.percentile(dist, 25), dist > np.percentile(dist, 75)
    assert np.median(radial[rows[far], cols[far]]) > 2 * np.median(radial[rows[near], cols[near]])
    # Total error is at least each part.
    ok = grid.visible
    assert np.all(grid.bands[0][ok] >= grid.bands[3][ok] - 1e-6) and np.all(grid.bands[0][ok] >= grid.bands[4][ok])
    poly = footprint_polygon(grid)
    from shapely.geometry import Point

    bottom = pixels_to_world(cam, [[cam.width / 2, cam.height - 20.0]], surf).xyz[0]
    assert poly.contains(Point(bottom[0], bottom[1]))
    behind = cam.position[:2] - 20.0 * (cam.optical_axis[:2] / np.linalg.norm(cam.optical_axis[:2]))
    assert not poly.contains(Point(*behind))
    assert np.hypot(*(np.array(poly.centroid.coords[0]) - cam.position[:2])) < 120.0
