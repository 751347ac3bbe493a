"""OpenCV's 5-term lens distortion, forward and (accurately) inverse, on normalized image coordinates.

Normalized coordinates are ``x = Xc / Zc``, ``y = Yc / Zc`` in the camera frame (OpenCV axes). The coefficients are
in OpenCV order ``[k1, k2, p1, p2, k3]``::

    r2 = x^2 + y^2
    radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
    xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
    yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y

:func:`undistort_normalized` inverts this with damped Newton iterations until the residual is below ``tol``
(default 1e-10 in normalized units, i.e. ~1e-7 px at f = 1000 px). OpenCV's ``undistortPoints`` runs a fixed five
fixed-point iterations, which leaves errors of tenths of a pixel to pixels near the corners of wide-angle frames.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

NDArray = np.ndarray


def as_dist(dist: ArrayLike | None) -> NDArray:
    """Return distortion coefficients as a float64 array of 5 values (None -> zeros)."""
    if dist is None:
        return np.zeros(5)
    d = np.asarray(dist, dtype=np.float64).ravel()
    if d.size < 5:
        d = np.concatenate([d, np.zeros(5 - d.size)])
    if d.size != 5:
        raise ValueError(f"distortion must have at most 5 coefficients [k1, k2, p1, p2, k3], got {d.size}")
    return d


def distort_normalized(xy: NDArray, dist: NDArray) -> NDArray:
    """Apply distortion to normalized coordinates ``xy`` (N, 2); returns distorted normalized (N, 2)."""
    k1, k2, p1, p2, k3 = dist
    x = xy[..., 0]
    y = xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def undistort_normalized(xyd: NDArray, dist: NDArray, *, tol: float = 1e-10, max_iter: int = 50) -> NDArray:
    """Invert :func:`distort_normalized` for distorted normalized coordinates ``xyd`` (N, 2).

    Damped Newton iterations (per point, compiled with numba) from one fixed-point step ``xyd / radial(xyd)``,
    which moves the start towards the solution for barrel and pincushion lenses alike, away from the fold. A point
    whose residual does not fall below ``tol`` (normalized units) gets NaN: it lies outside the region where the
    lens model is invertible (e.g. beyond the radius where strong distortion folds back), so no trustworthy ray
    exists for it; so does a point where the model's Jacobian determinant is not positive (past the fold).
    """
    xyd = np.asarray(xyd, dtype=np.float64)
    if not np.any(dist):
        return xyd.copy()
    from trafficgeo.camera._undistort import undistort_points  # numba: compiled on first use, then cached

    flat = np.ascontiguousarray(xyd.reshape(-1, 2))
    out = undistort_points(flat, np.ascontiguousarray(dist, dtype=np.float64), float(tol), int(max_iter))
    return out.reshape(xyd.shape)


def max_monotonic_radius(dist: NDArray, r_max: float = 4.0, samples: int = 4000) -> float:
    """Largest normalized radius up to ``r_max`` over which the radial distortion ``r * radial(r)`` increases.

    Beyond it the lens model folds back (two scene directions map to one pixel) and cannot be trusted.
    """
    k1, k2, _, _, k3 = dist
    r = np.linspace(0.0, r_max, samples)
    r2 = r * r
    # d/dr [r (1 + k1 r^2 + k2 r^4 + k3 r^6)]
    deriv = 1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2 + 7.0 * k3 * r2 * r2 * r2
    bad = np.nonzero(deriv <= 0)[0]
    return float(r_max if bad.size == 0 else r[max(bad[0] - 1, 0)])
