"""One vehicle's length from its boxes in many frames: :func:`estimate_length` (centres and headings known) and
:func:`estimate_length_refit` (fitted with the length); see :mod:`trafficgeo.traffic.box_points`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from trafficgeo.camera.model import Camera
from trafficgeo.geo.cuboids import Cuboids, cuboid_boxes, free_edges, units_per_metre
from trafficgeo.geo.mapping import Surface
from trafficgeo.traffic.box_points import box_ground_points


# ---------------------------------------------------------------------------------------------------- length
@dataclass(frozen=True)
class _SizePrior:
    """Prior knowledge of a vehicle's size (metres): width and height with standard deviations (0 fixes them),
    and the length to start from."""

    width_m: float
    height_m: float
    width_sigma_m: float
    height_sigma_m: float
    length0_m: float

    def start(self) -> np.ndarray:
        return np.array([self.length0_m, self.width_m, self.height_m], dtype=np.float64)

    def fixed(self) -> np.ndarray:
        return np.array([False, self.width_sigma_m <= 0, self.height_sigma_m <= 0])

    def residual(self, theta: np.ndarray) -> np.ndarray:
        """Whitened prior residuals (2,) of width and height (0 for fixed ones)."""
        sigma = np.array([self.width_sigma_m, self.height_sigma_m])
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(sigma > 0, (theta[1:] - [self.width_m, self.height_m]) / sigma, 0.0)


def estimate_length(camera: Camera, centres: ArrayLike, heading_deg: ArrayLike, boxes: ArrayLike, width_m: float,
                    height_m: float, *, length0_m: float = 4.5, width_sigma_m: float = 0.1,
                    height_sigma_m: float = 0.2, pixel_sigma: float = 1.0, max_std_m: float = 0.5,
                    border_px: float = 2.0, use_top: bool = True) -> tuple[float, float]:
    """Length (m) and its 1-sigma uncertainty (m) of ONE vehicle seen in M frames at KNOWN footprint centres.

    The centres must not come from these boxes with an assumed length: :func:`box_ground_points` places the
    centre so that the box's bottom edge and centre match the assumed size, and this fit would then mostly return
    the assumed length. Use :func:`estimate_length_refit` for that case. The headings are taken as exact: seen
    nearly end-on, a heading error ``e`` biases the length by ``L e / tan(a)``, ``a`` the angle between line of
    sight and heading (see :func:`estimate_length_refit`).

    Args:
        camera: the calibrated camera.
        centres: (M, 3) footprint centres in CRS units, held fixed.
        heading_deg: (M,) heading in each frame, degrees clockwise from north.
        boxes: (M, 4) observed boxes ``x1, y1, x2, y2`` px.
        width_m, height_m: the vehicle's width and height in metres (e.g. of its class), used as priors with
            standard deviations ``width_sigma_m`` and ``height_sigma_m`` (0 fixes them).
        length0_m: starting value of the length (m).
        pixel_sigma: standard deviation (px) of a box edge; residuals larger than that raise it.
        max_std_m: the length is NaN when its standard deviation exceeds this. The default, 0.5 m, is about the
            spread of lengths within the car class: a less certain estimate says nothing the class does not.
        border_px: box edges within this of the outermost pixel centres are clipped (:func:`free_edges`) and left
            out, as are rows with NaN.
        use_top: whether to use the boxes' top edges. A real vehicle's top is not a cuboid's (the roof is shorter
            than the footprint), so its top edge can mislead the length when it is the only evidence (views from
            behind or ahead); with ``use_top=False`` such views give NaN.

    Returns ``(length_m, length_std_m)``; ``(nan, inf)`` when no box edge is usable.

    Method: Gauss-Newton least squares for (length, width, height) over all free box edges of all frames, with
    Gaussian priors on width and height.
    """
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    heading = np.broadcast_to(np.asarray(heading_deg, dtype=np.float64), (c.shape[0],))
    obs = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    usable = np.isfinite(heading) & np.all(np.isfinite(c), axis=1)
    free = free_edges(camera, obs, border_px) & usable[:, None]
    free[:, 1] &= use_top
    upm = units_per_metre(camera)

    def predict(theta: np.ndarray) -> np.ndarray:
        return cuboid_boxes(camera, c, heading, *(theta * upm))

    prior = _SizePrior(width_m, height_m, width_sigma_m, height_sigma_m, length0_m)
    return _fit_length(predict, obs, free, prior, pixel_sigma, max_std_m, nuisance=0)


def estimate_length_refit(camera: Camera, surface: Surface, heading_deg: ArrayLike, boxes: ArrayLike, width_m: float,
                          height_m: float, *, length0_m: float = 4.5, width_sigma_m: float = 0.1,
                          height_sigma_m: float = 0.2, pixel_sigma: float = 1.0, max_std_m: float = 0.5,
                          border_px: float = 2.0, use_top: bool = True,
                          refine_heading: bool = True) -> tuple[float, float]:
    """Length (m) and its 1-sigma uncertainty (m) of ONE vehicle seen in M frames, its footprint centres unknown.

    The centres are fitted with the size, so the length is judged only by what they cannot absorb: the box's
    horizontal extent and its top edge.

    Args:
        camera: the calibrated camera.
        surface: the road surface.
        heading_deg: (M,) heading in each frame, degrees clockwise from north.
        boxes: (M, 4) observed boxes ``x1, y1, x2, y2`` px, in time order; frames :func:`box_ground_points`
            cannot correct are left out.
        refine_heading: fit each frame's heading too, the vehicle moving along it (the given headings are a
            prior of +-``HEADING_PRIOR_DEG``). Seen nearly end-on the length shows in the box's width only through
            ``L sin(a)``, ``a`` the angle between the line of sight and the heading, so a heading error ``e``
            biases it by ``L e / tan(a)``: 0.5 deg at ``a`` = 5 deg is 10 %. A heading smoothed from the boxes'
            bottom centres is off by that much, and always the same way (the bottom centre lies towards the
            nearest corner, whose offset from the centre turns as the vehicle passes the camera); the fitted
            centres' motion is not. Off, the headings are taken as exact.

    The other arguments and the result are those of :func:`estimate_length`.

    Geometry: seen from the side or obliquely, the length shows in the box's width and is found to a few
    centimetres. Seen exactly from behind (or ahead), it shows only in the top edge, where it trades off against
    the height (about 7 m of length per metre of height at 20 m from an 8 m high camera); only the change of that
    trade-off with distance separates them, so the standard deviation is large and the length NaN unless the
    boxes are very precise.

    Method: Gauss-Newton least squares over the size (length, width, height; Gaussian priors on width and height),
    every frame's footprint centre (x, y) on the surface and, with ``refine_heading``, its heading, against the
    free box edges (``pixel_sigma`` px each) and the motion: the step between consecutive centres lies along
    their mean heading (to ``MOTION_SIGMA_M``, 1 sigma), and the heading turns by about ``TURN_SIGMA_DEG`` per
    frame. Without ``refine_heading`` and the top edge, each centre then meets its box's horizontal centre and
    bottom exactly, as in :func:`box_ground_points`, and only the box's width judges the size. The centres start
    from :func:`box_ground_points` with the given headings and the prior size; the derivatives of the boxes are
    those of the corners that make their edges, and the normal equations (block-tridiagonal in the frames) are
    solved as a band matrix. About 10 ms for 40 frames.
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    heading = np.broadcast_to(np.asarray(heading_deg, dtype=np.float64), (b.shape[0],))
    prior = _SizePrior(width_m, height_m, width_sigma_m, height_sigma_m, length0_m)
    first = box_ground_points(camera, surface, b, heading, prior.start(), border_px=border_px,
                              tol_px=_FIRST_TOL_PX)
    use = first.ok
    b, heading, xy = b[use], heading[use], first.xyz[use, :2]
    free = free_edges(camera, b, border_px)
    free[:, 1] &= use_top
    if not free.any():
        return float("nan"), float("inf")
    fit = _VehicleFit(camera, surface, b, free, heading, prior, pixel_sigma, refine_heading)
    return fit.solve(xy, max_std_m)


_FIRST_TOL_PX = 0.02  # the first centres (which frames are usable, and where the fit starts)
HEADING_PRIOR_DEG = 10.0  # standard deviation of a given heading (estimate_length_refit, refine_heading)
MOTION_SIGMA_M = 0.05  # how far the step between two frames' centres may stray from their mean heading (m)
TURN_SIGMA_DEG = 2.0  # how far the heading may turn from one frame to the next (deg)


class _VehicleFit:
    """The least-squares problem of :func:`estimate_length_refit`. Parameters: the free sizes (m), and per frame
    the centre's (x, y) (CRS units) and, with ``refine_heading``, the heading (radians). Residuals are whitened.

    Its normal equations are block-tridiagonal in the frames (the motion ties neighbours) with a border for the
    sizes: :func:`_solve_bordered` solves them as a band matrix (fast, and free of multi-threaded BLAS, which
    slows small problems down on a busy machine)."""

    def __init__(self, camera: Camera, surface: Surface, obs: np.ndarray, free: np.ndarray, heading_deg: np.ndarray,
                 prior: _SizePrior, pixel_sigma: float, refine_heading: bool) -> None:
        self.camera, self.surface, self.obs, self.free, self.prior = camera, surface, obs, free, prior
        self.heading0 = np.unwrap(np.radians(heading_deg))  # no jumps at north: mean headings and turns
        self.pixel_sigma, self.refine = float(pixel_sigma), refine_heading
        self.upm = units_per_metre(camera)
        self.sizes = np.flatnonzero(~prior.fixed())
        self.m = obs.shape[0]
        self.prior_jac = np.zeros((2, 3))
        for i, sigma in enumerate((prior.width_sigma_m, prior.height_sigma_m)):
            if sigma > 0:
                self.prior_jac[i, i + 1] = 1.0 / sigma
        self.prior_jac = self.prior_jac[:, self.sizes]

    def normal_equations(self, theta: np.ndarray, xy: np.ndarray, h: np.ndarray) -> tuple:
        """Cost, data cost and count (box edges and motion, not priors), and the Gauss-Newton normal equations:
        per-frame diagonal blocks D (M, q, q), blocks E (M-1, q, q) between neighbours, frame-size blocks
        C (M, q, k), the sizes' block G (k, k), and the gradients a (M, q) and g (k,) (J^T r)."""
        m, upm = self.m, self.upm
        model = Cuboids.at(self.camera, self.surface, np.degrees(h))
        pred, j_xy, j_more = model.boxes_jac(xy, np.broadcast_to(theta * upm, (m, 3)))
        w = np.where(self.free, 1.0 / self.pixel_sigma, 0.0)  # (M, 4)
        r = np.where(self.free, pred - self.obs, 0.0) * w
        Jp = (np.concatenate([j_xy, j_more[:, :, 3:]], axis=2) if self.refine else j_xy) * w[..., None]
        Jg = j_more[:, :, self.sizes] * upm * w[..., None]
        D = np.einsum("nep,neq->npq", Jp, Jp)
        E = np.zeros((max(m - 1, 0),) + D.shape[1:])
        C = np.einsum("nep,neg->npg", Jp, Jg)
        G = np.einsum("neg,nef->gf", Jg, Jg)
        a = np.einsum("nep,ne->np", Jp, r)
        g = np.einsum("neg,ne->g", Jg, r)
        data_cost, n_data = float(np.sum(r * r)), int(self.free.sum())
        prior_cost = 0.0
        if self.refine and m > 1:
            mid = 0.5 * (h[:-1] + h[1:])
            ahead = np.column_stack([np.sin(mid), np.cos(mid)])
            right = np.column_stack([np.cos(mid), -np.sin(mid)])
            step = np.diff(xy, axis=0)
            s = MOTION_SIGMA_M * upm
            along = np.sum(step * ahead, axis=1)
            zero = np.zeros(m - 1)
            # The step between frames i and i+1 across their mean heading; then the turn between them.
            rows = [(np.sum(step * right, axis=1) / s,
                     np.column_stack([-right / s, -0.5 * along / s]), np.column_stack([right / s, -0.5 * along / s])),
                    (np.diff(h) / np.radians(TURN_SIGMA_DEG),
                     np.column_stack([zero, zero, zero - 1.0 / np.radians(TURN_SIGMA_DEG)]),
                     np.column_stack([zero, zero, zero + 1.0 / np.radians(TURN_SIGMA_DEG)]))]
            for k, (res, u, v) in enumerate(rows):
                D[:-1] += np.einsum("np,nq->npq", u, u)
                D[1:] += np.einsum("np,nq->npq", v, v)
                E += np.einsum("np,nq->npq", u, v)
                a[:-1] += u * res[:, None]
                a[1:] += v * res[:, None]
                if k == 0:
                    data_cost, n_data = data_cost + float(res @ res), n_data + m - 1
                else:
                    prior_cost += float(res @ res)
        if self.refine:
            given = np.radians(HEADING_PRIOR_DEG)
            res = (h - self.heading0) / given
            D[:, 2, 2] += given**-2
            a[:, 2] += res / given
            prior_cost += float(res @ res)
        res = self.prior.residual(theta)
        G += self.prior_jac.T @ self.prior_jac
        g += self.prior_jac.T @ res
        prior_cost += float(res @ res)
        return data_cost + prior_cost, data_cost, n_data, D, E, C, G, a, g

    def solve(self, xy: np.ndarray, max_std_m: float, iterations: int = 20,
              step_tol_m: float = 1e-3) -> tuple[float, float]:
        """Gauss-Newton from the prior size, the centres ``xy`` and the given headings; a step that raises the cost
        is halved. Stops when the size moves by under ``step_tol_m`` or nothing improves. Returns the length and
        its standard deviation (scaled up by the data's residuals when they exceed their sigmas)."""
        theta, h = self.prior.start(), self.heading0.copy()
        cost, data_cost, n_data, *system = self.normal_equations(theta, xy, h)
        for _ in range(iterations):
            if not np.isfinite(cost):
                return float("nan"), float("inf")
            step_p, step_g, S = _solve_bordered(*system)
            if not (np.all(np.isfinite(step_p)) and np.all(np.isfinite(step_g))):
                return float("nan"), float("inf")
            t = 1.0
            for _ in range(6):
                trial_theta = theta.copy()
                trial_theta[self.sizes] -= t * step_g
                trial_xy = xy - t * step_p[:, :2]
                trial_h = h - t * step_p[:, 2] if self.refine else h
                trial = self.normal_equations(trial_theta, trial_xy, trial_h)
                if trial[0] <= cost:
                    break
                t *= 0.5
            else:
                break
            gain = cost - trial[0]
            theta, xy, h = trial_theta, trial_xy, trial_h
            cost, data_cost, n_data, *system = trial
            if np.max(np.abs(t * step_g)) < step_tol_m or gain < 1e-9 * cost:
                break
        _, _, S = _solve_bordered(*system)
        with np.errstate(invalid="ignore"):
            var = float(np.linalg.inv(S)[0, 0]) if np.all(np.isfinite(S)) and np.linalg.cond(S) < 1e12 else np.inf
        n_par = self.sizes.size + self.m * (3 if self.refine else 2)
        dof = n_data - n_par
        scale = max(1.0, data_cost / dof) if dof > 0 else 1.0
        length_std = float(np.sqrt(var * scale)) if var >= 0 else float("inf")
        length = abs(float(theta[0]))
        return (length if length_std <= max_std_m else float("nan")), length_std


def _solve_bordered(D: np.ndarray, E: np.ndarray, C: np.ndarray, G: np.ndarray, a: np.ndarray,
                    g: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve ``[[B, C], [C^T, G]] [u; v] = [a; g]`` for a symmetric positive definite block-tridiagonal ``B``
    (diagonal blocks D (M, q, q), upper blocks E (M-1, q, q)) bordered by C (M, q, k) and G (k, k), ``B`` as a
    band matrix. Returns u (M, q), v (k,) and the Schur complement ``G - C^T B^-1 C`` (the inverse covariance of v
    when these are normal equations); NaN if ``B`` is not positive definite."""
    m, q = D.shape[:2]
    n, u = m * q, 2 * q - 1  # order and upper bandwidth of B
    B = np.zeros((n, n))
    idx = np.arange(m)[:, None, None] * q
    rows, cols = np.arange(q)[None, :, None], np.arange(q)[None, None, :]
    B[idx + rows, idx + cols] = D
    B[idx[:-1] + rows, idx[:-1] + q + cols] = E
    band = np.zeros((u + 1, n))
    for d in range(min(u, n - 1) + 1):
        band[u - d, d:] = np.diagonal(B, d)
    rhs = np.concatenate([a.reshape(n, 1), C.reshape(n, -1)], axis=1)
    try:
        X = scipy.linalg.solveh_banded(band, rhs, check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        k = G.shape[0]
        return np.full((m, q), np.nan), np.full(k, np.nan), np.full((k, k), np.nan)
    Cf = C.reshape(n, -1)
    S = G - Cf.T @ X[:, 1:]
    try:
        v = np.linalg.solve(S, g - Cf.T @ X[:, 0])
    except np.linalg.LinAlgError:
        v = np.full(G.shape[0], np.nan)
    return (X[:, 0] - X[:, 1:] @ v).reshape(m, q), v, S


def _fit_length(predict: Callable[[np.ndarray], np.ndarray], obs: np.ndarray, free: np.ndarray, prior: _SizePrior,
                pixel_sigma: float, max_std_m: float, nuisance: int,
                iterations: int = 15) -> tuple[float, float]:
    """Least-squares length for predicted boxes ``predict(theta)`` (M, 4) of sizes ``theta`` = (length, width,
    height) m against ``obs`` over the ``free`` edges; ``nuisance`` counts parameters fitted inside ``predict``
    (for the degrees of freedom)."""
    n_pix = int(free.sum())
    if n_pix == 0:
        return float("nan"), float("inf")

    def residual(theta: np.ndarray) -> np.ndarray:
        return np.concatenate([(predict(theta) - obs)[free] / pixel_sigma, prior.residual(theta)])

    theta, J = _gauss_newton_params(residual, prior.start(), prior.fixed(), iterations)
    length_std = _length_std(residual(theta)[:n_pix], J, prior.fixed(), n_pix - nuisance)
    length = abs(float(theta[0]))
    return (length if length_std <= max_std_m else float("nan")), length_std


def _jacobian(residual: Callable[[np.ndarray], np.ndarray], theta: np.ndarray, r: np.ndarray, free: np.ndarray,
              step: float) -> np.ndarray:
    """Forward-difference Jacobian (len(r), len(theta)) of ``residual`` at ``theta``; zero columns but ``free``."""
    J = np.zeros((r.size, theta.size))
    for k in free:
        J[:, k] = (residual(theta + step * np.eye(theta.size)[k]) - r) / step
    return J


def _gauss_newton_params(residual: Callable[[np.ndarray], np.ndarray], theta: np.ndarray, fixed: np.ndarray,
                         iterations: int, step: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on a few parameters (metres) with a forward-difference Jacobian; ``fixed`` ones stay put.
    Stops when a step changes the parameters by under a micrometre or the cost by under a part in 1e9 (along a
    direction the data do not determine, steps only chase rounding). Returns the parameters and the Jacobian at
    them (NaN if the residuals are not finite there)."""
    free = np.flatnonzero(~fixed)
    cost = np.inf
    for _ in range(iterations + 1):
        r = residual(theta)
        J = _jacobian(residual, theta, r, free, step)
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
            return theta, np.full_like(J, np.nan)
        new_cost = float(r @ r)
        delta = np.zeros_like(theta)
        delta[free] = -np.linalg.lstsq(J[:, free], r, rcond=None)[0]
        if np.max(np.abs(delta)) < 1e-6 or cost - new_cost < 1e-9 * new_cost:
            break
        theta, cost = theta + delta, new_cost
    return theta, J


def _length_std(pixel_residual: np.ndarray, J: np.ndarray, fixed: np.ndarray, dof: int) -> float:
    """Standard deviation of the length (parameter 0) from the Gauss-Newton normal matrix, scaled up by the
    whitened pixel residuals when their variance per degree of freedom (``dof`` minus the free sizes) exceeds 1."""
    free = np.flatnonzero(~fixed)
    N = J[:, free].T @ J[:, free]
    if not np.all(np.isfinite(N)) or np.linalg.cond(N) > 1e12:
        return float("inf")
    cov = np.linalg.inv(N)
    scale = max(1.0, float(np.sum(pixel_residual**2)) / max(dof - free.size, 1))
    return float(np.sqrt(cov[0, 0] * scale))

