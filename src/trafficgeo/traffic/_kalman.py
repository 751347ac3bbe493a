"""The constant-velocity Kalman filter and RTS smoother loop, compiled with numba (see
:mod:`trafficgeo.traffic.smoothing` for the model; this module only runs it)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _predict(x: np.ndarray, P: np.ndarray, dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    F = np.eye(4)
    F[0, 2] = dt
    F[1, 3] = dt
    Q = np.zeros((4, 4))
    q11, q12, q22 = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
    Q[0, 0] = Q[1, 1] = q11
    Q[0, 2] = Q[2, 0] = Q[1, 3] = Q[3, 1] = q12
    Q[2, 2] = Q[3, 3] = q22
    return F @ x, F @ P @ F.T + Q


@njit(cache=True, nogil=True)
def kalman_rts(t: np.ndarray, z: np.ndarray, R: np.ndarray, q: float, gate: float,
               x0: np.ndarray, P0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Forward filter with chi-square gating, then the RTS backward pass.

    ``t`` (N,) s, ``z`` (N, 2) m, ``R`` (N, 2, 2) m^2, ``q`` m^2/s^3, ``x0``/``P0`` the state and covariance at
    the first point before its measurement. Returns the smoothed states (N, 4), covariances (N, 4, 4) and the
    outlier flags (N,) (the first point is never an outlier).
    """
    n = t.size
    xf = np.zeros((n, 4))
    Pf = np.zeros((n, 4, 4))
    xp = np.zeros((n, 4))
    Pp = np.zeros((n, 4, 4))
    outlier = np.zeros(n, dtype=np.bool_)
    x = x0.copy()
    P = P0.copy()
    for k in range(n):
        if k > 0:
            x, P = _predict(x, P, t[k] - t[k - 1], q)
        xp[k] = x
        Pp[k] = P
        S = P[:2, :2] + R[k]
        det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
        Si = np.array([[S[1, 1], -S[0, 1]], [-S[1, 0], S[0, 0]]]) / det
        innov = z[k] - x[:2]
        d2 = innov @ Si @ innov
        if k > 0 and d2 > gate:
            outlier[k] = True  # coast: keep the prediction
        else:
            K = np.ascontiguousarray(P[:, :2]) @ Si  # (4, 2)
            x = x + K @ innov
            P = P - K @ np.ascontiguousarray(P[:2, :])
            P = 0.5 * (P + P.T)
        xf[k] = x
        Pf[k] = P
    xs = xf.copy()
    Ps = Pf.copy()
    for k in range(n - 2, -1, -1):
        dt = t[k + 1] - t[k]
        F = np.eye(4)
        F[0, 2] = dt
        F[1, 3] = dt
        C = Pf[k] @ F.T @ np.linalg.inv(Pp[k + 1])
        xs[k] = xf[k] + C @ (xs[k + 1] - xp[k + 1])
        Ps[k] = Pf[k] + C @ (Ps[k + 1] - Pp[k + 1]) @ C.T
    return xs, Ps, outlier
