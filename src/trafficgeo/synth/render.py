"""Render camera frames of a synthetic road scene: the orthophoto draped on the road surface, vehicles as shaded
low-poly meshes of their class and true size (:mod:`trafficgeo.synth.vehicle_mesh`: body, cabin with glass, lamps,
bumper, plate and wheels; plain boxes when no class is given), drawn far to near so nearer vehicles hide farther
ones, with optional blurred sun and contact shadows.

Everything goes through :class:`trafficgeo.camera.Camera` (distortion included), so a mesh vertex lands exactly
where ``camera.project`` puts it. Polygon edges are drawn straight between projected vertices (a lens bends them by
well under a pixel over a vehicle's extent). Vehicles sit level at the height of their footprint centre. Each
vehicle is drawn at 3x resolution in its own pixel window and averaged down (anti-aliasing by supersampling).

Conventions: world coordinates in the camera CRS (metres); ``heading_deg`` clockwise from north; a box's ``centre``
is the centre of its footprint on the road; corners are ordered front-left, front-right, rear-right, rear-left,
bottom (0-3) then top (4-7).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.geo.cuboids import cuboid_corners
from trafficgeo.geo.drape import drape_orthophoto as drape
from trafficgeo.geo.mapping import Surface
from trafficgeo.geo.raster import GeoRaster
from trafficgeo.synth.vehicle_mesh import BODY, GLASS, MATERIAL_RGB, Mesh, kind_name, place, vehicle_mesh

SUPERSAMPLE = 3
SHADOW_DARKEN = 0.45  # the sun shadow removes this share of the light
CONTACT_DARKEN = 0.5  # under the vehicle
SKY_TOP = np.array([170.0, 196.0, 228.0])
SKY_HORIZON = np.array([214.0, 222.0, 230.0])


@dataclass(frozen=True)
class Boxes:
    """N vehicles: ``centre`` (N, 3) footprint centres, ``heading_deg`` (N,), ``length``, ``width``, ``height`` (N,)
    in metres, ``colour`` (N, 3) RGB 0-255, ``kind`` (N,) class names drawn as vehicle meshes (``car``, ``van``,
    ``truck``, ``bus``, ``motorcycle``, ``bicycle``; other names as cars) or None: plain shaded boxes."""

    centre: np.ndarray
    heading_deg: np.ndarray
    length: np.ndarray
    width: np.ndarray
    height: np.ndarray
    colour: np.ndarray
    kind: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.centre.shape[0])

    def corners(self) -> np.ndarray:
        """World corners (N, 8, 3) (:func:`trafficgeo.traffic.box_points.cuboid_corners`)."""
        return cuboid_corners(self.centre, self.heading_deg, self.length, self.width, self.height)

    def kinds(self) -> np.ndarray:
        """Mesh kind per vehicle (N,) str (``box`` without ``kind``)."""
        if self.kind is None:
            return np.full(len(self), "box", dtype=object)
        return np.array([kind_name(k) for k in np.asarray(self.kind, dtype=object).reshape(-1)], dtype=object)


@dataclass(frozen=True)
class FrameTruth:
    """What the renderer drew, per vehicle: its silhouette box (x1, y1, x2, y2), the bounding box of its projected
    mesh vertices clipped to the frame (NaN when not drawn), the projected footprint centre (u, v), and the fraction
    of its drawn silhouette inside the frame left visible after nearer vehicles were drawn (0..1, counted on the
    3x supersampled masks)."""

    box: np.ndarray
    ground_point: np.ndarray
    visible_fraction: np.ndarray


def drape_orthophoto(camera: Camera, surface: Surface, ortho: GeoRaster) -> np.ndarray:
    """The static background (H, W, 3) float32 RGB: the orthophoto through the camera
    (:func:`trafficgeo.geo.drape.drape_orthophoto`); pixels that see no ground get a sky gradient."""
    view = drape(camera, surface, ortho)
    h = camera.image_size[1]
    t = np.clip(np.arange(h, dtype=np.float64) / max(h - 1, 1), 0.0, 1.0)[:, None, None]
    sky_rgb = (SKY_TOP * (1 - t) + SKY_HORIZON * t).astype(np.float32)
    return np.where(view.ground[..., None], view.image[..., :3], sky_rgb).astype(np.float32)


def _fill(img: np.ndarray, poly: np.ndarray, colour: object, aa: bool = True) -> None:
    cv2.fillConvexPoly(img, np.round(poly * 16).astype(np.int32), colour, lineType=cv2.LINE_AA if aa else cv2.LINE_8,
                       shift=4)


def _window(poly: np.ndarray, w: int, h: int) -> tuple[int, int, int, int] | None:
    """Integer pixel window (x0, y0, x1, y1), exclusive ends, covering a polygon clipped to the frame."""
    x0, y0 = np.floor(poly.min(axis=0)).astype(int) - 1
    x1, y1 = np.ceil(poly.max(axis=0)).astype(int) + 2
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None




# Lambert shading per material: light = ambient + diffuse * max(n . sun, 0).
_AMBIENT = np.full(len(MATERIAL_RGB), 0.4)
_DIFFUSE = np.full(len(MATERIAL_RGB), 0.6)
_AMBIENT[GLASS], _DIFFUSE[GLASS] = 0.8, 0.4
_AMBIENT[5:8], _DIFFUSE[5:8] = 0.75, 0.25  # lamps and plate


@dataclass(frozen=True)
class _Placed:
    """One vehicle's mesh in the world: vertices (V, 3), their pixels (V, 2), face normals (F, 3), group centres."""

    mesh: Mesh
    verts: np.ndarray
    uv: np.ndarray
    normals: np.ndarray
    centres: np.ndarray


def _place_all(camera: Camera, boxes: Boxes, limit: float) -> list[_Placed | None]:
    """Meshes of all vehicles placed and projected (vehicles sharing kind and size at once); None for a vehicle
    partly behind the camera or projecting absurdly far outside the frame (near the lens model's limit)."""
    kinds = boxes.kinds()
    dims = np.column_stack([boxes.length, boxes.width, boxes.height]).astype(np.float64)
    groups: dict[tuple, list[int]] = {}
    for i in range(len(boxes)):
        groups.setdefault((kinds[i], *np.round(dims[i], 6)), []).append(i)
    out: list[_Placed | None] = [None] * len(boxes)
    for (kind, length, width, height), idx in groups.items():
        mesh = vehicle_mesh(kind, length, width, height)
        verts, normals, centres = place(mesh, boxes.centre[idx], boxes.heading_deg[idx])
        flat = verts.reshape(-1, 3)
        uv = camera.project(flat).reshape(verts.shape[0], -1, 2)
        depth = camera.world_to_camera(flat)[:, 2].reshape(verts.shape[0], -1)
        ok = np.all(depth > 0.5, axis=1) & np.all(np.isfinite(uv), axis=(1, 2)) & np.all(np.abs(uv) < limit,
                                                                                          axis=(1, 2))
        for k, i in enumerate(idx):
            if ok[k]:
                out[i] = _Placed(mesh, verts[k], uv[k], normals[k], centres[k])
    return out


def _shadows(img: np.ndarray, camera: Camera, boxes: Boxes, placed: list[_Placed | None], sun: np.ndarray,
             limit: float) -> None:
    """Darken the road under the sun shadows (each mesh's outline flattened along the sun onto the plane of its
    footprint, blurred) and the contact shadows (the footprint, slightly inset, blurred less). Overlapping
    shadows do not darken twice."""
    h, w = img.shape[:2]
    feet = boxes.corners()[:, :4]
    polys, owner = [], []
    for i, p in enumerate(placed):
        if p is None:
            continue
        c = boxes.centre[i]
        rel = p.verts - c
        flat = rel[:, :2] - sun[None, :2] * (rel[:, 2] / sun[2])[:, None]
        hull = cv2.convexHull(flat.astype(np.float32))[:, 0, :].astype(np.float64)
        for poly in (c[:2] + hull, c[:2] + 0.96 * (feet[i, :, :2] - c[:2])):
            polys.append(np.column_stack([poly, np.full(len(poly), c[2])]))
        owner.append(i)
    if not polys:
        return
    pix = np.split(camera.project(np.vstack(polys)), np.cumsum([len(q) for q in polys])[:-1])
    shadows = []
    for k in range(len(owner)):
        sun_pts, foot_pts = pix[2 * k], pix[2 * k + 1]
        both = np.vstack([sun_pts, foot_pts])
        win = _window(both, w, h) if np.all(np.isfinite(both)) and np.all(np.abs(both) < limit) else None
        if win is not None:
            shadows.append((sun_pts, foot_pts, (max(win[0] - 4, 0), max(win[1] - 4, 0), min(win[2] + 4, w),
                                                min(win[3] + 4, h))))
    if not shadows:
        return
    wins = np.array([s[2] for s in shadows])
    ux0, uy0 = wins[:, :2].min(axis=0)
    ux1, uy1 = wins[:, 2:].max(axis=0)
    factor = np.ones((uy1 - uy0, ux1 - ux0), dtype=np.float32)
    for sun_pts, foot_pts, (x0, y0, x1, y1) in shadows:
        local = np.ones((y1 - y0, x1 - x0), dtype=np.float32)
        for pts, strength, sigma in ((sun_pts, SHADOW_DARKEN, 1.5), (foot_pts, CONTACT_DARKEN, 0.8)):
            mask = np.zeros_like(local)
            _fill(mask, pts - [x0, y0], 1.0)
            local *= 1.0 - strength * cv2.GaussianBlur(mask, (0, 0), sigma)
        part = factor[y0 - uy0:y1 - uy0, x0 - ux0:x1 - ux0]
        np.minimum(part, local, out=part)
    _scale(img[uy0:uy1, ux0:ux1], factor)


def _scale(sub: np.ndarray, factor: np.ndarray) -> None:
    """sub (h, w, 3) *= factor (h, w) in place (uint8: rounded and saturated)."""
    if sub.dtype == np.uint8:
        f8 = cv2.convertScaleAbs(factor, alpha=255.0)
        sub[:] = cv2.multiply(sub, cv2.merge([f8, f8, f8]), scale=1.0 / 255.0)
    else:
        sub *= factor[..., None].astype(sub.dtype)


def _draw_order(camera: Camera, p: _Placed) -> np.ndarray:
    """Indices of the faces to draw, in order: back faces dropped, groups far to near (by their centres), inside
    a group by layer (a surface, then its decals, then the wheels)."""
    mesh = p.mesh
    front = np.einsum("fk,fk->f", p.normals, camera.position - p.verts[mesh.faces[:, 0]]) > 0
    rank = np.argsort(np.argsort(-np.linalg.norm(p.centres - camera.position, axis=1)))
    order = np.lexsort((np.arange(len(front)), mesh.layer, rank[mesh.group]))
    return order[front[order]]


def _draw_vehicle(img: np.ndarray, camera: Camera, p: _Placed, colour: np.ndarray, sun: np.ndarray,
                  win: tuple[int, int, int, int]) -> np.ndarray:
    """Draw one vehicle into its window of ``img`` at SUPERSAMPLE x resolution; returns its supersampled silhouette
    mask (uint8 0/1). Back faces are dropped; groups are drawn far to near, each surface before its decals."""
    mesh, s = p.mesh, SUPERSAMPLE
    x0, y0, x1, y1 = win
    order = _draw_order(camera, p)
    lam = np.clip(p.normals[order] @ sun, 0.0, None)
    mat = mesh.material[order]
    base = np.where((mat == BODY)[:, None], colour[None, :], MATERIAL_RGB[mat])
    rgb = np.clip(base * (_AMBIENT[mat] + _DIFFUSE[mat] * lam)[:, None], 1.0, 255.0).tolist()
    # Window pixel (u, v) covers [u - 0.5, u + 0.5]; its s x s sub-pixels have centres at u - 0.5 + (k + 0.5) / s.
    pts = np.round(((p.uv - [x0, y0] + 0.5) * s - 0.5) * 16).astype(np.int32)[mesh.faces[order]]
    canvas = np.zeros(((y1 - y0) * s, (x1 - x0) * s, 3), dtype=np.uint8)
    for poly, c in zip(pts, rgb, strict=True):
        cv2.fillConvexPoly(canvas, poly, c, lineType=cv2.LINE_8, shift=4)
    mask = (cv2.cvtColor(canvas, cv2.COLOR_RGB2GRAY) > 0).view(np.uint8)  # every face colour is >= 1
    size = (x1 - x0, y1 - y0)
    cover = cv2.resize(mask * np.uint8(255), size, interpolation=cv2.INTER_AREA)
    paint = cv2.resize(canvas, size, interpolation=cv2.INTER_AREA)  # premultiplied by the coverage
    sub = img[y0:y1, x0:x1]
    if sub.dtype == np.uint8:
        _scale(sub, (255 - cover).astype(np.float32) / 255.0)
        sub[:] = cv2.add(sub, paint)
    else:
        sub[:] = sub * (1.0 - cover[..., None] / np.float32(255.0)) + paint
    return mask


def _visible_fractions(masks: dict[int, tuple[tuple[int, int, int, int], np.ndarray]], order: np.ndarray,
                       n: int) -> np.ndarray:
    """Share of each vehicle's supersampled mask not covered by the masks of vehicles drawn after it."""
    s = SUPERSAMPLE
    visible = np.zeros(n)
    nearer: list[int] = []
    for i in order[::-1]:
        if i not in masks:
            continue
        (ax0, ay0, _, _), m = masks[i]
        ax0, ay0 = ax0 * s, ay0 * s
        ax1, ay1 = ax0 + m.shape[1], ay0 + m.shape[0]
        covered = np.zeros_like(m)
        for j in nearer:
            (bx0, by0, _, _), mj = masks[j]
            bx0, by0 = bx0 * s, by0 * s
            ox0, oy0 = max(ax0, bx0), max(ay0, by0)
            ox1, oy1 = min(ax1, bx0 + mj.shape[1]), min(ay1, by0 + mj.shape[0])
            if ox1 > ox0 and oy1 > oy0:
                covered[oy0 - ay0:oy1 - ay0, ox0 - ax0:ox1 - ax0] |= mj[oy0 - by0:oy1 - by0, ox0 - bx0:ox1 - bx0]
        area = cv2.countNonZero(m)
        visible[i] = (area - cv2.countNonZero(m & covered)) / area if area else 0.0
        nearer.append(i)
    return visible


def render_frame(camera: Camera, background: np.ndarray, boxes: Boxes, *, sun: np.ndarray | None = None,
                 shadows: bool = True) -> tuple[np.ndarray, FrameTruth]:
    """Draw ``boxes`` over ``background`` (H, W, 3, uint8 or float32); returns the frame (same type) and the truth.

    ``sun``: unit vector towards the sun (default from the south-west, 40 deg high); faces are shaded by their
    angle to it, and with ``shadows`` each vehicle casts its shadow on the plane of its footprint. Work is confined
    to each vehicle's pixel window, so the cost grows with the vehicles' image size, not the frame's.
    """
    sun = np.array([-0.45, -0.55, 0.64]) if sun is None else np.asarray(sun, dtype=np.float64)
    sun = sun / np.linalg.norm(sun)
    img = background.copy()
    h, w = img.shape[:2]
    n = len(boxes)
    box = np.full((n, 4), np.nan)
    ground_pt = np.full((n, 2), np.nan)
    if n == 0:
        return img, FrameTruth(box, ground_pt, np.zeros(0))
    ground_pt[:] = camera.project(boxes.centre)
    limit = 20.0 * max(w, h)
    placed = _place_all(camera, boxes, limit)
    order = np.argsort(-np.linalg.norm(boxes.centre - camera.position, axis=1), kind="stable")  # far to near
    if shadows:
        _shadows(img, camera, boxes, placed, sun, limit)
    masks = {}
    for i in order:
        p = placed[i]
        if p is None:
            continue
        x1, y1 = np.clip(p.uv.min(axis=0), [0, 0], [w - 1, h - 1])
        x2, y2 = np.clip(p.uv.max(axis=0), [0, 0], [w - 1, h - 1])
        win = _window(p.uv, w, h)
        if x2 <= x1 or y2 <= y1 or win is None:
            continue
        box[i] = (x1, y1, x2, y2)
        masks[i] = (win, _draw_vehicle(img, camera, p, np.asarray(boxes.colour[i], dtype=np.float64), sun, win))
    return img, FrameTruth(box, ground_pt, _visible_fractions(masks, order, n))
