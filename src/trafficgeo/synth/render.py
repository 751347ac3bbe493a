"""Render camera frames of a synthetic road scene: the orthophoto draped on the road surface, vehicles as shaded 3-D
boxes of their true size, drawn far to near so nearer vehicles hide farther ones, with optional sun shadows.

Everything goes through :class:`trafficgeo.camera.Camera` (distortion included), so a vehicle corner lands exactly
where ``camera.project`` puts it. Box edges are drawn straight between projected corners (a lens bends them by
well under a pixel over a vehicle's extent). Boxes sit level at the height of their footprint centre.

Conventions: world coordinates in the camera CRS (metres); ``heading_deg`` clockwise from north; a box's ``centre``
is the centre of its footprint on the road; corners are ordered front-left, front-right, rear-right, rear-left,
bottom (0-3) then top (4-7).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.geo.mapping import Surface, pixels_to_world
from trafficgeo.geo.raster import GeoRaster
from trafficgeo.traffic.boxes import cuboid_corners

# The 6 faces of a box as corner indices, counter-clockwise seen from outside.
_FACES = np.array([[0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7], [4, 5, 6, 7], [3, 2, 1, 0]])
SKY_TOP = np.array([170.0, 196.0, 228.0])
SKY_HORIZON = np.array([214.0, 222.0, 230.0])


@dataclass(frozen=True)
class Boxes:
    """N vehicles as boxes: ``centre`` (N, 3) footprint centres, ``heading_deg`` (N,), ``length``, ``width``,
    ``height`` (N,) in metres, ``colour`` (N, 3) RGB 0-255."""

    centre: np.ndarray
    heading_deg: np.ndarray
    length: np.ndarray
    width: np.ndarray
    height: np.ndarray
    colour: np.ndarray

    def __len__(self) -> int:
        return int(self.centre.shape[0])

    def corners(self) -> np.ndarray:
        """World corners (N, 8, 3) (:func:`trafficgeo.traffic.boxes.cuboid_corners`)."""
        return cuboid_corners(self.centre, self.heading_deg, self.length, self.width, self.height)


@dataclass(frozen=True)
class FrameTruth:
    """What the renderer drew, per box: the image box (x1, y1, x2, y2) of the projected corners clipped to the
    frame (NaN when not in view), the projected footprint centre (u, v), and the fraction of the box's projected
    area left visible after nearer boxes were drawn (0..1)."""

    box: np.ndarray
    ground_point: np.ndarray
    visible_fraction: np.ndarray


def drape_orthophoto(camera: Camera, surface: Surface, ortho: GeoRaster) -> np.ndarray:
    """The static background (H, W, 3) float32 RGB: each pixel's ray meets the surface, the orthophoto is sampled
    there (bilinear); pixels that see no ground get a sky gradient."""
    w, h = camera.image_size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    g = pixels_to_world(camera, np.column_stack([u.ravel(), v.ravel()]), surface, min_incidence_deg=0.0,
                        with_lonlat=False)
    col, row = ortho.map_to_pixel(g.xyz[:, 0], g.xyz[:, 1])
    map_x = (col - 0.5).reshape(h, w).astype(np.float32)  # cv2.remap: integer = pixel centre
    map_y = (row - 0.5).reshape(h, w).astype(np.float32)
    rgb = np.ascontiguousarray(ortho.data[:3].transpose(1, 2, 0)).astype(np.float32)
    ground = cv2.remap(rgb, np.nan_to_num(map_x, nan=-1e6), np.nan_to_num(map_y, nan=-1e6), cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
    sky = ~g.ok.reshape(h, w)
    t = np.clip(v / max(h - 1, 1), 0.0, 1.0)[..., None]
    sky_rgb = (SKY_TOP * (1 - t) + SKY_HORIZON * t).astype(np.float32)
    return np.where(sky[..., None], sky_rgb, ground).astype(np.float32)


def _fill(img: np.ndarray, poly: np.ndarray, colour: object, aa: bool = True) -> None:
    cv2.fillConvexPoly(img, np.round(poly * 16).astype(np.int32), colour, lineType=cv2.LINE_AA if aa else cv2.LINE_8,
                       shift=4)


def _window(poly: np.ndarray, w: int, h: int) -> tuple[int, int, int, int] | None:
    """Integer pixel window (x0, y0, x1, y1), exclusive ends, covering a polygon clipped to the frame."""
    x0, y0 = np.floor(poly.min(axis=0)).astype(int) - 1
    x1, y1 = np.ceil(poly.max(axis=0)).astype(int) + 2
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None


def render_frame(camera: Camera, background: np.ndarray, boxes: Boxes, *, sun: np.ndarray | None = None,
                 shadows: bool = True) -> tuple[np.ndarray, FrameTruth]:
    """Draw ``boxes`` over ``background`` (H, W, 3, uint8 or float32); returns the frame (same type) and the truth.

    ``sun``: unit vector towards the sun (default from the south-west, 40 deg high); faces are shaded by their
    angle to it, and with ``shadows`` each box casts its shadow on the road plane at its footprint height. Work is
    confined to each box's pixel window, so the cost grows with the vehicles' image size, not the frame's.
    """
    sun = np.array([-0.45, -0.55, 0.64]) if sun is None else np.asarray(sun, dtype=np.float64)
    sun = sun / np.linalg.norm(sun)
    img = background.copy()
    h, w = img.shape[:2]
    n = len(boxes)
    box = np.full((n, 4), np.nan)
    ground_pt = np.full((n, 2), np.nan)
    visible = np.zeros(n)
    if n == 0:
        return img, FrameTruth(box, ground_pt, visible)
    corners = boxes.corners()
    uv = camera.project(corners.reshape(-1, 3)).reshape(n, 8, 2)
    depth = camera.world_to_camera(corners.reshape(-1, 3))[:, 2].reshape(n, 8)
    ground_pt[:] = camera.project(boxes.centre)
    # Boxes behind the camera, or projecting absurdly far outside the frame (near the lens model's limit), are
    # not drawn.
    limit = 20.0 * max(w, h)
    in_front = (np.all(depth > 0.5, axis=1) & np.all(np.isfinite(uv), axis=(1, 2))
                & np.all(np.abs(uv) < limit, axis=(1, 2)))
    dist = np.linalg.norm(boxes.centre - camera.position, axis=1)
    order = np.argsort(-dist)  # far to near
    if shadows:
        polys = []
        for i in order:
            if not in_front[i]:
                continue
            z0 = boxes.centre[i, 2]
            top = corners[i, 4:]
            flat = top - sun[None, :] * ((top[:, 2] - z0) / sun[2])[:, None]
            hull = cv2.convexHull(np.vstack([corners[i, :4, :2], flat[:, :2]]).astype(np.float32))[:, 0, :]
            pts = camera.project(np.column_stack([hull, np.full(len(hull), z0)]))
            if np.all(np.isfinite(pts)) and np.all(np.abs(pts) < limit):
                polys.append(pts)
        if polys:
            win = _window(np.vstack(polys), w, h)
            if win is not None:
                x0, y0, x1, y1 = win
                mask = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
                for pts in polys:
                    _fill(mask, pts - [x0, y0], 255)
                sub = img[y0:y1, x0:x1]
                alpha = 1.0 - 0.45 * (mask.astype(np.float32) / 255.0)[..., None]
                sub[:] = (sub * alpha).astype(img.dtype)
    # Which box owns each pixel, over the window all boxes share (for the visible fractions).
    union = _window(uv[in_front].reshape(-1, 2), w, h) if in_front.any() else None
    ux0, uy0, ux1, uy1 = union if union is not None else (0, 0, 0, 0)
    ids = np.full((uy1 - uy0, ux1 - ux0), -1, dtype=np.int32)
    areas = np.zeros(n)
    # Face normals, visibility (front faces) and Lambert shading for all boxes at once.
    quads = corners[:, _FACES]  # (n, 6, 4, 3)
    normals = np.cross(quads[:, :, 1] - quads[:, :, 0], quads[:, :, 3] - quads[:, :, 0])
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    front = np.einsum("nfk,nfk->nf", normals, camera.position - quads[:, :, 0]) > 0
    light = 0.4 + 0.6 * np.clip(normals @ sun, 0.0, None)
    for i in order:
        if not in_front[i]:
            continue
        p = uv[i]
        x1, y1 = np.clip(p.min(axis=0), [0, 0], [w - 1, h - 1])
        x2, y2 = np.clip(p.max(axis=0), [0, 0], [w - 1, h - 1])
        win = _window(p, w, h)
        if x2 <= x1 or y2 <= y1 or win is None:
            continue
        box[i] = (x1, y1, x2, y2)
        wx0, wy0, wx1, wy1 = win
        mask = np.zeros((wy1 - wy0, wx1 - wx0), dtype=np.uint8)
        for k, face in enumerate(_FACES):
            if not front[i, k]:
                continue
            _fill(img, p[face], (boxes.colour[i] * light[i, k]).tolist())
            _fill(mask, p[face] - [wx0, wy0], 1, aa=False)
        areas[i] = mask.sum()
        ids[wy0 - uy0:wy1 - uy0, wx0 - ux0:wx1 - ux0][mask > 0] = i
    drawn = ids[ids >= 0]
    counts = np.bincount(drawn, minlength=n) if drawn.size else np.zeros(n)
    visible = np.where(areas > 0, counts / np.maximum(areas, 1), 0.0)
    return img, FrameTruth(box, ground_pt, visible)
