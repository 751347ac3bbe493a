"""Low-poly vehicle meshes for the synthetic renderer: cars, vans, trucks, buses and two-wheelers built procedurally
from their length, width and height, so that a learned (COCO) detector sees vehicles rather than boxes.

A mesh is a list of flat convex polygons in the **vehicle frame** (metres): ``x`` forward from the footprint
centre, ``y`` to the right, ``z`` up from the road; every vertex lies inside the cuboid
``|x| <= L/2, |y| <= W/2, 0 <= z <= H`` (the wheels touch ``z = 0``). :func:`place` puts meshes in the world with
the convention of :func:`trafficgeo.traffic.box_points.cuboid_corners` (``heading_deg`` clockwise from north,
``centre`` the footprint centre on the road, the vehicle level).

Each polygon carries an outward normal (for back-face culling and Lambert shading), a material and a draw
``group`` and ``layer``: the renderer orders groups far to near by their centre and, inside a group, draws
layer 0 (the surface), then the decals lying on it (lamps, plate, windows, wheel wells), then the wheels.
The underside is left open: the camera is always above the road.

Kinds: ``car``, ``van``, ``truck``, ``bus``, ``motorcycle``, ``bicycle`` (a two-wheeler), and ``box`` (a plain
cuboid: the old look, exactly the cuboid). Other names are drawn as cars (:data:`KIND_ALIASES` first).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

# Materials (index into MATERIAL_RGB); BODY takes the vehicle's colour.
BODY, GLASS, TYRE, WELL, TRIM, TAIL_LAMP, HEAD_LAMP, PLATE, HUB, CARGO, RIDER = range(11)
MATERIAL_RGB = np.array([
    [0, 0, 0], [34, 40, 52], [24, 24, 26], [10, 10, 10], [40, 40, 43], [200, 22, 28], [244, 240, 222],
    [236, 236, 228], [130, 130, 136], [214, 214, 208], [48, 48, 58]], dtype=np.float64)
KINDS = ("box", "car", "van", "truck", "bus", "motorcycle", "bicycle")
KIND_ALIASES = {"passenger": "car", "delivery": "van", "lorry": "truck", "coach": "bus", "motorbike": "motorcycle",
                "bike": "bicycle", "": "car"}


@dataclass(frozen=True)
class Mesh:
    """Polygons in the vehicle frame: ``vertices`` (V, 3) m; ``faces`` (F, K) vertex indices (rows padded by
    repeating their last index), ``sizes`` (F,) vertices per face; ``normals`` (F, 3) unit outward; ``material``,
    ``group``, ``layer`` (F,) ints; ``group_centre`` (G, 3) m, the point a group is ordered by."""

    vertices: np.ndarray
    faces: np.ndarray
    sizes: np.ndarray
    normals: np.ndarray
    material: np.ndarray
    group: np.ndarray
    layer: np.ndarray
    group_centre: np.ndarray


class _Builder:
    def __init__(self) -> None:
        self.polys: list[np.ndarray] = []
        self.normals: list[np.ndarray] = []
        self.material: list[int] = []
        self.group: list[int] = []
        self.layer: list[int] = []
        self.n_groups = 0

    def new_group(self) -> int:
        self.n_groups += 1
        return self.n_groups - 1

    def add(self, poly: ArrayLike, material: int, *, inside: ArrayLike = None, normal: ArrayLike = None,
            group: int | None = None, layer: int = 0) -> int:
        """One convex polygon (k, 3); its normal is ``normal`` or Newell's, turned away from the point ``inside``."""
        p = np.asarray(poly, dtype=np.float64)
        if normal is None:
            n = np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)
            n /= max(np.linalg.norm(n), 1e-12)
            if inside is not None and n @ (p.mean(axis=0) - np.asarray(inside, dtype=np.float64)) < 0:
                n = -n
        else:
            n = np.asarray(normal, dtype=np.float64)
        self.polys.append(p)
        self.normals.append(n)
        self.material.append(material)
        self.group.append(self.new_group() if group is None else group)
        self.layer.append(layer)
        return len(self.polys) - 1

    def mesh(self) -> Mesh:
        sizes = np.array([len(p) for p in self.polys])
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        k = np.arange(sizes.max())
        faces = starts[:, None] + np.minimum(k[None, :], sizes[:, None] - 1)
        vertices = np.vstack(self.polys)
        group = np.array(self.group)
        layer = np.array(self.layer)
        centroids = np.array([p.mean(axis=0) for p in self.polys])
        base = layer == 0
        centre = np.zeros((self.n_groups, 3))
        for g in range(self.n_groups):
            sel = (group == g) & base
            centre[g] = centroids[sel if sel.any() else group == g].mean(axis=0)
        arrays = [vertices, faces, sizes, np.array(self.normals), np.array(self.material), group, layer, centre]
        for a in arrays:
            a.flags.writeable = False  # meshes are cached and shared
        return Mesh(*arrays)

    # ------------------------------------------------------------------ parts
    def loft(self, x: ArrayLike, section: ArrayLike, materials: object, *, caps: tuple[bool, bool] = (True, True),
             skip_top: object = ()) -> dict[str, object]:
        """A solid lofted along ``x`` (S,) through cross-sections ``section`` (S, P, 2) of (y, z) points, each an
        open polyline from the left bottom over the top to the right bottom (convex with the bottom chord).
        ``materials`` (S-1, P-1): material of each side/top face per segment (-1 = none); ``skip_top``: (segment,
        edge) pairs left out (faces hidden under another part). The faces of the first and last edges (the lower
        sides) of all segments share one draw group per side. Returns the face indices: ``rear``/``front`` caps,
        ``left``/``right`` lower sides (with their ``left_group``/``right_group``), ``faces`` by (segment, edge)."""
        x = np.asarray(x, dtype=np.float64)
        sec = np.asarray(section, dtype=np.float64)
        mats = np.asarray(materials)
        n_seg, n_edge = len(x) - 1, sec.shape[1] - 1
        mid = np.array([0.5 * (x[0] + x[-1]), 0.0, 0.5 * (sec[:, :, 1].min() + sec[:, :, 1].max())])
        pts = np.concatenate([np.broadcast_to(x[:, None, None], sec.shape[:2] + (1,)), sec], axis=2)
        left, right = self.new_group(), self.new_group()
        out: dict[str, object] = {"left": [], "right": [], "left_group": left, "right_group": right, "faces": {}}
        for s in range(n_seg):
            for e in range(n_edge):
                if mats[s, e] < 0 or (s, e) in skip_top:
                    continue
                quad = np.array([pts[s, e], pts[s + 1, e], pts[s + 1, e + 1], pts[s, e + 1]])
                keep = np.r_[True, np.linalg.norm(np.diff(quad, axis=0), axis=1) > 1e-9]
                if keep.sum() < 3:
                    continue
                inside = mid.copy()
                inside[0] = quad[:, 0].mean()
                group = left if e == 0 else right if e == n_edge - 1 else None
                i = self.add(quad[keep], int(mats[s, e]), inside=inside, group=group)
                out["faces"][(s, e)] = i
                if e in (0, n_edge - 1):
                    out["left" if e == 0 else "right"].append(i)
        for on, sign in zip(caps, (-1.0, 1.0), strict=True):
            if on:
                k = 0 if sign < 0 else -1
                out["rear" if sign < 0 else "front"] = self.add(pts[k], int(mats[k, 0]), normal=[sign, 0.0, 0.0])
        return out

    def decal(self, parent: int, poly2d: ArrayLike, material: int, layer: int = 1) -> int:
        """A flat polygon on face ``parent`` (an end cap at constant x, or a side at constant y), given as
        (k, 2) in-plane points: (y, z) on an end cap, (x, z) on a side."""
        n = self.normals[parent]
        p0 = self.polys[parent][0]
        q = np.asarray(poly2d, dtype=np.float64)
        if abs(n[0]) > 0.99:
            poly = np.column_stack([np.full(len(q), p0[0]), q[:, 0], q[:, 1]])
        else:
            poly = np.column_stack([q[:, 0], np.full(len(q), p0[1]), q[:, 1]])
        return self.add(poly, material, normal=n, group=self.group[parent], layer=layer)

    def inset_decal(self, parent: int, material: int, shrink: float, t0: float = 0.0, t1: float = 1.0) -> int:
        """A decal on a quad (or triangle) ``parent``: its part between fractions ``t0``..``t1`` of its length
        along x, shrunk towards its own centre by ``shrink`` (0..1)."""
        p = self.polys[parent]
        order = np.argsort(p[:, 0], kind="stable")
        x_lo, x_hi = p[order[0], 0], p[order[-1], 0]
        xa, xb = x_lo + t0 * (x_hi - x_lo), x_lo + t1 * (x_hi - x_lo)
        # Clip the polygon to xa <= x <= xb (Sutherland-Hodgman on two planes).
        for bound, keep_above in ((xa, True), (xb, False)):
            out = []
            for a, b in zip(p, np.roll(p, -1, axis=0), strict=True):
                ina = a[0] >= bound - 1e-12 if keep_above else a[0] <= bound + 1e-12
                inb = b[0] >= bound - 1e-12 if keep_above else b[0] <= bound + 1e-12
                if ina:
                    out.append(a)
                if ina != inb:
                    out.append(a + (bound - a[0]) / (b[0] - a[0]) * (b - a))
            p = np.array(out)
        c = p.mean(axis=0)
        return self.add(c + (p - c) * shrink, material, normal=self.normals[parent], group=self.group[parent],
                        layer=1)

    def wheel(self, x: float, radius: float, y_out: float, tyre_width: float, group: int, hub: bool = True,
              sides: int = 6) -> None:
        """A ``sides``-gon wheel at ``x`` touching the road, its outer face at ``y_out`` (sign = side)."""
        sign = np.sign(y_out)
        a = np.radians(270.0 + 180.0 / sides + np.arange(sides) * 360.0 / sides)  # a flat bottom edge
        zc = radius * np.cos(np.pi / sides)  # flat bottom edge on the road
        ring = np.column_stack([x + radius * np.cos(a), zc + radius * np.sin(a)])
        outer = np.column_stack([ring[:, 0], np.full(sides, y_out), ring[:, 1]])
        inner = outer.copy()
        inner[:, 1] = y_out - sign * tyre_width
        cap = self.add(outer, TYRE, normal=[0.0, sign, 0.0], group=group, layer=2)
        self.add(inner, TYRE, normal=[0.0, -sign, 0.0], group=group, layer=2)
        for k in range(sides):
            j = (k + 1) % sides
            mid = a[k] + np.pi / sides
            self.add([outer[k], outer[j], inner[j], inner[k]], TYRE, normal=[np.cos(mid), 0.0, np.sin(mid)],
                     group=group, layer=2)
        if hub:
            self.decal(cap, np.column_stack([x + 0.55 * radius * np.cos(a), zc + 0.55 * radius * np.sin(a)]), HUB,
                       layer=3)

    def well(self, parent: int, x: float, radius: float, z_centre: float, z_bottom: float) -> None:
        """The dark wheel-arch opening on a side face: the circle (x, z_centre, radius) above ``z_bottom``."""
        lo = np.arcsin(np.clip((z_bottom - z_centre) / radius, -1.0, 1.0))
        a = np.linspace(lo, np.pi - lo, 9)
        self.decal(parent, np.column_stack([x + radius * np.cos(a), z_centre + radius * np.sin(a)]), WELL)


def _section(hb: float, ht: float, zb: float, zm: float, zt: float) -> np.ndarray:
    """A 6-point cross-section (y, z): vertical lower sides up to the belt ``zm``, a bevel to the top."""
    return np.array([[-hb, zb], [-hb, zm], [-ht, zt], [ht, zt], [hb, zm], [hb, zb]])


def _trapezoid(hb: float, ht: float, zb: float, zt: float) -> np.ndarray:
    return np.array([[-hb, zb], [-ht, zt], [ht, zt], [hb, zb]])


def _rect(y0: float, y1: float, z0: float, z1: float) -> np.ndarray:
    return np.array([[y0, z0], [y1, z0], [y1, z1], [y0, z1]])


def _end_decals(b: _Builder, cap: int, hb: float, zb: float, zm: float, *, front: bool, lamp_h: float,
                plate_w: float = 0.52, grille: bool = True, bumper_h: float = 0.13) -> None:
    """Bumper band, lamps and plate (and a grille at the front) on an end cap."""
    b.decal(cap, _rect(-hb, hb, zb, zb + bumper_h), TRIM)
    lamp = HEAD_LAMP if front else TAIL_LAMP
    z1 = zm - 0.02
    for s in (-1.0, 1.0):
        b.decal(cap, _rect(s * 0.55 * hb, s * 0.95 * hb, z1 - lamp_h, z1), lamp)
    if front and grille:
        b.decal(cap, _rect(-0.45 * hb, 0.45 * hb, zb + bumper_h + 0.06, z1 - 0.02), TRIM)
    zp = zb + 0.02 if front else zb + bumper_h + 0.04
    b.decal(cap, _rect(-0.5 * plate_w, 0.5 * plate_w, zp, zp + 0.11), PLATE, layer=2)


def _wheels(b: _Builder, body: dict, xs: list[float], radius: float, hb: float, zb: float, tyre: float,
            arch: float = 1.2) -> None:
    zc = radius * np.cos(np.pi / 6)
    for side, sign in (("left", -1.0), ("right", 1.0)):
        faces = body[side]
        for x in xs:
            parent = min(faces, key=lambda f: abs(b.polys[f][:, 0].mean() - x))
            b.well(parent, x, arch * radius, zc, zb)
            b.wheel(x, radius, sign * (hb - 0.02), tyre, body[f"{side}_group"])


def _cabin_windows(b: _Builder, cabin: dict, split_middle: bool = True) -> None:
    for side in ("left", "right"):
        faces = cabin[side]
        for k, f in enumerate(faces):
            if split_middle and k == 1:
                b.inset_decal(f, GLASS, 0.86, 0.0, 0.5)
                b.inset_decal(f, GLASS, 0.86, 0.53, 1.0)
            else:
                b.inset_decal(f, GLASS, 0.78)


def _car(L: float, W: float, H: float) -> Mesh:
    b = _Builder()
    zb, r = 0.11 * H, 0.21 * H
    hb, ht = 0.5 * W, 0.43 * W
    xs = np.array([-0.5, -0.44, -0.30, 0.14, 0.42, 0.5]) * L
    zt = np.array([0.58, 0.66, 0.67, 0.60, 0.55, 0.50]) * H
    zm = np.minimum(0.46 * H, zt - 0.02 * H)
    body = b.loft(xs, [_section(hb, ht, zb, m, t) for m, t in zip(zm, zt, strict=True)],
                  np.full((5, 5), BODY), skip_top={(2, 2)})
    _end_decals(b, body["rear"], hb, zb, zm[0], front=False, lamp_h=0.14)
    _end_decals(b, body["front"], hb, zb, zm[-1], front=True, lamp_h=0.12)
    _wheels(b, body, [0.5 * L - 0.2 * L, -0.5 * L + 0.19 * L], r, hb, zb, 0.2)
    cx = np.array([-0.30, -0.17, 0.02, 0.14]) * L
    base = np.interp(cx, xs, zt)
    top = np.array([base[0], H, H, base[3]])
    hw = np.array([ht, 0.37 * W, 0.37 * W, ht])
    cabin = b.loft(cx, [_trapezoid(ht, h, z, t) for h, z, t in zip(hw, base, top, strict=True)],
                   np.array([[BODY, GLASS, BODY], [BODY, BODY, BODY], [BODY, GLASS, BODY]]), caps=(False, False))
    _cabin_windows(b, cabin)
    return b.mesh()


def _van(L: float, W: float, H: float) -> Mesh:
    b = _Builder()
    zb, r = 0.085 * H, 0.14 * H
    hb = 0.5 * W
    xs = np.array([-0.5, 0.34, 0.44, 0.5]) * L
    zt = np.array([0.40, 0.40, 0.37, 0.33]) * H
    zm = np.minimum(0.36 * H, zt - 0.015 * H)
    body = b.loft(xs, [_section(hb, 0.47 * W, zb, m, t) for m, t in zip(zm, zt, strict=True)],
                  np.full((3, 5), BODY), skip_top={(0, 2)})
    _end_decals(b, body["rear"], hb, zb, zm[0], front=False, lamp_h=0.22)
    _end_decals(b, body["front"], hb, zb, zm[-1], front=True, lamp_h=0.13)
    _wheels(b, body, [0.5 * L - 0.17 * L, -0.5 * L + 0.19 * L], r, hb, zb, 0.21)
    cx = np.array([-0.5, 0.2, 0.34]) * L
    base = np.interp(cx, xs, zt)
    top = np.array([H, H, base[2]])
    hw = np.array([0.46, 0.44, 0.47]) * W
    up = b.loft(cx, [_trapezoid(0.47 * W, h, z, t) for h, z, t in zip(hw, base, top, strict=True)],
                np.array([[BODY, BODY, BODY], [BODY, GLASS, BODY]]), caps=(True, False))
    for f in up["left"][1:] + up["right"][1:]:
        b.inset_decal(f, GLASS, 0.78)
    for f in up["left"][:1] + up["right"][:1]:
        b.inset_decal(f, GLASS, 0.8, 0.86, 1.0)
    zr = base[0]
    for s in (-1.0, 1.0):  # rear door windows
        b.decal(up["rear"], _rect(s * 0.04 * W, s * 0.4 * W, zr + 0.45 * (H - zr), H - 0.12 * (H - zr)), GLASS)
    return b.mesh()


def _bus(L: float, W: float, H: float) -> Mesh:
    b = _Builder()
    zb, r = 0.1 * H, 0.16 * H
    hb = 0.5 * W
    xs = np.array([-0.5, 0.5]) * L
    zt = np.array([0.38, 0.38]) * H
    zm = np.full(2, 0.37 * H)
    body = b.loft(xs, [_section(hb, hb, zb, m, t) for m, t in zip(zm, zt, strict=True)], np.full((1, 5), BODY),
                  skip_top={(0, 2)})
    _end_decals(b, body["rear"], hb, zb, zm[0], front=False, lamp_h=0.3, bumper_h=0.2)
    _end_decals(b, body["front"], hb, zb, zm[-1], front=True, lamp_h=0.18, bumper_h=0.2, grille=False)
    _wheels(b, body, [0.5 * L - 0.22 * L, -0.5 * L + 0.28 * L], r, hb, zb, 0.3)
    cx = np.array([-0.5, 0.475, 0.5]) * L
    base = zt[0] * np.ones(3)
    top = np.array([H, H, base[0] + 0.05 * H])
    up = b.loft(cx, [_trapezoid(hb, 0.485 * W, z, t) for z, t in zip(base, top, strict=True)],
                np.array([[BODY, BODY, BODY], [BODY, GLASS, BODY]]), caps=(True, False))
    n_win = max(2, round(L / 1.6))
    for f in up["left"][:1] + up["right"][:1]:
        for k in range(n_win):
            t0, t1 = k / n_win, (k + 1) / n_win
            b.inset_decal(f, GLASS, 0.85, t0 + 0.03 / n_win, t1 - 0.03 / n_win)
    zr = base[0]
    b.decal(up["rear"], _rect(-0.42 * W, 0.42 * W, zr + 0.45 * (H - zr), H - 0.1 * (H - zr)), GLASS)
    return b.mesh()


def _truck(L: float, W: float, H: float) -> Mesh:
    b = _Builder()
    r = min(0.52, 0.14 * H)
    zb, zc = 0.12 * H, 0.3 * H
    hb = 0.5 * W
    xs = np.array([-0.5, 0.5]) * L
    chassis = b.loft(xs, [_section(hb, hb, zb, zc - 0.01, zc)] * 2, np.full((1, 5), TRIM), skip_top={(0, 2)})
    _end_decals(b, chassis["rear"], hb, zb, zc - 0.01, front=False, lamp_h=0.14, bumper_h=0.16)
    _wheels(b, chassis, [0.5 * L - 1.4 * L / 12, -0.5 * L + 3.0 * L / 12, -0.5 * L + 4.3 * L / 12], r, hb, zb,
            0.3, arch=1.1)
    cab_len = min(2.3, 0.3 * L)
    box_x = np.array([-0.5 * L, 0.5 * L - cab_len - 0.3])
    box = b.loft(box_x, [_trapezoid(hb, hb, zc, H)] * 2, np.full((1, 3), CARGO))
    # Rear doors: a frame, the seam between the doors and their lock bars; a rail along the bottom of each side.
    f = 0.07
    for rect in (_rect(-hb, hb, zc, zc + f), _rect(-hb, hb, H - f, H), _rect(-hb, -hb + f, zc, H),
                 _rect(hb - f, hb, zc, H)):
        b.decal(box["rear"], rect, HUB)
    b.decal(box["rear"], _rect(-0.01 * W, 0.01 * W, zc + f, H - f), TRIM)
    for y in (-0.3 * W, -0.1 * W, 0.1 * W, 0.3 * W):
        b.decal(box["rear"], _rect(y - 0.02, y + 0.02, zc + f, H - f), HUB, layer=2)
    for f_side in box["left"] + box["right"]:
        b.decal(f_side, np.array([[box_x[0], zc], [box_x[1], zc], [box_x[1], zc + 0.16], [box_x[0], zc + 0.16]]),
                TRIM)
    cab_h = zc + 0.7 * (H - zc)
    cx = np.array([0.5 * L - cab_len, 0.5 * L - 0.35, 0.5 * L])
    cab = b.loft(cx, [_section(hb, 0.46 * W, zc - 0.3, zc + 0.45, t) for t in (cab_h, cab_h, zc + 0.55)],
                 np.array([[BODY] * 5, [BODY, BODY, GLASS, BODY, BODY]]), caps=(True, True))
    _end_decals(b, cab["front"], hb, zc - 0.3, zc + 0.45, front=True, lamp_h=0.2, bumper_h=0.25)
    for f in cab["left"][:1] + cab["right"][:1]:
        b.decal(f, np.array([[cx[1] - 0.9, zc - 0.25], [cx[1] - 0.1, zc - 0.25], [cx[1] - 0.1, zc + 0.4],
                             [cx[1] - 0.9, zc + 0.4]]), TRIM)
    for e in (1, 3):  # side windows on the upper side faces of the cab, at its front
        b.inset_decal(cab["faces"][(0, e)], GLASS, 0.8, 0.55, 1.0)
    return b.mesh()


def _two_wheeler(L: float, W: float, H: float) -> Mesh:
    b = _Builder()
    r = min(0.32, 0.16 * L)
    hw = 0.5 * W
    body = b.loft(np.array([-0.3, -0.1, 0.15, 0.3]) * L,
                  [_trapezoid(0.2 * hw, 0.3 * hw, 0.24 * H, t * H) for t in (0.5, 0.55, 0.6, 0.55)],
                  np.full((3, 3), BODY))
    b.decal(body["rear"], _rect(-0.12 * hw, 0.12 * hw, 0.4 * H, 0.47 * H), TAIL_LAMP)
    b.decal(body["front"], _rect(-0.15 * hw, 0.15 * hw, 0.42 * H, 0.52 * H), HEAD_LAMP)
    g = b.new_group()
    for x in (0.5 * L - r, -0.5 * L + r):
        b.wheel(x, r, 0.09, 0.18, g, hub=False, sides=8)
    b.loft(np.array([-0.2, 0.02]) * L, [_trapezoid(0.6 * hw, 0.5 * hw, 0.55 * H, 0.86 * H)] * 2,
           np.full((1, 3), RIDER))
    b.loft(np.array([-0.12, 0.0]) * L, [_trapezoid(0.28 * hw, 0.24 * hw, 0.86 * H, H)] * 2, np.full((1, 3), BODY))
    return b.mesh()


def _box(L: float, W: float, H: float) -> Mesh:
    b = _Builder()
    b.loft(np.array([-0.5, 0.5]) * L, [_trapezoid(0.5 * W, 0.5 * W, 0.0, H)] * 2, np.full((1, 3), BODY))
    return b.mesh()


_BUILDERS = {"box": _box, "car": _car, "van": _van, "truck": _truck, "bus": _bus, "motorcycle": _two_wheeler,
             "bicycle": _two_wheeler}


def kind_name(kind: object) -> str:
    """The mesh kind for a class name (case-insensitive; aliases; unknown names are cars)."""
    k = str(kind).strip().lower()
    k = KIND_ALIASES.get(k, k)
    return k if k in _BUILDERS else "car"


@lru_cache(maxsize=256)
def vehicle_mesh(kind: str, length: float, width: float, height: float) -> Mesh:
    """The mesh of one vehicle of ``kind`` and size (m), in the vehicle frame (see the module docstring)."""
    return _BUILDERS[kind_name(kind)](float(length), float(width), float(height))


def place(mesh: Mesh, centre: ArrayLike, heading_deg: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World vertices (N, V, 3), normals (N, F, 3) and group centres (N, G, 3) of ``mesh`` placed at footprint
    centres ``centre`` (N, 3) with ``heading_deg`` (N,) clockwise from north (as ``cuboid_corners``)."""
    c = np.asarray(centre, dtype=np.float64).reshape(-1, 3)
    h = np.radians(np.broadcast_to(np.asarray(heading_deg, dtype=np.float64), (c.shape[0],)))
    zero, one = np.zeros_like(h), np.ones_like(h)
    # Rows: world x, y, z; columns: the vehicle's forward, right, up.
    rot = np.stack([np.stack([np.sin(h), np.cos(h), zero], 1), np.stack([np.cos(h), -np.sin(h), zero], 1),
                    np.stack([zero, zero, one], 1)], axis=2)
    verts = c[:, None, :] + np.einsum("nij,vj->nvi", rot, mesh.vertices)
    normals = np.einsum("nij,fj->nfi", rot, mesh.normals)
    centres = c[:, None, :] + np.einsum("nij,gj->ngi", rot, mesh.group_centre)
    return verts, normals, centres
