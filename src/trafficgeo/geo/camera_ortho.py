"""True orthorectification of an image by its camera: every cell of a north-up grid over the ground the image shows
gets the image's colour where the camera sees that ground point on the surface (a DEM, a point cloud's ground, a
plane). Unlike a projective fit (:mod:`trafficgeo.geo.image_projective`), which is exact only for flat ground seen
by a camera without lens distortion, this follows the terrain and the lens, and leaves out ground the surface hides
from the camera (behind a crest, a wall).

Conventions: the camera's pixels as in :mod:`trafficgeo.camera.model` ((0, 0) the centre of the top-left pixel),
map coordinates in the camera's CRS and units; the grid's transform has the corner convention of GeoTIFF.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from affine import Affine
from numpy.typing import ArrayLike

from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs, pixels_to_world, world_to_pixels

MAX_CELLS = 60_000_000  # output cells at most; coarser cells beyond
BLOCK_ROWS = 256  # output rows per block (bounds the memory of the occlusion test)
SAMPLES = 97  # pixels per side of the grid that finds the ground the image shows


@dataclass(frozen=True)
class CheckPoints:
    """Control points used as checks of a camera's orthophoto: the ground distance (CRS units) between each point's
    surveyed x, y and where its pixel's ray meets the surface."""

    n_points: int
    errors: np.ndarray  # (N,) CRS units; NaN where the pixel's ray misses the surface

    @property
    def rmse(self) -> float:
        e = self.errors[np.isfinite(self.errors)]
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")

    @property
    def max_error(self) -> float:
        e = self.errors[np.isfinite(self.errors)]
        return float(e.max()) if e.size else float("nan")


def ground_sample_distance(camera: Camera, surface: Surface, *, max_distance: float | None = None
                           ) -> tuple[np.ndarray, float]:
    """The ground the image shows: the (N, 3) points where a grid of pixels meets ``surface`` (within
    ``max_distance`` CRS units of the camera, horizontally, when given), and the median size of one pixel on it (CRS
    units)."""
    w, h = camera.image_size
    gu, gv = np.meshgrid(np.linspace(0.0, w - 1.0, SAMPLES), np.linspace(0.0, h - 1.0, SAMPLES))
    hit = pixels_to_world(camera, np.column_stack([gu.ravel(), gv.ravel()]), surface, with_lonlat=False).xyz
    xyz = hit.reshape(SAMPLES, SAMPLES, 3)
    step = np.array([(w - 1.0) / (SAMPLES - 1), (h - 1.0) / (SAMPLES - 1)])
    along_u = np.linalg.norm(np.diff(xyz[:, :, :2], axis=1), axis=2) / step[0]
    along_v = np.linalg.norm(np.diff(xyz[:, :, :2], axis=0), axis=2) / step[1]
    ok = np.all(np.isfinite(hit), axis=1)
    if max_distance is not None:
        ok &= np.hypot(hit[:, 0] - camera.position[0], hit[:, 1] - camera.position[1]) <= max_distance
    sizes = np.concatenate([along_u[np.isfinite(along_u)], along_v[np.isfinite(along_v)]])
    if not ok.any() or not sizes.size:
        raise InputError("camera: no pixel of the image meets the surface (the camera looks away from it, or the "
                         "surface lies elsewhere); check the camera's CRS and the surface", parameters=("camera",))
    return hit[ok], float(np.median(sizes))


def orthorectify_with_camera(data: np.ndarray, camera: Camera, surface: Surface, *,
                             resolution_m: float | None = None, max_distance_m: float | None = None,
                             occlusion: bool = True) -> tuple[np.ndarray, Affine]:
    """Resample ``data`` (bands, rows, cols; the image the camera took) onto a north-up grid over the ground it
    shows: returns (the grid's data, same dtype, 0 where the image does not see the ground; its corner-convention
    transform).

    ``resolution_m``: the cell size in metres (default: the median size of one image pixel on the ground);
    ``max_distance_m``: leave out ground farther than this from the camera (horizontally); ``occlusion``: leave out
    cells the surface hides from the camera (by more than 0.5 m).
    """
    bands, rows, cols = data.shape
    if (cols, rows) != tuple(camera.image_size):
        raise InputError(f"camera: the image is {cols}x{rows} px, the camera {camera.image_size[0]}x"
                         f"{camera.image_size[1]}; give the camera of this image (at its resolution)",
                         parameters=("camera",))
    crs = camera_crs(camera)
    unit_m = metres_per_unit(crs) if crs is not None else 1.0
    reach = None if max_distance_m is None else float(max_distance_m) / unit_m
    ground, gsd = ground_sample_distance(camera, surface, max_distance=reach)
    cell = gsd if resolution_m is None else float(resolution_m) / unit_m
    if not (np.isfinite(cell) and cell > 0):
        raise InputError(f"resolution_m {resolution_m}: give a positive cell size in metres",
                         parameters=("resolution_m",))
    lo, hi = ground[:, :2].min(axis=0) - cell, ground[:, :2].max(axis=0) + cell
    width, height = (hi - lo) / cell
    if width * height > MAX_CELLS:
        cell *= float(np.sqrt(width * height / MAX_CELLS))
    out_cols = max(1, int(np.ceil((hi[0] - lo[0]) / cell)))
    out_rows = max(1, int(np.ceil((hi[1] - lo[1]) / cell)))
    transform = Affine(cell, 0.0, float(lo[0]), 0.0, -cell, float(hi[1]))
    out = np.zeros((bands, out_rows, out_cols), dtype=data.dtype)
    gx = lo[0] + (np.arange(out_cols) + 0.5) * cell
    # the view in undistorted normalized coordinates (a little wider): a lens polynomial can fold points far
    # outside the view back into the frame, so points outside it are never sampled
    edge = np.concatenate([np.column_stack([np.linspace(0, cols - 1, 33), np.full(33, v)]) for v in (0, rows - 1)]
                          + [np.column_stack([np.full(33, u), np.linspace(0, rows - 1, 33)]) for u in (0, cols - 1)])
    view = camera.pixels_to_normalized(edge)
    view = view[np.all(np.isfinite(view), axis=1)]
    pad = 0.05 * (view.max(axis=0) - view.min(axis=0))
    view_lo, view_hi = view.min(axis=0) - pad, view.max(axis=0) + pad
    planes = [np.ascontiguousarray(data[b]) for b in range(bands)]
    for r0 in range(0, out_rows, BLOCK_ROWS):
        gy = hi[1] - (np.arange(r0, min(out_rows, r0 + BLOCK_ROWS)) + 0.5) * cell
        xx, yy = np.meshgrid(gx, gy)
        zz = surface.elevation(xx.ravel(), yy.ravel())
        xyz = np.column_stack([xx.ravel(), yy.ravel(), zz])
        seen = np.isfinite(zz)
        if reach is not None:
            seen &= np.hypot(xx.ravel() - camera.position[0], yy.ravel() - camera.position[1]) <= reach
        xc = camera.world_to_camera(np.where(seen[:, None], xyz, camera.position + 1.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            norm = xc[:, :2] / xc[:, 2:3]
        seen &= (xc[:, 2] > 0) & np.all((norm >= view_lo) & (norm <= view_hi), axis=1)
        uv = np.full((xyz.shape[0], 2), -1e6)
        if seen.any():
            img = world_to_pixels(camera, xyz[seen], surface if occlusion else None,
                                  occlusion_tolerance_m=0.5)
            use = img.status == "ok"
            idx = np.flatnonzero(seen)[use]
            uv[idx] = img.uv[use]
        mapx = uv[:, 0].reshape(xx.shape).astype(np.float32)
        mapy = uv[:, 1].reshape(xx.shape).astype(np.float32)
        for b, plane in enumerate(planes):
            out[b, r0:r0 + xx.shape[0]] = cv2.remap(plane, mapx, mapy, cv2.INTER_LINEAR,
                                                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, transform


def check_points(camera: Camera, surface: Surface, pixels: ArrayLike, world_xy: ArrayLike) -> CheckPoints:
    """How far (CRS units, on the ground) each control point's pixel, mapped through ``camera`` onto ``surface``,
    lands from its surveyed x, y: the check of an orthophoto made with the camera."""
    uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    xy = np.asarray(world_xy, dtype=np.float64).reshape(-1, 2)
    hit = pixels_to_world(camera, uv, surface, with_lonlat=False).xyz
    return CheckPoints(len(uv), np.hypot(hit[:, 0] - xy[:, 0], hit[:, 1] - xy[:, 1]))


__all__ = ["CheckPoints", "check_points", "ground_sample_distance", "orthorectify_with_camera"]
