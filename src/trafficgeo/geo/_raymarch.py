"""The DEM ray march, compiled with numba (one ray at a time: each stops as soon as it is resolved).

Grid space: ``(col, row, z)`` with cell centres at ``+0.5``; a ray is ``g0 + t * dg`` with ``t`` the world
distance. See :class:`trafficgeo.geo.surface.DEMSurface` for the method; status codes match
:data:`trafficgeo.geo.surface.STATUSES` (0 ok, 1 above_horizon, 3 miss, 4 no_data, 6 outside_lens).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_OK, _ABOVE_HORIZON, _MISS, _NO_DATA, _OUTSIDE_LENS = 0, 1, 3, 4, 6


@njit(cache=True, nogil=True)
def _cell(values: np.ndarray, gc: float, gr: float) -> tuple[int, int, int, int, float, float]:
    """Bilinear patch of grid coordinates: corner indices r0, c0, r1, c1 and weights wc, wr (clamped at the edges)."""
    rows, cols = values.shape
    fc = min(max(gc - 0.5, 0.0), cols - 1.0)
    fr = min(max(gr - 0.5, 0.0), rows - 1.0)
    c0 = min(int(fc), max(cols - 2, 0))
    r0 = min(int(fr), max(rows - 2, 0))
    return r0, c0, min(r0 + 1, rows - 1), min(c0 + 1, cols - 1), fc - c0, fr - r0


@njit(cache=True, nogil=True)
def _height(values: np.ndarray, gc: float, gr: float) -> float:
    """Bilinear elevation at grid coordinates (clamped in the outer half cell; NaN outside or over no data)."""
    rows, cols = values.shape
    if gc < 0.0 or gc > cols or gr < 0.0 or gr > rows or not (gc == gc and gr == gr):
        return math.nan
    r0, c0, r1, c1, wc, wr = _cell(values, gc, gr)
    top = values[r0, c0] + (values[r0, c1] - values[r0, c0]) * wc
    bot = values[r1, c0] + (values[r1, c1] - values[r1, c0]) * wc
    return top + (bot - top) * wr


@njit(cache=True, nogil=True)
def _gradient(values: np.ndarray, gc: float, gr: float) -> tuple[float, float]:
    """dZ/dcol, dZ/drow of the bilinear surface (zero across the clamped outer half cell)."""
    rows, cols = values.shape
    r0, c0, r1, c1, wc, wr = _cell(values, gc, gr)
    dzdc = (values[r0, c1] - values[r0, c0]) * (1 - wr) + (values[r1, c1] - values[r1, c0]) * wr
    top = values[r0, c0] + (values[r0, c1] - values[r0, c0]) * wc
    bot = values[r1, c0] + (values[r1, c1] - values[r1, c0]) * wc
    dzdr = bot - top
    if gc - 0.5 < 0.0 or gc - 0.5 > cols - 1:
        dzdc = 0.0
    if gr - 0.5 < 0.0 or gr - 0.5 > rows - 1:
        dzdr = 0.0
    return dzdc, dzdr


@njit(cache=True, nogil=True)
def _gap(values: np.ndarray, g0: np.ndarray, dc: float, dr: float, dz: float, t: float) -> float:
    """Height of the ray above the surface at t (NaN over no data or outside)."""
    return g0[2] + t * dz - _height(values, g0[0] + t * dc, g0[1] + t * dr)


@njit(cache=True, nogil=True)
def _refine(values: np.ndarray, g0: np.ndarray, dc: float, dr: float, dz: float, ta: float, tb: float, fa: float,
            fb: float, tol: float) -> float:
    """Root in [ta, tb] (fa > 0 >= fb) by regula falsi with the Illinois modification."""
    cheb = max(abs(dc), abs(dr))
    tm = tb
    side = 0
    for _ in range(60):
        if tb - ta <= 0.0:
            return tb
        tm = (ta * fb - tb * fa) / (fb - fa) if fa != fb else 0.5 * (ta + tb)
        tm = min(max(tm, ta), tb)
        fm = _gap(values, g0, dc, dr, dz, tm)
        if not (fm == fm):
            fm = -tol
        if fm > 0.0:
            ta, fa = tm, fm
            if side == 1:
                fb *= 0.5
            side = 1
        else:
            tb, fb = tm, fm
            if side == -1:
                fa *= 0.5
            side = -1
        if abs(fm) <= tol or (tb - ta) * cheb <= 1e-9:
            break
    return tm


@njit(cache=True, nogil=True)
def _first_crossing(values: np.ndarray, g0: np.ndarray, dc: float, dr: float, dz: float, ts: float, te: float,
                    gs: float, ge: float, max_twist: float) -> tuple[bool, float, float, float, float]:
    """First sign change of the ray's height in [ts, te] (at most half a cell long).

    The height is continuous and piecewise quadratic along the segment, with kinks where it crosses the lines
    between cell centres (at most one per axis); it is evaluated at the kinks, and inside a piece, where the
    bilinear cross term could bend it below zero between two positive ends, at the piece's vertex.
    """
    knot_c = te
    knot_r = te
    for axis in range(2):
        d = dc if axis == 0 else dr
        a = g0[axis] + ts * d
        b = g0[axis] + te * d
        line = math.floor(max(a, b) - 0.5) + 0.5
        if min(a, b) < line < max(a, b):
            if axis == 0:
                knot_c = ts + (line - a) / d
            else:
                knot_r = ts + (line - a) / d
    k1 = min(knot_c, knot_r)
    k2 = max(knot_c, knot_r)
    f_a = gs
    t_a = ts
    for p in range(3):
        t_b = k1 if p == 0 else (k2 if p == 1 else te)
        if t_b <= t_a and p < 2:
            continue
        f_b = ge if t_b >= te else _gap(values, g0, dc, dr, dz, t_b)
        if f_a > 0.0 and f_b <= 0.0:
            return True, t_a, t_b, f_a, f_b
        length = t_b - t_a
        if f_a > 0.0 and f_b > 0.0 and length > 0.0 and min(f_a, f_b) < max_twist * abs(dc * dr) * length**2 / 4:
            fm = _gap(values, g0, dc, dr, dz, 0.5 * (t_a + t_b))
            curv = 2.0 * (f_a + f_b) - 4.0 * fm  # A L^2 in g(s) = f_a + (f_b - f_a) s + A L^2 s (s - 1)
            if curv > 0.0:
                s = min(max(0.5 - (f_b - f_a) / (2.0 * curv), 0.0), 1.0)
                g = f_a + (f_b - f_a) * s + curv * s * (s - 1.0)
                if g <= 0.0:
                    return True, t_a, t_a + s * length, f_a, g
        t_a = t_b
        f_a = f_b
        if t_b >= te:
            break
    if not (gs == gs) and ge == ge and ge <= 0.0:  # entering data below the surface from a no-data hole
        return True, te, te, 0.0, ge
    return False, te, te, ge, ge


@njit(cache=True, nogil=True)
def _extent(g0: np.ndarray, dc: float, dr: float, dz: float, rows: int, cols: int, zmin: float,
            zmax: float) -> tuple[float, float, bool]:
    """Ray parameters [t0, t1] inside the grid's footprint and the elevation slab, and whether the ray sinks
    below ``zmin`` inside the footprint."""
    t0 = 0.0
    t1 = math.inf
    for axis in range(2):
        o = g0[axis]
        d = dc if axis == 0 else dr
        size = cols if axis == 0 else rows
        if d == 0.0:
            if not (0.0 <= o <= size):
                return 1.0, 0.0, False
        else:
            ta = (0.0 - o) / d
            tb = (size - o) / d
            t0 = max(t0, min(ta, tb))
            t1 = min(t1, max(ta, tb))
    sinks = False
    if dz < 0.0:
        if g0[2] > zmax:
            t0 = max(t0, (zmax - g0[2]) / dz)
        t_bottom = (zmin - g0[2]) / dz
        sinks = t_bottom < t1
        t1 = min(t1, t_bottom)
    elif dz > 0.0:
        t1 = min(t1, (zmax - g0[2]) / dz)
    return t0, t1, sinks


@njit(cache=True, nogil=True)
def intersect_rays(values: np.ndarray, pyramid: np.ndarray, offsets: np.ndarray, ncols: np.ndarray,
                   reach: np.ndarray, max_twist: float, zmin: float, zmax: float, g0: np.ndarray,
                   dg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First hits of rays ``g0 + t dg[i]`` (grid space): t, status code and the grid gradient (N, 2) at the hit."""
    n = dg.shape[0]
    rows, cols = values.shape
    # The slab is widened a hair so that rounding cannot start a ray below a flat surface.
    pad = 1e-7 * (1.0 + abs(zmax) + abs(zmin))
    t0 = np.empty(n)
    t1 = np.empty(n)
    sinks = np.zeros(n, dtype=np.bool_)
    code = np.full(n, _MISS, dtype=np.int8)
    live = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        dc, dr, dz = dg[i, 0], dg[i, 1], dg[i, 2]
        if not (dc == dc and dr == dr and dz == dz):
            code[i] = _OUTSIDE_LENS
            continue
        if dz >= 0.0 and g0[2] > zmax + pad:
            code[i] = _ABOVE_HORIZON
            continue
        t0[i], t1[i], sinks[i] = _extent(g0, dc, dr, dz, rows, cols, zmin - pad, zmax + pad)
        live[i] = t0[i] <= t1[i]
    t_hit, code_m = march(values, pyramid, offsets, ncols, reach, max_twist, zmax - zmin, g0, dg, t0, t1, live)
    grad = np.full((n, 2), np.nan)
    for i in range(n):
        if code[i] != _MISS:
            continue
        c = code_m[i] if live[i] else _MISS
        if c == _MISS and sinks[i]:
            c = _NO_DATA
        if c == _MISS and dg[i, 2] >= 0.0:
            c = _ABOVE_HORIZON
        code[i] = c
        if c == _OK:
            grad[i, 0], grad[i, 1] = _gradient(values, g0[0] + t_hit[i] * dg[i, 0], g0[1] + t_hit[i] * dg[i, 1])
    return t_hit, code, grad


@njit(cache=True, nogil=True)
def march(values: np.ndarray, pyramid: np.ndarray, offsets: np.ndarray, ncols: np.ndarray, reach: np.ndarray,
          max_twist: float, zrange: float, g0: np.ndarray, dg: np.ndarray, t0: np.ndarray,
          t1: np.ndarray, live: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hits of rays ``g0 + t dg[i]`` for t in [t0[i], t1[i]]: (t, status code) per ray.

    A step is taken only where the ray stays above the pyramid's maximum within the step's reach (levels L and
    L - 1 are tried; after a step limited by its reach the next try is one level coarser, after one that met the
    level's envelope one level finer); at the finest levels the ray advances half a cell at a time and
    :func:`_first_crossing` brackets the crossing, which :func:`_refine` solves.
    """
    n = dg.shape[0]
    rows, cols = values.shape
    top = reach.shape[0] - 1
    tol = 1e-9 * (1.0 + abs(g0[2]))
    t_hit = np.full(n, np.nan)
    code = np.full(n, _MISS, dtype=np.int8)
    for i in range(n):
        if not live[i]:
            continue
        dc, dr, dz = dg[i, 0], dg[i, 1], dg[i, 2]
        t = t0[i]
        tend = t1[i]
        cheb = max(abs(dc), abs(dr))
        fine = 0.5 / cheb if cheb > 0 else math.inf
        inv_cheb = 1.0 / cheb if cheb > 0 else math.inf
        descent = max(-dz, 0.0)
        inv_descent = 1.0 / descent if descent > 0 else math.inf
        run_cells = (zrange + 1e-9) * inv_descent * cheb
        level = min(max(int(math.log2(min(max(run_cells, 1.0), 2.0**top))), 2), top)
        gap = _gap(values, g0, dc, dr, dz, t)
        if gap < 0.0:  # enters the grid's footprint through its side, below the surface
            continue
        crossed = False
        while True:
            if t >= tend:
                code[i] = _NO_DATA if crossed else _MISS
                break
            gc = g0[0] + t * dc
            gr = g0[1] + t * dr
            z = g0[2] + t * dz
            ci = min(max(int(gc), 0), cols - 1)
            ri = min(max(int(gr), 0), rows - 1)
            lo = max(level - 1, 1)
            room_hi = z - pyramid[offsets[level] + (ri >> level) * ncols[level] + (ci >> level)]
            room_lo = z - pyramid[offsets[lo] + (ri >> lo) * ncols[lo] + (ci >> lo)]
            reach_hi = reach[level] * inv_cheb
            reach_lo = reach[lo] * inv_cheb
            drop_hi = room_hi * inv_descent if room_hi > 0 else 0.0
            drop_lo = room_lo * inv_descent if room_lo > 0 else 0.0
            safe_hi = min(reach_hi, drop_hi)
            safe_lo = min(reach_lo, drop_lo)
            if safe_hi >= fine:
                t += safe_hi
                level = min(level + 1, top) if reach_hi <= drop_hi else max(level - 1, 1)
                gap = math.nan
            elif safe_lo >= fine:
                t += safe_lo
                level = level if reach_lo <= drop_lo else max(level - 2, 1)
                gap = math.nan
            elif lo > 1:
                level = max(level - 2, 1)
            else:
                te = min(t + fine, tend)
                if not (gap == gap):
                    gap = _gap(values, g0, dc, dr, dz, t)
                ge = _gap(values, g0, dc, dr, dz, te)
                if not (ge == ge):
                    crossed = True
                found, ta, tb, fa, fb = _first_crossing(values, g0, dc, dr, dz, t, te, gap, ge, max_twist)
                if found:
                    t_hit[i] = _refine(values, g0, dc, dr, dz, ta, tb, fa if fa == fa else 0.0, fb, tol)
                    code[i] = _OK
                    break
                t = te
                gap = ge
                level = 2 if ge > 0 else 1
    return t_hit, code
