"""Vehicle ground points from image bounding boxes, corrected for the vehicle's 3-D extent.

A detector gives a vehicle's axis-aligned image box ``(x1, y1, x2, y2)`` in pixels (OpenCV pixel-centre convention:
pixel (0, 0) is the centre of the top-left pixel). The naive ground point, the box's bottom centre
``((x1 + x2) / 2, y2)`` mapped to the road, is where the vehicle's *nearest bottom corner or edge* meets the road,
not its footprint centre: it lies up to half the vehicle's length or width (1-2 m) towards the camera.

With a calibrated camera, a road surface and the vehicle's heading (from its track), :func:`box_ground_points`
models the vehicle as a level cuboid of typical size (:data:`trafficgeo.geo.cuboids.VEHICLE_DIMENSIONS`) and solves
for the footprint centre whose projected cuboid matches the observed box's horizontal centre and bottom edge, the two
box quantities least sensitive to the size being a bit wrong. :mod:`trafficgeo.traffic.box_length` recovers one
vehicle's length from many frames.

Conventions: :mod:`trafficgeo.geo.cuboids`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from trafficgeo.camera.model import Camera
from trafficgeo.geo.cuboids import Cuboids, cuboid_corners, free_edges, units_per_metre
from trafficgeo.geo.mapping import Surface, pixels_to_world

# Statuses of box_ground_points beyond those of pixels_to_world ("ok", "above_horizon", ...).
NO_BOX = "no_box"  # the box is missing or not finite
NO_HEADING = "no_heading"  # heading is NaN: naive point kept
NO_DIMENSIONS = "no_dimensions"  # dimensions not finite and positive: naive point kept
CLIPPED_BOTTOM = "clipped_bottom"  # the box's bottom touches the frame border: naive point kept
CLIPPED_SIDES = "clipped_sides"  # both side edges touch the frame border: naive point kept
NOT_CONVERGED = "not_converged"  # the fit found no cuboid matching the box: NaN
TOP_EDGE = "top_edge"  # the box's bottom touches the frame border: fitted to its top edge instead (top_edge=True)
FALLBACK_STATUSES = (NO_HEADING, NO_DIMENSIONS, CLIPPED_BOTTOM, CLIPPED_SIDES)


# ---------------------------------------------------------------------------------------------------- ground points
@dataclass(frozen=True)
class BoxGroundPoints:
    """Footprint centres of vehicles from their image boxes.

    Attributes:
        xyz: (N, 3) CRS units. The corrected footprint centre where ``status`` is ``ok``; the naive point where the
            correction is not possible (statuses in :data:`FALLBACK_STATUSES`); NaN otherwise.
        status: (N,) ``ok``; a status of :func:`~trafficgeo.geo.mapping.pixels_to_world` when the box's bottom
            centre does not map to the ground; ``no_box``, ``no_heading``, ``no_dimensions``, ``clipped_bottom``,
            ``clipped_sides`` or ``not_converged``.
        naive_xyz: (N, 3) CRS units, the box's bottom centre mapped to the surface (NaN where it does not map).
        residual_px: (N,) RMS difference (px) between the fitted cuboid's box and the observed box over the edges
            the frame does not clip, all of them, not only the two fitted: about 0 when the dimensions and heading
            are right, larger when they are not. NaN unless ``status`` is ``ok``.
    """

    xyz: np.ndarray
    status: np.ndarray
    naive_xyz: np.ndarray
    residual_px: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        """(N,) True where the footprint centre was corrected."""
        return self.status == "ok"


def _selection(free: np.ndarray, top: np.ndarray | None = None) -> np.ndarray:
    """Weights (N, 2, 4) that take the two fitted box quantities from a box ``x1, y1, x2, y2``: the horizontal
    centre (or the one side edge the frame leaves) and the bottom edge (the top edge where ``top`` (N,) is
    True)."""
    use_x1, use_x2 = free[:, 0], free[:, 2]
    both = use_x1 & use_x2
    top = np.zeros(free.shape[0], dtype=bool) if top is None else top
    T = np.zeros((free.shape[0], 2, 4))
    T[:, 0, 0] = np.where(both, 0.5, use_x1)
    T[:, 0, 2] = np.where(both, 0.5, ~use_x1)
    T[:, 1, 1] = top
    T[:, 1, 3] = ~top
    return T


def _apply(T: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """The fitted quantities (N, 2) of boxes (N, 4) (``T`` from :func:`_selection`)."""
    return np.einsum("nqe,ne->nq", T, boxes)


def _solve2(J: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``J^-1 r`` for stacks of 2x2 systems (N, 2, 2), (N, 2); NaN where ``J`` is singular."""
    det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    scale = np.abs(J).max(axis=(1, 2)) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        det = np.where(np.abs(det) > 1e-12 * scale, det, np.nan)
        return np.column_stack([J[:, 1, 1] * r[:, 0] - J[:, 0, 1] * r[:, 1],
                                J[:, 0, 0] * r[:, 1] - J[:, 1, 0] * r[:, 0]]) / det[:, None]


def _norm(r: np.ndarray) -> np.ndarray:
    """Row norms with NaN as infinity (so a step into NaN is never an improvement)."""
    return np.nan_to_num(np.linalg.norm(r, axis=1), nan=np.inf)



def _newton_centres(model: Cuboids, xy: np.ndarray, dims: np.ndarray, T: np.ndarray, target: np.ndarray,
                    iterations: int, tol_px: float,
                    halvings: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Newton iterations on the footprint centres (N, 2) so that the cuboids' fitted box quantities (``T``, from
    :func:`_selection`) match ``target`` (N, 2) px, halving a step that does not reduce a row's residual. Rows
    stop once their residual is within ``tol_px``.

    Returns the centres' (x, y), and at them the boxes, their derivatives (:meth:`Cuboids.boxes_jac`) and the
    residual norms (px)."""
    n = xy.shape[0]
    xy = xy.copy()
    dims = np.broadcast_to(dims, (n, 3))
    boxes, j_xy, j_dims = np.full((n, 4), np.nan), np.full((n, 4, 2), np.nan), np.full((n, 4, 4), np.nan)
    rnorm = np.full(n, np.inf)
    rows = np.arange(n)
    for it in range(iterations + 1):
        sub = model.take(rows)
        boxes[rows], j_xy[rows], j_dims[rows] = sub.boxes_jac(xy[rows], dims[rows])
        r = _apply(T[rows], boxes[rows]) - target[rows]
        rnorm[rows] = _norm(r)
        todo = rnorm[rows] > tol_px
        if it == iterations or not todo.any():
            break
        rows, r, sub = rows[todo], r[todo], sub.take(np.flatnonzero(todo))
        delta = -_solve2(np.einsum("nqe,nej->nqj", T[rows], j_xy[rows]), r)
        ok = np.all(np.isfinite(delta), axis=1)
        rows, delta, sub = rows[ok], delta[ok], sub.take(np.flatnonzero(ok))
        pending = np.ones(rows.size, dtype=bool)
        t = 1.0
        for _ in range(halvings + 1):
            if not pending.any():
                break
            idx = np.flatnonzero(pending)
            cand = xy[rows[idx]] + t * delta[idx]
            pred = sub.take(idx).boxes(cand, dims[rows[idx]])
            better = _norm(_apply(T[rows[idx]], pred) - target[rows[idx]]) < rnorm[rows[idx]]
            xy[rows[idx[better]]] = cand[better]
            pending[idx[better]] = False
            t *= 0.5
        rows = rows[~pending]  # a row no step improves is stuck (e.g. a bump of the surface): it would stay so
        if not rows.size:
            break
    return xy, boxes, j_xy, j_dims, rnorm


def _naive_points(camera: Camera, surface: Surface, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The boxes' bottom centres on the surface: xyz (N, 3) and status (N,) of pixels_to_world."""
    bottom = np.column_stack([0.5 * (boxes[:, 0] + boxes[:, 2]), boxes[:, 3]])
    g = pixels_to_world(camera, bottom, surface, with_lonlat=False)
    return g.xyz, g.status.astype(object)


def _precheck(boxes: np.ndarray, heading: np.ndarray, dims: np.ndarray, naive_status: np.ndarray,
              free: np.ndarray) -> np.ndarray:
    """Status (N,) before fitting: why a box cannot be corrected, "ok" where it can (first reason wins)."""
    status = naive_status.copy()
    ok = status == "ok"
    reasons = [
        (~np.isfinite(heading), NO_HEADING),
        (~np.all(np.isfinite(dims) & (dims > 0), axis=1), NO_DIMENSIONS),
        (~free[:, 3], CLIPPED_BOTTOM),
        (~free[:, 0] & ~free[:, 2], CLIPPED_SIDES),
    ]
    for bad, name in reasons:
        status[ok & bad] = name
        ok &= ~bad
    status[~np.all(np.isfinite(boxes), axis=1)] = NO_BOX
    return status


def _edge_rms(pred: np.ndarray, obs: np.ndarray, free: np.ndarray) -> np.ndarray:
    """RMS (N,) px of ``pred - obs`` over the free edges (N, 4)."""
    d2 = np.where(free, (pred - obs) ** 2, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(d2.sum(axis=1) / free.sum(axis=1))


def box_ground_points(camera: Camera, surface: Surface, boxes: ArrayLike, heading_deg: ArrayLike, dims: ArrayLike, *,
                      iterations: int = 10, tol_px: float = 1e-3, border_px: float = 2.0,
                      top_edge: bool = False) -> BoxGroundPoints:
    """Footprint centres of vehicles from their image boxes, modelling each vehicle as a level cuboid.

    Args:
        camera: the calibrated camera; world coordinates in its CRS units.
        surface: the road surface (``elevation(x, y)`` in CRS units).
        boxes: (N, 4) ``x1, y1, x2, y2`` px, OpenCV pixel-centre convention, as the detector gives them (clipped to
            the frame).
        heading_deg: (N,) direction of travel, degrees clockwise from north (from the track); NaN if unknown.
        dims: (N, 3) or (3,) ``length, width, height`` in metres (e.g. :func:`dimensions_for`).
        iterations: at most this many Newton iterations.
        tol_px: the fit converges when the two fitted box quantities match to ``tol_px`` px (1e-3 px is ~2 mm at
            120 m from an 8 m high camera).
        border_px: box edges within this of the outermost pixel centres are taken as clipped (:func:`free_edges`).
        top_edge: fit a box clipped at the bottom to its top edge instead (status ``top_edge``; see below).

    Method: starting from the naive point (the bottom centre mapped to ``surface``) moved away from the camera by
    the footprint's reach along the line of sight, Newton iterations on the footprint centre (x, y), with
    ``z = surface.elevation(x, y)``, match the projected cuboid's box to the observed one in two quantities: its
    horizontal centre (or, when the frame clips one side, the other side edge) and its bottom edge ``y2``. These
    two depend least on the dimensions being exact: the centre is symmetric in them and the bottom edge sees only
    the footprint. (The derivatives are those of the corners that make the box's edges.) A box clipped at one side
    is fitted with the other side edge and its bottom, provided the fitted cuboid's lowest corner is in the frame
    (else the box's bottom is where the frame cuts the vehicle). A box clipped at the bottom (or whose lowest
    corner is out of the frame), or at both sides, keeps its naive point (status ``clipped_bottom`` /
    ``clipped_sides``), as does one without heading (``no_heading``): without the heading the direction from the
    nearest corner to the centre is unknown, so no correction is attempted. Over a rough surface (a DEM from
    lidar) the bottom edge can stop moving monotonically along the line of sight far away: a box whose fit cannot
    get within ``tol_px`` there is ``not_converged``.

    With ``top_edge``, a box clipped at the bottom whose top edge and at least one side are in view (a vehicle
    leaving through the bottom of a frame from a camera close to the road) is fitted with its horizontal centre
    (or free side) and its top edge, the cuboid's far end: status ``top_edge``. That edge depends on the vehicle's
    length and height as well, so these points are worse than ``ok`` ones by about the error of the dimensions
    (a real roof is shorter than its vehicle: the fitted centre then lies a little towards the camera). A fit
    whose cuboid would end above the frame's bottom (not the clipped box it was fitted to) keeps
    ``clipped_bottom``.
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    n = b.shape[0]
    heading = np.broadcast_to(np.asarray(heading_deg, dtype=np.float64), (n,))
    dims_m = np.broadcast_to(np.asarray(dims, dtype=np.float64).reshape(-1, 3), (n, 3))
    naive, naive_status = _naive_points(camera, surface, b)
    free = free_edges(camera, b, border_px)
    status = _precheck(b, heading, dims_m, naive_status, free)
    xyz = np.where(np.isin(status, FALLBACK_STATUSES)[:, None], naive, np.nan)
    residual_px = np.full(n, np.nan)
    if top_edge:
        _fit_top_edges(camera, surface, b, heading, dims_m, naive, free, status, xyz, iterations, tol_px, border_px)
    fit = np.flatnonzero(status == "ok")
    if fit.size:
        dims_u = dims_m[fit] * units_per_metre(camera)
        xyz_fit, converged, residual_fit = _fit_centres(camera, surface, b[fit], heading[fit], dims_u, naive[fit],
                                                        free[fit], iterations, tol_px)
        xyz[fit] = np.where(converged[:, None], xyz_fit, np.nan)
        residual_px[fit] = np.where(converged, residual_fit, np.nan)
        status[fit[~converged]] = NOT_CONVERGED
        cut = converged & _lowest_corner_cut(camera, xyz_fit, heading[fit], dims_u, free[fit], border_px)
        status[fit[cut]] = CLIPPED_BOTTOM
        xyz[fit[cut]], residual_px[fit[cut]] = naive[fit[cut]], np.nan
    return BoxGroundPoints(xyz=xyz, status=status, naive_xyz=naive, residual_px=residual_px)


def _fit_top_edges(camera: Camera, surface: Surface, b: np.ndarray, heading: np.ndarray, dims_m: np.ndarray,
                   naive: np.ndarray, free: np.ndarray, status: np.ndarray, xyz: np.ndarray, iterations: int,
                   tol_px: float, border_px: float) -> None:
    """Fit the boxes clipped at the bottom only (top and a side free) by their top edge; where the fitted cuboid
    reaches the frame's bottom as the clipped box does, set ``status`` to ``top_edge`` and ``xyz`` to its
    centre (in place)."""
    top = np.flatnonzero((status == CLIPPED_BOTTOM) & free[:, 1] & (free[:, 0] | free[:, 2]))
    if not top.size:
        return
    dims_u = dims_m[top] * units_per_metre(camera)
    fitted, converged, _ = _fit_centres(camera, surface, b[top], heading[top], dims_u, naive[top], free[top],
                                        iterations, tol_px, top=np.ones(top.size, dtype=bool))
    full = Cuboids.at(camera, surface, heading[top]).boxes(fitted[:, :2], dims_u)
    height = b[top, 3] - b[top, 1]
    with np.errstate(invalid="ignore"):
        reaches = full[:, 3] >= camera.height - 1 - border_px - np.maximum(4.0, 0.1 * height)
    good = converged & reaches
    status[top[good]] = TOP_EDGE
    xyz[top[good]] = fitted[good]


def _lowest_corner_cut(camera: Camera, centre: np.ndarray, heading: np.ndarray, dims: np.ndarray, free: np.ndarray,
                       border_px: float) -> np.ndarray:
    """(N,) True where a side of the box is clipped and the fitted cuboid's lowest bottom corner lies beyond it:
    a detector's box then ends where the frame cuts the vehicle, not at its lowest point, so its bottom edge is
    not the cuboid's."""
    corners = cuboid_corners(centre, heading, dims[:, 0], dims[:, 1], dims[:, 2])[:, :4]
    uv = camera.project(corners.reshape(-1, 3)).reshape(-1, 4, 2)
    u = uv[np.arange(uv.shape[0]), np.argmax(np.nan_to_num(uv[:, :, 1], nan=-np.inf), axis=1), 0]
    with np.errstate(invalid="ignore"):
        return (~free[:, 0] & ~(u > border_px)) | (~free[:, 2] & ~(u < camera.width - 1 - border_px))


def _fit_centres(camera: Camera, surface: Surface, boxes: np.ndarray, heading: np.ndarray, dims: np.ndarray,
                 start: np.ndarray, free: np.ndarray, iterations: int, tol_px: float,
                 top: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fitted centres (N, 3), converged (N,) and all-edge RMS residuals (N,) px; ``dims`` in CRS units; ``top``
    (N,): fit the top edge instead of the bottom (:func:`_selection`)."""
    model = Cuboids.at(camera, surface, heading)
    T = _selection(free, top)
    # The box's bottom is the footprint's corner nearest the camera: start from its centre seen from there.
    ray = start[:, :2] - camera.position[:2]
    norm = np.linalg.norm(ray, axis=1, keepdims=True)
    ray = np.divide(ray, norm, out=np.zeros_like(ray), where=norm > 0)
    reach = (0.5 * dims[:, 0] * np.abs(np.einsum("ni,ni->n", ray, model.axes[:, 0, :2]))
             + 0.5 * dims[:, 1] * np.abs(np.einsum("ni,ni->n", ray, model.axes[:, 1, :2])))
    xy0 = start[:, :2] + reach[:, None] * ray
    xy, pred, _, _, rnorm = _newton_centres(model, xy0, dims, T, _apply(T, boxes), iterations, tol_px)
    converged = rnorm <= tol_px
    return model.centres(xy), converged, _edge_rms(pred, boxes, free)


