"""Georeferenced rasters (orthophotos and DEMs) read and written with rasterio.

Conventions
-----------
* ``GeoRaster.data`` is ``(bands, rows, cols)``. Band indices in this module are 0-based (rasterio's are 1-based).
* ``transform`` follows rasterio/GDAL: it maps the continuous pixel position ``(col, row)`` of a pixel *corner* to
  map ``(x, y)``. The top-left corner of the grid is ``(0, 0)``; the centre of pixel ``[r, c]`` is
  ``(c + 0.5, r + 0.5)``. (OpenCV and :mod:`trafficgeo.camera` put pixel centres on integers instead.)
* Map coordinates are float64 in the units of ``crs`` (metres or feet; :func:`trafficgeo.crs.metres_per_unit`).
  Large coordinates (5e6) are differenced against the transform origin before anything else, so they keep
  float64 precision.
* DEMs (:func:`read_dem`) are float64 with NaN where the file has nodata; their elevation unit is whatever the file
  stores (normally the CRS's linear unit).

World files (``.wld``, ``.jgw``, ``.pgw``, ``.tfw`` ...) are six lines ``A, D, B, E, C, F`` where ``(C, F)`` is the
*centre* of the upper-left pixel: ``x = A col + B row + C`` with ``(col, row)`` pixel centres on integers. GDAL reads
them itself; :func:`read_raster` parses them only when GDAL reports no georeferencing.

Reading a raster decimated for display (and its colours) is :mod:`trafficgeo.geo.raster_display`.
"""

from __future__ import annotations

import errno
import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj
import rasterio
from affine import Affine
from numpy.typing import ArrayLike, DTypeLike
from rasterio.errors import NotGeoreferencedWarning, RasterioError, RasterioIOError, WindowError
from rasterio.windows import Window

from trafficgeo.crs import crs_label, is_geographic, parse_crs, utm_crs_for
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_path

__all__ = ["GeoRaster", "map_to_pixel", "open_raster", "pixel_size", "pixel_to_map", "read_dem", "read_raster",
           "write_geotiff"]

#: World-file suffixes tried beside an image, besides the ``<ext[0]><ext[-1]>w`` and ``<ext>w`` forms.
_WORLD_SUFFIXES = (".wld",)
_TILE = 256


def _readonly(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (the caller's array stays writable)."""
    view = a.view()
    view.flags.writeable = False
    return view


def _as_affine(transform: object) -> Affine:
    if isinstance(transform, Affine):
        return transform
    values = tuple(float(v) for v in transform)  # type: ignore[attr-defined]
    if len(values) not in (6, 9):
        raise ValueError(f"transform must be an affine.Affine or 6 numbers (a, b, c, d, e, f), got {len(values)}")
    return Affine(*values[:6])


def to_pyproj_crs(crs: object) -> pyproj.CRS | None:
    """pyproj CRS from a pyproj CRS, rasterio CRS, EPSG/WKT/PROJ text or None."""
    if crs is None or isinstance(crs, pyproj.CRS):
        return crs
    if isinstance(crs, rasterio.crs.CRS):
        return pyproj.CRS.from_wkt(crs.to_wkt())
    return parse_crs(crs)  # type: ignore[arg-type]


# ---------------------------------------------------------------------- pixel <-> map
def pixel_to_map(transform: Affine, col: ArrayLike, row: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Continuous pixel ``(col, row)`` (corner convention) -> map ``(x, y)`` in CRS units through ``transform``,
    float64, vectorized."""
    t = transform
    c = np.asarray(col, dtype=np.float64)
    r = np.asarray(row, dtype=np.float64)
    return t.c + (t.a * c + t.b * r), t.f + (t.d * c + t.e * r)


def map_to_pixel(transform: Affine, x: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Map ``(x, y)`` (CRS units) -> continuous pixel ``(col, row)`` (corner convention) through ``transform``,
    float64, vectorized. The coordinates are differenced against the transform's origin first, so 5e6-sized ones
    keep their precision."""
    t = transform
    dx = np.asarray(x, dtype=np.float64) - t.c
    dy = np.asarray(y, dtype=np.float64) - t.f
    det = t.a * t.e - t.b * t.d
    return (t.e * dx - t.b * dy) / det, (t.a * dy - t.d * dx) / det


def pixel_size(transform: Affine) -> tuple[float, float]:
    """(xres, yres): pixel width and height of ``transform``, positive, in CRS units."""
    t = transform
    return float(math.hypot(t.a, t.d)), float(math.hypot(t.b, t.e))


@dataclass(frozen=True, eq=False)
class GeoRaster:
    """An in-memory georeferenced raster.

    Attributes:
        data: ``(bands, rows, cols)`` array (a 2-D array is taken as one band). DEMs: float64, NaN = nodata.
        transform: pixel-corner ``(col, row)`` -> map ``(x, y)`` (rasterio convention; centres at ``+0.5``).
        crs: CRS of the map coordinates, or None (unknown local coordinates).
        nodata: value marking missing cells (NaN for DEMs), or None.
        descriptions: one description (or None) per band; ``()`` means none.
        path: the file it was read from, for messages.

    Equality is identity (``eq=False``): compare fields explicitly. ``data`` is stored as a read-only view.
    """

    data: np.ndarray
    transform: Affine
    crs: pyproj.CRS | None
    nodata: float | None = None
    descriptions: tuple[str | None, ...] = ()
    path: str | None = None

    def __post_init__(self) -> None:
        data = np.asarray(self.data)
        if data.ndim == 2:
            data = data[None, :, :]
        if data.ndim != 3 or min(data.shape) < 1:
            raise ValueError(f"GeoRaster data must be (bands, rows, cols) with every size >= 1, got {data.shape}")
        transform = _as_affine(self.transform)
        if not all(math.isfinite(v) for v in transform[:6]) or abs(transform.determinant) == 0:
            raise ValueError(f"GeoRaster transform must be finite and invertible, got {tuple(transform[:6])}")
        descriptions = tuple(None if d is None else str(d) for d in self.descriptions)
        if descriptions and len(descriptions) != data.shape[0]:
            raise ValueError(f"{len(descriptions)} band descriptions for {data.shape[0]} bands")
        object.__setattr__(self, "data", _readonly(data))
        object.__setattr__(self, "transform", transform)
        object.__setattr__(self, "crs", to_pyproj_crs(self.crs))
        object.__setattr__(self, "nodata", None if self.nodata is None else float(self.nodata))
        object.__setattr__(self, "descriptions", descriptions or (None,) * data.shape[0])
        object.__setattr__(self, "path", None if self.path is None else str(self.path))

    # ------------------------------------------------------------------ shape and extent
    @property
    def count(self) -> int:
        """Number of bands."""
        return int(self.data.shape[0])

    @property
    def rows(self) -> int:
        return int(self.data.shape[1])

    @property
    def cols(self) -> int:
        return int(self.data.shape[2])

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        return self.rows, self.cols

    @property
    def resolution(self) -> tuple[float, float]:
        """(xres, yres): pixel width and height, positive, in CRS units."""
        return pixel_size(self.transform)

    @property
    def is_north_up(self) -> bool:
        """True when the transform has no rotation or shear terms (``b == d == 0``)."""
        return self.transform.b == 0 and self.transform.d == 0

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(left, bottom, right, top) of the whole grid (outer pixel edges) in map units."""
        xs, ys = self.pixel_to_map([0, self.cols, self.cols, 0], [0, 0, self.rows, self.rows])
        return float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())

    @property
    def label(self) -> str:
        """The file path, or a placeholder for rasters built in memory (for messages)."""
        return self.path or "<in-memory raster>"

    # ------------------------------------------------------------------ pixel <-> map
    def map_to_pixel(self, x: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Map ``(x, y)`` (CRS units) -> continuous pixel ``(col, row)`` (corner convention), float64, vectorized."""
        return map_to_pixel(self.transform, x, y)

    def pixel_to_map(self, col: ArrayLike, row: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Continuous pixel ``(col, row)`` (corner convention) -> map ``(x, y)`` in CRS units, float64, vectorized."""
        return pixel_to_map(self.transform, col, row)

    # ------------------------------------------------------------------ derived rasters
    def _replace(self, data: np.ndarray, transform: Affine) -> GeoRaster:
        return GeoRaster(data, transform, self.crs, self.nodata, self.descriptions, self.path)

    def crop(self, bounds: tuple[float, float, float, float]) -> GeoRaster:
        """The pixels intersecting ``bounds = (left, bottom, right, top)`` (map units), with the matching transform.

        Partial overlaps are clipped to the grid. For a rotated grid the window is the pixel bounding box of the
        bounds' corners. The data are copied.

        Raises:
            InputError: the bounds are not ordered or do not overlap the raster.
        """
        left, bottom, right, top = (float(v) for v in bounds)
        if not (left < right and bottom < top) or not all(map(math.isfinite, (left, bottom, right, top))):
            raise InputError(
                f"crop of {self.label}: bounds {(left, bottom, right, top)} are not (left, bottom, right, top) "
                "with left < right and bottom < top; give them in that order"
            )
        cols, rows = self.map_to_pixel([left, right, right, left], [bottom, bottom, top, top])
        eps = 1e-9
        c0 = max(math.floor(cols.min() + eps), 0)
        c1 = min(math.ceil(cols.max() - eps), self.cols)
        r0 = max(math.floor(rows.min() + eps), 0)
        r1 = min(math.ceil(rows.max() - eps), self.rows)
        if c1 <= c0 or r1 <= r0:
            b = self.bounds
            raise InputError(
                f"crop of {self.label}: bounds {(left, bottom, right, top)} do not overlap the raster, which covers "
                f"({b[0]:.3f}, {b[1]:.3f}, {b[2]:.3f}, {b[3]:.3f}) in {crs_label(self.crs)}; give bounds inside it"
            )
        data = np.array(self.data[:, r0:r1, c0:c1], copy=True)
        return self._replace(data, self.transform @ Affine.translation(c0, r0))

    def _valid(self, band: np.ndarray) -> np.ndarray:
        """Boolean mask of the cells of ``band`` that hold data (not NaN, not ``nodata``)."""
        valid = np.ones(band.shape, dtype=bool)
        if np.issubdtype(band.dtype, np.floating):
            valid &= ~np.isnan(band)
        if self.nodata is not None and not math.isnan(self.nodata):
            valid &= band != self.nodata
        return valid

    # ------------------------------------------------------------------ sampling
    def sample_bilinear(self, x: ArrayLike, y: ArrayLike, band: int = 0) -> np.ndarray:
        """Bilinear interpolation of ``band`` (0-based) at map ``(x, y)``; float64 array of the broadcast shape.

        Interpolates between the four nearest pixel centres. Points inside the grid but within half a pixel of its
        edge use the edge pixels (constant extension). NaN outside the grid, for non-finite input, and where any of
        the four neighbours is nodata/NaN.
        """
        if not 0 <= band < self.count:
            raise InputError(
                f"{self.label} has {self.count} band(s); band {band} does not exist, use 0 to {self.count - 1}"
            )
        xa, ya = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        col, row = self.map_to_pixel(xa.ravel(), ya.ravel())
        inside = (col >= 0) & (col <= self.cols) & (row >= 0) & (row <= self.rows)
        c = np.clip(np.where(inside, col, 0.5) - 0.5, 0.0, self.cols - 1)
        r = np.clip(np.where(inside, row, 0.5) - 0.5, 0.0, self.rows - 1)
        c0 = np.minimum(np.floor(c).astype(np.intp), max(self.cols - 2, 0))
        r0 = np.minimum(np.floor(r).astype(np.intp), max(self.rows - 2, 0))
        c1 = np.minimum(c0 + 1, self.cols - 1)
        r1 = np.minimum(r0 + 1, self.rows - 1)
        fc = c - c0
        fr = r - r0
        grid = self.data[band]
        valid = self._valid(grid)
        values = np.where(valid, grid, np.nan) if not valid.all() else grid

        def at(rr: np.ndarray, cc: np.ndarray) -> np.ndarray:
            return values[rr, cc].astype(np.float64)

        top = at(r0, c0) * (1.0 - fc) + at(r0, c1) * fc
        bottom = at(r1, c0) * (1.0 - fc) + at(r1, c1) * fc
        out = top * (1.0 - fr) + bottom * fr
        out[~inside] = np.nan
        return out.reshape(xa.shape)


# ---------------------------------------------------------------------- reading
def _check_file(path: Path, what: str) -> None:
    if not path.exists():
        raise InputError(f"{what} {path} does not exist; check the path")
    if path.is_dir():
        raise InputError(f"{what} {path} is a folder, not a file; give the path of the {what}")


def world_file_candidates(path: Path) -> list[Path]:
    ext = path.suffix.lower()
    suffixes: list[str] = []
    if len(ext) >= 3:
        suffixes.append(ext[:2] + ext[-1] + "w")  # .jpg -> .jgw, .tif -> .tfw, .png -> .pgw
    if ext:
        suffixes.append(ext + "w")  # .jpg -> .jpgw
    suffixes.extend(_WORLD_SUFFIXES)
    out: list[Path] = []
    for suffix in suffixes:
        for variant in (suffix, suffix.upper()):
            candidate = path.with_suffix(variant)
            if candidate.is_file() and candidate not in out:
                out.append(candidate)
    return out


def read_world_file(path: Path) -> Affine:
    """Corner-convention transform from a world file (six numbers A, D, B, E, C, F; C, F = centre of pixel (0, 0)).

    Raises:
        InputError: the file does not hold six numbers or describes a degenerate pixel.
    """
    try:
        tokens = path.read_text(encoding="utf-8", errors="replace").split()
        values = [float(t) for t in tokens]
    except ValueError:
        raise InputError(
            f"world file {path} is not six numbers (A, D, B, E, C, F, one per line); fix or delete it"
        ) from None
    if len(values) != 6 or not all(map(math.isfinite, values)):
        raise InputError(
            f"world file {path} has {len(values)} values, need six finite numbers (A, D, B, E, C, F); fix or delete it"
        )
    a, d, b, e, c, f = values
    if a * e - b * d == 0:
        raise InputError(f"world file {path} describes a zero-area pixel (A*E - B*D = 0); fix or delete it")
    centre = Affine(a, b, c, d, e, f)
    return centre @ Affine.translation(-0.5, -0.5)


def _open_error(path: Path, exc: Exception, label: str | None = None) -> InputError:
    reason = " ".join(str(exc).split())
    if len(reason) > 100:
        reason = reason[:97] + "..."
    return InputError(f"{label or path} is not a raster GDAL can read ({reason}); give a GeoTIFF or an image with a "
                      "world file")


def _georeferencing(path: Path, transform: Affine, has_gcps: bool, label: str) -> Affine:
    """``transform`` when it georeferences the file, else the transform of a world file beside it.

    Raises:
        InputError: neither (``label`` starts the message), or the file has only ground control points.
    """
    if not (transform.is_identity or transform.determinant == 0 or not all(map(math.isfinite, transform[:6]))):
        return transform
    worlds = world_file_candidates(path)
    if worlds:
        return read_world_file(worlds[0])
    if has_gcps:
        raise InputError(f"{label}: georeferenced only by ground control points, not a geotransform; "
                         "warp it first (e.g. gdalwarp in.tif out.tif)")
    raise InputError(f"{label}: no georeferencing; add a world file (.wld) or use a GeoTIFF")


def _read(path: str | os.PathLike[str], crs: object, what: str, bands: Sequence[int] | None, *,
          heights: bool = False, bounds: tuple[float, float, float, float] | None = None) -> GeoRaster:
    """Open ``path`` with rasterio and read ``bands`` (1-based; all when None) with georeferencing. With
    ``heights``, an 8-bit image of 3 or more bands is refused: a colour image (an orthophoto) where heights go.
    With ``bounds`` (left, bottom, right, top, in the file's CRS units) only the whole pixels that touch them are
    read (a district's orthophoto need not fit in memory); an InputError when they miss the raster."""
    p = Path(path)
    _check_file(p, what)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(p) as ds:
                transform = ds.transform
                file_crs = ds.crs
                has_gcps = bool(ds.gcps[0])
                nodata = ds.nodata
                descriptions = tuple(ds.descriptions)
                if heights and ds.count >= 3 and ds.dtypes[0] == "uint8":
                    raise InputError(f"{what} {p} has {ds.count} 8-bit bands: a colour image (an orthophoto?), not "
                                     "heights; give the DEM GeoTIFF (one band of elevations), or the point cloud")
                indexes = list(bands) if bands is not None else list(range(1, ds.count + 1))
                window = None
                if bounds is not None and ds.transform != Affine.identity() and ds.transform.b == ds.transform.d == 0:
                    full = Window(0, 0, ds.width, ds.height)
                    cols, rows = map_to_pixel(ds.transform, [bounds[0], bounds[2]], [bounds[3], bounds[1]])
                    c0, r0 = math.floor(min(cols)), math.floor(min(rows))  # whole pixels touching the bounds
                    want = Window(c0, r0, math.ceil(max(cols)) - c0, math.ceil(max(rows)) - r0)
                    try:
                        window = want.intersection(full)
                    except WindowError:
                        raise InputError(f"{what} {p} does not cover the area asked for ({bounds[0]:.1f}.."
                                         f"{bounds[2]:.1f}, {bounds[1]:.1f}..{bounds[3]:.1f}); give the raster of "
                                         "this site, in its CRS") from None
                    transform = ds.transform @ Affine.translation(window.col_off, window.row_off)
                data = ds.read(indexes, window=window)
    except RasterioIOError as exc:
        raise _open_error(p, exc) from None
    except RasterioError as exc:
        raise InputError(f"{what} {p} could not be read ({' '.join(str(exc).split())}); check the file") from None
    transform = _georeferencing(p, transform, has_gcps, str(p))
    out_crs = parse_crs(crs) if crs is not None else to_pyproj_crs(file_crs)
    picked = tuple(descriptions[i - 1] for i in indexes)
    return GeoRaster(data, transform, out_crs, nodata, picked, str(p))


def read_raster(path: str | os.PathLike[str], crs: str | pyproj.CRS | None = None, *,
                bounds: tuple[float, float, float, float] | None = None) -> GeoRaster:
    """Read every band of a GeoTIFF, or of any GDAL-readable image with a world file, keeping its dtype.

    Args:
        path: the raster file.
        crs: overrides (or supplies) the CRS, as anything :func:`trafficgeo.crs.parse_crs` accepts. When omitted,
            the file's CRS is used (None if it has none, e.g. a JPEG with only a world file).
        bounds: (left, bottom, right, top) in the file's CRS units: read only the whole pixels touching them.

    Raises:
        InputError: missing file, not a raster, no georeferencing (no geotransform and no world file), or
            ``bounds`` that miss it.
    """
    return _read(path, crs, "raster", None, bounds=bounds)


def read_dem(path: str | os.PathLike[str], crs: str | pyproj.CRS | None = None) -> GeoRaster:
    """Read band 1 of a DEM as float64 ``(1, rows, cols)`` with nodata cells set to NaN (``nodata`` = NaN).

    Elevations keep the file's unit (normally the CRS's linear unit). ``crs`` as in :func:`read_raster`.

    Raises:
        InputError: as :func:`read_raster`; also when every cell is nodata, the CRS is geographic (lon/lat), or the
            file is an 8-bit colour image (an orthophoto given where the DEM goes: band 1 would be read as heights).
    """
    raw = _read(path, crs, "DEM", [1], heights=True)
    data = raw.data.astype(np.float64)
    if raw.nodata is not None and not math.isnan(raw.nodata):
        data[data == raw.nodata] = np.nan
    if not np.isfinite(data).any():
        raise InputError(
            f"DEM {raw.path}: every cell is nodata (nodata = {raw.nodata}); "
            "check the file, or its nodata value (gdalinfo shows it)"
        )
    dem = GeoRaster(data, raw.transform, raw.crs, math.nan, raw.descriptions, raw.path)
    if is_geographic(dem.crs):
        left, bottom, right, top = dem.bounds
        try:  # x, y of a geographic raster are longitude, latitude (GDAL's traditional GIS order)
            code = ":".join(utm_crs_for((left + right) / 2.0, (bottom + top) / 2.0).to_authority())
        except InputError:
            code = "EPSG:xxxx"
        raise InputError(
            f"DEM {dem.path} is in the geographic CRS {crs_label(dem.crs)} (degrees); reproject to a projected CRS, "
            f"e.g. gdalwarp -t_srs {code} {dem.path} dem_projected.tif"
        )
    return dem


# ---------------------------------------------------------------------- opening
def open_raster(path: str | os.PathLike[str], what: str = "raster") -> tuple[rasterio.io.DatasetReader, Affine]:
    """Open a raster with rasterio: the open dataset (the caller closes it) and its pixel-corner ``(col, row)`` ->
    map ``(x, y)`` transform (the file's geotransform, else a world file's). ``what`` starts the messages (the
    option or the kind of file).

    Raises:
        InputError: the file is missing, not a raster GDAL reads, or not georeferenced by a geotransform or a
            world file.
    """
    p = Path(path)
    _check_file(p, what)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            ds = rasterio.open(p)
    except RasterioError as exc:
        raise _open_error(p, exc, f"{what} {p}") from None
    try:
        return ds, _georeferencing(p, ds.transform, bool(ds.gcps[0]), f"{what} {p}")
    except InputError:
        ds.close()
        raise


# ---------------------------------------------------------------------- writing
def _rasterio_crs(crs: object) -> rasterio.crs.CRS | None:
    pj = to_pyproj_crs(crs)
    if pj is None:
        return None
    auth = pj.to_authority(min_confidence=100)
    if auth is not None and auth[0] == "EPSG":
        return rasterio.crs.CRS.from_epsg(int(auth[1]))
    return rasterio.crs.CRS.from_wkt(pj.to_wkt())


def _write_bands(dst: rasterio.io.DatasetWriter, data: np.ndarray, descriptions: Sequence[str | None]) -> None:
    """Write every band and its description to an open dataset."""
    for i in range(data.shape[0]):
        dst.write(data[i], i + 1)
        if descriptions[i] is not None:
            dst.set_band_description(i + 1, descriptions[i])


def _reads_back(path: Path, arr: np.ndarray) -> bool:
    """Whether the GeoTIFF ``path`` reads back as ``arr`` (bands, rows, cols), every block of it."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as src:
                back = src.read()
    except RasterioError:
        return False
    return back.shape == arr.shape and np.array_equal(back, arr, equal_nan=np.issubdtype(arr.dtype, np.floating))


def write_geotiff(
    path: str | os.PathLike[str],
    data: ArrayLike,
    transform: Affine,
    crs: str | pyproj.CRS | None,
    nodata: float | None = None,
    descriptions: Sequence[str | None] | None = None,
    dtype: DTypeLike | None = None,
) -> None:
    """Write a ``(bands, rows, cols)`` (or ``(rows, cols)``) array as a DEFLATE-compressed GeoTIFF, atomically.

    Floating-point data are stored as float32 and integer data in their own dtype unless ``dtype`` is given.
    Float NaN cells are written as ``nodata`` when a (non-NaN) nodata value is given. The file is tiled 256 x 256
    when both sides are >= 256 px. ``transform`` uses the rasterio corner convention; ``crs`` may be None.
    The file appears only when complete (:func:`trafficgeo.io.atomic.atomic_path`) and read back whole: a disk
    that refuses part of it (full, or a file-size limit), which libtiff reports only as a message, raises
    :class:`~trafficgeo.errors.OutputError` (the partial file removed).
    """
    arr = np.asarray(data)
    if arr.ndim == 2:
        arr = arr[None, :, :]
    if arr.ndim != 3 or min(arr.shape) < 1:
        raise ValueError(f"write_geotiff data must be (bands, rows, cols), got {arr.shape}")
    if dtype is None:
        out_dtype = np.dtype(np.float32) if np.issubdtype(arr.dtype, np.floating) else arr.dtype
    else:
        out_dtype = np.dtype(dtype)
    if out_dtype == np.bool_:
        out_dtype = np.dtype(np.uint8)
    if nodata is not None and not math.isnan(nodata) and np.issubdtype(arr.dtype, np.floating):
        arr = np.where(np.isnan(arr), nodata, arr)
    elif np.issubdtype(arr.dtype, np.floating) and not np.issubdtype(out_dtype, np.floating) and np.isnan(arr).any():
        raise ValueError("data contain NaN but the output dtype is an integer; give a nodata value")
    arr = arr.astype(out_dtype, copy=False)
    bands, rows, cols = arr.shape
    descs = tuple(descriptions) if descriptions is not None else (None,) * bands
    if len(descs) != bands:
        raise ValueError(f"{len(descs)} band descriptions for {bands} bands")
    profile: dict[str, object] = {
        "driver": "GTiff",
        "width": cols,
        "height": rows,
        "count": bands,
        "dtype": out_dtype.name,
        "transform": _as_affine(transform),
        "crs": _rasterio_crs(crs),
        "nodata": nodata,
        "compress": "deflate",
        "predictor": 3 if np.issubdtype(out_dtype, np.floating) else 2,
        "BIGTIFF": "IF_SAFER",
    }
    if rows >= _TILE and cols >= _TILE:
        profile.update(tiled=True, blockxsize=_TILE, blockysize=_TILE)
    with atomic_path(path) as tmp:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(tmp, "w", **profile) as dst:
                    _write_bands(dst, arr, descs)
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            whole = _reads_back(tmp, arr)
        except RasterioError as exc:
            raise OSError(errno.EIO, f"GDAL could not write the GeoTIFF ({' '.join(str(exc).split())})") from exc
        if not whole:  # libtiff tells a failed write only as a message: the file would look written
            raise OSError(errno.EIO, "the GeoTIFF does not read back whole: the disk did not take all of it "
                                     "(full, or over a size limit)")
