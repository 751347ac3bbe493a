"""Rasters read for display (an orthophoto under the GCP app's map or the report's figures): :func:`read_display`
reads a raster (or a part of it) decimated, optionally warped to another CRS or north up, into a
:class:`DisplayRaster`, and :func:`display_rgb` turns any raster's bands into 8-bit RGB. Conventions (band order,
pixel-corner transforms, map units) as in :mod:`trafficgeo.geo.raster`, which opens the files."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import pyproj
from affine import Affine
from rasterio.errors import RasterioError

from trafficgeo.errors import InputError
from trafficgeo.geo.raster import open_raster, pixel_to_map, to_pyproj_crs

__all__ = ["DisplayRaster", "display_rgb", "read_display"]


def display_rgb(data: np.ndarray, valid: np.ndarray | None = None,
                stretch: tuple[float, float] = (2.0, 98.0)) -> np.ndarray:
    """Colours to show a raster: ``data`` (bands, rows, cols) of any type -> (rows, cols, 3) uint8 RGB.

    Bands 1-3 are red, green and blue (one or two bands: band 1 as grey). 8-bit data is shown as it is; other
    types are stretched per band from the ``stretch`` percentiles of their valid cells (``valid`` (rows, cols)
    bool, and finite) to 0-255, the usual 2-98 % cut of GIS viewers (the whole range where those two are equal).
    Invalid cells are black (the caller masks them)."""
    a = np.asarray(data)
    if a.ndim != 3 or a.shape[0] < 1:
        raise ValueError(f"display_rgb: data must be (bands, rows, cols), got shape {a.shape}")
    bands = a[:3] if a.shape[0] >= 3 else a[:1]
    ok = np.ones(a.shape[1:], dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    if bands.dtype == np.uint8:
        out = np.where(ok, bands, 0).astype(np.uint8)
    else:
        out = np.zeros(bands.shape, dtype=np.uint8)
        for b, band in enumerate(bands.astype(np.float64)):
            good = ok & np.isfinite(band)
            if not good.any():
                continue
            lo, hi = np.percentile(band[good], stretch)
            if hi <= lo:  # mostly one value: stretch over the whole range instead
                lo, hi = band[good].min(), band[good].max()
            scaled = (band - lo) * (255.0 / (hi - lo)) if hi > lo else np.zeros_like(band)
            out[b] = np.where(good, np.clip(np.rint(scaled), 0, 255), 0).astype(np.uint8)
    if out.shape[0] == 1:
        out = np.repeat(out, 3, axis=0)
    return np.moveaxis(out, 0, -1)



@dataclass(frozen=True, eq=False)
class DisplayRaster:
    """A raster (or a part of it) read decimated for display (:func:`read_display`): ``data`` ``(bands, rows, cols)``
    in the file's dtype (bands 1-3 and the alpha band 4 of files with 3 or more bands, else band 1); ``valid``
    ``(rows, cols)``, GDAL's mask of band 1 (False at nodata, transparent alpha, outside a warped source);
    ``transform``: display pixel ``(col, row)`` (corners) -> map ``(x, y)``; ``factor``: full-resolution pixels per
    display pixel (integer, 1: none); ``grid_transform``: the same for the full-resolution grid (the file's, or the
    warped one); ``window``: ``(col_off, row_off, cols, rows)`` of that grid read (what the image covers), with its
    ``bounds`` (left, bottom, right, top) in map units."""

    data: np.ndarray
    valid: np.ndarray
    transform: Affine
    crs: pyproj.CRS | None
    nodata: float | None
    factor: int
    grid_transform: Affine
    window: tuple[int, int, int, int]
    bounds: tuple[float, float, float, float]
    path: str


def read_display(path: str | os.PathLike[str], max_px: int, *, bounds: tuple[float, float, float, float] | None = None,
                 crs: pyproj.CRS | None = None, north_up: bool = False, what: str = "raster") -> DisplayRaster | None:
    """Read a raster for display, decimated by the smallest integer factor ``k`` that brings its longer side to at
    most ``max_px`` pixels (each display pixel the average of ``k x k`` file pixels; GDAL uses the file's overviews
    when it has them), so that even huge files need little memory.

    ``bounds`` (left, bottom, right, top; map units, of ``crs`` when warped): read only the whole pixels within them
    (None: the whole raster; the result is None when they do not overlap it). ``crs``: reproject to it when the file
    has another CRS (one without is taken to be in it). ``north_up``: reproject a rotated grid to a north-up one.
    ``what`` starts the messages (the option or the kind of file).

    Raises:
        InputError: as :func:`open_raster`, or the file cannot be read.
    """
    from rasterio.enums import Resampling
    from rasterio.errors import WindowError
    from rasterio.vrt import WarpedVRT
    from rasterio.windows import Window, from_bounds

    from trafficgeo.crs import same_horizontal_crs

    src, grid = open_raster(path, what)
    with src:
        try:
            src_crs = to_pyproj_crs(src.crs)
            warp = (crs is not None and src_crs is not None and not same_horizontal_crs(src_crs, crs)) or \
                (north_up and (grid.b != 0 or grid.d != 0))
            if warp:
                extra = {} if grid == src.transform else {"src_transform": grid}
                ds = WarpedVRT(src, crs=crs.to_wkt() if (crs is not None and src_crs is not None) else src.crs,
                               resampling=Resampling.bilinear, **extra)
                grid = ds.transform
            else:
                ds = src
            try:
                full = Window(0, 0, ds.width, ds.height)
                win = full
                if bounds is not None:
                    try:
                        win = from_bounds(*bounds, transform=grid).intersection(full)
                    except WindowError:
                        return None
                    c0, r0 = math.floor(win.col_off), math.floor(win.row_off)
                    win = Window(c0, r0, math.ceil(win.col_off + win.width) - c0,
                                 math.ceil(win.row_off + win.height) - r0)
                    if win.width < 1 or win.height < 1:
                        return None
                k = max(1, math.ceil(max(win.width, win.height) / max_px))
                shape = (math.ceil(win.height / k), math.ceil(win.width / k))
                idx = list(range(1, min(ds.count, 4) + 1)) if ds.count >= 3 else [1]
                resampling = Resampling.average if k > 1 else Resampling.nearest
                data = ds.read(idx, window=win, out_shape=(len(idx), *shape), resampling=resampling, masked=False)
                mask = ds.read_masks(1, window=win, out_shape=shape, resampling=Resampling.nearest)
            finally:
                if ds is not src:
                    ds.close()
        except RasterioError as exc:
            raise InputError(f"{what} {path}: could not be read ({' '.join(str(exc).split())}); check the "
                             "file") from None
        nodata = src.nodata
    cols, rows = int(win.width), int(win.height)
    offset = (int(win.col_off), int(win.row_off))
    transform = grid @ Affine.translation(*offset) @ Affine.scale(cols / shape[1], rows / shape[0])
    out_crs = crs if (warp and crs is not None and src_crs is not None) else src_crs
    (left, right), (bottom, top) = pixel_to_map(grid, [offset[0], offset[0] + cols], [offset[1] + rows, offset[1]])
    return DisplayRaster(data, mask > 0, transform, out_crs, nodata, k, grid, (*offset, cols, rows),
                         (float(left), float(bottom), float(right), float(top)), str(path))
