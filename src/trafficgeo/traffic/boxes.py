"""Vehicle ground points from image bounding boxes, corrected for the vehicle's 3-D extent.

A detector gives a vehicle's axis-aligned image box ``(x1, y1, x2, y2)`` in pixels (OpenCV pixel-centre convention:
pixel (0, 0) is the centre of the top-left pixel). The naive ground point, the box's bottom centre
``((x1 + x2) / 2, y2)`` mapped to the road, is where the vehicle's *nearest bottom corner or edge* meets the road,
not its footprint centre: it lies up to half the vehicle's length or width (1-2 m) towards the camera.

With a calibrated camera, a road surface and the vehicle's heading (from its track), :func:`box_ground_points`
models the vehicle as a level cuboid of typical size (:data:`VEHICLE_DIMENSIONS`) and solves for the footprint
centre whose projected cuboid matches the observed box's horizontal centre and bottom edge, the two box quantities
least sensitive to the size being a bit wrong. :func:`estimate_length_refit` (centres refitted) and
:func:`estimate_length` (centres known) recover one vehicle's length from many frames.

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


def _targets(boxes: np.ndarray, use_x1: np.ndarray, use_x2: np.ndarray) -> np.ndarray:
    """The two fitted box quantities (N, 2) px: the horizontal centre (or the one side edge the frame leaves),
    and the bottom edge."""
    both = use_x1 & use_x2
    horizontal = np.where(both, 0.5 * (boxes[:, 0] + boxes[:, 2]), np.where(use_x1, boxes[:, 0], boxes[:, 2]))
    return np.column_stack([horizontal, boxes[:, 3]])


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


def _gauss_newton_xy(residual: Callable[[np.ndarray], np.ndarray], xy: np.ndarray, step: float, iterations: int,
                     tol_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Newton iterations on (N, 2) horizontal positions for the (N, 2) pixel residuals, with a forward-difference
    Jacobian (steps of ``step`` CRS units) and step halving when a full step does not reduce the residual.
    Returns the positions and their final residual norms (px)."""
    r = residual(xy)
    for _ in range(iterations):
        todo = _norm(r) > tol_px
        if not todo.any():
            break
        J = np.stack([(residual(xy + step * e) - r) / step for e in np.eye(2)], axis=2)  # (N, 2 px, 2 xy)
        delta = -_solve2(J, r)
        delta[~todo] = 0.0
        xy, r = _line_search(residual, xy, r, delta)
    return xy, _norm(r)


def _line_search(residual: Callable[[np.ndarray], np.ndarray], xy: np.ndarray, r: np.ndarray, delta: np.ndarray,
                 halvings: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Take, per row, the longest of the steps ``delta / 2^k`` that reduces its residual; rows with none stay put."""
    xy, r = xy.copy(), r.copy()
    delta = np.where(np.isfinite(delta), delta, 0.0)
    pending = np.any(delta != 0.0, axis=1)
    t = 1.0
    for _ in range(halvings + 1):
        if not pending.any():
            break
        cand = xy + t * np.where(pending[:, None], delta, 0.0)
        rc = residual(cand)
        better = pending & (_norm(rc) < _norm(r))
        xy[better], r[better] = cand[better], rc[better]
        pending &= ~better
        t *= 0.5
    return xy, r


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

    Method: starting from the naive point (the bottom centre mapped to ``surface``), Newton iterations on the
    footprint centre (x, y), with ``z = surface.elevation(x, y)``, match the projected cuboid's box to the observed
    one in two quantities: its horizontal centre (or, when the frame clips one side, the other side edge) and its
    bottom edge ``y2``. These two depend least on the dimensions being exact: the centre is symmetric in them and
    the bottom edge sees only the footprint. A box clipped at one side is fitted with the other side edge and its
    bottom, provided the fitted cuboid's lowest corner is in the frame (else the box's bottom is where the frame
    cuts the vehicle). A box clipped at the bottom (or whose lowest corner is out of the frame), or at both sides,
    keeps its naive point (status ``clipped_bottom`` / ``clipped_sides``), as does one without heading
    (``no_heading``): without the heading the direction from the nearest corner to the centre is unknown, so no
    correction is attempted.
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
    use_x1, use_x2 = free[:, 0], free[:, 2]
    observed = _targets(boxes, use_x1, use_x2)

    def predicted_boxes(xy: np.ndarray) -> np.ndarray:
        centre = np.column_stack([xy, surface.elevation(xy[:, 0], xy[:, 1])])
        return cuboid_boxes(camera, centre, heading, dims[:, 0], dims[:, 1], dims[:, 2])

    def residual(xy: np.ndarray) -> np.ndarray:
        return _targets(predicted_boxes(xy), use_x1, use_x2) - observed

    step = 1e-3 * _units_per_metre(camera)  # 1 mm
    xy, rnorm = _gauss_newton_xy(residual, start[:, :2].copy(), step, iterations, tol_px)
    converged = rnorm <= tol_px
    xyz = np.column_stack([xy, surface.elevation(xy[:, 0], xy[:, 1])])
    return xyz, converged, _edge_rms(predicted_boxes(xy), boxes, free)


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
    the assumed length. Use :func:`estimate_length_refit` for that case.

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
                          border_px: float = 2.0, use_top: bool = True) -> tuple[float, float]:
    """Length (m) and its 1-sigma uncertainty (m) of ONE vehicle seen in M frames, its footprint centres unknown.

    For every trial size the centres are refitted as :func:`box_ground_points` does (matching each box's centre
    and bottom edge), so the length is judged only by what the centres cannot absorb: the box's horizontal
    extent and its top edge.

    Args:
        camera: the calibrated camera.
        surface: the road surface.
        heading_deg: (M,) heading in each frame, degrees clockwise from north.
        boxes: (M, 4) observed boxes ``x1, y1, x2, y2`` px; frames :func:`box_ground_points` cannot correct are
            left out.

    The other arguments and the result are those of :func:`estimate_length`.

    Geometry: seen from the side or obliquely, the length shows in the box's width and is found to a few
    centimetres. Seen exactly from behind (or ahead), it shows only in the top edge, where it trades off against
    the height (about 7 m of length per metre of height at 20 m from an 8 m high camera); only the change of that
    trade-off with distance separates them, so the standard deviation is large and the length NaN unless the
    boxes are very precise.
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    heading = np.broadcast_to(np.asarray(heading_deg, dtype=np.float64), (b.shape[0],))
    prior = _SizePrior(width_m, height_m, width_sigma_m, height_sigma_m, length0_m)
    first = box_ground_points(camera, surface, b, heading, prior.start(), border_px=border_px)
    use = first.ok
    b, heading, start = b[use], heading[use], first.xyz[use]
    free = free_edges(camera, b, border_px)
    fit_free = free.copy()
    fit_free[:, 1] &= use_top
    upm = _units_per_metre(camera)

    def predict(theta: np.ndarray) -> np.ndarray:
        dims = np.tile(theta * upm, (b.shape[0], 1))
        xyz, _, _ = _fit_centres(camera, surface, b, heading, dims, start, free, iterations=30, tol_px=1e-8)
        return cuboid_boxes(camera, xyz, heading, *dims.T)

    return _fit_length(predict, b, fit_free, prior, pixel_sigma, max_std_m, nuisance=2 * b.shape[0])


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
