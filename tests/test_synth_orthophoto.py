"""Synthetic orthophoto: georeferenced GeoTIFF, markings where the geometry says, dash corners, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from trafficgeo.geo.raster import read_raster, write_geotiff
from trafficgeo.synth.gcp_scene import RoadSurface
from trafficgeo.synth.orthophoto import ASPHALT, GRASS, WHITE, YELLOW, RoadMarkings, dash_corners, render_orthophoto

E0, N0, Z0 = 245000.0, 5182600.0, 90.0
ROAD = RoadSurface(origin=[E0, N0, Z0], azimuth_deg=30.0, grade=0.02, crossfall=0.02)
MARK = RoadMarkings(lanes_right=2, lanes_left=2)
BOUNDS = (E0 - 30.0, N0 - 30.0, E0 + 30.0, N0 + 30.0)


@pytest.fixture(scope="module")
def ortho(tmp_path_factory):
    img = render_orthophoto(ROAD, MARK, BOUNDS, resolution=0.05, seed=3)
    path = tmp_path_factory.mktemp("ortho") / "ortho.tif"
    write_geotiff(path, img.data, img.transform, img.crs, descriptions=img.descriptions)
    return read_raster(path)


def colour_at(ortho, s, o) -> np.ndarray:
    p = ROAD.points(np.atleast_1d(s), np.atleast_1d(o))
    return np.stack([ortho.sample_bilinear(p[:, 0], p[:, 1], band=b) for b in range(3)], axis=1)


def near(c: np.ndarray, ref: np.ndarray, tol: float = 25.0) -> np.ndarray:
    return np.all(np.abs(c - ref) < tol, axis=1)


@pytest.mark.slow
def test_geotiff_is_georeferenced_rgb(ortho):
    assert ortho.count == 3 and ortho.data.dtype == np.uint8
    assert ortho.crs.to_epsg() == 2949
    assert ortho.resolution == pytest.approx((0.05, 0.05))
    assert ortho.bounds == pytest.approx(BOUNDS)


@pytest.mark.slow
def test_markings_lie_where_the_geometry_puts_them(ortho):
    s_dash = np.arange(-18.0, 18.0, 9.0) + 1.5  # dash centres (phase 0, 3 m dashes every 9 m)
    s_gap = s_dash + 4.5
    for line in MARK.lane_lines():
        assert near(colour_at(ortho, s_dash, np.full(s_dash.shape, line)), WHITE).all()
        assert near(colour_at(ortho, s_gap, np.full(s_gap.shape, line)), ASPHALT).all()
    s = np.linspace(-20, 20, 9)
    assert near(colour_at(ortho, s, np.zeros(s.shape)), YELLOW, 30).all()
    assert near(colour_at(ortho, s, np.full(s.shape, MARK.right_edge - 0.075)), WHITE).all()
    assert near(colour_at(ortho, s, np.full(s.shape, MARK.left_edge + 0.075)), WHITE).all()
    assert near(colour_at(ortho, s, np.full(s.shape, 1.75)), ASPHALT).all()  # lane centre
    assert near(colour_at(ortho, s, np.full(s.shape, MARK.right_edge + 5.0)), GRASS, 45).all()


def test_dash_corners_are_the_corners_of_painted_dashes(ortho):
    corners = dash_corners(ROAD, MARK, (-20.0, 20.0))
    assert len(corners) == 4 * 4 * len(MARK.lane_lines())  # dashes starting at -18, -9, 0, 9 (3 m long)
    np.testing.assert_allclose(corners[:, 2], ROAD.z(corners[:, 0], corners[:, 1]))
    s, o = ROAD.station_offset(corners[:, 0], corners[:, 1])
    centre_s = s.reshape(-1, 4).mean(axis=1).repeat(4)
    centre_o = o.reshape(-1, 4).mean(axis=1).repeat(4)
    inward = colour_at(ortho, s + 0.15 * np.sign(centre_s - s), o + 0.02 * np.sign(centre_o - o))
    outward = colour_at(ortho, s - 0.15 * np.sign(centre_s - s), o)
    assert near(inward, WHITE, 40).all()
    assert near(outward, ASPHALT, 30).all()


@pytest.mark.slow
def test_same_seed_same_image_and_one_way_has_no_centre_line():
    a = render_orthophoto(ROAD, MARK, BOUNDS, resolution=0.2, seed=1)
    b = render_orthophoto(ROAD, MARK, BOUNDS, resolution=0.2, seed=1)
    c = render_orthophoto(ROAD, MARK, BOUNDS, resolution=0.2, seed=2)
    assert np.array_equal(a.data, b.data) and not np.array_equal(a.data, c.data)
    one_way = RoadMarkings(lanes_right=3, lanes_left=0)
    assert one_way.lane_lines().tolist() == [3.5, 7.0]
    img = render_orthophoto(ROAD, one_way, BOUNDS, resolution=0.05, seed=1)
    p = ROAD.points([0.0], [0.0])
    rgb = np.array([img.sample_bilinear(p[:, 0], p[:, 1], band=k)[0] for k in range(3)])
    assert not near(rgb[None], YELLOW, 40)[0]
    with pytest.raises(ValueError):
        RoadMarkings(lanes_right=0)
