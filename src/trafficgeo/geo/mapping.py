"""Image <-> world mapping through a camera and a road surface.

``pixels_to_world`` casts the ray of each pixel (OpenCV pixel-centre convention, distortion removed) from the
camera position and intersects it with a surface (:mod:`trafficgeo.geo.surface`); ``world_to_pixels`` projects world
points and, given a surface, checks that nothing on the surface hides them. World coordinates are in the camera's
CRS and its units (x, y, z alike); lon/lat are EPSG:4326 degrees.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import pyproj
from numpy.typing import ArrayLike

from trafficgeo.camera.calibrated import CalibratedCamera, as_camera
from trafficgeo.camera.model import Camera
from trafficgeo.crs import is_geographic, metres_per_unit, projected_to_lonlat
from trafficgeo.geo.surface import (
    DEFAULT_MIN_INCIDENCE_DEG,
    OK,
    OUTSIDE_IMAGE,
    OUTSIDE_LENS,
    STATUSES,
    RayHits,
)


class Surface(Protocol):
    """What :func:`pixels_to_world` needs from a surface."""

    crs: pyproj.CRS | None

    def elevation(self, x: ArrayLike, y: ArrayLike) -> np.ndarray: ...

    def normal(self, x: ArrayLike, y: ArrayLike) -> np.ndarray: ...

    def intersect(self, origin: ArrayLike, directions: ArrayLike, height: float = 0.0,
                  min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG) -> RayHits: ...

    def describe(self) -> str: ...


@dataclass(frozen=True)
class GroundPoints:
    """Pixels mapped to the ground.

    Attributes:
        xyz: (N, 3) world points in the camera's CRS units (NaN unless status is ``ok``).
        status: (N,) names from :data:`trafficgeo.geo.surface.STATUSES`.
        distance_m: (N,) distance from the camera to the point in metres.
        incidence_deg: (N,) angle between the viewing ray and the surface (90 = looking straight down at it).
        lon, lat: (N,) EPSG:4326 degrees, or None when the camera has no CRS.
    """

    xyz: np.ndarray
    status: np.ndarray
    distance_m: np.ndarray
    incidence_deg: np.ndarray
    lon: np.ndarray | None
    lat: np.ndarray | None

    @property
    def ok(self) -> np.ndarray:
        return self.status == "ok"


@dataclass(frozen=True)
class ImagePoints:
    """World points projected into the image.

    Attributes:
        uv: (N, 2) pixels (NaN for points behind the camera).
        status: (N,) ``ok``, ``behind_camera``, ``outside_image`` or ``occluded`` (hidden by the surface).
        depth: (N,) distance in front of the camera along its optical axis, CRS units.
    """

    uv: np.ndarray
    status: np.ndarray
    depth: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        return self.status == "ok"


def camera_crs(camera: Camera) -> pyproj.CRS | None:
    """The camera's CRS as a pyproj CRS (None if it has none); the camera parsed it when it was made."""
    return camera.crs


def lonlat_of(x: np.ndarray, y: np.ndarray, crs: pyproj.CRS | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """lon/lat (EPSG:4326) of projected points, NaN where x or y is NaN; (None, None) without a projected CRS."""
    if crs is None or is_geographic(crs):
        return None, None
    return projected_to_lonlat(x, y, crs)


def pixels_to_world(camera: Camera, uv: ArrayLike, surface: Surface, *, height: float = 0.0,
                    min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG, frame_margin_px: float = 0.5,
                    with_lonlat: bool = True) -> GroundPoints:
    """Map pixels (N, 2) to the first point where their rays meet ``surface`` lifted by ``height`` (CRS units).

    Pixels more than ``frame_margin_px`` outside the frame get status ``outside_image`` (the lens model is only
    known inside it).
    """
    pts = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    in_frame = camera.in_image(pts, margin=-frame_margin_px)
    finite = np.all(np.isfinite(pts), axis=1)
    rays = np.full((pts.shape[0], 3), np.nan)
    use = in_frame & finite
    if use.any():
        rays[use] = camera.rays(pts[use])
    hits = surface.intersect(camera.position, rays, height=height, min_incidence_deg=min_incidence_deg)
    code = hits.code.copy()
    code[~use] = OUTSIDE_IMAGE
    code[use & ~np.all(np.isfinite(rays), axis=1)] = OUTSIDE_LENS
    xyz = np.where((code == OK)[:, None], hits.points, np.nan)
    crs = camera_crs(camera)
    m = metres_per_unit(crs) if crs is not None else 1.0
    lon, lat = lonlat_of(xyz[:, 0], xyz[:, 1], crs) if with_lonlat else (None, None)
    return GroundPoints(xyz=xyz, status=np.asarray(STATUSES, dtype=object)[code],
                        distance_m=np.where(code == OK, hits.distance * m, np.nan),
                        incidence_deg=np.where(code == OK, hits.incidence_deg, np.nan), lon=lon, lat=lat)


def world_to_pixels(camera: Camera, xyz: ArrayLike, surface: Surface | None = None, *,
                    occlusion_tolerance_m: float = 0.5) -> ImagePoints:
    """Project world points (N, 3) into the image; with ``surface``, flag points the surface hides from the camera.

    A point is ``occluded`` when the ray towards it meets the surface more than ``occlusion_tolerance_m`` before
    reaching it (points on or above the surface that the camera can see are ``ok``).
    """
    pts = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    depth = camera.world_to_camera(pts)[:, 2]
    uv = camera.project(pts)
    status = np.full(pts.shape[0], "ok", dtype=object)
    status[~camera.in_image(np.nan_to_num(uv, nan=-1e9))] = "outside_image"
    behind = ~(depth > 0)
    status[behind] = "behind_camera"
    uv[behind] = np.nan
    if surface is not None:
        check = np.flatnonzero(status == "ok")
        if check.size:
            rel = pts[check] - camera.position
            dist = np.linalg.norm(rel, axis=1)
            hits = surface.intersect(camera.position, rel / dist[:, None], min_incidence_deg=0.0)
            crs = camera_crs(camera)
            tol = occlusion_tolerance_m / (metres_per_unit(crs) if crs is not None else 1.0)
            hidden = hits.ok & (hits.distance < dist - tol)
            status[check[hidden]] = "occluded"
    return ImagePoints(uv=uv, status=status, depth=depth)


def georeference(camera: Camera | CalibratedCamera, pixels: ArrayLike, surface: Surface, *, height_m: float = 0.0,
                 min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG) -> GroundPoints:
    """Pixels (N, 2) ``u, v`` (pixel-centre convention, :mod:`trafficgeo.camera.model`) to the ground: where each
    pixel's ray first meets ``surface`` lifted by ``height_m`` metres (e.g. a car roof), in the camera's CRS, with a
    status for pixels that cannot be mapped (above the horizon, outside the image, grazing rays, off the data).

    >>> import numpy as np, trafficgeo as tg
    >>> cam = tg.Camera.from_orientation((1920, 1080), 1400.0, [0.0, 0.0, 10.0], 0.0, 20.0)
    >>> ground = tg.georeference(cam, [[959.5, 800.0], [959.5, 0.0]], tg.ConstantSurface(0.0))
    >>> ground.status.tolist(), np.round(ground.xyz[0], 2).tolist()
    (['ok', 'above_horizon'], [0.0, 16.95, 0.0])
    """
    camera = as_camera(camera)
    crs = camera_crs(camera)
    from trafficgeo.crs import metres_per_unit

    lift = float(height_m) / (metres_per_unit(crs) if crs is not None else 1.0)
    return pixels_to_world(camera, pixels, surface, height=lift, min_incidence_deg=min_incidence_deg)
