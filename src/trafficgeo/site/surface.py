"""The road surface of a site, from what a user gives (``surface``, ``--surface``): the one loader.

A :class:`~trafficgeo.geo.mapping.Surface` is taken as it is; else one of: a number (constant elevation in the
camera CRS's units), ``"plane"`` (least-squares plane through the calibration's inlier control GCPs, which a
:class:`~trafficgeo.camera.calibrated.CalibratedCamera` carries), a GeoTIFF DEM, or a LAS/LAZ point cloud (made into
a ground DEM at ``resolution_m`` m, see :func:`trafficgeo.geo.pointcloud.cloud_to_dem`). Rasters and clouds must be
in the camera's CRS (same horizontal CRS, same units); a file without a CRS needs ``surface_crs``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyproj

from trafficgeo.camera.calibrated import CalibratedCamera, load_calibrated_camera
from trafficgeo.camera.model import Camera
from trafficgeo.crs import crs_label, parse_crs, same_horizontal_crs
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs
from trafficgeo.geo.surface import ConstantSurface, DEMSurface, PlaneSurface

DEM_SUFFIXES = (".tif", ".tiff", ".vrt", ".img", ".asc")
CLOUD_SUFFIXES = (".las", ".laz")
SURFACE_HINT = "give a number (constant elevation), 'plane', a GeoTIFF DEM or a LAS/LAZ point cloud"


def check_resolution(resolution_m: float) -> float:
    """``resolution_m`` if it is a usable cell size (m) for gridding a point cloud, else an InputError."""
    if not (resolution_m > 0 and resolution_m < float("inf")):
        raise InputError(f"resolution_m {resolution_m}: must be a positive cell size in metres, e.g. 0.25",
                         parameters=("resolution_m",))
    return float(resolution_m)


def plane_from_gcps(camera: CalibratedCamera) -> PlaneSurface:
    """Robust least-squares plane through the control GCPs the calibration kept (points off the road, such as pole
    tops, are left out by the robust fit), in the camera's CRS."""
    pts = camera.control_xyz()
    if camera.gcps is None and not camera.source:
        raise InputError("surface 'plane': the GCP plane comes from the calibration's GCPs; give the camera as its "
                         "JSON's path or as a CalibratedCamera (tg.calibrate(...).calibrated_camera())",
                         parameters=("surface",))
    if len(pts) < 3:
        raise InputError(f"surface plane needs the GCPs that 'trafficgeo calibrate' stores in the camera JSON; "
                         f"{camera.where} has {len(pts)} inliers: use a number, a DEM or a point cloud instead",
                         parameters=("surface",))
    try:
        return PlaneSurface.fit(pts, crs=camera_crs(camera.camera))
    except ValueError as exc:
        raise InputError(f"{camera.where}: cannot fit a plane to the GCPs ({exc}); use a DEM or a point cloud"
                         ) from None


def _check_crs(path: Path, file_crs: pyproj.CRS | None, cam_crs: pyproj.CRS | None) -> None:
    if file_crs is None:
        raise InputError(f"{path}: the file has no CRS; say which it is with surface_crs (e.g. EPSG:2994)",
                         parameters=("surface_crs",))
    if cam_crs is not None and not same_horizontal_crs(file_crs, cam_crs):
        raise InputError(f"{path}: CRS {crs_label(file_crs)} differs from the camera's {crs_label(cam_crs)}; "
                         "reproject it (gdalwarp -t_srs / pdal translate) or calibrate in its CRS")


def load_surface(surface: Surface | float | str | os.PathLike, camera: CalibratedCamera | Camera | str | os.PathLike,
                 *, surface_crs: str | None = None, resolution_m: float = 0.25) -> Surface:
    """The road surface named by ``surface`` (see the module docstring) for ``camera`` (a CalibratedCamera, a
    Camera or the path of its camera JSON), in the camera's CRS."""
    if hasattr(surface, "elevation") and hasattr(surface, "normal"):
        return surface  # type: ignore[return-value]  # a Surface
    check_resolution(resolution_m)
    calibrated = load_calibrated_camera(camera)
    if isinstance(surface, bool) or not isinstance(surface, int | float | str | os.PathLike):
        raise InputError(f"surface: {type(surface).__name__} is not a surface, a number, 'plane' or a file path",
                         parameters=("surface",))
    if isinstance(surface, str) and surface.strip().lower() == "plane":
        return plane_from_gcps(calibrated)
    return surface_in_crs(surface, camera_crs(calibrated.camera), surface_crs=surface_crs, resolution_m=resolution_m)


def surface_in_crs(surface: float | str | os.PathLike, crs: pyproj.CRS | None, *, surface_crs: str | None = None,
                   resolution_m: float = 0.25) -> Surface:
    """The surface named by a constant elevation or a DEM / point-cloud file, in ``crs`` (files in another CRS are
    refused); 'plane' needs a calibrated camera's GCPs (:func:`load_surface`)."""
    check_resolution(resolution_m)
    if isinstance(surface, bool) or not isinstance(surface, int | float | str | os.PathLike):
        raise InputError(f"surface: {type(surface).__name__} is not a surface, a number or a file path",
                         parameters=("surface",))
    spec = repr(float(surface)) if isinstance(surface, int | float) else os.fspath(surface)
    cam_crs = crs
    text = spec.strip()
    try:
        z = float(text)
    except ValueError:
        z = None
    if z is not None:
        if not np.isfinite(z):
            raise InputError(f"surface {spec!r}: a constant elevation must be a finite number (CRS units)",
                             parameters=("surface",))
        return ConstantSurface(z, crs=cam_crs)
    if text.lower() == "plane":
        raise InputError("surface 'plane' is fitted to a camera's GCPs, and there are none yet; give a DEM, a "
                         "point cloud or a constant elevation", parameters=("surface",))
    path = Path(text)
    suffix = path.suffix.lower()
    given = parse_crs(surface_crs) if surface_crs else None
    if suffix in DEM_SUFFIXES:
        from trafficgeo.geo.raster import read_dem

        raster = read_dem(path, crs=given)
        _check_crs(path, raster.crs, cam_crs)
        try:
            return DEMSurface.from_raster(raster, name=path.name)
        except ValueError as exc:
            raise InputError(f"{path}: {exc}") from None
    if suffix in CLOUD_SUFFIXES:
        from trafficgeo.geo.pointcloud import cloud_to_dem, read_point_cloud

        cloud = read_point_cloud(path, crs=given)
        _check_crs(path, cloud.crs, cam_crs)
        dem = cloud_to_dem(cloud, resolution_m)
        return DEMSurface.from_raster(dem, name=f"{path.name} (ground DEM {resolution_m:g} m)")
    if not path.exists() and not suffix:
        raise InputError(f"surface '{spec}' is not a number, 'plane' or a file; {SURFACE_HINT}",
                         parameters=("surface",))
    raise InputError(f"{path}: unknown surface type '{suffix or path.name}'; {SURFACE_HINT}")
