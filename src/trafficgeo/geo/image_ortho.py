"""An orthophoto from a georeferenced image that is not a GeoTIFF: a PNG/JPG (any GDAL-readable image) with a world
file, or with three or more control points (pixel -> map), and a CRS given by the user.

World files (``.pgw``, ``.jgw``, ``.wld``, ...) are six lines ``A, D, B, E, C, F``: ``x = A col + B row + C`` and
``y = D col + E row + F``, where ``(col, row)`` are pixel *centres* on integers, so ``(C, F)`` is the centre of the
top-left pixel, not its corner (a half-pixel shift if read the other way). They carry no CRS: give it.

Control points (a CSV, :func:`read_control_points`) tie image positions to map coordinates (from four points on, a
projective fit resamples a perspective image onto a north-up grid: :mod:`trafficgeo.geo.image_projective`; the
affine below is for three): columns ``u, v`` (pixels,
``(0, 0)`` the centre of the top-left pixel, as everywhere in trafficgeo) or ``corner`` (``top-left``, ``top-right``,
``bottom-right``, ``bottom-left``: the outer corners of the image), and ``x, y`` in the CRS. The pixel -> map affine
(six parameters) is their least-squares fit; with more than three points its RMS residual tells how well an affine
describes the image (a photo that is not an orthophoto, or points mistyped, show as metres).

With the image's camera (pose, lens) and the surface, the image is orthorectified instead: each ground cell takes
the colour where the camera sees it (:mod:`trafficgeo.geo.camera_ortho`); control points then check it.

Everything ends as a :class:`~trafficgeo.geo.raster.GeoRaster` (corner-convention transform) that
:func:`~trafficgeo.geo.raster.write_geotiff` writes, so every command that takes an orthophoto GeoTIFF takes it.
"""

from __future__ import annotations

import csv
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine
from numpy.typing import ArrayLike
from rasterio.errors import NotGeoreferencedWarning, RasterioError

from trafficgeo.camera.model import Camera
from trafficgeo.crs import is_geographic, parse_crs
from trafficgeo.errors import InputError
from trafficgeo.geo.camera_ortho import CheckPoints, check_points, orthorectify_with_camera
from trafficgeo.geo.image_projective import ProjectiveFit, check_control_points, fit_projective, orthorectify
from trafficgeo.geo.mapping import Surface
from trafficgeo.geo.raster import GeoRaster, pixel_to_map, read_world_file, world_file_candidates, write_geotiff

CORNER_NAMES = ("top-left", "top-right", "bottom-right", "bottom-left")


@dataclass(frozen=True)
class ControlFit:
    """The pixel -> map affine fitted to control points.

    Attributes:
        transform: corner-convention ``(col, row)`` -> ``(x, y)`` (rasterio's), CRS units.
        n_points: control points used.
        rmse: RMS distance (CRS units) between the points' map coordinates and the fitted affine's; 0 for 3 points.
        max_error: the largest of those distances (CRS units).
    """

    transform: Affine
    n_points: int
    rmse: float
    max_error: float


def fit_affine(pixels: ArrayLike, world: ArrayLike) -> ControlFit:
    """Least-squares affine from ``pixels`` (N, 2: u, v with pixel centres on integers) to ``world`` (N, 2, CRS units).

    Raises:
        InputError: fewer than 3 points, or points on one line in the image (no unique affine).
    """
    uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    xy = np.asarray(world, dtype=np.float64).reshape(-1, 2)
    check_control_points(uv, xy, 3, "an affine")
    n = uv.shape[0]
    origin = xy.mean(axis=0)  # map coordinates of 5e6 keep their precision
    corner = uv + 0.5  # pixel centres -> rasterio's corner convention
    design = np.column_stack([corner, np.ones(n)])
    spread = np.linalg.svd(corner - corner.mean(axis=0), compute_uv=False)
    if spread[-1] <= 1e-6 * max(spread[0], 1.0):
        raise InputError("control: the control points lie on one line in the image; add a point off that line",
                         parameters=("control",))
    coef, *_ = np.linalg.lstsq(design, xy - origin, rcond=None)
    (a, d), (b, e), (c, f) = coef
    transform = Affine(a, b, c + origin[0], d, e, f + origin[1])
    residual = np.linalg.norm(design @ coef - (xy - origin), axis=1)
    if not (np.all(np.isfinite(coef)) and abs(a * e - b * d) > 0):
        raise InputError("control: the control points give no usable map position for the pixels (repeated map "
                         "coordinates?); fix the table", parameters=("control",))
    return ControlFit(transform, n, float(np.sqrt(np.mean(residual ** 2))), float(residual.max()))


def read_control_points(path: str | os.PathLike[str], image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) and map coordinates (N, 2) from a control-point CSV (see the module docstring).

    ``image_size`` (width, height) [px] places the named corners: top-left is pixel (-0.5, -0.5), bottom-right
    (W - 0.5, H - 0.5).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"control {p}: file not found; give a CSV with u,v,x,y (or corner,x,y) columns",
                         parameters=("control",))
    try:
        with p.open(newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.DictReader(fh))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"control {p}: not a text CSV ({type(exc).__name__}); give a CSV with u,v,x,y (or "
                         "corner,x,y) columns", parameters=("control",)) from None
    if not rows:
        raise InputError(f"control {p}: no rows; give a CSV with u,v,x,y (or corner,x,y) columns",
                         parameters=("control",))
    cols = {k.strip().lower(): k for k in rows[0] if k is not None}
    has_uv, has_corner = {"u", "v"} <= set(cols), "corner" in cols
    if not ({"x", "y"} <= set(cols)) or not (has_uv or has_corner):
        raise InputError(f"control {p}: columns {', '.join(cols)}; need x, y and either u, v (pixels) or corner "
                         f"({', '.join(CORNER_NAMES)})", parameters=("control",))
    w, h = image_size
    places = {"top-left": (-0.5, -0.5), "top-right": (w - 0.5, -0.5), "bottom-right": (w - 0.5, h - 0.5),
              "bottom-left": (-0.5, h - 0.5)}
    uv, xy = [], []
    for i, row in enumerate(rows, start=2):
        try:
            name = (row.get(cols["corner"]) or "").strip().lower() if has_corner else ""
            if name:
                if name not in places:
                    raise InputError(f"control {p}, line {i}: corner '{name}' is not one of "
                                     f"{', '.join(CORNER_NAMES)}", parameters=("control",))
                uv.append(places[name])
            else:
                if not has_uv:
                    raise ValueError
                uv.append((float(row[cols["u"]]), float(row[cols["v"]])))
            xy.append((float(row[cols["x"]]), float(row[cols["y"]])))
        except InputError:
            raise
        except (TypeError, ValueError):
            raise InputError(f"control {p}, line {i}: needs numbers in u, v (or a corner name) and x, y",
                             parameters=("control",)) from None
    return np.array(uv, dtype=np.float64), np.array(xy, dtype=np.float64)


MAX_IMAGE_BYTES = 1_000_000_000  # decoded size of an image read whole (a PNG of a few hundred kB can hold GBs)


MODELS = ("auto", "affine", "projective")


def read_image_ortho(image: str | os.PathLike[str], crs: object, *, world_file: str | os.PathLike[str] | None = None,
                     control: str | os.PathLike[str] | None = None, model: str = "auto",
                     camera: Camera | None = None, surface: Surface | None = None,
                     resolution_m: float | None = None, max_distance_m: float | None = None
                     ) -> tuple[GeoRaster, ControlFit | ProjectiveFit | CheckPoints | None]:
    """The orthophoto of ``image`` in the projected ``crs``: georeferenced by ``world_file``, or by the control-point
    CSV ``control``, or else by a world file beside it (``.pgw`` for ``.png``, ``.jgw`` for ``.jpg``, ``.wld``); or
    orthorectified through the image's ``camera`` onto ``surface`` (:mod:`trafficgeo.geo.camera_ortho`; cells of
    ``resolution_m`` metres, within ``max_distance_m`` of the camera), when ``control`` points are then given they
    check it.

    Returns the raster and, for control points, the fit (with its residuals), or with a camera their check.
    ``model`` says how control points are fitted: "affine" (the image is georeferenced as it is), "projective" (a
    homography, the image resampled onto a north-up grid: :mod:`trafficgeo.geo.image_projective`), or "auto":
    projective from 4 points on, affine from 3.

    Raises:
        InputError: no such image or not an image GDAL reads, no CRS or a geographic one, both ``world_file`` and
            ``control``, no georeferencing, bad world file or control points, a camera without a surface, of
            another CRS or another image size.
    """
    p = Path(image)
    target = parse_crs(crs) if crs is not None else None
    if target is None or is_geographic(target):
        raise InputError(f"`crs`: {p} needs a projected CRS for its map coordinates, e.g. EPSG:32633 (world files "
                         "and control points carry none)", parameters=("crs",))
    if model not in MODELS:
        raise InputError(f"model {model!r} is not one of {', '.join(MODELS)}", parameters=("model",))
    if world_file is not None and control is not None:
        raise InputError("give the world file or the control points, not both", parameters=("world_file", "control"))
    if camera is not None:
        if world_file is not None:
            raise InputError("give the camera or a world file, not both (the camera places every pixel)",
                             parameters=("camera", "world_file"))
        if surface is None:
            raise InputError("camera: an orthophoto from a camera needs the ground it looks at: give `surface` (a "
                             "DEM, a point cloud or a constant height)", parameters=("camera", "surface"))
        if camera.crs is not None and not parse_crs(camera.crs).equals(target):
            raise InputError(f"camera: its CRS ({camera.crs_text}) is not `crs` {crs}; give the camera in the "
                             "orthophoto's CRS", parameters=("camera", "crs"))
    if not p.is_file():
        raise InputError(f"image {p}: file not found; check the path")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(p) as ds:
                need = ds.count * ds.width * ds.height * np.dtype(ds.dtypes[0]).itemsize
                if need > MAX_IMAGE_BYTES:  # told by the header, before a small compressed file decodes to GBs
                    raise InputError(f"image {p}: {ds.width} x {ds.height} px x {ds.count} bands would take "
                                     f"{need / 1e9:.1f} GB decoded, more than {MAX_IMAGE_BYTES / 1e9:g} GB; give a "
                                     "smaller image (e.g. cut to the camera's view) or a tiled GeoTIFF")
                data = ds.read()
                nodata = ds.nodata
    except RasterioError as exc:
        raise InputError(f"image {p} is not an image GDAL can read ({' '.join(str(exc).split())[:100]}); give a "
                         "PNG, JPEG or TIFF") from None
    fit: ControlFit | ProjectiveFit | None = None
    if camera is not None:
        grid, transform = orthorectify_with_camera(data, camera, surface, resolution_m=resolution_m,
                                                   max_distance_m=max_distance_m)
        checks = None
        if control is not None:
            uv, xy = read_control_points(control, (data.shape[2], data.shape[1]))
            checks = check_points(camera, surface, uv, xy)
        return GeoRaster(grid, transform, target, 0 if nodata is None else nodata, (), str(p)), checks
    if control is not None:
        uv, xy = read_control_points(control, (data.shape[2], data.shape[1]))
        if model == "projective" or (model == "auto" and len(uv) >= 4):
            pfit = fit_projective(uv, xy)
            grid, transform = orthorectify(data, pfit, uv, xy)
            return GeoRaster(grid, transform, target, 0 if nodata is None else nodata, (), str(p)), pfit
        fit = fit_affine(uv, xy)
        transform = fit.transform
    elif world_file is not None:
        wf = Path(world_file)
        if not wf.is_file():
            raise InputError(f"world_file {wf}: file not found; check the path", parameters=("world_file",))
        transform = read_world_file(wf)
    else:
        found = world_file_candidates(p)
        if not found:
            raise InputError(f"image {p}: no world file beside it ({p.with_suffix('.wld').name} or the like); give "
                             "`world_file` or control points (`control`)", parameters=("world_file", "control"))
        transform = read_world_file(found[0])
    return GeoRaster(data, transform, target, nodata, (), str(p)), fit


def image_to_geotiff(image: str | os.PathLike[str], output: str | os.PathLike[str], crs: object, *,
                     world_file: str | os.PathLike[str] | None = None,
                     control: str | os.PathLike[str] | None = None, model: str = "auto",
                     camera: Camera | None = None, surface: Surface | None = None,
                     resolution_m: float | None = None, max_distance_m: float | None = None
                     ) -> tuple[GeoRaster, ControlFit | ProjectiveFit | CheckPoints | None]:
    """Write the orthophoto of :func:`read_image_ortho` as a GeoTIFF at ``output`` (atomically); returns the same."""
    raster, fit = read_image_ortho(image, crs, world_file=world_file, control=control, model=model, camera=camera,
                                   surface=surface, resolution_m=resolution_m, max_distance_m=max_distance_m)
    write_geotiff(output, raster.data, raster.transform, raster.crs, nodata=raster.nodata)
    return raster, fit


def image_corners(raster: GeoRaster) -> np.ndarray:
    """Map coordinates (4, 2) of the outer corners of ``raster``: top-left, top-right, bottom-right, bottom-left."""
    cols = np.array([0.0, raster.cols, raster.cols, 0.0])
    rows = np.array([0.0, 0.0, raster.rows, raster.rows])
    x, y = pixel_to_map(raster.transform, cols, rows)
    return np.column_stack([x, y])
