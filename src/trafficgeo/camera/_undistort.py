"""Per-point damped Newton inversion of OpenCV's 5-term distortion, compiled with numba.

See :func:`trafficgeo.camera.distortion.undistort_normalized` for the method and the conventions.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _distort(x: float, y: float, k1: float, k2: float, p1: float, p2: float, k3: float) -> tuple[float, float]:
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


@njit(cache=True, nogil=True)
def _jacobian(x: float, y: float, k1: float, k2: float, p1: float, p2: float,
              k3: float) -> tuple[float, float, float, float]:
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    a = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))
    cross = a * x * y + 2.0 * p1 * x + 2.0 * p2 * y
    return (radial + a * x * x + 2.0 * p1 * y + 6.0 * p2 * x, cross, cross,
            radial + a * y * y + 6.0 * p1 * y + 2.0 * p2 * x)


@njit(cache=True, nogil=True)
def undistort_points(xyd: np.ndarray, dist: np.ndarray, tol: float, max_iter: int) -> np.ndarray:
    """Undistorted normalized coordinates (N, 2) of distorted ones; NaN where the model is not invertible."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    n = xyd.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        xd, yd = xyd[i, 0], xyd[i, 1]
        r2d = xd * xd + yd * yd
        radial_d = 1.0 + r2d * (k1 + r2d * (k2 + r2d * k3))
        x, y = (xd / radial_d, yd / radial_d) if radial_d > 0.2 else (xd, yd)
        fx, fy = _distort(x, y, k1, k2, p1, p2, k3)
        rx, ry = fx - xd, fy - yd
        err = math.hypot(rx, ry)
        for _ in range(max_iter):
            if not (err > tol):
                break
            a, b, c, d = _jacobian(x, y, k1, k2, p1, p2, k3)
            det = a * d - b * c
            if abs(det) < 1e-300:
                det = 1e-300
            sx = (d * rx - b * ry) / det
            sy = (-c * rx + a * ry) / det
            scale = 1.0
            improved = False
            for _ in range(9):  # backtrack where a full Newton step does not reduce the residual
                nx, ny = x - scale * sx, y - scale * sy
                fx, fy = _distort(nx, ny, k1, k2, p1, p2, k3)
                nrx, nry = fx - xd, fy - yd
                new_err = math.hypot(nrx, nry)
                if new_err < err:
                    improved = True
                    break
                scale *= 0.5
            if not improved:
                break
            x, y, rx, ry, err = nx, ny, nrx, nry, new_err
        a, b, c, d = _jacobian(x, y, k1, k2, p1, p2, k3)
        if err > tol or not (a * d - b * c > 0.0):  # not converged, or beyond the fold of the lens model
            out[i, 0] = math.nan
            out[i, 1] = math.nan
        else:
            out[i, 0] = x
            out[i, 1] = y
    return out
