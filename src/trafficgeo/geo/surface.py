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

The DEM intersection marches along the ray through a max-height pyramid: a step is taken only where the ray stays
above the highest cell within the step's reach, so no hit is skipped; near the surface it advances half a cell at a
time and brackets the crossing, which regula falsi refines to well under a millimetre. All rays advance together in
vectorized numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pyproj

STATUSES = ("ok", "above_horizon", "behind_camera", "miss", "no_data", "grazing", "outside_lens", "outside_image")
OK, ABOVE_HORIZON, BEHIND_CAMERA, MISS, NO_DATA, GRAZING, OUTSIDE_LENS, OUTSIDE_IMAGE = range(len(STATUSES))

DEFAULT_MIN_INCIDENCE_DEG = 0.5
_MARCHING = -1  # internal: ray not finished yet
_CHUNK = 1 << 14  # rays marched together (state arrays stay in the CPU cache)
_CHUNK_ITERATIONS = 40


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


def _check_rays(origin: object, directions: object) -> tuple[np.ndarray, np.ndarray]:
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

    def elevation(self, x: object, y: object) -> np.ndarray:
        """Surface Z at (x, y) (arrays broadcast)."""
        xb, _ = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return np.full(xb.shape, float(self.z))

    def normal(self, x: object, y: object) -> np.ndarray:
        """Unit upward normals (N, 3)."""
        n = np.asarray(x, dtype=np.float64).reshape(-1).size
        return np.tile([0.0, 0.0, 1.0], (n, 1))

    def intersect(self, origin: object, directions: object, height: float = 0.0,
                  min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG) -> RayHits:
        """First hits of rays from ``origin`` (3,) along unit ``directions`` (N, 3); see the module docstring."""
        o, d = _check_rays(origin, directions)
        return _plane_intersect(o, d, np.array([o[0], o[1], float(self.z)]), 0.0, 0.0, height, min_incidence_deg)

    def describe(self) -> str:
        return f"constant elevation {self.z:g}"


@dataclass(frozen=True, eq=False)
class PlaneSurface:
    """Plane ``Z = point[2] + gx (x - point[0]) + gy (y - point[1])`` (gradients dZ/dx, dZ/dy, unitless)."""

    point: np.ndarray
    gx: float
    gy: float
    crs: pyproj.CRS | None = None
    rms: float = field(default=float("nan"))  # RMS of the fit residuals in Z, CRS units (when fitted)

    def __post_init__(self) -> None:
        object.__setattr__(self, "point", np.asarray(self.point, dtype=np.float64).reshape(3))

    @classmethod
    def fit(cls, points: object, crs: pyproj.CRS | None = None) -> PlaneSurface:
        """Least-squares plane through (N >= 3) world points (N, 3), about their centroid."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        if p.shape[0] < 3:
            raise ValueError(f"a plane needs at least 3 points, got {p.shape[0]}")
        c = p.mean(axis=0)
        rel = p - c
        A = np.column_stack([rel[:, 0], rel[:, 1], np.ones(len(rel))])
        coef, *_ = np.linalg.lstsq(A, rel[:, 2], rcond=None)
        if np.linalg.matrix_rank(A) < 3:
            raise ValueError("the points are collinear: they do not define a plane")
        resid = rel[:, 2] - A @ coef
        point = c + np.array([0.0, 0.0, coef[2]])
        return cls(point=point, gx=float(coef[0]), gy=float(coef[1]), crs=crs, rms=float(np.sqrt(np.mean(resid**2))))

    def elevation(self, x: object, y: object) -> np.ndarray:
        xx, yy = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return self.point[2] + self.gx * (xx - self.point[0]) + self.gy * (yy - self.point[1])

    def normal(self, x: object, y: object) -> np.ndarray:
        n = np.asarray(x, dtype=np.float64).reshape(-1).size
        v = np.array([-self.gx, -self.gy, 1.0])
        return np.tile(v / np.linalg.norm(v), (n, 1))

    def intersect(self, origin: object, directions: object, height: float = 0.0,
                  min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG) -> RayHits:
        o, d = _check_rays(origin, directions)
        return _plane_intersect(o, d, self.point, self.gx, self.gy, height, min_incidence_deg)

    def describe(self) -> str:
        slope = np.degrees(np.arctan(np.hypot(self.gx, self.gy)))
        return f"plane through ({self.point[0]:.3f}, {self.point[1]:.3f}, {self.point[2]:.3f}), slope {slope:.2f} deg"


class DEMSurface:
    """Bilinear surface over a north-up elevation grid.

    ``values[r, c]`` is the elevation at the centre of cell (r, c), i.e. at map
    ``x = left + (c + 0.5) xres``, ``y = top - (r + 0.5) yres``. Between centres the surface is bilinear; in the
    outer half-cell ring it is clamped to the edge values, so the surface covers the raster's bounds exactly. A
    bilinear patch with any NaN corner is no data.
    """

    def __init__(self, values: object, left: float, top: float, xres: float, yres: float,
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
    def from_raster(cls, raster: object, name: str | None = None) -> DEMSurface:
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

    def elevation(self, x: object, y: object) -> np.ndarray:
        """Bilinear elevation at map (x, y) (arrays broadcast); NaN outside the grid or over no-data cells."""
        xx, yy = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        gc, gr = self._grid(xx.reshape(-1), yy.reshape(-1))
        return self._bilinear_grid(gc, gr)[0].reshape(xx.shape)

    def normal(self, x: object, y: object) -> np.ndarray:
        """Unit upward normals (N, 3) of the bilinear surface at map (x, y); NaN outside."""
        gc, gr = self._grid(np.asarray(x, dtype=np.float64).reshape(-1), np.asarray(y, dtype=np.float64).reshape(-1))
        _, dzdc, dzdr = self._bilinear_grid(gc, gr)
        gx = dzdc / self.xres
        gy = -dzdr / self.yres
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=1)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    # -- ray marching ---------------------------------------------------------------------------------------------
    def intersect(self, origin: object, directions: object, height: float = 0.0,
                  min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG) -> RayHits:
        """First hits of rays from ``origin`` (3,) along unit ``directions`` (N, 3); see the module docstring."""
        o, d = _check_rays(origin, directions)
        n = d.shape[0]
        code = np.full(n, MISS, dtype=np.int8)
        t_hit = np.full(n, np.nan)
        rows, cols = self.values.shape
        # Grid space: g = (col, row, z - height); t stays the world distance along the ray.
        g0 = np.array([(o[0] - self.left) / self.xres, (self.top - o[1]) / self.yres, o[2] - height])
        dg = np.column_stack([d[:, 0] / self.xres, -d[:, 1] / self.yres, d[:, 2]])
        valid = np.all(np.isfinite(d), axis=1)
        code[~valid] = OUTSIDE_LENS

        # Parameter range inside the raster footprint (2-D slab test) and inside the slab zmin <= z <= zmax.
        t0 = np.zeros(n)
        t1 = np.full(n, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            for axis, size in ((0, cols), (1, rows)):
                ta = (0.0 - g0[axis]) / dg[:, axis]
                tb = (size - g0[axis]) / dg[:, axis]
                lo, hi = np.minimum(ta, tb), np.maximum(ta, tb)
                par = dg[:, axis] == 0
                inside_axis = 0.0 <= g0[axis] <= size
                lo = np.where(par, -np.inf if inside_axis else np.inf, lo)
                hi = np.where(par, np.inf if inside_axis else -np.inf, hi)
                t0 = np.maximum(t0, lo)
                t1 = np.minimum(t1, hi)
            # The slab is widened a hair so that rounding cannot start a ray below a flat surface.
            pad = 1e-7 * (1.0 + abs(self.zmax) + abs(self.zmin))
            zmax, zmin = self.zmax + pad, self.zmin - pad
            tz_top = (zmax - g0[2]) / dg[:, 2]
            tz_bot = (zmin - g0[2]) / dg[:, 2]
        descending = dg[:, 2] < 0
        # Rays that never come below the highest point of the surface cannot hit it.
        never_low = np.where(descending, False, g0[2] > zmax)
        t0 = np.where(descending & (g0[2] > zmax), np.maximum(t0, tz_top), t0)
        # A descending ray that sinks below the lowest surface point inside the footprint without a hit must have
        # passed over cells without data.
        sinks = descending & (tz_bot < t1)
        t1 = np.where(descending, np.minimum(t1, tz_bot), np.where(dg[:, 2] > 0, np.minimum(t1, tz_top), t1))
        code[valid & never_low] = ABOVE_HORIZON
        live = valid & ~never_low & (t0 <= t1)
        # Camera below the surface at its own position: the surface lies behind / above it.
        z_here = self._bilinear_grid(np.array([g0[0]]), np.array([g0[1]]))[0][0]
        if np.isfinite(z_here) and g0[2] < z_here:
            code[valid] = BEHIND_CAMERA
            live[:] = False

        # March in cache-sized chunks for a bounded number of iterations; the few rays that skim the surface for
        # a long way (near the horizon) then finish together.
        live_idx = np.flatnonzero(live)
        pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        for start in range(0, live_idx.size, _CHUNK):
            idx = live_idx[start:start + _CHUNK]
            t_c, code_c, crossed_c = self._march(g0, dg[idx], t0[idx], t1[idx], max_iter=_CHUNK_ITERATIONS)
            t_hit[idx] = t_c
            code[idx] = code_c
            more = code_c == _MARCHING
            if more.any():
                pending.append((idx[more], t_c[more], crossed_c[more]))
        if pending:
            idx = np.concatenate([p[0] for p in pending])
            t_c, code_c, _ = self._march(g0, dg[idx], np.concatenate([p[1] for p in pending]), t1[idx],
                                         crossed=np.concatenate([p[2] for p in pending]))
            t_hit[idx] = t_c
            code[idx] = code_c
        code[(code == MISS) & sinks] = NO_DATA
        # Rays that rise and end without a hit: above the horizon rather than a miss.
        rising = (code == MISS) & (dg[:, 2] >= 0) & valid
        code[rising] = ABOVE_HORIZON

        normal = np.full((n, 3), np.nan)
        hit = code == OK
        if hit.any():
            p = o + t_hit[hit, None] * d[hit]
            normal[hit] = self.normal(p[:, 0], p[:, 1])
        return _finish(o, d, t_hit, code, normal, min_incidence_deg)

    def _height(self, gc: np.ndarray, gr: np.ndarray) -> np.ndarray:
        """Bilinear elevation at grid coordinates (hot path of the ray march; NaN outside or over no data)."""
        rows, cols = self.values.shape
        fc = np.clip(gc - 0.5, 0.0, cols - 1.0)
        fr = np.clip(gr - 0.5, 0.0, rows - 1.0)
        c0 = np.minimum(fc.astype(np.intp), max(cols - 2, 0))
        r0 = np.minimum(fr.astype(np.intp), max(rows - 2, 0))
        wc = fc - c0
        wr = fr - r0
        i00 = r0 * cols + c0
        v = self._flat
        z00 = v[i00]
        z01 = v[i00 + self._dc]
        z10 = v[i00 + self._dr]
        z11 = v[i00 + self._dr + self._dc]
        top = z00 + (z01 - z00) * wc
        z = top + (z10 + (z11 - z10) * wc - top) * wr
        outside = (gc < 0) | (gc > cols) | (gr < 0) | (gr > rows)
        z[outside] = np.nan
        return z

    def _march(self, g0: np.ndarray, dg: np.ndarray, t0: np.ndarray, t1: np.ndarray, max_iter: int = 10**7,
               crossed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """March rays (grid-space directions ``dg``) from t0 to t1.

        Returns (t, code, crossed): t of the first hit where code is OK; for rays still marching after
        ``max_iter`` iterations code is ``_MARCHING`` and t is how far the ray is known to be clear of the surface
        (pass it back as t0, with ``crossed``, to resume). ``crossed``: the ray passed over no-data cells.

        Each iteration looks up the pyramid at the ray's level L and at L - 1 and jumps by the larger safe step
        (then tries one level coarser); where neither is safe at the finest levels it advances half a cell and
        brackets a sign change of the ray's height above the surface.
        """
        n = dg.shape[0]
        t_hit = np.full(n, np.nan)
        code = np.full(n, MISS, dtype=np.int8)
        crossed_out = np.zeros(n, dtype=bool) if crossed is None else crossed.copy()
        if n == 0:
            return t_hit, code, crossed_out
        pyr = self._pyramid
        rows, cols = self.values.shape
        top = pyr.levels - 1
        # Compact per-ray state of the rays still marching.
        idx = np.arange(n)
        dz = dg[:, 2]
        cheb = np.maximum(np.abs(dg[:, 0]), np.abs(dg[:, 1]))  # cells per unit t (Chebyshev)
        with np.errstate(divide="ignore", invalid="ignore"):
            fine = np.where(cheb > 0, 0.5 / cheb, np.inf)  # half a cell along the ray
            inv_cheb = np.where(cheb > 0, 1.0 / cheb, np.inf)
            descent = np.maximum(-dz, 0.0)
            inv_descent = np.where(descent > 0, 1.0 / descent, np.inf)
            # Start at the level whose reach matches the run through the elevation slab.
            run_cells = (self.zmax - self.zmin + 1e-9) * inv_descent * cheb
            level = np.clip(np.floor(np.log2(np.maximum(run_cells, 1.0))), 2, top).astype(np.intp)
        crossed = crossed_out.copy()
        # Float state of the marching rays as rows of one array, so that dropping finished rays is one gather.
        T, TEND, DC, DR, DZ, FINE, INVC, INVD, GAP = range(9)
        state = np.empty((9, n))
        state[T], state[TEND], state[DC], state[DR], state[DZ] = t0, t1, dg[:, 0], dg[:, 1], dg[:, 2]
        state[FINE], state[INVC], state[INVD] = fine, inv_cheb, inv_descent
        # A ray that enters the grid's footprint through its side below the surface never crosses it from above.
        state[GAP] = g0[2] + t0 * dg[:, 2] - self._height(g0[0] + t0 * dg[:, 0], g0[1] + t0 * dg[:, 1])
        keep = ~(state[GAP] < 0)
        idx, level, crossed, state = idx[keep], level[keep], crossed[keep], state[:, keep]
        reach = pyr.reach
        for _ in range(max_iter):
            if idx.size == 0:
                break
            t, dc, dr, dz = state[T], state[DC], state[DR], state[DZ]
            ci = np.clip((g0[0] + t * dc).astype(np.intp), 0, cols - 1)
            ri = np.clip((g0[1] + t * dr).astype(np.intp), 0, rows - 1)
            z = g0[2] + t * dz
            lo = np.maximum(level - 1, 1)
            room_hi = z - pyr.lookup(level, ri, ci)
            room_lo = z - pyr.lookup(lo, ri, ci)
            reach_hi = reach[level] * state[INVC]
            reach_lo = reach[lo] * state[INVC]
            with np.errstate(invalid="ignore"):
                drop_hi = room_hi * state[INVD]
                drop_lo = room_lo * state[INVD]
            safe_hi = np.minimum(reach_hi, drop_hi)
            safe_lo = np.minimum(reach_lo, drop_lo)
            safe_hi[~(room_hi > 0)] = 0.0
            safe_lo[~(room_lo > 0)] = 0.0
            use_hi = safe_hi >= state[FINE]
            use_lo = ~use_hi & (safe_lo >= state[FINE])
            jump = use_hi | use_lo
            state[T] = t + np.where(use_hi, safe_hi, np.where(use_lo, safe_lo, 0.0))
            # Next level: coarser after a jump limited by reach, finer after one that met the level's envelope.
            level = np.where(use_hi, np.where(reach_hi <= drop_hi, level + 1, level - 1),
                             np.where(use_lo, np.where(reach_lo <= drop_lo, level, level - 2), level - 2))
            level = np.clip(level, 1, top)
            state[GAP, jump] = np.nan  # unknown after a jump
            # Finest level and no safe jump: advance half a cell and look for a sign change.
            step = ~jump & (lo <= 1)
            hit = np.zeros(idx.size, dtype=bool)
            if step.any():
                sub = state[:, step]
                ts, sdc, sdr, sdz, gp = sub[T], sub[DC], sub[DR], sub[DZ], sub[GAP]
                te = np.minimum(ts + sub[FINE], sub[TEND])
                unknown = np.isnan(gp)
                if unknown.any():
                    tu = ts[unknown]
                    gp[unknown] = g0[2] + tu * sdz[unknown] - self._height(g0[0] + tu * sdc[unknown],
                                                                           g0[1] + tu * sdr[unknown])
                gn = g0[2] + te * sdz - self._height(g0[0] + te * sdc, g0[1] + te * sdr)
                crossed[step] |= ~np.isfinite(gn)
                found, ta, tb, fa, fb = self._bracket(g0, sdc, sdr, sdz, ts, te, gp, gn)
                if found.any():
                    where = np.flatnonzero(step)[found]
                    dgc = np.column_stack([sdc[found], sdr[found], sdz[found]])
                    t_hit[idx[where]] = self._refine(g0, dgc, ta[found], tb[found], fa[found], fb[found])
                    code[idx[where]] = OK
                    hit[where] = True
                state[T, step] = te
                state[GAP, step] = gn
                level[step] = np.where(np.isfinite(gn) & (gn > 0), 2, 1)
            done = hit | (state[T] >= state[TEND])
            if done.any():
                ended = done & ~hit
                code[idx[ended]] = np.where(crossed[ended], NO_DATA, MISS)
                keep = ~done
                idx, level, crossed, state = idx[keep], level[keep], crossed[keep], state[:, keep]
        if idx.size:
            t_hit[idx] = state[T]
            code[idx] = _MARCHING
            crossed_out[idx] = crossed
        return t_hit, code, crossed_out

    def _bracket(self, g0: np.ndarray, dc: np.ndarray, dr: np.ndarray, dz: np.ndarray, ts: np.ndarray,
                 te: np.ndarray, gs: np.ndarray, ge: np.ndarray) -> tuple[np.ndarray, ...]:
        """First sign change of the ray's height above the surface in [ts, te] (at most half a cell long).

        Along the segment the height is continuous and piecewise quadratic, with kinks where it crosses the lines
        between cell centres (at most one per axis). It is evaluated at those kinks, so ridges are not stepped
        over; inside a piece it can only dip below its chord by ``|twist dc dr| L^2 / 4`` (``twist`` the cell's
        bilinear cross term), and where that could reach zero the piece's vertex is evaluated too. Returns
        (found, ta, tb, fa, fb) with fa > 0 >= fb where found (a ray entering data below the surface from a
        no-data hole has ta = tb).
        """
        # Kinks: where the grid coordinate crosses k + 0.5 inside the segment.
        knots = []
        for g_origin, d in ((g0[0], dc), (g0[1], dr)):
            a_, b_ = g_origin + ts * d, g_origin + te * d
            line = np.floor(np.maximum(a_, b_) - 0.5) + 0.5
            inside = (line > np.minimum(a_, b_)) & (line < np.maximum(a_, b_))
            with np.errstate(divide="ignore", invalid="ignore"):
                tk = ts + (line - a_) / d
            knots.append(np.where(inside, tk, te))
        k1, k2 = np.minimum(knots[0], knots[1]), np.maximum(knots[0], knots[1])
        tk = np.concatenate([k1, k2])
        gk = g0[2] + tk * np.tile(dz, 2) - self._height(g0[0] + tk * np.tile(dc, 2), g0[1] + tk * np.tile(dr, 2))
        m = ts.size
        T = np.stack([ts, k1, k2, te])
        G = np.stack([gs, gk[:m], gk[m:], ge])
        found = np.zeros(m, dtype=bool)
        ta, tb, fa, fb = te.copy(), te.copy(), ge.copy(), ge.copy()
        twist_bound = self._max_twist * np.abs(dc * dr)
        for k in range(3):
            t_a, t_b, f_a, f_b = T[k], T[k + 1], G[k], G[k + 1]
            length = t_b - t_a
            sign = ~found & (f_a > 0) & (f_b <= 0)
            # A dip inside the piece with both ends above the surface.
            maybe = ~found & ~sign & (f_a > 0) & (f_b > 0) & (length > 0) & (np.minimum(f_a, f_b) <
                                                                           twist_bound * length**2 / 4)
            if maybe.any():
                j = np.flatnonzero(maybe)
                tm = 0.5 * (t_a[j] + t_b[j])
                fm = g0[2] + tm * dz[j] - self._height(g0[0] + tm * dc[j], g0[1] + tm * dr[j])
                curv = 2 * (f_a[j] + f_b[j]) - 4 * fm  # A L^2 of g(s) = f_a + (f_b - f_a) s + A L^2 s (s - 1)
                with np.errstate(divide="ignore", invalid="ignore"):
                    s_star = np.clip(0.5 - (f_b[j] - f_a[j]) / (2 * curv), 0.0, 1.0)
                s_star = np.where(curv > 0, s_star, 0.5)
                g_star = f_a[j] + (f_b[j] - f_a[j]) * s_star + curv * s_star * (s_star - 1)
                dip = np.isfinite(g_star) & (g_star <= 0)
                jd = j[dip]
                ta[jd], fa[jd] = t_a[jd], f_a[jd]
                tb[jd], fb[jd] = t_a[jd] + s_star[dip] * length[jd], g_star[dip]
                found[jd] = True
            ta[sign], tb[sign], fa[sign], fb[sign] = t_a[sign], t_b[sign], f_a[sign], f_b[sign]
            found |= sign
        # A ray that enters data already below the surface from a no-data hole hits where the data begin.
        enter = ~found & ~np.isfinite(gs) & np.isfinite(ge) & (ge <= 0)
        ta[enter], tb[enter], fa[enter], fb[enter] = te[enter], te[enter], 0.0, ge[enter]
        found |= enter
        return found, ta, tb, fa, fb

    def _refine(self, g0: np.ndarray, dg: np.ndarray, ta: np.ndarray, tb: np.ndarray, fa: np.ndarray,
                fb: np.ndarray, max_iterations: int = 40) -> np.ndarray:
        """Root of the ray's height above the surface in [ta, tb] (fa > 0 >= fb): regula falsi, Illinois variant,
        until the height is within 1e-9 of the elevation scale or the bracket is 1e-9 of a cell wide."""
        fa = np.where(np.isfinite(fa), fa, 0.0)
        out = tb.copy()
        act = np.flatnonzero(ta < tb)
        ta, tb, fa, fb = ta[act], tb[act], fa[act], fb[act]
        dg = dg[act]
        side = np.zeros(act.size, dtype=np.int8)
        tol = 1e-9 * (1.0 + abs(self.zmax))
        for _ in range(max_iterations):
            if act.size == 0:
                break
            with np.errstate(divide="ignore", invalid="ignore"):
                tm = np.where(fa != fb, (ta * fb - tb * fa) / (fb - fa), 0.5 * (ta + tb))
            tm = np.clip(tm, ta, tb)
            fm = g0[2] + tm * dg[:, 2] - self._height(g0[0] + tm * dg[:, 0], g0[1] + tm * dg[:, 1])
            fm = np.where(np.isfinite(fm), fm, -tol)
            out[act] = tm
            pos = fm > 0
            ta, fa = np.where(pos, tm, ta), np.where(pos, fm, fa)
            tb, fb = np.where(pos, tb, tm), np.where(pos, fb, fm)
            fb = np.where(pos & (side == 1), fb * 0.5, fb)
            fa = np.where(~pos & (side == -1), fa * 0.5, fa)
            side = np.where(pos, 1, -1).astype(np.int8)
            cheb = np.maximum(np.abs(dg[:, 0]), np.abs(dg[:, 1]))
            more = (np.abs(fm) > tol) & ((tb - ta) * cheb > 1e-9)
            act, ta, tb, fa, fb, side, dg = act[more], ta[more], tb[more], fa[more], fb[more], side[more], dg[more]
        return out


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
