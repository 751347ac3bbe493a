"""Ground elevation at DEM nodes from lidar ground points: local planes with an adaptive radius (numba).

Each node gets the value at the node of a least-squares plane through the ground points around it. The radius is
chosen per node from a ladder ``r_j = r0 * sqrt(2)^j`` (``r0`` holds about 6 points at the cloud's typical
density) by the intersection-of-confidence-intervals rule: the plane through more points is taken as long as its
value stays inside the confidence intervals (``gamma`` standard errors, from the cloud's noise ``sigma``) of all the
smaller ones, the first being the linear TIN of the points themselves (kept when even the smallest plane disagrees
with it, e.g. on the crown of a noise-free road). On a smooth road it averages up to ~96 points (noise shrinks as
1/sqrt(n)); where the ground bends more than the noise can hide (a kerb, a ditch) the radius stays small. A bend
the noise hides is smoothed by up to about ``gamma`` standard errors of the smallest planes (on a 2 % crown with
2 cm lidar noise: ~1.6 cm at the crown line, ~3 mm 1-3 m from it).

A level counts only with >= 6 points that surround the node (the prediction's variance factor at most 5/n, i.e.
the node within 2 standard deviations of the points' centroid), so nodes inside data holes get no value (NaN; the
caller fills them). The value is clamped to the z range of the points it was fitted to: no extrapolation.

All coordinates are local (relative to an origin near the points), CRS units.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

MIN_POINTS = 6  # points for a plane level to count
MAX_VAR_FACTOR = 5.0  # n * var(value) / sigma^2 = 1 + Mahalanobis^2 of the node from the points' centroid
GAMMA = 2.0  # half-width of the confidence intervals, in standard errors
# The TIN's interval is 1.5x wider: it rests on 3 points, and noise alone should rarely end the planes (at 2
# standard errors 0.5 % of nodes would keep the raw TIN value, up to 3 sigma off; at 3, about 0.01 %).
TIN_GAMMA_FACTOR = 1.5


@njit(cache=True, nogil=True)
def _plane_at_node(m: np.ndarray) -> tuple[float, float]:
    """Value at the node (the origin of the moments) of the least-squares plane, and its variance factor.

    ``m`` holds sums of 1, dx, dy, dx^2, dx dy, dy^2, z, dx z, dy z. Returns (NaN, inf) when degenerate.
    """
    n, sx, sy, sxx, sxy, syy, sz, sxz, syz = m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8]
    # Inverse of the symmetric normal matrix [[n, sx, sy], [sx, sxx, sxy], [sy, sxy, syy]] by cofactors.
    c00 = sxx * syy - sxy * sxy
    c01 = -(sx * syy - sxy * sy)
    c02 = sx * sxy - sxx * sy
    det = n * c00 + sx * c01 + sy * c02
    scale = n * (sxx + syy)
    if not (det > 1e-9 * scale * (sxx + syy)):
        return math.nan, math.inf
    return (c00 * sz + c01 * sxz + c02 * syz) / det, c00 / det


@njit(cache=True, nogil=True)
def fit_nodes(px: np.ndarray, py: np.ndarray, pz: np.ndarray, bucket_start: np.ndarray, bx0: float, by0: float,
              bsize: float, nbx: int, nby: int, qx: np.ndarray, qy: np.ndarray, tin_z: np.ndarray,
              tin_v: np.ndarray, r0: float, levels: int, sigma: float, gamma: float,
              k_stop: int) -> tuple[np.ndarray, np.ndarray]:
    """Adaptive local-plane ground z at nodes (qx, qy); NaN where no level qualifies. Also the points used.

    Points (px, py, pz) are sorted by bucket (row-major ``iy * nbx + ix`` over squares of ``bsize`` from
    (bx0, by0)); ``bucket_start`` has ``nbx * nby + 1`` offsets.
    """
    nq = qx.shape[0]
    out = np.full(nq, np.nan)
    used = np.zeros(nq, dtype=np.int64)
    r2 = np.empty(levels)
    for j in range(levels):
        r2[j] = (r0 * 2.0 ** (0.5 * j)) ** 2
    ring = np.zeros((levels, 9))
    zlo = np.empty(levels)
    zhi = np.empty(levels)
    cum = np.zeros(9)
    for i in range(nq):
        x, y = qx[i], qy[i]
        ring[:, :] = 0.0
        zlo[:] = math.inf
        zhi[:] = -math.inf
        cum[:] = 0.0
        cx = math.floor((x - bx0) / bsize)
        cy = math.floor((y - by0) / bsize)
        lo, hi = -math.inf, math.inf
        best, best_lo, best_hi = math.nan, math.inf, -math.inf
        if tin_z[i] == tin_z[i]:  # the TIN is the finest estimate: every plane must agree with it too
            sd = TIN_GAMMA_FACTOR * sigma * math.sqrt(tin_v[i])
            lo, hi = tin_z[i] - gamma * sd, tin_z[i] + gamma * sd
            best, best_lo, best_hi = tin_z[i], tin_z[i], tin_z[i]
        planes = False
        run_lo, run_hi = math.inf, -math.inf
        done = 0  # levels finished
        stop = False
        m = 0
        while not stop and done < levels:
            # Scan the buckets at Chebyshev distance m from the node's bucket.
            for iy in range(cy - m, cy + m + 1):
                if iy < 0 or iy >= nby:
                    continue
                edge_row = iy == cy - m or iy == cy + m
                step = 1 if edge_row else 2 * m
                ix = cx - m
                while ix <= cx + m:
                    if 0 <= ix < nbx:
                        b = iy * nbx + ix
                        for k in range(bucket_start[b], bucket_start[b + 1]):
                            dx = px[k] - x
                            dy = py[k] - y
                            d2 = dx * dx + dy * dy
                            if d2 > r2[levels - 1]:
                                continue
                            j = 0
                            while d2 > r2[j]:
                                j += 1
                            z = pz[k]
                            ring[j, 0] += 1.0
                            ring[j, 1] += dx
                            ring[j, 2] += dy
                            ring[j, 3] += dx * dx
                            ring[j, 4] += dx * dy
                            ring[j, 5] += dy * dy
                            ring[j, 6] += z
                            ring[j, 7] += dx * z
                            ring[j, 8] += dy * z
                            zlo[j] = min(zlo[j], z)
                            zhi[j] = max(zhi[j], z)
                    if m == 0:
                        break
                    ix += step
            covered = m * bsize  # every point within this distance of the node has been seen
            while done < levels and r2[done] <= covered * covered:
                j = done
                done += 1
                for c in range(9):
                    cum[c] += ring[j, c]
                run_lo = min(run_lo, zlo[j])
                run_hi = max(run_hi, zhi[j])
                if cum[0] < MIN_POINTS:
                    continue
                a, v = _plane_at_node(cum)
                if not (a == a) or v * cum[0] > MAX_VAR_FACTOR:
                    continue
                planes = True
                sd = sigma * math.sqrt(v)
                new_lo = max(lo, a - gamma * sd)
                new_hi = min(hi, a + gamma * sd)
                if new_lo > new_hi:
                    stop = True
                    break
                lo, hi = new_lo, new_hi
                best, best_lo, best_hi = a, run_lo, run_hi
                used[i] = int(cum[0])
                if cum[0] >= k_stop:
                    stop = True
                    break
            m += 1
        if planes:  # else no plane had enough points around the node (data hole, footprint edge): NaN
            out[i] = min(max(best, best_lo), best_hi)
    return out, used


def noise_sigma(xyz: np.ndarray, k: int = 16, n_sample: int = 20_000) -> tuple[float, float]:
    """Robust vertical noise of ground points and their typical spacing (CRS units).

    For up to ``n_sample`` points (a fixed random subset), the residual of the point from the least-squares plane
    through its ``k`` nearest neighbours, divided by its standard factor ``sqrt(1 + var factor)``; sigma is 1.4826
    times their median absolute value. Returns (sigma, median distance to the ``k``-th neighbour).
    """
    from scipy.spatial import cKDTree

    n = xyz.shape[0]
    if n < k + 1:
        return math.nan, math.nan
    rng = np.random.default_rng(0)
    pick = rng.choice(n, n_sample, replace=False) if n > n_sample else np.arange(n)
    dist, idx = cKDTree(xyz[:, :2]).query(xyz[pick, :2], k=k + 1)
    idx = idx[:, 1:]
    dx = xyz[idx, 0] - xyz[pick, 0:1]
    dy = xyz[idx, 1] - xyz[pick, 1:2]
    z = xyz[idx, 2]
    one = np.ones_like(dx)
    m = np.stack([one, dx, dy, dx * dx, dx * dy, dy * dy, z, dx * z, dy * z], axis=-1).sum(axis=1)
    res = np.full(len(pick), np.nan)
    for i in range(len(pick)):
        a, v = _plane_at_node(m[i])
        if a == a:
            res[i] = (xyz[pick[i], 2] - a) / math.sqrt(1.0 + v)
    res = res[np.isfinite(res)]
    sigma = 1.4826 * float(np.median(np.abs(res))) if res.size else math.nan
    return sigma, float(np.median(dist[:, -1]))


@njit(cache=True, nogil=True)
def _tin_walk(transform: np.ndarray, neighbors: np.ndarray, simplices: np.ndarray, z: np.ndarray,
              qx: np.ndarray, qy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TIN value and variance factor at each node by a visibility walk through a Delaunay triangulation (scipy's
    ``transform``, ``neighbors``, ``simplices``), starting from the previous node's triangle. NaN outside."""
    n = qx.shape[0]
    out = np.full(n, np.nan)
    var = np.full(n, np.nan)
    s = 0
    max_steps = 4 * transform.shape[0] + 10
    for i in range(n):
        x, y = qx[i], qy[i]
        for _ in range(max_steps):
            t = transform[s]
            b0 = t[0, 0] * (x - t[2, 0]) + t[0, 1] * (y - t[2, 1])
            b1 = t[1, 0] * (x - t[2, 0]) + t[1, 1] * (y - t[2, 1])
            b2 = 1.0 - b0 - b1
            if not (b0 == b0 and b1 == b1):
                break  # degenerate triangle: no value here
            k = 0
            low = b0
            if b1 < low:
                k, low = 1, b1
            if b2 < low:
                k, low = 2, b2
            if low >= -1e-12:
                c = simplices[s]
                out[i] = b0 * z[c[0]] + b1 * z[c[1]] + b2 * z[c[2]]
                var[i] = b0 * b0 + b1 * b1 + b2 * b2
                break
            nxt = neighbors[s, k]
            if nxt < 0:
                break  # outside the triangulation
            s = nxt
    return out, var


def _tin(xyz: np.ndarray, qx: np.ndarray, qy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear TIN (Delaunay) value at the nodes and its variance factor (sum of squared barycentric weights);
    NaN outside the triangulation."""
    from scipy.spatial import Delaunay, QhullError

    try:
        tri = Delaunay(xyz[:, :2])
    except (QhullError, ValueError):
        return np.full(qx.shape, np.nan), np.full(qx.shape, np.nan)
    return _tin_walk(tri.transform, tri.neighbors.astype(np.int64), tri.simplices.astype(np.int64),
                     np.ascontiguousarray(xyz[:, 2]), np.ascontiguousarray(qx, dtype=np.float64),
                     np.ascontiguousarray(qy, dtype=np.float64))


def adaptive_ground(xyz: np.ndarray, qx: np.ndarray, qy: np.ndarray, *, sigma_floor: float, gamma: float = GAMMA,
                    k_stop: int = 96, levels: int = 9) -> tuple[np.ndarray, float, float]:
    """Adaptive local-plane ground z at nodes (qx, qy) from ground points ``xyz`` (local coordinates).

    ``sigma_floor`` (CRS units) bounds the noise estimate from below (noise-free or quantized clouds). Returns
    (z per node, NaN where no level qualifies; the noise sigma used; the level-0 radius r0).
    """
    sigma, r16 = noise_sigma(xyz)
    if not math.isfinite(r16) or r16 <= 0:  # too few points to fit planes: no values
        return np.full(qx.shape, np.nan), math.nan, math.nan
    sigma = max(sigma, sigma_floor) if math.isfinite(sigma) else sigma_floor
    r0 = r16 * math.sqrt(MIN_POINTS / 16.0)
    bsize = r0
    bx0, by0 = float(xyz[:, 0].min()), float(xyz[:, 1].min())
    ix = np.floor((xyz[:, 0] - bx0) / bsize).astype(np.int64)
    iy = np.floor((xyz[:, 1] - by0) / bsize).astype(np.int64)
    nbx, nby = int(ix.max()) + 1, int(iy.max()) + 1
    key = iy * nbx + ix
    order = np.argsort(key, kind="stable")
    start = np.searchsorted(key[order], np.arange(nbx * nby + 1)).astype(np.int64)
    p = xyz[order]
    tin_z, tin_v = _tin(xyz, qx, qy)
    z, _ = fit_nodes(np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1]), np.ascontiguousarray(p[:, 2]),
                     start, bx0, by0, bsize, nbx, nby, np.ascontiguousarray(qx, dtype=np.float64),
                     np.ascontiguousarray(qy, dtype=np.float64), tin_z, tin_v, r0, levels, sigma, gamma, k_stop)
    return z, sigma, r0
