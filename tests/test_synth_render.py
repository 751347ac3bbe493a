"""Renderer: the draped orthophoto and the boxes agree with the Camera model; nearer boxes hide farther ones."""

from __future__ import annotations

import numpy as np
import pytest

from trafficgeo.camera.model import Camera
from trafficgeo.geo.surface import DEMSurface
from trafficgeo.synth.gcp_scene import RoadSurface
from trafficgeo.synth.orthophoto import ASPHALT, WHITE, RoadMarkings, dash_corners, render_orthophoto
from trafficgeo.synth.render import Boxes, drape_orthophoto, render_frame
from trafficgeo.synth.vehicle_mesh import HEAD_LAMP, MATERIAL_RGB, TAIL_LAMP, place, vehicle_mesh

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


@pytest.mark.slow
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


def one_box(s: float, o: float, colour=(200, 30, 30), length=4.5, width=1.8, height=1.5, kind=None,
            heading=0.0) -> Boxes:
    c = ROAD.points([s], [o])
    return Boxes(centre=c, heading_deg=np.array([heading]), length=np.array([length]), width=np.array([width]),
                 height=np.array([height]), colour=np.array([colour], dtype=float),
                 kind=None if kind is None else np.array([kind], dtype=object))


def join(*boxes: Boxes) -> Boxes:
    return Boxes(*(np.concatenate([getattr(b, f) for b in boxes]) for f in
                   ("centre", "heading_deg", "length", "width", "height", "colour", "kind")))


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
    """Intensity centroid of a flat box seen from above vs the centroid of its projected top face.

    Vehicles are drawn at 3x resolution and averaged down, so a polygon edge lands to within half a sub-pixel
    (1/6 px) of where it belongs: the tolerance (was 0.1 px with exact-coverage anti-aliasing) is that bound."""
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
        np.testing.assert_allclose(got, expected, atol=1 / 6)


# ---------------------------------------------------------------------------------------------------- vehicle meshes
SIZES = {"car": (4.5, 1.8, 1.5), "van": (5.4, 2.0, 2.4), "truck": (12.0, 2.55, 3.8), "bus": (12.0, 2.55, 3.1),
         "motorcycle": (2.2, 0.8, 1.5)}


def mesh_pixels(cam: Camera, boxes: Boxes, i: int) -> np.ndarray:
    """Projected vertices (V, 2) of vehicle i's mesh."""
    mesh = vehicle_mesh(boxes.kinds()[i], boxes.length[i], boxes.width[i], boxes.height[i])
    verts, _, _ = place(mesh, boxes.centre[i:i + 1], boxes.heading_deg[i:i + 1])
    return cam.project(verts[0])


def silhouette(cam: Camera, boxes: Boxes, i: int):
    """The exact silhouette of vehicle i: the union of all its projected polygons (shapely)."""
    from shapely.geometry import Polygon
    from shapely.ops import unary_union

    mesh = vehicle_mesh(boxes.kinds()[i], boxes.length[i], boxes.width[i], boxes.height[i])
    uv = mesh_pixels(cam, boxes, i)
    polys = [Polygon(uv[f[:k]]).buffer(0) for f, k in zip(mesh.faces, mesh.sizes, strict=True) if k >= 3]
    return unary_union([p for p in polys if p.area > 0])


@pytest.mark.parametrize("kind", sorted(SIZES))
def test_every_mesh_lies_in_its_cuboid_and_its_truth_box_is_the_projected_mesh(kind):
    cam = camera()
    black = np.zeros((SIZE[1], SIZE[0], 3), dtype=np.float32)
    length, width, height = SIZES[kind]
    mesh = vehicle_mesh(kind, length, width, height)
    v = mesh.vertices
    assert np.all(np.abs(v[:, 0]) <= length / 2 + 1e-9) and np.all(np.abs(v[:, 1]) <= width / 2 + 1e-9)
    assert v[:, 2].min() == pytest.approx(0.0, abs=1e-9) and v[:, 2].max() == pytest.approx(height)
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1.0)
    for heading in (0.0, 35.0, 120.0, 200.0, 300.0):
        boxes = one_box(40.0, 1.75, length=length, width=width, height=height, kind=kind, heading=heading)
        img, truth = render_frame(cam, black, boxes, shadows=False)
        uv = mesh_pixels(cam, boxes, 0)
        np.testing.assert_allclose(truth.box[0], [*uv.min(axis=0), *uv.max(axis=0)], atol=1e-9)
        cuboid = cam.project(boxes.corners()[0])
        lo, hi = cuboid.min(axis=0), cuboid.max(axis=0)
        assert np.all(truth.box[0, :2] >= lo - 1e-9) and np.all(truth.box[0, 2:] <= hi + 1e-9)
        # Tighter than the cuboid's box: the wheels, the bumpers' lower edge and the cabin are inset.
        area = np.prod(truth.box[0, 2:] - truth.box[0, :2])
        assert area < 0.97 * np.prod(hi - lo)
        # Every painted pixel's centre lies within half a pixel of the truth box (a pixel the silhouette touches),
        # and the painted extent reaches the box's edges.
        painted = np.argwhere(img.max(axis=2) > 0.5)
        (y1, x1), (y2, x2) = painted.min(axis=0), painted.max(axis=0)
        x1b, y1b, x2b, y2b = truth.box[0]
        tol = 0.5 + 1 / 48  # half a pixel, plus OpenCV's 1/16 sub-pixel vertex rounding
        assert x1 >= x1b - tol and y1 >= y1b - tol and x2 <= x2b + tol and y2 <= y2b + tol
        assert x1 <= x1b + 1 and y1 <= y1b + 1 and x2 >= x2b - 1 and y2 >= y2b - 1
        assert truth.visible_fraction[0] == pytest.approx(1.0)


def test_the_silhouette_box_is_clipped_to_the_frame():
    cam = camera()
    black = np.zeros((SIZE[1], SIZE[0], 3), dtype=np.float32)
    boxes = one_box(12.0, -6.0, kind="bus", length=12.0, width=2.55, height=3.1, heading=10.0)
    uv = mesh_pixels(cam, boxes, 0)
    assert uv[:, 0].min() < -10  # partly outside on the left
    _, truth = render_frame(cam, black, boxes, shadows=False)
    expect = np.clip([*uv.min(axis=0), *uv.max(axis=0)], 0, [SIZE[0] - 1, SIZE[1] - 1, SIZE[0] - 1, SIZE[1] - 1])
    np.testing.assert_allclose(truth.box[0], expect, atol=1e-9)
    assert truth.visible_fraction[0] == pytest.approx(1.0)  # leaving the frame is not being hidden


def bus_behind(kind: str, s_near: float, o_near: float) -> Boxes:
    """A bus at station 32 and, nearer the camera, a vehicle of ``kind`` hiding part of it."""
    far = one_box(32.0, 1.75, colour=(0, 0, 255), kind="bus", length=12.0, width=2.55, height=3.1, heading=3.0)
    length, width, height = SIZES[kind]
    near = one_box(s_near, o_near, colour=(255, 0, 0), kind=kind, length=length, width=width, height=height,
                   heading=355.0)
    return join(far, near)


@pytest.mark.parametrize(("kind", "s_near", "o_near"), [("van", 22.0, 3.0), ("car", 26.0, 1.75),
                                                         ("van", 24.0, 2.0)])
def test_visible_fraction_is_the_uncovered_share_of_the_silhouette(kind, s_near, o_near):
    """The visible share of the far vehicle's silhouette against the exact polygons (the renderer counts 3x
    sub-pixels: measured within 0.004)."""
    cam = camera()
    black = np.zeros((SIZE[1], SIZE[0], 3), dtype=np.float32)
    both = bus_behind(kind, s_near, o_near)
    _, truth = render_frame(cam, black, both, shadows=False)
    sil_far, sil_near = silhouette(cam, both, 0), silhouette(cam, both, 1)
    expect = sil_far.difference(sil_near).area / sil_far.area
    assert 0.05 < expect < 0.95
    assert truth.visible_fraction[0] == pytest.approx(expect, abs=0.01)
    assert truth.visible_fraction[1] == pytest.approx(1.0)


def test_the_near_vehicle_fully_hides_the_far_one_where_they_overlap():
    cam = camera()
    grey = np.full((SIZE[1], SIZE[0], 3), 100.0, dtype=np.float32)
    both = bus_behind("van", 22.0, 3.0)
    near = join(Boxes(*(getattr(both, f)[1:] for f in ("centre", "heading_deg", "length", "width", "height",
                                                        "colour", "kind"))))
    img, truth = render_frame(cam, grey, both, shadows=False)
    alone, _ = render_frame(cam, grey, near, shadows=False)
    on_white, _ = render_frame(cam, np.full_like(grey, 255.0), near, shadows=False)
    on_black, _ = render_frame(cam, np.zeros_like(grey), near, shadows=False)
    covered = np.all(on_white == on_black, axis=2) & (on_black.max(axis=2) > 0)  # the van's pixels, fully
    x1, y1, x2, y2 = truth.box[0]
    yy, xx = np.mgrid[0:SIZE[1], 0:SIZE[0]]
    overlap = covered & (xx >= x1) & (xx <= x2) & (yy >= y1) & (yy <= y2)
    assert overlap.sum() > 300
    np.testing.assert_array_equal(img[overlap], alone[overlap])  # not a trace of the bus
    assert (img[..., 2] > img[..., 0] + 100).sum() > 300  # the bus is drawn where it is not hidden


def test_shadows_darken_the_road_beside_and_under_a_vehicle():
    cam = camera()
    grey = np.full((SIZE[1], SIZE[0], 3), 100, dtype=np.uint8)
    boxes = one_box(25.0, 1.75, kind="car")
    plain, truth = render_frame(cam, grey, boxes, shadows=False)
    shaded, truth2 = render_frame(cam, grey, boxes, shadows=True)
    np.testing.assert_array_equal(truth.box, truth2.box)
    darker = shaded.astype(int).sum(axis=2) < plain.astype(int).sum(axis=2) - 30
    assert darker.sum() > 100
    assert shaded.min() < 100 * 0.6  # the sun shadow and the contact shadow together
    assert shaded.dtype == np.uint8


@pytest.mark.parametrize(("heading", "lit", "unlit"), [(0.0, TAIL_LAMP, HEAD_LAMP), (180.0, HEAD_LAMP, TAIL_LAMP)])
def test_back_faces_are_dropped_and_decals_drawn_on_their_face(heading, lit, unlit):
    """Driving away from the camera the tail lamps show and the head lamps (on the hidden front face) do not;
    driving towards it, the reverse."""
    from trafficgeo.synth.render import _AMBIENT, _DIFFUSE, _draw_order, _place_all

    cam = camera()
    black = np.zeros((SIZE[1], SIZE[0], 3), dtype=np.float32)
    boxes = one_box(25.0, 1.75, colour=(90, 90, 90), kind="car", heading=heading)
    img, _ = render_frame(cam, black, boxes, shadows=False)
    p = _place_all(cam, boxes, 1e9)[0]
    order = _draw_order(cam, p)
    toward = np.einsum("fk,fk->f", p.normals, cam.position - p.verts[p.mesh.faces[:, 0]]) > 0
    assert set(order) == set(np.flatnonzero(toward))  # exactly the faces turned towards the camera
    mat = p.mesh.material[order]
    assert (mat == lit).sum() == 2 and (mat == unlit).sum() == 0
    # Tail-lamp red is in the image only when the rear is seen.
    lo = MATERIAL_RGB[TAIL_LAMP] * _AMBIENT[TAIL_LAMP] - 2
    hi = MATERIAL_RGB[TAIL_LAMP] * (_AMBIENT[TAIL_LAMP] + _DIFFUSE[TAIL_LAMP]) + 2
    red = np.all((img >= lo) & (img <= hi), axis=2).sum()
    assert (red >= 4) == (lit == TAIL_LAMP), red
    # Inside a vehicle, groups are drawn far to near and each surface before the decals on it.
    rank = np.argsort(np.argsort(-np.linalg.norm(p.centres - cam.position, axis=1)))
    keys = np.column_stack([rank[p.mesh.group[order]], p.mesh.layer[order]])
    assert np.all(np.diff(keys[:, 0]) >= 0)
    same = np.diff(keys[:, 0]) == 0
    assert np.all(np.diff(keys[:, 1])[same] >= 0)
