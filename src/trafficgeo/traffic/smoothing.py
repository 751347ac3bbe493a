"""Smoothing world trajectories: a constant-velocity Kalman filter with outlier gating and an RTS smoother.

State ``[x, y, vx, vy]`` (metres, m/s) in a local metric frame; the motion model is constant velocity driven by
white-noise acceleration of spectral density ``accel_sigma^2`` (m^2/s^3), which lets vehicles brake and turn. Each
position measurement has standard deviation ``sigma`` (m, per axis; a scalar or one per point) or a full covariance
(one 2x2 matrix per point, m^2: a ground point seen at a low angle is uncertain mostly along the viewing ray).
Measurements whose innovation exceeds the ``gate`` (chi-square, 2 dof) are rejected as outliers (a wrong detection,
an ID switch) and the filter coasts through them; gaps in time are handled by the model. The Rauch-Tung-Striebel
backward pass then uses every point for every estimate.

Conventions: heading in degrees clockwise from north (x east, y north); speed in m/s with its 1-sigma uncertainty;
acceleration along the track in m/s^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def _measurement_covariance(sigma: object, n: int) -> np.ndarray:
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


def smooth_track(time: object, xy: object, sigma: object = 0.3, *, accel_sigma: float = 1.5,
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
