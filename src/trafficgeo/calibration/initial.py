"""Stage 1 and 2: starting cameras from GCPs, with no distortion.

Two routes, both run when they apply (several starts; the caller keeps the best after refinement):

* **DLT** (normalized, Hartley & Zisserman alg. 7.1) followed by an RQ decomposition ``P = K [R | t]`` with a
  positive diagonal and ``det(R) = +1``. Needs >= 6 points that are *not* near-coplanar: on a road the points span
  metres in X/Y but centimetres in Z, the 11-parameter DLT is then degenerate and returns noise (the paper's
  weak spot). :func:`planarity` measures this from the singular values of the centred points.
* **Focal sweep + SQPnP**: with the principal point at the image centre and square pixels, only the focal length
  is unknown besides the pose. For each focal on a log grid OpenCV's SQPnP (globally optimal PnP, works for planar
  and non-planar points) gives the pose; the focal with the lowest robust reprojection cost is refined by a bounded
  1-D search. A closed-form focal from the plane-to-image homography (Zhang's orthogonality constraints with a known
  principal point) is added to the grid when the points are near-planar.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import scipy.linalg
from scipy.optimize import minimize_scalar

from trafficgeo.calibration.params import points_in_front, project_full

PLANAR_RATIO = 0.05
"""Smallest-to-largest singular value ratio of the centred world points below which they count as near-coplanar."""


@dataclass(frozen=True)
class Start:
    """A starting camera as a full 15-vector about the local origin (see :mod:`.params`) and its origin route."""

    full: np.ndarray
    method: str
    cost: float


def planarity(local_world: np.ndarray) -> tuple[float, np.ndarray]:
    """(ratio of smallest to largest singular value, unit normal of the best plane) of centred world points."""
    centred = local_world - local_world.mean(axis=0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    ratio = float(s[2] / s[0]) if s[0] > 0 else 0.0
    return ratio, vt[2]


def _robust_cost(errors: np.ndarray, scale: float) -> float:
    """Soft-L1 cost of pixel error magnitudes; inf when any is not finite."""
    if not np.all(np.isfinite(errors)):
        return float("inf")
    z = (errors / scale) ** 2
    return float(np.sum(2.0 * (np.sqrt(1.0 + z) - 1.0)))


def _evaluate(full: np.ndarray, local_world: np.ndarray, pixels: np.ndarray, scale: float) -> float:
    if not np.all(np.isfinite(full)) or not points_in_front(full, local_world).all():
        return float("inf")
    uv, _ = project_full(full, local_world, jacobian=False)
    return _robust_cost(np.linalg.norm(uv - pixels, axis=1), scale)


def _full_from(K: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, dist: np.ndarray | None = None) -> np.ndarray:
    d = np.zeros(5) if dist is None else np.asarray(dist, float)
    return np.concatenate([np.ravel(rvec), np.ravel(tvec), [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], d])


# ---------------------------------------------------------------------------------------------------- DLT
def _normalization(points: np.ndarray) -> np.ndarray:
    """Similarity that moves points to their centroid and scales their mean distance to sqrt(dim)."""
    dim = points.shape[1]
    c = points.mean(axis=0)
    mean_dist = np.mean(np.linalg.norm(points - c, axis=1))
    s = np.sqrt(dim) / mean_dist if mean_dist > 0 else 1.0
    T = np.eye(dim + 1)
    T[:dim, :dim] *= s
    T[:dim, dim] = -s * c
    return T


def dlt_projection(local_world: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Normalized DLT: the 3x4 projection matrix P (defined up to scale) from >= 6 correspondences."""
    n = local_world.shape[0]
    Tw = _normalization(local_world)
    Ti = _normalization(pixels)
    Xw = (Tw @ np.hstack([local_world, np.ones((n, 1))]).T).T
    xi = (Ti @ np.hstack([pixels, np.ones((n, 1))]).T).T
    A = np.zeros((2 * n, 12))
    A[0::2, 0:4] = Xw
    A[0::2, 8:12] = -xi[:, 0:1] * Xw
    A[1::2, 4:8] = Xw
    A[1::2, 8:12] = -xi[:, 1:2] * Xw
    _, _, vt = np.linalg.svd(A)
    Pn = vt[-1].reshape(3, 4)
    return np.linalg.inv(Ti) @ Pn @ Tw


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RQ decomposition ``P = K [R | t]`` with K upper triangular, positive diagonal, K[2,2] = 1, det(R) = +1."""
    P = np.asarray(P, dtype=np.float64)
    if np.linalg.det(P[:, :3]) < 0:
        P = -P
    K, R = scipy.linalg.rq(P[:, :3])
    d = np.sign(np.diag(K))
    d[d == 0] = 1.0
    signs = np.diag(d)
    K = K @ signs
    R = signs @ R
    t = np.linalg.solve(K, P[:, 3])
    K = K / K[2, 2]
    return K, R, t


def dlt_start(local_world: np.ndarray, pixels: np.ndarray, image_size: tuple[int, int]) -> np.ndarray | None:
    """DLT start projected onto square pixels, zero skew and a centred principal point; None if unusable."""
    try:
        K, R, t = decompose_projection(dlt_projection(local_world, pixels))
    except (np.linalg.LinAlgError, ValueError):
        return None
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(R))):
        return None
    f = 0.5 * (abs(K[0, 0]) + abs(K[1, 1]))
    w, h = image_size
    Kc = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    rvec, _ = cv2.Rodrigues(R)
    full = _full_from(Kc, rvec, t)
    # Re-solve the pose for the constrained K (the DLT's own principal point may be far off).
    pose = _pnp(local_world, pixels, Kc)
    return pose if pose is not None else full


# ---------------------------------------------------------------------------------------------------- focal sweep
def _pnp(local_world: np.ndarray, pixels: np.ndarray, K: np.ndarray,
         dist: np.ndarray | None = None) -> np.ndarray | None:
    """SQPnP pose for fixed intrinsics; full 15-vector or None."""
    d = np.zeros(5) if dist is None else dist
    try:
        ok, rvec, tvec = cv2.solvePnP(local_world.reshape(-1, 1, 3), pixels.reshape(-1, 1, 2), K, d,
                                      flags=cv2.SOLVEPNP_SQPNP)
    except cv2.error:
        return None
    if not ok:
        return None
    return _full_from(K, rvec, tvec, d)


def homography_focal(local_world: np.ndarray, pixels: np.ndarray, image_size: tuple[int, int]) -> float | None:
    """Closed-form focal (px) from the plane->image homography, principal point at the image centre."""
    _, normal = planarity(local_world)
    centred = local_world - local_world.mean(axis=0)
    e1 = np.cross(normal, [0.0, 0.0, 1.0]) if abs(normal[2]) < 0.9 else np.cross(normal, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    plane = np.stack([centred @ e1, centred @ e2], axis=1)
    w, h = image_size
    img = pixels - np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    H, _ = cv2.findHomography(plane, img, 0)
    if H is None:
        return None
    h1, h2 = H[:, 0], H[:, 1]
    # Unknown a = 1/f^2: (h11 h12 + h21 h22) a + h31 h32 = 0 and (|h1xy|^2 - |h2xy|^2) a = h32^2 - h31^2.
    A = np.array([h1[0] * h2[0] + h1[1] * h2[1], h1[0] ** 2 + h1[1] ** 2 - h2[0] ** 2 - h2[1] ** 2])
    b = np.array([-h1[2] * h2[2], h2[2] ** 2 - h1[2] ** 2])
    denom = A @ A
    if denom <= 0:
        return None
    a = (A @ b) / denom
    if not np.isfinite(a) or a <= 0:
        return None
    return float(1.0 / np.sqrt(a))


def focal_sweep_start(local_world: np.ndarray, pixels: np.ndarray, image_size: tuple[int, int], *,
                      scale_px: float, extra_focals: tuple[float, ...] = ()) -> list[Start]:
    """Best poses over a focal grid (0.25 to 8 image widths) with SQPnP, refined by a 1-D search on log f."""
    w, h = image_size
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])

    def at(f: float) -> tuple[float, np.ndarray | None]:
        K = np.array([[f, 0.0, c[0]], [0.0, f, c[1]], [0.0, 0.0, 1.0]])
        full = _pnp(local_world, pixels, K)
        if full is None:
            return float("inf"), None
        return _evaluate(full, local_world, pixels, scale_px), full

    grid = list(np.geomspace(0.25 * w, 8.0 * w, 25)) + [f for f in extra_focals if 0.05 * w < f < 50 * w]
    results = [(f, *at(f)) for f in grid]
    results.sort(key=lambda r: r[1])
    starts: list[Start] = []
    for f0, cost0, _ in results[:3]:
        if not np.isfinite(cost0):
            continue
        res = minimize_scalar(lambda lf: at(float(np.exp(lf)))[0], bounds=(np.log(f0) - 0.15, np.log(f0) + 0.15),
                              method="bounded", options={"xatol": 1e-4})
        f_best = float(np.exp(res.x))
        cost, full = at(f_best)
        if full is not None and np.isfinite(cost):
            starts.append(Start(full, "focal sweep + SQPnP", cost))
    return starts


def initial_cameras(local_world: np.ndarray, pixels: np.ndarray, image_size: tuple[int, int], *,
                    scale_px: float, known_K: np.ndarray | None = None, known_dist: np.ndarray | None = None
                    ) -> tuple[list[Start], dict[str, object]]:
    """Starting cameras, best first, and notes for the report (planarity, which routes ran and why)."""
    ratio, _ = planarity(local_world)
    notes: dict[str, object] = {"planarity_ratio": ratio, "near_planar": ratio < PLANAR_RATIO}
    starts: list[Start] = []
    if known_K is not None:
        full = _pnp(local_world, pixels, known_K, known_dist)
        if full is not None:
            starts.append(Start(full, "SQPnP with given intrinsics", _evaluate(full, local_world, pixels, scale_px)))
        notes["routes"] = ["SQPnP with given intrinsics"]
        return sorted(starts, key=lambda s: s.cost), notes
    routes = []
    if ratio >= PLANAR_RATIO and len(local_world) >= 6:
        full = dlt_start(local_world, pixels, image_size)
        if full is not None:
            starts.append(Start(full, "DLT + RQ", _evaluate(full, local_world, pixels, scale_px)))
            routes.append("DLT + RQ")
    else:
        routes.append(f"DLT skipped: points near-coplanar (singular value ratio {ratio:.3f} < {PLANAR_RATIO})"
                      if ratio < PLANAR_RATIO else "DLT skipped: fewer than 6 points")
    extra: tuple[float, ...] = ()
    if len(local_world) >= 4:
        f_h = homography_focal(local_world, pixels, image_size)
        if f_h is not None:
            extra = (f_h,)
    starts += focal_sweep_start(local_world, pixels, image_size, scale_px=scale_px, extra_focals=extra)
    routes.append("focal sweep + SQPnP")
    notes["routes"] = routes
    notes["homography_focal_px"] = extra[0] if extra else None
    return sorted(starts, key=lambda s: s.cost), notes
