"""The orthophoto as a camera sees it: every pixel's ray meets the surface and the orthophoto is sampled there.

This is how the demo world renders its video background, and how :mod:`trafficgeo.registration` compares an
orthophoto with a video frame. Pixels follow the camera model's convention (:mod:`trafficgeo.camera.model`:
``(0, 0)`` is the centre of the top-left pixel); the orthophoto is sampled bilinearly at the ground point of each
pixel centre. A pixel is *visible* when its ray meets the surface (terrain in front of the ground hides what is
behind it: the ray march returns the first hit) and the orthophoto holds data there (inside its extent, not nodata).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.geo.mapping import Surface, pixels_to_world
from trafficgeo.geo.raster import GeoRaster

_FAR = -1e6  # a map coordinate cv2.remap reads as "outside"


@dataclass(frozen=True)
class DrapedView:
    """The orthophoto through a camera.

    Attributes:
        image: (H, W, B) float32, the orthophoto's bands (0-255 for an 8-bit RGB orthophoto) at each pixel whose ray
            meets the surface (beyond the orthophoto's edge its border cells are repeated); 0 where it meets nothing.
        ground: (H, W) bool, the pixel's ray meets the surface.
        visible: (H, W) bool, ``ground`` and the orthophoto holds data there (inside its extent, not nodata).
    """

    image: np.ndarray
    ground: np.ndarray
    visible: np.ndarray


def _ortho_pixels(camera: Camera, surface: Surface, ortho: GeoRaster, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthophoto (col, row) of the ground under pixels uv (N, 2), with the cv2 convention (integer = cell centre);
    NaN where the ray misses the surface."""
    g = pixels_to_world(camera, uv, surface, min_incidence_deg=0.0, with_lonlat=False)
    col, row = ortho.map_to_pixel(g.xyz[:, 0], g.xyz[:, 1])
    return np.asarray(col, dtype=np.float64) - 0.5, np.asarray(row, dtype=np.float64) - 0.5


def _valid_cells(ortho: GeoRaster) -> np.ndarray:
    """(rows, cols) float32 1 where every band holds data, else 0."""
    data = ortho.data
    ok = np.ones(data.shape[1:], dtype=bool)
    for band in data:
        if np.issubdtype(band.dtype, np.floating):
            ok &= np.isfinite(band)
        if ortho.nodata is not None and np.isfinite(ortho.nodata):
            ok &= band != ortho.nodata
    return ok.astype(np.float32)


def drape_orthophoto(camera: Camera, surface: Surface, ortho: GeoRaster, *, step_px: int = 1) -> DrapedView:
    """The orthophoto through ``camera`` onto ``surface`` (same CRS as the camera), with its visibility mask.

    ``step_px`` > 1 casts rays only every ``step_px`` pixels and interpolates the orthophoto coordinates between
    them (about ``step_px**2`` times fewer rays; a pixel is visible only where its four neighbouring rays are), for
    previews and texture maps. 1 casts a ray through every pixel centre.
    """
    if step_px < 1:
        raise ValueError(f"step_px must be >= 1, got {step_px}")
    w, h = camera.image_size
    if step_px == 1:
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        col, row = _ortho_pixels(camera, surface, ortho, np.column_stack([u.ravel(), v.ravel()]))
        map_x, map_y = col.reshape(h, w), row.reshape(h, w)
        hit = np.isfinite(map_x) & np.isfinite(map_y)
    else:
        gu = np.arange(0, w - 1 + step_px, step_px, dtype=np.float64)
        gv = np.arange(0, h - 1 + step_px, step_px, dtype=np.float64)
        u, v = np.meshgrid(gu, gv)
        col, row = _ortho_pixels(camera, surface, ortho, np.column_stack([u.ravel(), v.ravel()]))
        coarse_ok = (np.isfinite(col) & np.isfinite(row)).reshape(u.shape).astype(np.float32)
        cx = np.nan_to_num(col, nan=0.0).reshape(u.shape).astype(np.float32)
        cy = np.nan_to_num(row, nan=0.0).reshape(u.shape).astype(np.float32)
        fu, fv = np.meshgrid(np.arange(w, dtype=np.float32) / step_px, np.arange(h, dtype=np.float32) / step_px)
        map_x = cv2.remap(cx, fu, fv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        map_y = cv2.remap(cy, fu, fv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        hit = cv2.remap(coarse_ok, fu, fv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) > 0.999
    mx = np.where(hit, map_x, _FAR).astype(np.float32)
    my = np.where(hit, map_y, _FAR).astype(np.float32)
    bands = np.ascontiguousarray(ortho.data.transpose(1, 2, 0)).astype(np.float32)
    image = cv2.remap(bands, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if image.ndim == 2:
        image = image[..., None]
    # Inside the orthophoto and on data: the bilinear footprint's cells all valid (outside reads 0).
    valid = cv2.remap(_valid_cells(ortho), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=0.0) > 0.999
    image[~hit] = 0.0
    return DrapedView(image=image.astype(np.float32), ground=hit, visible=hit & valid)
