"""Which camera parameters a fit estimates, and the reprojection residuals with their Jacobian.

The full parameter vector follows OpenCV's ``projectPoints`` Jacobian order (15 values)::

    [rx, ry, rz, tx, ty, tz, fx, fy, cx, cy, k1, k2, p1, p2, k3]

``rvec``/``tvec`` map *local* world coordinates ``Xw - origin`` to the camera frame, so large projected coordinates
lose no precision. A :class:`ParameterModel` selects the free parameters and ties (square pixels: fx = fy = f) as a
linear map ``full = base + M @ free``; the Jacobian of the free parameters is ``J_full @ M``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from trafficgeo.camera.parameters import DIST_NAMES


@dataclass(frozen=True)
class ParameterModel:
    """Free parameters of a fit.

    Attributes:
        focal: "single" (fx = fy = f estimated), "separate" (fx, fy estimated) or "fixed".
        principal_point_free: estimate (cx, cy); otherwise they keep their start value (image centre by default).
        free_dist: names of the free distortion terms, a subset of k1, k2, p1, p2, k3 (the rest stay at their start).
        reasons: why each choice was made, for the report.
    """

    focal: str = "single"
    principal_point_free: bool = False
    free_dist: tuple[str, ...] = ()
    reasons: tuple[str, ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        if self.focal not in ("single", "separate", "fixed"):
            raise ValueError(f"focal must be single, separate or fixed, got {self.focal!r}")
        unknown = set(self.free_dist) - set(DIST_NAMES)
        if unknown:
            raise ValueError(f"unknown distortion terms {sorted(unknown)}")
        object.__setattr__(self, "free_dist", tuple(n for n in DIST_NAMES if n in self.free_dist))

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the free parameters, in the order of the free vector."""
        names = ["rx", "ry", "rz", "tx", "ty", "tz"]
        if self.focal == "single":
            names.append("f")
        elif self.focal == "separate":
            names += ["fx", "fy"]
        if self.principal_point_free:
            names += ["cx", "cy"]
        names += list(self.free_dist)
        return tuple(names)

    @property
    def n_free(self) -> int:
        return len(self.names)

    @property
    def n_intrinsic(self) -> int:
        return self.n_free - 6

    def matrix(self) -> np.ndarray:
        """The (15, n_free) map from free to full parameters."""
        M = np.zeros((15, self.n_free))
        col = 0
        for i in range(6):
            M[i, col] = 1.0
            col += 1
        if self.focal == "single":
            M[6, col] = M[7, col] = 1.0
            col += 1
        elif self.focal == "separate":
            M[6, col] = 1.0
            M[7, col + 1] = 1.0
            col += 2
        if self.principal_point_free:
            M[8, col] = 1.0
            M[9, col + 1] = 1.0
            col += 2
        for name in self.free_dist:
            M[10 + DIST_NAMES.index(name), col] = 1.0
            col += 1
        return M

    def describe(self) -> str:
        focal = {"single": "one focal length (square pixels)", "separate": "fx and fy", "fixed": "fixed focal"}
        parts = [focal[self.focal], "free principal point" if self.principal_point_free else "fixed principal point"]
        parts.append("distortion " + ", ".join(self.free_dist) if self.free_dist else "no distortion estimated")
        return "; ".join(parts)


def project_full(full: np.ndarray, local_world: np.ndarray,
                 jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Pixels (N, 2) of local world points and, if asked, the (2N, 15) Jacobian (rows u0, v0, u1, v1, ...)."""
    K = np.array([[full[6], 0.0, full[8]], [0.0, full[7], full[9]], [0.0, 0.0, 1.0]])
    pts = np.ascontiguousarray(local_world, dtype=np.float64).reshape(-1, 1, 3)
    uv, J = cv2.projectPoints(pts, full[0:3], full[3:6], K, full[10:15])
    return uv.reshape(-1, 2), (J[:, :15] if jacobian else None)


def points_in_front(full: np.ndarray, local_world: np.ndarray) -> np.ndarray:
    """Boolean (N,): whether the points lie in front of the camera (positive depth)."""
    R, _ = cv2.Rodrigues(full[0:3])
    depth = local_world @ R[2] + full[5]
    return depth > 0


def focal_bounds(image_size: tuple[int, int]) -> tuple[float, float]:
    """Plausible focal lengths (px): 0.15 to 30 image widths (fields of view of about 147 to 2 degrees)."""
    return 0.15 * image_size[0], 30.0 * image_size[0]
