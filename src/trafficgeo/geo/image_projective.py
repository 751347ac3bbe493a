"""A perspective image (a drone photo not taken straight down, a scanned oblique) made an orthophoto by a plane
projective fit: four or more control points tie image pixels to map coordinates on (nearly) flat ground, the
homography is their least-squares fit (OpenCV's DLT, coordinates centred on the points for float64 precision at
5e6), and the image is resampled onto a north-up grid whose cell is the image's median ground footprint at the
control points.

The map side of a homography runs to infinity at the image's horizon: only the image where the ground lies in front
of the camera, within :data:`REACH` times the control points' spread of their centre, is kept; the rest of the grid
is nodata (0). An affine (three points, or a world file) is exact for an image taken straight down; for an oblique
one it is metres off (1.94 m RMS on a real drone image, issue 42) where the projective fit is exact on flat ground.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from affine import Affine
from numpy.typing import ArrayLike

from trafficgeo.errors import InputError

MAX_MAP_COORDINATE = 1e8  # CRS units: no projected CRS reaches this far (the Earth is 4e7 m round)
MAX_PIXEL = 1e6  # px: no image is this large
REACH = 4.0  # the ortho covers the ground within this many times the control points' spread of their centre
MAX_CELLS = 60_000_000  # output cells at most; coarser cells beyond


@dataclass(frozen=True)
class ProjectiveFit:
    """The pixel -> map homography fitted to control points.

    Attributes:
        H: (3, 3) maps ``(u, v, 1)`` (pixel centres on integers) to ``(x - origin_x, y - origin_y, w)``.
        origin: (2,) map coordinates the fit is centred on (CRS units).
        n_points: control points used.
        rmse: RMS distance (CRS units) between the points' map coordinates and the fit's; 0 for 4 points.
        max_error: the largest of those distances (CRS units).
    """

    H: np.ndarray
    origin: np.ndarray
    n_points: int
    rmse: float
    max_error: float

    def to_map(self, uv: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) pixels -> map (N, 2) and the homogeneous scale w (N,) (w <= 0: beyond the horizon)."""
        p = np.column_stack([np.asarray(uv, dtype=np.float64).reshape(-1, 2), np.ones(len(np.atleast_2d(uv)))])
        q = p @ self.H.T
        with np.errstate(divide="ignore", invalid="ignore"):
            return q[:, :2] / q[:, 2:3] + self.origin, q[:, 2]


def check_control_points(uv: np.ndarray, xy: np.ndarray, least: int, fit: str) -> None:
    """Refuse, in one line, control points a fit of ``fit`` cannot use: fewer than ``least``, missing or non-finite
    values, or coordinates beyond any projected CRS or image (both fits, affine and projective, call this)."""
    n = uv.shape[0]
    if n < least or xy.shape[0] != n:
        raise InputError(f"control: {n} control points; {fit} needs at least {least} (not on one line) with pixel "
                         "and map coordinates", parameters=("control",))
    if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(xy))):
        raise InputError("control: a control point has a missing or non-finite coordinate; fix the table",
                         parameters=("control",))
    if np.abs(xy).max() > MAX_MAP_COORDINATE or np.abs(uv).max() > MAX_PIXEL:
        which = "map" if np.abs(xy).max() > MAX_MAP_COORDINATE else "pixel"
        raise InputError(f"control: a {which} coordinate reaches {np.abs(xy if which == 'map' else uv).max():.3g}, "
                         f"beyond any {'projected CRS' if which == 'map' else 'image'}; fix the table",
                         parameters=("control",))


def fit_projective(pixels: ArrayLike, world: ArrayLike) -> ProjectiveFit:
    """Least-squares homography from ``pixels`` (N, 2) to ``world`` (N, 2, CRS units), N >= 4, no three of the
    four best-spread points on one line.

    Raises:
        InputError: fewer than 4 points, non-finite values, or points that do not fix a homography.
    """
    uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    xy = np.asarray(world, dtype=np.float64).reshape(-1, 2)
    check_control_points(uv, xy, 4, "a projective fit")
    n = uv.shape[0]
    origin = xy.mean(axis=0)
    H, _ = cv2.findHomography(uv, xy - origin, method=0)
    if H is None or not np.all(np.isfinite(H)) or abs(np.linalg.det(H)) < 1e-300:
        raise InputError("control: the control points do not fix a projective fit (three of them on one line, or "
                         "repeated); add points spread over the image", parameters=("control",))
    fit = ProjectiveFit(H, origin, n, 0.0, 0.0)
    got, w = fit.to_map(uv)
    if np.any(w <= 0):
        raise InputError("control: the projective fit puts a control point beyond the horizon; check the points' "
                         "pixel and map coordinates", parameters=("control",))
    e = np.linalg.norm(got - xy, axis=1)
    return ProjectiveFit(H, origin, n, float(np.sqrt(np.mean(e ** 2))), float(e.max()))


def _footprint(fit: ProjectiveFit, uv: np.ndarray) -> np.ndarray:
    """Ground size (CRS units) of one pixel at ``uv`` (N, 2): sqrt of the area the pixel maps to."""
    a, _ = fit.to_map(uv)
    b, _ = fit.to_map(uv + [1.0, 0.0])
    c, _ = fit.to_map(uv + [0.0, 1.0])
    (px, py), (qx, qy) = (b - a).T, (c - a).T
    return np.sqrt(np.abs(px * qy - py * qx))


def orthorectify(data: np.ndarray, fit: ProjectiveFit, control_pixels: ArrayLike,
                 control_world: ArrayLike) -> tuple[np.ndarray, Affine]:
    """Resample ``data`` (bands, rows, cols) onto a north-up grid through ``fit``: returns (the grid's data, same
    dtype, 0 outside the image or beyond the reach; its corner-convention transform)."""
    bands, rows, cols = data.shape
    xy = np.asarray(control_world, dtype=np.float64).reshape(-1, 2)
    centre = xy.mean(axis=0)
    spread = max(float(np.max(np.linalg.norm(xy - centre, axis=1))), 1e-9)
    cell = float(np.median(_footprint(fit, np.asarray(control_pixels, dtype=np.float64).reshape(-1, 2))))
    # the ground the image shows, in front of the camera and within reach of the points
    gu, gv = np.meshgrid(np.linspace(-0.5, cols - 0.5, 65), np.linspace(-0.5, rows - 0.5, 65))
    ground, w = fit.to_map(np.column_stack([gu.ravel(), gv.ravel()]))
    keep = (w > 0) & (np.linalg.norm(ground - centre, axis=1) <= REACH * spread)
    if not keep.any():
        raise InputError("control: no part of the image maps onto the ground near the control points; check them",
                         parameters=("control",))
    lo, hi = ground[keep].min(axis=0), ground[keep].max(axis=0)
    lo, hi = np.maximum(lo, centre - REACH * spread), np.minimum(hi, centre + REACH * spread)
    width, height = (hi - lo) / cell
    if width * height > MAX_CELLS:
        cell *= float(np.sqrt(width * height / MAX_CELLS))
    out_cols, out_rows = max(1, int(np.ceil((hi[0] - lo[0]) / cell))), max(1, int(np.ceil((hi[1] - lo[1]) / cell)))
    transform = Affine(cell, 0.0, float(lo[0]), 0.0, -cell, float(hi[1]))
    # output pixel centre (j, i) -> map relative to the fit's origin -> image pixel, through H^-1
    out_to_map = np.array([[cell, 0.0, lo[0] + 0.5 * cell - fit.origin[0]],
                           [0.0, -cell, hi[1] - 0.5 * cell - fit.origin[1]], [0.0, 0.0, 1.0]])
    M = np.linalg.inv(fit.H) @ out_to_map
    jj, ii = np.meshgrid(np.arange(out_cols, dtype=np.float64), np.arange(out_rows, dtype=np.float64))
    den = M[2, 0] * jj + M[2, 1] * ii + M[2, 2]  # > 0: the image sees that ground point in front (w = 1 / den)
    with np.errstate(divide="ignore", invalid="ignore"):
        mapx = ((M[0, 0] * jj + M[0, 1] * ii + M[0, 2]) / den).astype(np.float32)
        mapy = ((M[1, 0] * jj + M[1, 1] * ii + M[1, 2]) / den).astype(np.float32)
    gx, gy = lo[0] + (jj + 0.5) * cell, hi[1] - (ii + 0.5) * cell
    valid = (den > 0) & np.isfinite(mapx) & np.isfinite(mapy)
    valid &= np.hypot(gx - centre[0], gy - centre[1]) <= REACH * spread
    mapx[~valid], mapy[~valid] = -1e6, -1e6
    out = np.zeros((bands, out_rows, out_cols), dtype=data.dtype)
    for b in range(bands):
        out[b] = cv2.remap(np.ascontiguousarray(data[b]), mapx, mapy, cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, transform


__all__ = ["MAX_MAP_COORDINATE", "MAX_PIXEL", "REACH", "ProjectiveFit", "check_control_points", "fit_projective",
           "orthorectify"]
