"""Smoothing world trajectories: a constant-velocity Kalman filter with outlier gating and an RTS smoother.

State ``[x, y, vx, vy]`` (metres, m/s) in a local metric frame; the motion model is constant velocity driven by
white-noise acceleration of spectral density ``accel_sigma^2`` (m^2/s^3), which lets vehicles brake and turn. Each
position measurement has standard deviation ``sigma`` (m, per axis; a scalar or one per point) or a full covariance
(one 2x2 matrix per point, m^2: a ground point seen at a low angle is uncertain mostly along the viewing ray).
Measurements whose innovation exceeds the ``gate`` (chi-square, 2 dof) are rejected as outliers (a wrong detection,
an ID switch) and the filter coasts through them; gaps in time are handled by the model. The Rauch-Tung-Striebel
backward pass then uses every point for every estimate.

:func:`along_track` gives speeds and the distance travelled along the direction of travel, which, unlike the
smoothed path's arc length or the magnitude of its velocity, a sideways wiggle of the path does not lengthen.

Conventions: heading in degrees clockwise from north (x east, y north); speed in m/s with its 1-sigma uncertainty;
acceleration along the track in m/s^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from trafficgeo.errors import InputError
from trafficgeo.traffic._kalman import kalman_rts

CHI2_2DOF_999 = 13.815510557964274  # 99.9 % quantile of chi-square with 2 degrees of freedom


@dataclass(frozen=True)
class SmoothedTrack:
    """A smoothed trajectory, one row per input point (arrays (N,)); ``outlier`` marks rejected measurements."""

    time: np.ndarray
    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    position_std: np.ndarray  # m, sqrt of the mean of the x and y variances
    speed: np.ndarray  # m/s
    speed_std: np.ndarray  # m/s
    heading_deg: np.ndarray
    accel: np.ndarray  # m/s^2 along the track
    outlier: np.ndarray


def _measurement_covariance(sigma: ArrayLike, n: int) -> np.ndarray:
    """(N, 2, 2) covariances from a scalar or (N,) sigma (m) or (N, 2, 2) covariances (m^2)."""
    arr = np.asarray(sigma, dtype=np.float64)
    if arr.ndim == 3:
        if arr.shape != (n, 2, 2) or not np.all(np.isfinite(arr)):
            raise InputError(f"measurement covariance must be finite with shape ({n}, 2, 2), got {arr.shape}")
        if not np.all(np.linalg.eigvalsh(0.5 * (arr + arr.transpose(0, 2, 1))) > 0):
            raise InputError("measurement covariance must be positive definite")
        return arr
    s = np.broadcast_to(arr, (n,))
    if not np.all(s > 0):
        raise InputError("measurement sigma must be positive (metres)")
    return s[:, None, None] ** 2 * np.eye(2)[None]


def smooth_track(time: ArrayLike, xy: ArrayLike, sigma: ArrayLike = 0.3, *, accel_sigma: float = 1.5,
                 gate: float = CHI2_2DOF_999) -> SmoothedTrack:
    """Kalman filter + RTS smoother for one track: ``time`` (N,) s strictly increasing, ``xy`` (N, 2) metres,
    ``sigma`` m (scalar or (N,)) or covariance m^2 (N, 2, 2)."""
    t = np.asarray(time, dtype=np.float64).reshape(-1)
    z = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = t.size
    if z.shape[0] != n or n == 0:
        raise InputError(f"a track needs one (x, y) per time and at least one point; got {n} times, {len(z)} points")
    if n > 1 and not np.all(np.diff(t) > 0):
        raise InputError("track times must increase strictly (sort the points; one point per frame)")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(z))):
        raise InputError("track times and positions must be finite numbers")
    R_all = _measurement_covariance(sigma, n)
    q = float(accel_sigma) ** 2
    origin = z[0].copy()
    zl = z - origin  # local frame: no precision lost on 5e6 coordinates
    # Start: at the first point, speed unknown (30 m/s 1-sigma).
    P0 = np.zeros((4, 4))
    P0[:2, :2] = R_all[0] * 1e6  # the first measurement alone sets the position
    P0[2, 2] = P0[3, 3] = 30.0**2
    x0 = np.array([zl[0, 0], zl[0, 1], 0.0, 0.0])
    xs, Ps, outlier = kalman_rts(t, np.ascontiguousarray(zl), np.ascontiguousarray(R_all), q, float(gate), x0, P0)
    vx, vy = xs[:, 2], xs[:, 3]
    speed = np.hypot(vx, vy)
    with np.errstate(invalid="ignore", divide="ignore"):
        ux, uy = np.where(speed > 0, vx / speed, 0.0), np.where(speed > 0, vy / speed, 0.0)
    var_speed = ux * ux * Ps[:, 2, 2] + 2 * ux * uy * Ps[:, 2, 3] + uy * uy * Ps[:, 3, 3]
    accel = np.gradient(speed, t) if n > 1 else np.zeros(1)
    return SmoothedTrack(time=t, x=xs[:, 0] + origin[0], y=xs[:, 1] + origin[1], vx=vx, vy=vy,
                         position_std=np.sqrt(0.5 * (Ps[:, 0, 0] + Ps[:, 1, 1])), speed=speed,
                         speed_std=np.sqrt(np.clip(var_speed, 0.0, None)),
                         heading_deg=np.degrees(np.arctan2(vx, vy)) % 360.0, accel=accel, outlier=outlier)


DIRECTION_SMOOTHING_S = 1.0  # s: sigma of the Gaussian weights of the direction of travel (the velocity's trend)
MIN_DIRECTION_SPEED = 1.0  # m/s: slower trends give no direction (a stop); the nearest faster one is used


def _local_linear(t: np.ndarray, values: np.ndarray, sigma_s: float, block: int = 256) -> np.ndarray:
    """Local linear regression of ``values`` (N, K) on ``t`` (N,) with Gaussian weights of ``sigma_s`` (cut at
    3 sigma), evaluated at each t: a smooth trend that passes through a steady turn and, near the ends, follows
    the trend instead of lagging behind it. Works in blocks of ``block`` rows (memory ~ block x window)."""
    tt = t - t[0]
    n = tt.size
    out = np.empty((n, values.shape[1]))
    lo_all = np.searchsorted(tt, tt - 3.0 * sigma_s, side="left")
    hi_all = np.searchsorted(tt, tt + 3.0 * sigma_s, side="right")
    for b in range(0, n, block):
        rows = np.arange(b, min(b + block, n))
        lo, hi = lo_all[rows[0]], hi_all[rows[-1]]
        dt = tt[lo:hi][None, :] - tt[rows][:, None]
        w = np.where(np.abs(dt) <= 3.0 * sigma_s, np.exp(-0.5 * (dt / sigma_s) ** 2), 0.0)
        s0, s1, s2 = w.sum(axis=1), (w * dt).sum(axis=1), (w * dt * dt).sum(axis=1)
        m0, m1 = w @ values[lo:hi], (w * dt) @ values[lo:hi]
        det = s0 * s2 - s1 * s1
        ok = det > 1e-9 * s0 * s0 * sigma_s**2  # else too few distinct times in the window for a trend
        linear = (s2[:, None] * m0 - s1[:, None] * m1) / np.where(ok, det, 1.0)[:, None]
        out[rows] = np.where(ok[:, None], linear, m0 / s0[:, None])
    return out


def travel_direction(sm: SmoothedTrack, sigma_s: float = DIRECTION_SMOOTHING_S) -> np.ndarray:
    """(N, 2) unit vectors (x east, y north): each point's direction of travel, the trend of the smoothed velocity
    over a few ``sigma_s`` s (:func:`_local_linear`, so the direction follows a curve to the track's ends). A
    sideways wiggle of the smoothed path faster than about one period in ``3 sigma_s`` does not turn it. Where the
    trend is slower than :data:`MIN_DIRECTION_SPEED` (a stop), the nearest faster point's direction; for a track
    that never moves, the direction of its net displacement."""
    v = _local_linear(sm.time, np.column_stack([sm.vx, sm.vy]), sigma_s)
    speed = np.hypot(v[:, 0], v[:, 1])
    moving = speed > MIN_DIRECTION_SPEED
    if not moving.any():
        d = np.array([sm.x[-1] - sm.x[0], sm.y[-1] - sm.y[0]])
        norm = float(np.hypot(*d))
        return np.tile(d / norm if norm > 0 else np.array([0.0, 1.0]), (sm.time.size, 1))
    idx = np.flatnonzero(moving)
    nearest = idx[np.clip(np.searchsorted(idx, np.arange(sm.time.size)), 0, idx.size - 1)]
    v = np.where(moving[:, None], v, v[nearest])
    return v / np.hypot(v[:, 0], v[:, 1])[:, None]


def along_track(sm: SmoothedTrack, sigma_s: float = DIRECTION_SMOOTHING_S) -> tuple[np.ndarray, float]:
    """Speed along the direction of travel (:func:`travel_direction`) at each point (m/s, (N,); 0 where the
    vehicle moves backwards: noise about a stop) and the distance travelled along it (m): each step of the
    smoothed path projected on the direction of travel there. Unlike the path's arc length, neither includes the
    path's residual sideways wiggle (which lengthens a noisy path), and noise along the road only moves the two
    ends; on a curve the direction turns with the road."""
    d = travel_direction(sm, sigma_s)
    speed = np.clip(sm.vx * d[:, 0] + sm.vy * d[:, 1], 0.0, None)
    if sm.time.size < 2:
        return speed, 0.0
    mid = d[1:] + d[:-1]
    norm = np.hypot(mid[:, 0], mid[:, 1])
    mid = np.where(norm[:, None] > 1e-9, mid / np.where(norm > 1e-9, norm, 1.0)[:, None], d[1:])
    return speed, float(np.sum(np.diff(sm.x) * mid[:, 0] + np.diff(sm.y) * mid[:, 1]))
