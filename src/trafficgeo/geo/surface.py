"""Road surfaces and the intersection of camera rays with them.

A surface gives the ground elevation ``Z(x, y)`` in the units of its CRS (the camera's CRS: x, y, z in the same
unit, e.g. metres or international feet). Three kinds share one interface:

* :class:`ConstantSurface` - ``Z = z0``;
* :class:`PlaneSurface` - ``Z = z0 + gx (x - x0) + gy (y - y0)``, e.g. fitted to the inlier GCPs;
* :class:`DEMSurface` - a north-up elevation grid sampled bilinearly between cell centres (NaN = no data). A point
  cloud becomes a surface through a DEM (:func:`trafficgeo.geo.pointcloud.cloud_to_dem`).

Rays are ``P(t) = origin + t * d`` with ``t >= 0`` in CRS units along unit direction ``d``. :meth:`intersect`
returns the *first* point where the ray meets ``Z(x, y) + height`` (``height`` lifts the surface, e.g. to intersect
the ray through a vehicle's roof with the plane of the roof), or a status saying why there is none:

==================  =========================================================================================
``ok``              hit
``above_horizon``   the ray rises (or runs level) and never reaches the surface
``behind_camera``   the ray's line meets the surface only behind the camera (e.g. the surface is above it)
``miss``            the ray leaves the surface's extent without meeting it (DEM edge)
``no_data``         the ray passes over DEM cells without data and meets no valid surface
``grazing``         the hit is at less than ``min_incidence_deg`` between ray and surface: too ill-conditioned
``outside_lens``    the pixel lies outside the invertible region of the lens model (no ray)
``outside_image``   the pixel lies outside the frame (set by :mod:`trafficgeo.geo.mapping`)
==================  =========================================================================================

The DEM intersection marches along each ray through a max-height pyramid: a step is taken only where the ray stays
above the highest cell within the step's reach, so no hit is skipped; near the surface it advances half a cell at a
time, checks the piecewise-quadratic height of the ray above the bilinear surface for a sign change (kinks and
bulges included), and regula falsi solves the crossing to ~1e-9 of the elevation scale. The per-ray loop is
compiled with numba (:mod:`trafficgeo.geo._raymarch`): each ray stops as soon as it is resolved.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pyproj
from numpy.typing import ArrayLike

STATUSES = ("ok", "above_horizon", "behind_camera", "miss", "no_data", "grazing", "outside_lens", "outside_image")
OK, ABOVE_HORIZON, BEHIND_CAMERA, MISS, NO_DATA, GRAZING, OUTSIDE_LENS, OUTSIDE_IMAGE = range(len(STATUSES))

DEFAULT_MIN_INCIDENCE_DEG = 0.5


@dataclass(frozen=True)
class RayHits:
    """Result of intersecting N rays with a surface.

    Attributes:
        points: (N, 3) world points in CRS units (NaN where ``code != OK``).
        distance: (N,) distance from the ray origin to the hit along the ray, CRS units (NaN where no hit).
        incidence_deg: (N,) angle between the ray and the surface at the hit (90 = perpendicular; NaN if no hit).
        code: (N,) int status codes, indices into :data:`STATUSES`.
    """

    points: np.ndarray
    distance: np.ndarray
    incidence_deg: np.ndarray
    code: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        return self.code == OK

    @property
    def status(self) -> np.ndarray:
        """(N,) status names (see :data:`STATUSES`)."""
        return np.asarray(STATUSES, dtype=object)[self.code]


def _check_rays(origin: ArrayLike, directions: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    return o, d


def _finish(o: np.ndarray, d: np.ndarray, t: np.ndarray, code: np.ndarray, normal: np.ndarray,
            min_incidence_deg: float) -> RayHits:
    """Points, incidence angles and the grazing test for rays with a tentative hit at ``t`` (code OK)."""
    hit = code == OK
    with np.errstate(invalid="ignore"):
        sin_inc = np.abs(np.einsum("ij,ij->i", d, normal))
    incidence = np.degrees(np.arcsin(np.clip(sin_inc, 0.0, 1.0)))
    code = np.where(hit & (incidence < min_incidence_deg), GRAZING, code)
    hit = code == OK
    t = np.where(hit, t, np.nan)
    points = o + t[:, None] * d
    return RayHits(points=points, distance=t, incidence_deg=np.where(hit, incidence, np.nan), code=code)


def _plane_intersect(o: np.ndarray, d: np.ndarray, p0: np.ndarray, gx: float, gy: float, height: float,
                     min_incidence_deg: float) -> RayHits:
    """Rays against the plane ``Z = p0z + height + gx (x - p0x) + gy (y - p0y)``; arithmetic relative to ``p0``."""
    rel = o - p0
    normal = np.array([-gx, -gy, 1.0]) / np.sqrt(gx * gx + gy * gy + 1.0)
    # Signed height of the ray origin above the plane, measured along the normal, and the ray's rate of approach.
    above = (rel[2] - height - gx * rel[0] - gy * rel[1]) * normal[2]
    rate = d @ normal  # < 0: the ray approaches the plane from above
    code = np.full(d.shape[0], OK, dtype=np.int8)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -above / rate
    nan_ray = ~np.all(np.isfinite(d), axis=1)
    if above >= 0:
        code[rate >= 0] = ABOVE_HORIZON
    else:  # the camera is below the surface: rays that meet it go up through it
        code[rate <= 0] = BEHIND_CAMERA
    code[nan_ray] = OUTSIDE_LENS
    normals = np.broadcast_to(normal, d.shape)
    return _finish(o, d, t, code, normals, min_incidence_deg)


@dataclass(frozen=True, eq=False)
class ConstantSurface:
    """Horizontal surface ``Z = z`` (CRS units)."""

    z: float
    crs: pyproj.CRS | None = None

    def elevation(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Surface Z at (x, y) (arrays broadcast)."""
        xb, _ = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return np.full(xb.shape, float(self.z))

    def normal(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Unit upward normals (N, 3)."""
        n = np.asarray(x, dtype=np.float64).reshape(-1).size
        return np.tile([0.0, 0.0, 1.0], (n, 1))

    def intersect(self, origin: ArrayLike, directions: ArrayLike, height: float = 0.0,
                  min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG) -> RayHits:
        """First hits of rays from ``origin`` (3,) along unit ``directions`` (N, 3); see the module docstring."""
        o, d = _check_rays(origin, directions)
        return _plane_intersect(o, d, np.array([o[0], o[1], float(self.z)]), 0.0, 0.0, height, min_incidence_deg)

    def describe(self) -> str:
        return f"constant elevation {self.z:g}"


def _plane_lstsq(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gx, gy, dz) of the least-squares plane through points (N, 3) about their centroid, and the centroid."""
    c = p.mean(axis=0)
    rel = p - c
    A = np.column_stack([rel[:, 0], rel[:, 1], np.ones(len(rel))])
    if np.linalg.matrix_rank(A) < 3:
        raise ValueError("the points are collinear: they do not define a plane")
    coef, *_ = np.linalg.lstsq(A, rel[:, 2], rcond=None)
    return coef, c


def _consensus_plane(p: np.ndarray, finite: np.ndarray, tol: float, max_triples: int = 3000) -> np.ndarray:
    """Points within ``tol`` in Z of the plane through the triple of points that most points agree with.

    Every triple is tried for up to ~26 points (else ``max_triples`` random ones, seeded): a few pole tops or wrong
    heights cannot outvote the road the way they can bias a least-squares start.
    """
    from itertools import combinations

    idx = np.flatnonzero(finite)
    rel = p[idx] - p[idx].mean(axis=0)
    if len(idx) <= 26:
        triples = np.array(list(combinations(range(len(idx)), 3)))
    else:
        triples = np.random.default_rng(0).integers(0, len(idx), (max_triples, 3))
    a, b, c = rel[triples[:, 0]], rel[triples[:, 1]], rel[triples[:, 2]]
    normal = np.cross(b - a, c - a)
    good = np.abs(normal[:, 2]) > 1e-9 * np.linalg.norm(normal, axis=1).clip(1e-300)
    normal, a = normal[good], a[good]
    if len(normal) == 0:
        return finite.copy()
    # Z residual of every point for every candidate plane: n . (x - a) = 0  ->  z = a_z - (nx dx + ny dy) / nz.
    dz = rel[None, :, 2] - (a[:, None, 2] - (normal[:, None, 0] * (rel[None, :, 0] - a[:, None, 0])
                                             + normal[:, None, 1] * (rel[None, :, 1] - a[:, None, 1]))
                            / normal[:, None, 2])
    votes = (np.abs(dz) <= tol).sum(axis=1)
    best = int(np.argmax(votes))
    use = np.zeros_like(finite)
    use[idx[np.abs(dz[best]) <= tol]] = True
    return use if use.sum() >= 3 else finite.copy()


@dataclass(frozen=True, eq=False)
class PlaneSurface:
    """Plane ``Z = point[2] + gx (x - point[0]) + gy (y - point[1])`` (gradients dZ/dx, dZ/dy, unitless)."""

    point: np.ndarray
    gx: float
    gy: float
    crs: pyproj.CRS | None = None
    rms: float = field(default=float("nan"))  # RMS of the fit residuals in Z, CRS units (when fitted)
    excluded: tuple[int, ...] = ()  # indices of the points a robust fit left out

    def __post_init__(self) -> None:
        object.__setattr__(self, "point", np.asarray(self.point, dtype=np.float64).reshape(3))

    @classmethod
    def fit(cls, points: ArrayLike, crs: pyproj.CRS | None = None, robust: bool = True) -> PlaneSurface:
        """Least-squares plane through (N >= 3) world points (N, 3), about their centroid.

        ``robust``: the plane starts from the consensus of all point triples (within 10 cm), then points off it by
        more than 3 robust sigmas (and 5 cm) are dropped and the plane refitted until the set is stable, so pole
        tops or wrong heights among road points do not tilt it; see ``excluded``.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        finite = np.all(np.isfinite(p), axis=1)
        if finite.sum() < 3:
            raise ValueError(f"a plane needs at least 3 points, got {int(finite.sum())}")
        from trafficgeo.crs import metres_per_unit

        floor = 0.05 / (metres_per_unit(crs) if crs is not None else 1.0)
        use = finite.copy()
        if robust and finite.sum() > 4:
            use = _consensus_plane(p, finite, 2.0 * floor)
        for _ in range(10):
            coef, c = _plane_lstsq(p[use])
            resid = p[:, 2] - (c[2] + coef[2] + coef[0] * (p[:, 0] - c[0]) + coef[1] * (p[:, 1] - c[1]))
            if not robust:
                break
            r = resid[use]
            scale = 1.4826 * np.median(np.abs(r - np.median(r)))
            new = finite & (np.abs(resid) <= max(3.0 * scale, floor))
            if new.sum() < 3 or np.array_equal(new, use):
                break
            use = new
        point = c + np.array([0.0, 0.0, coef[2]])
        return cls(point=point, gx=float(coef[0]), gy=float(coef[1]), crs=crs,
                   rms=float(np.sqrt(np.mean(resid[use] ** 2))), excluded=tuple(int(i) for i in np.flatnonzero(
                       finite & ~use)))

    def elevation(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        xx, yy = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return self.point[2] + self.gx * (xx - self.point[0]) + self.gy * (yy - self.point[1])

    def normal(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        n = np.asarray(x, dtype=np.float64).reshape(-1).size
        v = np.array([-self.gx, -self.gy, 1.0])
        return np.tile(v / np.linalg.norm(v), (n, 1))

    def intersect(self, origin: ArrayLike, directions: ArrayLike, height: float = 0.0,
                  min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG) -> RayHits:
        o, d = _check_rays(origin, directions)
        return _plane_intersect(o, d, self.point, self.gx, self.gy, height, min_incidence_deg)

    def describe(self) -> str:
        slope = np.degrees(np.arctan(np.hypot(self.gx, self.gy)))
        text = f"plane through ({self.point[0]:.3f}, {self.point[1]:.3f}, {self.point[2]:.3f}), slope {slope:.2f} deg"
        if np.isfinite(self.rms):
            text += f", RMS {self.rms:.3f}"
        if self.excluded:
            text += f", {len(self.excluded)} point(s) off the plane left out"
        return text


class DEMSurface:
    """Bilinear surface over a north-up elevation grid.

    ``values[r, c]`` is the elevation at the centre of cell (r, c), i.e. at map
    ``x = left + (c + 0.5) xres``, ``y = top - (r + 0.5) yres``. Between centres the surface is bilinear; in the
    outer half-cell ring it is clamped to the edge values, so the surface covers the raster's bounds exactly. A
    bilinear patch with any NaN corner is no data.
    """

    def __init__(self, values: ArrayLike, left: float, top: float, xres: float, yres: float,
                 crs: pyproj.CRS | None = None, name: str = "DEM") -> None:
        z = np.asarray(values, dtype=np.float64)
        if z.ndim != 2 or min(z.shape) < 1:
            raise ValueError(f"DEM values must be a 2-D grid, got shape {z.shape}")
        if not (xres > 0 and yres > 0):
            raise ValueError(f"DEM resolution must be positive, got ({xres}, {yres})")
        finite = np.isfinite(z)
        if not finite.any():
            raise ValueError("the DEM has no valid cells")
        self.values = z
        self.left, self.top, self.xres, self.yres = float(left), float(top), float(xres), float(yres)
        self.crs = crs
        self.name = name
        self.zmin = float(z[finite].min())
        self.zmax = float(z[finite].max())
        self._pyramid = _MaxPyramid(z)
        self._flat = z.ravel()
        # Largest bilinear cross term |z00 - z01 - z10 + z11| of any cell: bounds how far the surface can bulge
        # between samples along a ray (see _bracket).
        twist = np.abs(z[:-1, :-1] - z[:-1, 1:] - z[1:, :-1] + z[1:, 1:]) if min(z.shape) > 1 else np.zeros(1)
        self._max_twist = float(np.nanmax(twist)) if np.isfinite(twist).any() else 0.0
        self._dc = 1 if z.shape[1] > 1 else 0  # flat-index offsets of the right and lower bilinear neighbours
        self._dr = z.shape[1] if z.shape[0] > 1 else 0

    @classmethod
    def from_raster(cls, raster: ArrayLike, name: str | None = None) -> DEMSurface:
        """From a :class:`trafficgeo.geo.raster.GeoRaster` (band 1; must be north-up)."""
        tr = raster.transform  # type: ignore[attr-defined]
        if abs(tr.b) > 1e-12 or abs(tr.d) > 1e-12 or tr.a <= 0 or tr.e >= 0:
            raise ValueError("the DEM is not north-up (rotated or flipped geotransform); warp it first, "
                             "e.g. gdalwarp -t_srs <its CRS>")
        data = np.asarray(raster.data, dtype=np.float64)  # type: ignore[attr-defined]
        values = data[0] if data.ndim == 3 else data
        return cls(values, tr.c, tr.f, tr.a, -tr.e, crs=raster.crs,  # type: ignore[attr-defined]
                   name=name or str(getattr(raster, "path", None) or "DEM"))

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape  # type: ignore[return-value]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        rows, cols = self.values.shape
        return (self.left, self.top - rows * self.yres, self.left + cols * self.xres, self.top)

    def describe(self) -> str:
        rows, cols = self.values.shape
        return f"{self.name}: {cols}x{rows} cells of {self.xres:g}x{self.yres:g}, z {self.zmin:.2f}..{self.zmax:.2f}"

    # -- sampling -------------------------------------------------------------------------------------------------
    def _grid(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Continuous grid coordinates (col, row) of map points; cell centres at +0.5."""
        return (x - self.left) / self.xres, (self.top - y) / self.yres

    def _bilinear_grid(self, gc: np.ndarray, gr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Elevation and its grid-space gradient (dZ/dcol, dZ/drow) at grid coordinates; NaN outside."""
        rows, cols = self.values.shape
        inside = (gc >= 0) & (gc <= cols) & (gr >= 0) & (gr <= rows)
        fc = np.clip(gc - 0.5, 0.0, cols - 1.0)
        fr = np.clip(gr - 0.5, 0.0, rows - 1.0)
        c0 = np.minimum(np.floor(fc).astype(np.intp), max(cols - 2, 0))
        r0 = np.minimum(np.floor(fr).astype(np.intp), max(rows - 2, 0))
        c1 = np.minimum(c0 + 1, cols - 1)
        r1 = np.minimum(r0 + 1, rows - 1)
        wc = fc - c0
        wr = fr - r0
        v = self.values
        z00, z01, z10, z11 = v[r0, c0], v[r0, c1], v[r1, c0], v[r1, c1]
        top = z00 + (z01 - z00) * wc
        bot = z10 + (z11 - z10) * wc
        z = top + (bot - top) * wr
        dzdc = (z01 - z00) * (1 - wr) + (z11 - z10) * wr
        dzdr = bot - top
        # In the clamped edge ring the surface is flat across the clamped axis.
        dzdc = np.where((gc - 0.5 < 0) | (gc - 0.5 > cols - 1), 0.0, dzdc)
        dzdr = np.where((gr - 0.5 < 0) | (gr - 0.5 > rows - 1), 0.0, dzdr)
        nan = np.where(inside, 0.0, np.nan)
        return z + nan, dzdc + nan, dzdr + nan

    def elevation(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Bilinear elevation at map (x, y) (arrays broadcast); NaN outside the grid or over no-data cells."""
        xx, yy = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        gc, gr = self._grid(xx.reshape(-1), yy.reshape(-1))
        return self._bilinear_grid(gc, gr)[0].reshape(xx.shape)

    def normal(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Unit upward normals (N, 3) of the bilinear surface at map (x, y); NaN outside."""
        gc, gr = self._grid(np.asarray(x, dtype=np.float64).reshape(-1), np.asarray(y, dtype=np.float64).reshape(-1))
        _, dzdc, dzdr = self._bilinear_grid(gc, gr)
        gx = dzdc / self.xres
        gy = -dzdr / self.yres
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=1)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    # -- ray marching ---------------------------------------------------------------------------------------------
    def intersect(self, origin: ArrayLike, directions: ArrayLike, height: float = 0.0,
                  min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG) -> RayHits:
        """First hits of rays from ``origin`` (3,) along unit ``directions`` (N, 3); see the module docstring."""
        o, d = _check_rays(origin, directions)
        n = d.shape[0]
        code = np.full(n, MISS, dtype=np.int8)
        t_hit = np.full(n, np.nan)
        # Grid space: g = (col, row, z - height); t stays the world distance along the ray.
        g0 = np.array([(o[0] - self.left) / self.xres, (self.top - o[1]) / self.yres, o[2] - height])
        dg = np.column_stack([d[:, 0] / self.xres, -d[:, 1] / self.yres, d[:, 2]])
        # Camera below the surface at its own position: the surface lies behind / above it.
        z_here = self._bilinear_grid(np.array([g0[0]]), np.array([g0[1]]))[0][0]
        if np.isfinite(z_here) and g0[2] < z_here:
            code[:] = BEHIND_CAMERA
            code[~np.all(np.isfinite(d), axis=1)] = OUTSIDE_LENS
            return _finish(o, d, t_hit, code, np.full((n, 3), np.nan), min_incidence_deg)
        from trafficgeo.geo._raymarch import intersect_rays

        pyr = self._pyramid
        t_hit, code, grad = intersect_rays(self.values, pyr.data, pyr.offsets, pyr.ncols, pyr.reach,
                                           self._max_twist, self.zmin, self.zmax, g0, dg)
        normal = np.column_stack([-grad[:, 0] / self.xres, grad[:, 1] / self.yres, np.ones(n)])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        return _finish(o, d, t_hit, code, normal, min_incidence_deg)


class _MaxPyramid:
    """Max-height pyramid for conservative ray steps.

    Level L (L >= 1) holds, for each block of 2^L x 2^L cells, the maximum over that block and its 8 neighbours.
    Every point within a Chebyshev distance of ``2^L - 1`` cells of a point in the block has its bilinear support
    inside that 3x3 block neighbourhood, so a ray that stays above the stored maximum over that reach cannot meet
    the surface. NaN cells count as -inf (no surface). Level 0 is unused (its reach is zero).
    """

    def __init__(self, values: np.ndarray) -> None:
        from scipy.ndimage import maximum_filter

        z = np.where(np.isfinite(values), values, -np.inf).astype(np.float32)
        # float32 rounding must stay conservative: round maxima up.
        z = np.nextafter(z, np.float32(np.inf))
        rows, cols = z.shape
        blocks = z
        flat: list[np.ndarray] = [np.full(1, np.inf, dtype=np.float32)]  # level 0: never safe
        offsets = [0]
        shapes = [(1, 1)]
        size = 1
        level = 0
        offset = 1
        while True:
            level += 1
            size *= 2
            r, c = blocks.shape
            pr, pc = (r + 1) // 2 * 2, (c + 1) // 2 * 2
            padded = np.full((pr, pc), -np.inf, dtype=np.float32)
            padded[:r, :c] = blocks
            blocks = padded.reshape(pr // 2, 2, pc // 2, 2).max(axis=(1, 3))
            dilated = maximum_filter(blocks, size=3, mode="nearest")
            flat.append(dilated.ravel())
            offsets.append(offset)
            shapes.append(dilated.shape)
            offset += dilated.size
            if size >= max(rows, cols) * 2:
                break
        self.levels = level + 1
        self.data = np.concatenate(flat)
        self.offsets = np.asarray(offsets, dtype=np.intp)
        self.ncols = np.asarray([s[1] for s in shapes], dtype=np.intp)
        self.reach = np.asarray([max(2**lv - 1, 0) for lv in range(self.levels)], dtype=np.float64)

    def lookup(self, level: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Stored maxima at cells (row, col) for per-point pyramid levels (intp arrays)."""
        return self.data[self.offsets[level] + (row >> level) * self.ncols[level] + (col >> level)]

