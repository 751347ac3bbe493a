"""Renderer: the draped orthophoto and the boxes agree with the Camera model; nearer boxes hide farther ones."""

from __future__ import annotations

import numpy as np
import pytest

from trafficgeo.camera.model import Camera
from trafficgeo.geo.surface import DEMSurface
from trafficgeo.synth.gcp_scene import RoadSurface
from trafficgeo.synth.orthophoto import ASPHALT, WHITE, RoadMarkings, dash_corners, render_orthophoto
from trafficgeo.synth.render import Boxes, drape_orthophoto, render_frame

E0, N0, Z0 = 245000.0, 5182600.0, 90.0
ROAD = RoadSurface(origin=[E0, N0, Z0], azimuth_deg=0.0, grade=0.02, crossfall=0.02)
MARK = RoadMarkings(lanes_right=2, lanes_left=2)
SIZE = (640, 360)


def camera() -> Camera:
    return Camera.from_orientation(SIZE, 500.0, [E0 + 12.0, N0 - 10.0, Z0 + 8.0], -15.0, 14.0, 0.0,
                                   dist=[-0.08, 0.01, 0, 0, 0], crs="EPSG:2949")


@pytest.fixture(scope="module")
def background():
    bounds = (E0 - 40.0, N0 - 20.0, E0 + 40.0, N0 + 120.0)
    ortho = render_orthophoto(ROAD, MARK, bounds, resolution=0.05, seed=0)
    res = 0.25
    x = bounds[0] + (np.arange(320) + 0.5) * res
    y = bounds[3] - (np.arange(560) + 0.5) * res
    X, Y = np.meshgrid(x, y)
    dem = DEMSurface(ROAD.z(X, Y), bounds[0], bounds[3], res, res)
    return drape_orthophoto(camera(), dem, ortho)


def test_draped_orthophoto_shows_the_markings_where_the_camera_projects_them(background):
    cam = camera()
    # Near dashes (a 10 cm line is a few pixels wide there; farther away it blends with the asphalt).
    corners = dash_corners(ROAD, MARK, (8.0, 22.0)).reshape(-1, 4, 3)
    centres = corners.mean(axis=1)
    uv = cam.project(centres)
    keep = cam.in_image(uv, margin=2)
    assert keep.sum() >= 2
    r, c = np.round(uv[keep, 1]).astype(int), np.round(uv[keep, 0]).astype(int)
    brightest = np.max([background[r + dr, c + dc].mean(axis=1) for dr in (-1, 0, 1) for dc in (-1, 0, 1)], axis=0)
    assert np.all(brightest > WHITE.mean() - 25)  # a painted pixel within one pixel of the projection
    lane_centre = cam.project(ROAD.points([15.0, 25.0], [1.75, 1.75]))
    px = background[np.round(lane_centre[:, 1]).astype(int), np.round(lane_centre[:, 0]).astype(int)]
    assert np.all(np.abs(px - ASPHALT).max(axis=1) < 30)
    assert np.all(np.abs(background[0, 320] - [170, 196, 228]) < 5)  # sky at the top


def one_box(s: float, o: float, colour=(200, 30, 30), length=4.5, width=1.8, height=1.5) -> Boxes:
    c = ROAD.points([s], [o])
    return Boxes(centre=c, heading_deg=np.array([0.0]), length=np.array([length]), width=np.array([width]),
                 height=np.array([height]), colour=np.array([colour], dtype=float))


def test_box_pixels_agree_with_the_camera_projection():
    cam = camera()
    black = np.zeros((SIZE[1], SIZE[0], 3), dtype=np.float32)
    boxes = one_box(25.0, 1.75, colour=(255, 255, 255))
    img, truth = render_frame(cam, black, boxes, shadows=False)
    expect = cam.project(boxes.corners()[0])
    np.testing.assert_allclose(truth.box[0], [*expect.min(axis=0), *expect.max(axis=0)], atol=1e-9)
    painted = np.argwhere(img.max(axis=2) > 20)
    (y1, x1), (y2, x2) = painted.min(axis=0), painted.max(axis=0)
    # Anti-aliased edges: the painted extent matches the projected corners to a pixel.
    np.testing.assert_allclose([x1, y1, x2, y2], truth.box[0], atol=1.0)
    np.testing.assert_allclose(truth.ground_point[0], cam.project(boxes.centre)[0])
    assert truth.visible_fraction[0] == pytest.approx(1.0)


def test_nearer_box_hides_the_farther_one_and_faces_are_shaded():
    cam = camera()
    grey = np.full((SIZE[1], SIZE[0], 3), 100.0, dtype=np.float32)
    far = one_box(30.0, 1.75, colour=(0, 0, 255), height=3.5, length=10.0)
    near = one_box(20.0, 1.75, colour=(255, 0, 0), height=1.5)
    both = Boxes(*(np.concatenate([getattr(far, f), getattr(near, f)]) for f in
                   ("centre", "heading_deg", "length", "width", "height", "colour")))
    img, truth = render_frame(cam, grey, both, shadows=True)
    assert truth.visible_fraction[1] == pytest.approx(1.0)
    assert 0.0 < truth.visible_fraction[0] < 0.95
    # Where the two image boxes overlap, red (near) wins over blue (far).
    x1, y1 = np.maximum(truth.box[0, :2], truth.box[1, :2]).astype(int)
    x2, y2 = np.minimum(truth.box[0, 2:], truth.box[1, 2:]).astype(int)
    overlap = img[y1:y2, x1:x2]
    reddish = (overlap[..., 0] > overlap[..., 2] + 40).sum()
    bluish = (overlap[..., 2] > overlap[..., 0] + 40).sum()
    assert reddish > 3 * bluish
    # Shading: different faces of the same box get different brightness.
    red_px = img[(img[..., 0] > 60) & (img[..., 1] < 20) & (img[..., 2] < 20)][:, 0]
    assert red_px.max() - red_px.min() > 40
    # The shadow darkens the road next to the boxes.
    assert img.min() < 100 * 0.6


def test_rendered_geometry_matches_the_camera_projection_to_a_tenth_of_a_pixel():
    """Intensity centroid of a flat box seen from above vs the centroid of its projected top face."""
    from shapely.geometry import Polygon

    cam = Camera.from_orientation(SIZE, 500.0, [E0, N0 - 5.0, Z0 + 20.0], 10.0, 60.0, 0.0,
                                  dist=[-0.08, 0.01, 0, 0, 0], crs="EPSG:2949")
    black = np.zeros((SIZE[1], SIZE[0], 3), dtype=np.float32)
    for s, o in ((8.0, 1.0), (12.0, -2.5), (6.0, 3.3)):
        boxes = one_box(s, o, colour=(255, 255, 255), length=3.3, width=2.1, height=0.002)
        img, _ = render_frame(cam, black, boxes, sun=np.array([0.0, 0.0, 1.0]), shadows=False)
        top = cam.project(boxes.corners()[0, 4:])
        expected = np.array(Polygon(top).centroid.coords[0])
        weight = img[..., 0].astype(np.float64)
        yy, xx = np.mgrid[0:SIZE[1], 0:SIZE[0]]
        got = np.array([(weight * xx).sum(), (weight * yy).sum()]) / weight.sum()
        np.testing.assert_allclose(got, expected, atol=0.1)
