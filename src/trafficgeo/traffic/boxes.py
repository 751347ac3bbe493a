"""Vehicle ground points from image bounding boxes, corrected for the vehicle's 3-D extent.

A detector gives a vehicle's axis-aligned image box ``(x1, y1, x2, y2)`` in pixels (OpenCV pixel-centre convention:
pixel (0, 0) is the centre of the top-left pixel). The naive ground point, the box's bottom centre
``((x1 + x2) / 2, y2)`` mapped to the road, is where the vehicle's *nearest bottom corner or edge* meets the road,
not its footprint centre: it lies up to half the vehicle's length or width (1-2 m) towards the camera.

With a calibrated camera, a road surface and the vehicle's heading (from its track), :func:`box_ground_points`
models the vehicle as a level cuboid of typical size (:data:`VEHICLE_DIMENSIONS`) and solves for the footprint
centre whose projected cuboid matches the observed box's horizontal centre and bottom edge, the two box quantities
least sensitive to the size being a bit wrong. :func:`estimate_length_refit` (centres and headings fitted with the
size) and :func:`estimate_length` (centres and headings known) recover one vehicle's length from many frames.

Conventions (those of :mod:`trafficgeo.synth.render`, whose boxes :func:`cuboid_corners` builds):

* World coordinates in the camera's CRS and its units (x east, y north, z up). Vehicle dimensions given in metres
  are converted to CRS units with :func:`trafficgeo.crs.metres_per_unit` (US-foot CRSs exist).
* ``heading_deg``: direction of travel, degrees clockwise from grid north.
* A cuboid's ``centre`` is the centre of its footprint on the road; the cuboid is level (its bottom at the height of
  the centre, even on a grade), ``length`` along the heading, ``width`` across it, ``height`` up.
* Corners are ordered front-left, front-right, rear-right, rear-left, bottom (0-3) then top (4-7).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.geo.mapping import Surface, camera_crs, pixels_to_world

# Typical (length, width, height) in metres: car, van, truck and bus as the synthetic world's SUMO vehicle types
# (trafficgeo.synth.sumo_world.VEHICLE_CLASSES); two-wheelers with their rider.
VEHICLE_DIMENSIONS: dict[str, tuple[float, float, float]] = {
    "car": (4.5, 1.8, 1.5),
    "van": (5.4, 2.0, 2.4),
    "truck": (12.0, 2.55, 3.8),
    "bus": (12.0, 2.55, 3.1),
    "motorcycle": (2.2, 0.8, 1.5),
    "bicycle": (1.8, 0.6, 1.7),
}
DEFAULT_CLASS = "car"
# Other common spellings of the classes (VOC "motorbike", SUMO vClass names, ...).
CLASS_ALIASES: dict[str, str] = {"motorbike": "motorcycle", "bike": "bicycle", "passenger": "car",
                                 "delivery": "van", "lorry": "truck", "coach": "bus"}

# Statuses of box_ground_points beyond those of pixels_to_world ("ok", "above_horizon", ...).
NO_BOX = "no_box"  # the box is missing or not finite
NO_HEADING = "no_heading"  # heading is NaN: naive point kept
NO_DIMENSIONS = "no_dimensions"  # dimensions not finite and positive: naive point kept
CLIPPED_BOTTOM = "clipped_bottom"  # the box's bottom touches the frame border: naive point kept
CLIPPED_SIDES = "clipped_sides"  # both side edges touch the frame border: naive point kept
NOT_CONVERGED = "not_converged"  # the fit found no cuboid matching the box: NaN
FALLBACK_STATUSES = (NO_HEADING, NO_DIMENSIONS, CLIPPED_BOTTOM, CLIPPED_SIDES)


# ---------------------------------------------------------------------------------------------------- dimensions
def dimensions_for(classes: object) -> np.ndarray:
    """Typical (length, width, height) in metres, (N, 3), for class names (N,) (case-insensitive; aliases in
    :data:`CLASS_ALIASES`); unknown or empty names get the dimensions of a car."""
    names = np.asarray(classes, dtype=object).reshape(-1)
    if names.size == 0:
        return np.zeros((0, 3))
    uniq, inverse = np.unique(np.char.lower(np.char.strip(names.astype(str))), return_inverse=True)
    default = VEHICLE_DIMENSIONS[DEFAULT_CLASS]
    table = np.array([VEHICLE_DIMENSIONS.get(CLASS_ALIASES.get(u, u), default) for u in uniq], dtype=np.float64)
    return table[inverse.reshape(-1)]


def _units_per_metre(camera: Camera) -> float:
    """CRS units in one metre for the camera's CRS (1 without a CRS)."""
    crs = camera_crs(camera)
    return 1.0 / (metres_per_unit(crs) if crs is not None else 1.0)


# ---------------------------------------------------------------------------------------------------- cuboids
def cuboid_corners(centre: object, heading_deg: object, length: object, width: object, height: object) -> np.ndarray:
    """World corners (N, 8, 3) of level cuboids: footprint centres ``centre`` (N, 3), ``heading_deg`` (N,) clockwise
    from north, ``length``/``width``/``height`` (N,) or scalars in the units of ``centre``. Corner order:
    front-left, front-right, rear-right, rear-left at the bottom (0-3), then the same on top (4-7)."""
    c = np.asarray(centre, dtype=np.float64).reshape(-1, 3)
    n = c.shape[0]
    h = np.radians(np.broadcast_to(np.asarray(heading_deg, dtype=np.float64), (n,)))
    size = [np.broadcast_to(np.asarray(a, dtype=np.float64), (n,))[:, None] for a in (length, width, height)]
    fwd = 0.5 * size[0] * np.stack([np.sin(h), np.cos(h), np.zeros_like(h)], axis=1)  # centre to front
    right = 0.5 * size[1] * np.stack([np.cos(h), -np.sin(h), np.zeros_like(h)], axis=1)  # centre to right side
    up = size[2] * np.array([0.0, 0.0, 1.0])
    bottom = [c + fwd - right, c + fwd + right, c - fwd + right, c - fwd - right]
    return np.stack(bottom + [b + up for b in bottom], axis=1)


def cuboid_boxes(camera: Camera, centre: object, heading_deg: object, length: object, width: object,
                 height: object) -> np.ndarray:
    """Image boxes (N, 4) ``x1, y1, x2, y2`` (px, unclipped) of the projected corners of :func:`cuboid_corners`
    (dimensions in CRS units); NaN rows where a corner is behind the camera."""
    corners = cuboid_corners(centre, heading_deg, length, width, height)
    n = corners.shape[0]
    uv = camera.project(corners.reshape(-1, 3)).reshape(n, 8, 2)
    return np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)  # NaN propagates


def free_edges(camera: Camera, boxes: object, border_px: float = 2.0) -> np.ndarray:
    """Boolean (N, 4) for ``x1, y1, x2, y2``: True where the edge is finite and lies more than ``border_px`` inside
    the outermost pixel centres (0 and W-1, H-1), i.e. the detector did not clip it. The margin catches boxes
    clipped to pixel centres ``[0, W-1]`` as well as to pixel edges ``[-0.5, W-0.5]`` or ``[0, W]``."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    lo = np.array([border_px, border_px])
    hi = np.array([camera.width - 1 - border_px, camera.height - 1 - border_px])
    with np.errstate(invalid="ignore"):
        return np.concatenate([b[:, :2] > lo, b[:, 2:] < hi], axis=1)


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


def _selection(free: np.ndarray) -> np.ndarray:
    """Weights (N, 2, 4) that take the two fitted box quantities from a box ``x1, y1, x2, y2``: the horizontal
    centre (or the one side edge the frame leaves) and the bottom edge."""
    use_x1, use_x2 = free[:, 0], free[:, 2]
    both = use_x1 & use_x2
    T = np.zeros((free.shape[0], 2, 4))
    T[:, 0, 0] = np.where(both, 0.5, use_x1)
    T[:, 0, 2] = np.where(both, 0.5, ~use_x1)
    T[:, 1, 3] = 1.0
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


# Corner k of a cuboid is centre + sum_p _SIGNS[k, p] * dims[p] * axis[p] with the axes forward, right and up; the
# order is that of cuboid_corners.
_SIGNS = np.array([[1, -1, 0], [1, 1, 0], [-1, 1, 0], [-1, -1, 0],
                   [1, -1, 1], [1, 1, 1], [-1, 1, 1], [-1, -1, 1]], dtype=np.float64) * [0.5, 0.5, 1.0]
_EDGE_COMPONENT = np.array([0, 1, 0, 1])  # x1, y1, x2, y2 are extremes of u, v, u, v


@dataclass(frozen=True)
class _Cuboids:
    """Level cuboids standing on ``surface`` in N frames at fixed headings: their boxes as functions of the
    footprint centres' (x, y) and of the dimensions, with derivatives.

    A box edge is the extreme of its 8 projected corners, so it is piecewise smooth; its derivatives are those of
    the extreme corner (exact on either side of a switch, where forward differences of the box would straddle the
    kink and mislead Newton steps). The projection and the surface are differentiated numerically, by central and
    forward differences of ``step`` CRS units.
    """

    camera: Camera
    surface: Surface
    axes: np.ndarray  # (N, 3, 3): unit forward, right and up vectors
    step: float

    @classmethod
    def at(cls, camera: Camera, surface: Surface, heading_deg: np.ndarray) -> _Cuboids:
        h = np.radians(np.asarray(heading_deg, dtype=np.float64))
        zero = np.zeros_like(h)
        axes = np.stack([np.stack([np.sin(h), np.cos(h), zero], axis=1),
                         np.stack([np.cos(h), -np.sin(h), zero], axis=1),
                         np.stack([zero, zero, zero + 1.0], axis=1)], axis=1)
        return cls(camera, surface, axes, 1e-3 * _units_per_metre(camera))

    def take(self, rows: np.ndarray) -> _Cuboids:
        """The cuboids of some frames."""
        return _Cuboids(self.camera, self.surface, self.axes[rows], self.step)

    def centres(self, xy: np.ndarray) -> np.ndarray:
        return np.column_stack([xy, self.surface.elevation(xy[:, 0], xy[:, 1])])

    def _corners(self, centres: np.ndarray, dims: np.ndarray) -> np.ndarray:
        return centres[:, None, :] + np.einsum("kp,np,npx->nkx", _SIGNS, dims, self.axes)

    def boxes(self, xy: np.ndarray, dims: np.ndarray) -> np.ndarray:
        """Boxes (N, 4) of the cuboids with footprint centres at ``xy`` (N, 2) and ``dims`` (N, 3), CRS units."""
        n = xy.shape[0]
        uv = self.camera.project(self._corners(self.centres(xy), dims).reshape(-1, 3)).reshape(n, 8, 2)
        return np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)

    def boxes_jac(self, xy: np.ndarray, dims: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Boxes (N, 4) and their derivatives by the centres' (x, y), (N, 4, 2) px per CRS unit, and by the
        dimensions and the heading, (N, 4, 4): px per CRS unit of length, width and height, px per radian."""
        n, s = xy.shape[0], self.step
        probe = np.concatenate([xy, xy + [s, 0.0], xy + [0.0, s]])
        z = self.surface.elevation(probe[:, 0], probe[:, 1]).reshape(3, n)
        slope = ((z[1:] - z[0]) / s).T  # (N, 2): dz/dx, dz/dy
        corners = self._corners(np.column_stack([xy, z[0]]), dims)
        uv = self.camera.project(corners.reshape(-1, 3)).reshape(n, 8, 2)
        boxes = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
        filled = np.nan_to_num(uv, nan=0.0)
        active = np.concatenate([filled.argmin(axis=1), filled.argmax(axis=1)], axis=1)  # (N, 4) corner per edge
        rows = np.arange(n)[:, None]
        extreme = corners[rows, active]  # (N, 4, 3)
        d = s * np.concatenate([np.eye(3), -np.eye(3)])
        uvd = self.camera.project((extreme[:, :, None, :] + d).reshape(-1, 3)).reshape(n, 4, 6, 2)
        uvd = uvd[:, np.arange(4), :, _EDGE_COMPONENT]  # (4, N, 6) -> the edge's coordinate
        grad = np.moveaxis((uvd[:, :, :3] - uvd[:, :, 3:]) / (2 * s), 0, 1)  # (N, 4, 3): d edge / d corner
        j_xy = grad[:, :, :2] + grad[:, :, 2:] * slope[:, None, :]
        signs = _SIGNS[active]  # (N, 4, 3)
        d_dims = signs[..., None] * self.axes[:, None, :, :]  # (N, 4, 3, 3): d corner / d (length, width, height)
        # Turning clockwise by dh moves the forward axis by dh * right and the right axis by -dh * forward.
        d_heading = (signs[..., 0, None] * dims[:, None, 0, None] * self.axes[:, None, 1]
                     - signs[..., 1, None] * dims[:, None, 1, None] * self.axes[:, None, 0])
        j_dims = np.einsum("nex,nepx->nep", grad, np.concatenate([d_dims, d_heading[:, :, None]], axis=2))
        return boxes, j_xy, j_dims


def _newton_centres(model: _Cuboids, xy: np.ndarray, dims: np.ndarray, T: np.ndarray, target: np.ndarray,
                    iterations: int, tol_px: float,
                    halvings: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Newton iterations on the footprint centres (N, 2) so that the cuboids' fitted box quantities (``T``, from
    :func:`_selection`) match ``target`` (N, 2) px, halving a step that does not reduce a row's residual. Rows
    stop once their residual is within ``tol_px``.

    Returns the centres' (x, y), and at them the boxes, their derivatives (:meth:`_Cuboids.boxes_jac`) and the
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


def box_ground_points(camera: Camera, surface: Surface, boxes: object, heading_deg: object, dims: object, *,
                      iterations: int = 10, tol_px: float = 1e-3, border_px: float = 2.0) -> BoxGroundPoints:
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
    fit = np.flatnonzero(status == "ok")
    if fit.size:
        dims_u = dims_m[fit] * _units_per_metre(camera)
        xyz_fit, converged, residual_fit = _fit_centres(camera, surface, b[fit], heading[fit], dims_u, naive[fit],
                                                        free[fit], iterations, tol_px)
        xyz[fit] = np.where(converged[:, None], xyz_fit, np.nan)
        residual_px[fit] = np.where(converged, residual_fit, np.nan)
        status[fit[~converged]] = NOT_CONVERGED
        cut = converged & _lowest_corner_cut(camera, xyz_fit, heading[fit], dims_u, free[fit], border_px)
        status[fit[cut]] = CLIPPED_BOTTOM
        xyz[fit[cut]], residual_px[fit[cut]] = naive[fit[cut]], np.nan
    return BoxGroundPoints(xyz=xyz, status=status, naive_xyz=naive, residual_px=residual_px)


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
                 start: np.ndarray, free: np.ndarray, iterations: int,
                 tol_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fitted centres (N, 3), converged (N,) and all-edge RMS residuals (N,) px; ``dims`` in CRS units."""
    model = _Cuboids.at(camera, surface, heading)
    T = _selection(free)
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


def estimate_length(camera: Camera, centres: object, heading_deg: object, boxes: object, width_m: float,
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
    upm = _units_per_metre(camera)

    def predict(theta: np.ndarray) -> np.ndarray:
        return cuboid_boxes(camera, c, heading, *(theta * upm))

    prior = _SizePrior(width_m, height_m, width_sigma_m, height_sigma_m, length0_m)
    return _fit_length(predict, obs, free, prior, pixel_sigma, max_std_m, nuisance=0)


def estimate_length_refit(camera: Camera, surface: Surface, heading_deg: object, boxes: object, width_m: float,
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
        self.upm = _units_per_metre(camera)
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
        model = _Cuboids.at(self.camera, self.surface, np.degrees(h))
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
