"""Level vehicle cuboids: typical dimensions (metres), world corners, projected image boxes (px) and, for the
fits in :mod:`trafficgeo.traffic.box_points` and :mod:`trafficgeo.traffic.box_length`, their derivatives.

Conventions (those of :mod:`trafficgeo.synth.render`, whose boxes :func:`cuboid_corners` builds):

* World coordinates in the camera's CRS and its units (x east, y north, z up). Vehicle dimensions given in metres
  are converted to CRS units with :func:`trafficgeo.crs.metres_per_unit` (US-foot CRSs exist).
* ``heading_deg``: direction of travel, degrees clockwise from grid north.
* A cuboid's ``centre`` is the centre of its footprint on the road; the cuboid is level (its bottom at the height of
  the centre, even on a grade), ``length`` along the heading, ``width`` across it, ``height`` up.
* Corners are ordered front-left, front-right, rear-right, rear-left, bottom (0-3) then top (4-7).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.geo.mapping import Surface, camera_crs

# Typical (length, width, height) in metres: car, van, truck and bus as the synthetic world's SUMO vehicle types
# (trafficgeo.synth.sumo_scene.VEHICLE_CLASSES); two-wheelers with their rider.
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
# ---------------------------------------------------------------------------------------------------- dimensions
def dimensions_for(classes: ArrayLike) -> np.ndarray:
    """Typical (length, width, height) in metres, (N, 3), for class names (N,) (case-insensitive; aliases in
    :data:`CLASS_ALIASES`); unknown or empty names get the dimensions of a car."""
    names = np.asarray(classes, dtype=object).reshape(-1)
    if names.size == 0:
        return np.zeros((0, 3))
    uniq, inverse = np.unique(np.char.lower(np.char.strip(names.astype(str))), return_inverse=True)
    default = VEHICLE_DIMENSIONS[DEFAULT_CLASS]
    table = np.array([VEHICLE_DIMENSIONS.get(CLASS_ALIASES.get(u, u), default) for u in uniq], dtype=np.float64)
    return table[inverse.reshape(-1)]


def units_per_metre(camera: Camera) -> float:
    """CRS units in one metre for the camera's CRS (1 without a CRS)."""
    crs = camera_crs(camera)
    return 1.0 / (metres_per_unit(crs) if crs is not None else 1.0)


# ---------------------------------------------------------------------------------------------------- cuboids
def cuboid_corners(centre: ArrayLike, heading_deg: ArrayLike, length: ArrayLike, width: ArrayLike,
                   height: ArrayLike) -> np.ndarray:
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


def cuboid_boxes(camera: Camera, centre: ArrayLike, heading_deg: ArrayLike, length: ArrayLike, width: ArrayLike,
                 height: ArrayLike) -> np.ndarray:
    """Image boxes (N, 4) ``x1, y1, x2, y2`` (px, unclipped) of the projected corners of :func:`cuboid_corners`
    (dimensions in CRS units); NaN rows where a corner is behind the camera."""
    corners = cuboid_corners(centre, heading_deg, length, width, height)
    n = corners.shape[0]
    uv = camera.project(corners.reshape(-1, 3)).reshape(n, 8, 2)
    return np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)  # NaN propagates


def free_edges(camera: Camera, boxes: ArrayLike, border_px: float = 2.0) -> np.ndarray:
    """Boolean (N, 4) for ``x1, y1, x2, y2``: True where the edge is finite and lies more than ``border_px`` inside
    the outermost pixel centres (0 and W-1, H-1), i.e. the detector did not clip it. The margin catches boxes
    clipped to pixel centres ``[0, W-1]`` as well as to pixel edges ``[-0.5, W-0.5]`` or ``[0, W]``."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    lo = np.array([border_px, border_px])
    hi = np.array([camera.width - 1 - border_px, camera.height - 1 - border_px])
    with np.errstate(invalid="ignore"):
        return np.concatenate([b[:, :2] > lo, b[:, 2:] < hi], axis=1)



# Corner k of a cuboid is centre + sum_p _SIGNS[k, p] * dims[p] * axis[p] with the axes forward, right and up; the
# order is that of cuboid_corners.
_SIGNS = np.array([[1, -1, 0], [1, 1, 0], [-1, 1, 0], [-1, -1, 0],
                   [1, -1, 1], [1, 1, 1], [-1, 1, 1], [-1, -1, 1]], dtype=np.float64) * [0.5, 0.5, 1.0]
_EDGE_COMPONENT = np.array([0, 1, 0, 1])  # x1, y1, x2, y2 are extremes of u, v, u, v


@dataclass(frozen=True)
class Cuboids:
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
    def at(cls, camera: Camera, surface: Surface, heading_deg: np.ndarray) -> Cuboids:
        h = np.radians(np.asarray(heading_deg, dtype=np.float64))
        zero = np.zeros_like(h)
        axes = np.stack([np.stack([np.sin(h), np.cos(h), zero], axis=1),
                         np.stack([np.cos(h), -np.sin(h), zero], axis=1),
                         np.stack([zero, zero, zero + 1.0], axis=1)], axis=1)
        return cls(camera, surface, axes, 1e-3 * units_per_metre(camera))

    def take(self, rows: np.ndarray) -> Cuboids:
        """The cuboids of some frames."""
        return Cuboids(self.camera, self.surface, self.axes[rows], self.step)

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


