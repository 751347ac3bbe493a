"""The OpenCV parameter vector of a camera about a local origin (15 values, ``projectPoints`` Jacobian order)::

    [rx, ry, rz, tx, ty, tz, fx, fy, cx, cy, k1, k2, p1, p2, k3]

``rvec``/``tvec`` map *local* world coordinates ``Xw - origin`` to the camera frame (CRS units), so large projected
coordinates lose no precision; ``fx .. cy`` in pixels; distortion in OpenCV's normalized-coordinate model. The
calibration fits this vector and the camera JSON's covariance block is stated over it.
"""

from __future__ import annotations

import numpy as np

from trafficgeo.camera.model import Camera, CRSInput

DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")
FULL_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz", "fx", "fy", "cx", "cy", *DIST_NAMES)


def camera_to_full(camera: Camera, origin: np.ndarray) -> np.ndarray:
    """Full 15-vector of a camera about a local ``origin`` (skew is not represented and must be zero)."""
    rvec, tvec = camera.rvec_tvec(origin)
    K = camera.K
    return np.concatenate([rvec, tvec, [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], camera.dist])


def full_to_camera(full: np.ndarray, origin: np.ndarray, image_size: tuple[int, int], crs: CRSInput) -> Camera:
    """Camera from a full 15-vector about ``origin``."""
    K = np.array([[full[6], 0.0, full[8]], [0.0, full[7], full[9]], [0.0, 0.0, 1.0]])
    return Camera.from_rvec_tvec(image_size, K, full[10:15], full[0:3], full[3:6], origin=origin, crs=crs)
