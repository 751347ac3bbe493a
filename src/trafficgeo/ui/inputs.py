"""What ``trafficgeo gcp-ui`` works on: the video frame, the orthophoto and the ground (DEM or lidar) heights.

Conventions
-----------
* **Frame pixels** ``(u, v)``: the camera's convention (:mod:`trafficgeo.camera.model`): ``(0, 0)`` is the *centre*
  of the top-left pixel, u right, v down; a ``W x H`` frame spans ``-0.5 <= u <= W - 0.5``,
  ``-0.5 <= v <= H - 0.5``.
* **Orthophoto pixels** ``(col, row)``: the raster convention (:mod:`trafficgeo.geo.raster`): continuous positions
  with ``(0, 0)`` the top-left *corner* of the grid (pixel centres at ``+0.5``), always in the full-resolution
  grid, even when the browser is shown a downsampled image. They map to world ``(x, y)`` through the raster's
  affine transform in float64 (here, never in the browser).
* **World** ``(x, y, z)``: the orthophoto's projected CRS (CRS units, metres or feet), float64.

Every problem a user can fix raises :class:`~trafficgeo.errors.InputError` with a one-line message.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pyproj
from affine import Affine
from numpy.typing import ArrayLike

from trafficgeo.crs import crs_label, is_geographic, same_horizontal_crs
from trafficgeo.errors import InputError
from trafficgeo.geo.georef import GroundCheckOptions, check_gcp_heights
from trafficgeo.geo.raster import map_to_pixel, pixel_size, pixel_to_map, read_dem
from trafficgeo.geo.raster_display import DisplayRaster, display_rgb, read_display
from trafficgeo.geo.surface import DEMSurface

#: Largest side (px) of the orthophoto image sent to the browser; larger orthophotos are shown block-averaged.
MAX_DISPLAY_PX = 8192
#: Resolution (m) of the ground DEM made from a point cloud to draw the footprint and grid; Z lookups use the points.
CLOUD_DEM_RESOLUTION_M = 1.0


def _png(image: np.ndarray, what: str) -> bytes:
    """PNG bytes of an 8-bit BGR(A) or grey image (fast compression: the file only travels to the browser)."""
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise InputError(f"{what}: OpenCV could not encode it as PNG for the browser")
    return buf.tobytes()


# ------------------------------------------------------------------------------------------------------- frame
@dataclass(frozen=True, eq=False)
class FrameImage:
    """The video frame the GCP pixels are picked on.

    Attributes:
        image: (H, W, 3) uint8 BGR, upright as a player shows it.
        png: the same image as PNG bytes (what the browser shows, full resolution).
        source: where it came from, for messages ("frame.png", "video.mp4 at 12.000 s (frame 300)").
        video: the video it was taken from (None for an image file), and ``time_s`` its time in it (s): the
            orthophoto refinement takes a still without traffic from around that time.
    """

    image: np.ndarray
    png: bytes
    source: str
    video: Path | None = None
    time_s: float | None = None

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.image.shape[1]), int(self.image.shape[0])

    def contains(self, u: float, v: float) -> bool:
        """Whether pixel (u, v) lies in the frame (pixel-centre convention, edges included)."""
        w, h = self.size
        return -0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5

    @classmethod
    def from_array(cls, image: np.ndarray, source: str, *, video: Path | None = None,
                   time_s: float | None = None) -> FrameImage:
        """From an (H, W, 3) uint8 BGR array (or (H, W) grey); ``video``, ``time_s`` where it was taken from."""
        img = np.asarray(image)
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        if img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype != np.uint8 or min(img.shape[:2]) < 2:
            raise InputError(f"{source}: expected an 8-bit colour image of at least 2x2 pixels, got an array of "
                             f"shape {img.shape} and type {img.dtype}")
        img = np.ascontiguousarray(img[:, :, :3])
        return cls(image=img, png=_png(img, source), source=source, video=video, time_s=time_s)


def load_frame(path: str | Path) -> FrameImage:
    """Read a frame image (PNG, JPEG, TIFF, ... anything OpenCV reads), upright per its EXIF orientation."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"frame {p} does not exist; check the path, or grab one with 'trafficgeo frame VIDEO -o "
                         "frame.png'")
    if p.is_dir():
        raise InputError(f"frame {p} is a folder, not an image; give the path of a PNG or JPEG frame")
    image = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"frame {p} is not an image OpenCV can read; give a PNG or JPEG frame (e.g. from "
                         "'trafficgeo frame VIDEO -o frame.png')")
    return FrameImage.from_array(image, str(p))


def load_video_frame(path: str | Path, at_s: float) -> FrameImage:
    """The frame of a video shown at ``at_s`` seconds (:func:`trafficgeo.video.reader.read_frame_at`)."""
    from trafficgeo.video.reader import read_frame_at

    if not (math.isfinite(at_s) and at_s >= 0):
        raise InputError(f"at_s {at_s:g} must be a time in seconds from the start of the video, >= 0",
                         parameters=("at_s",))
    picked = read_frame_at(path, at_s)
    return FrameImage.from_array(picked.image, f"{path} at {picked.time_s:.3f} s (frame {picked.index})",
                                 video=Path(path), time_s=float(picked.time_s))


# --------------------------------------------------------------------------------------------------- orthophoto
def _to_display(raster: DisplayRaster) -> np.ndarray:
    """8-bit BGRA image of a raster: colours from :func:`~trafficgeo.geo.raster_display.display_rgb`, band 4 of 8-bit
    rasters as alpha; nodata cells are transparent."""
    data = raster.data
    n = data.shape[0]
    valid = np.ones(data.shape[1:], dtype=bool)
    for b in range(min(n, 3)):
        band = data[b]
        if np.issubdtype(band.dtype, np.floating):
            valid &= np.isfinite(band)
        if raster.nodata is not None and not math.isnan(raster.nodata):
            valid &= band != raster.nodata
    if data.dtype != np.uint8 and not valid.any():
        raise InputError(f"orthophoto {raster.path}: every cell is nodata; check the file")
    rgb = display_rgb(data, valid)
    alpha = np.where(valid, 255, 0).astype(np.uint8)
    if n >= 4 and data.dtype == np.uint8:
        alpha = np.minimum(alpha, data[3])
    return np.dstack([rgb[..., 2], rgb[..., 1], rgb[..., 0], alpha])


@dataclass(frozen=True, eq=False)
class Orthophoto:
    """The georeferenced orthophoto: its full-resolution grid for coordinates, a (maybe downsampled) PNG to show.

    Attributes:
        transform: affine map of full-resolution raster positions ``(col, row)`` (corner convention) to world
            ``(x, y)`` in CRS units.
        crs: the orthophoto's projected CRS, or None (local coordinates).
        cols, rows: size of the full-resolution grid (px).
        png: the display image (RGBA); it covers ``display_extent`` (cols, rows) of the full-resolution grid.
        display_factor: 1, or how many times the display image is smaller than the grid (orthophotos above
            :data:`MAX_DISPLAY_PX` on a side).
        source: the file, for messages.
    """

    transform: Affine
    crs: pyproj.CRS | None
    cols: int
    rows: int
    png: bytes
    display_factor: int
    display_extent: tuple[int, int]
    source: str

    @property
    def resolution(self) -> tuple[float, float]:
        """(xres, yres): pixel width and height in CRS units."""
        return pixel_size(self.transform)

    def contains(self, col: float, row: float) -> bool:
        """Whether raster position (col, row) (corner convention) lies on the orthophoto."""
        return 0.0 <= col <= self.cols and 0.0 <= row <= self.rows

    def pixel_to_map(self, col: ArrayLike, row: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """World (x, y) in CRS units (float64 arrays) of raster positions (col, row) (corner convention)."""
        return pixel_to_map(self.transform, col, row)

    def map_to_pixel(self, x: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Raster positions (col, row) (corner convention, float64 arrays) of world (x, y) in CRS units; the
        coordinates are differenced against the transform origin first, so 5e6-sized ones keep their precision."""
        return map_to_pixel(self.transform, x, y)

    def pixel_to_world(self, col: float, row: float) -> tuple[float, float]:
        """World (x, y) in CRS units of one raster position (col, row) (corner convention)."""
        x, y = self.pixel_to_map(col, row)
        return float(x), float(y)

    def world_to_pixel(self, x: float, y: float) -> tuple[float, float]:
        """Raster position (col, row) (corner convention) of one world point (x, y) in CRS units."""
        col, row = self.map_to_pixel(x, y)
        return float(col), float(row)

    def world_corners(self) -> np.ndarray:
        """(4, 2) world (x, y) of the grid's corners (top-left, top-right, bottom-right, bottom-left)."""
        x, y = self.pixel_to_map([0, self.cols, self.cols, 0], [0, 0, self.rows, self.rows])
        return np.column_stack([x, y])

    @property
    def note(self) -> str:
        """One line about the display image (empty at full resolution)."""
        if self.display_factor == 1:
            return ""
        return (f"the orthophoto ({self.cols}x{self.rows} px) is shown downsampled {self.display_factor}x "
                f"(at most {MAX_DISPLAY_PX} px a side); picked coordinates still use the full-resolution grid")

    @classmethod
    def from_display(cls, display: DisplayRaster) -> Orthophoto:
        """From an orthophoto read for display (:func:`~trafficgeo.geo.raster_display.read_display`, whole raster)."""
        crs = display.crs
        if crs is not None and is_geographic(crs):
            raise InputError(f"orthophoto {display.path} is in the geographic CRS {crs_label(crs)} (degrees); "
                             "reproject it to a projected CRS, e.g. gdalwarp -t_srs EPSG:32633 in.tif out.tif")
        _, _, cols, rows = display.window
        return cls(transform=display.grid_transform, crs=crs, cols=cols, rows=rows,
                   png=_png(_to_display(display), display.path), display_factor=display.factor,
                   display_extent=(cols, rows), source=display.path)


def load_ortho(path: str | Path) -> Orthophoto:
    """Read a georeferenced orthophoto (a GeoTIFF, or any GDAL raster with a geotransform or a world file).

    Orthophotos above :data:`MAX_DISPLAY_PX` on a side are read decimated by an integer factor
    (:func:`~trafficgeo.geo.raster_display.read_display`), so even huge files need little memory; coordinates always use
    the full-resolution grid.
    """
    display = read_display(path, MAX_DISPLAY_PX, what="orthophoto")
    assert display is not None  # no bounds: the whole raster
    return Orthophoto.from_display(display)


# ------------------------------------------------------------------------------------------------------- ground
@dataclass(frozen=True)
class GroundSample:
    """The ground around one picked point (from :func:`trafficgeo.geo.georef.check_gcp_heights`).

    Attributes:
        z: ground elevation at (x, y) (CRS units), NaN where there is none.
        spread_m: local roughness (m): robust standard deviation (1.4826 MAD) of the lidar ground points within
            ``radius_m``, or of the DEM sampled on two rings of ``radius_m / 2`` and ``radius_m``.
        slope_deg: slope of the DEM at (x, y), degrees (NaN for a point cloud).
        points: lidar ground points within the radius (-1 for a DEM).
        dz_m: the pair's z minus the ground (m); 0 when z follows the ground.
        check: ``ok``, ``rough`` (spread above the roughness limit: a kerb, verge or vegetation),
            ``disagrees`` (|dz| above the tolerance), ``outside`` (no ground data here) or ``empty`` (no ground
            points within the radius).
    """

    z: float
    spread_m: float
    slope_deg: float
    points: int
    dz_m: float
    check: str


class Ground:
    """Ground heights for picked points: a DEM, or the ground points of a lidar cloud.

    Z lookups of a cloud use its ground points directly (median within ``options.radius_m``). :attr:`surface`
    (a :class:`~trafficgeo.geo.surface.DEMSurface`: the DEM, or a ground DEM made from the cloud on first use) draws
    the footprint and the grid and gives a DEM's slope.
    """

    def __init__(self, kind: str, source: str, crs: pyproj.CRS | None, surface: DEMSurface | Callable[[], DEMSurface],
                 index: object | None = None, options: GroundCheckOptions | None = None) -> None:
        self.kind = kind
        self.source = source
        self.crs = crs
        self._surface = surface
        self.index = index
        self.options = options or GroundCheckOptions()

    @property
    def surface(self) -> DEMSurface:
        if not isinstance(self._surface, DEMSurface):
            self._surface = self._surface()
        return self._surface

    def middle_z(self) -> float:
        """A typical ground elevation (CRS units): the median of the ground points, or the DEM's mid-range."""
        if self.index is not None:
            return float(np.median(self.index.xyz[:, 2]))  # type: ignore[attr-defined]
        return 0.5 * (self.surface.zmin + self.surface.zmax)

    def describe(self) -> str:
        if self.kind == "cloud":
            return f"lidar ground points of {self.source} (median within {self.options.radius_m:g} m)"
        return f"DEM {self.source}"

    def sample(self, x: ArrayLike, y: ArrayLike, z: ArrayLike | None = None) -> list[GroundSample]:
        """The ground at world points (N,) in CRS units; ``z`` (NaN = follow the ground) is checked against it.

        The slope is given for DEMs (NaN for clouds, whose roughness is the spread of their points).
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        y = np.asarray(y, dtype=np.float64).reshape(-1)
        zz = np.full(x.shape, np.nan) if z is None else np.asarray(z, dtype=np.float64).reshape(-1)
        if x.size == 0:
            return []
        table = pd.DataFrame({"x": x, "y": y, "z": zz})
        ground = self.index if self.index is not None else self.surface
        out = check_gcp_heights(table, ground, self.crs, self.options)
        slope = np.full(x.size, np.nan)
        if self.index is None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                normal = self.surface.normal(x, y)
                slope = np.degrees(np.arccos(np.clip(normal[:, 2], -1.0, 1.0)))
        points = out["ground_points"].to_numpy() if "ground_points" in out.columns else np.full(x.size, -1)
        samples = []
        for i in range(x.size):
            check = str(out["z_check"].iloc[i])
            dz = float(out["dz_m"].iloc[i])
            samples.append(GroundSample(
                z=float(out["z_ground"].iloc[i]), spread_m=float(out["ground_spread_m"].iloc[i]),
                slope_deg=float(slope[i]), points=int(points[i]), dz_m=0.0 if np.isnan(zz[i]) else dz,
                check="ok" if check == "filled" else check))
        return samples


def _check_same_crs(what: str, path: Path, crs: pyproj.CRS | None, ortho_crs: pyproj.CRS | None) -> None:
    if crs is not None and is_geographic(crs):
        raise InputError(f"{what} {path} is in the geographic CRS {crs_label(crs)} (degrees); reproject it to the "
                         "orthophoto's projected CRS")
    if crs is not None and ortho_crs is not None and not same_horizontal_crs(crs, ortho_crs):
        raise InputError(f"{what} {path}: CRS {crs_label(crs)} differs from the orthophoto's {crs_label(ortho_crs)}; "
                         "reproject it (gdalwarp -t_srs / pdal translate) to the orthophoto's CRS")


def load_ground(*, dem: str | Path | None = None, cloud: str | Path | None = None,
                ortho_crs: pyproj.CRS | None = None, options: GroundCheckOptions | None = None) -> Ground | None:
    """The ground from a DEM (GeoTIFF) or a LAS/LAZ point cloud in the orthophoto's CRS; None when neither."""
    if dem is not None and cloud is not None:
        raise InputError("give either `dem` or `cloud` for the GCP heights, not both", parameters=("dem", "cloud"))
    if dem is not None:
        p = Path(dem)
        raster = read_dem(p)
        _check_same_crs("DEM", p, raster.crs, ortho_crs)
        try:
            surface = DEMSurface.from_raster(raster, name=p.name)
        except ValueError as exc:
            raise InputError(f"DEM {p}: {exc}") from None
        return Ground("dem", str(p), raster.crs or ortho_crs, surface, None, options)
    if cloud is not None:
        from trafficgeo.geo.pointcloud import GroundIndex, cloud_to_dem, read_point_cloud

        p = Path(cloud)
        pc = read_point_cloud(p)
        _check_same_crs("point cloud", p, pc.crs, ortho_crs)
        crs = pc.crs or ortho_crs
        if pc.crs is None and crs is not None:
            from trafficgeo.geo.pointcloud import PointCloud

            pc = PointCloud(pc.xyz, pc.classification, pc.rgb, crs, pc.path)
        index = GroundIndex.from_cloud(pc)

        def ground_dem() -> DEMSurface:
            dem_raster = cloud_to_dem(pc, CLOUD_DEM_RESOLUTION_M)
            return DEMSurface.from_raster(dem_raster, name=f"{p.name} (ground DEM {CLOUD_DEM_RESOLUTION_M:g} m)")

        return Ground("cloud", str(p), crs, ground_dem, index, options)
    return None
