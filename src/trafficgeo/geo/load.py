"""Build a road surface from what a user gives on the command line (``--surface``).

``SURFACE`` is one of: a number (constant elevation in the camera CRS's units), ``plane`` (least-squares plane
through the calibration's inlier GCPs, stored in the camera JSON), a GeoTIFF DEM, or a LAS/LAZ point cloud (made
into a ground DEM, see :func:`trafficgeo.geo.pointcloud.cloud_to_dem`). Rasters and clouds must be in the camera's
CRS (same horizontal CRS, same units); a file without a CRS needs ``surface_crs``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from trafficgeo.camera.model import Camera
from trafficgeo.crs import crs_label, parse_crs, same_horizontal_crs
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs
from trafficgeo.geo.surface import ConstantSurface, DEMSurface, PlaneSurface

DEM_SUFFIXES = (".tif", ".tiff", ".vrt", ".img", ".asc")
CLOUD_SUFFIXES = (".las", ".laz")
SURFACE_HINT = "give a number (constant elevation), 'plane', a GeoTIFF DEM or a LAS/LAZ point cloud"


def plane_from_gcps(doc: dict[str, Any], crs: pyproj.CRS | None, where: str) -> PlaneSurface:
    """Robust least-squares plane through the inlier control GCPs recorded in a camera JSON document (points off
    the road, such as pole tops, are left out by the robust fit)."""
    rows = doc.get("gcps") or []
    use = [r for r in rows if isinstance(r, dict) and r.get("inlier", True) and r.get("role", "control") == "control"]
    pts = [(r["x"], r["y"], r["z"]) for r in use]
    if len(pts) < 3:
        raise InputError(f"surface plane needs the GCPs that 'trafficgeo calibrate' stores in the camera JSON; {where} "
                         f"has {len(pts)} inliers: use a number, a DEM or a point cloud instead",
                         parameters=("surface",))
    try:
        return PlaneSurface.fit(np.asarray(pts, dtype=np.float64), crs=crs)
    except ValueError as exc:
        raise InputError(f"{where}: cannot fit a plane to the GCPs ({exc}); use a DEM or a point cloud") from None


def _check_crs(path: Path, file_crs: pyproj.CRS | None, cam_crs: pyproj.CRS | None) -> None:
    if file_crs is None:
        raise InputError(f"{path}: the file has no CRS; say which it is with surface_crs (e.g. EPSG:2994)",
                         parameters=("surface_crs",))
    if cam_crs is not None and not same_horizontal_crs(file_crs, cam_crs):
        raise InputError(f"{path}: CRS {crs_label(file_crs)} differs from the camera's {crs_label(cam_crs)}; "
                         "reproject it (gdalwarp -t_srs / pdal translate) or calibrate in its CRS")


def load_surface(spec: str, camera: Camera, doc: dict[str, Any] | None = None, *, surface_crs: str | None = None,
                 resolution_m: float = 0.25, where: str = "camera JSON") -> Surface:
    """The surface named by ``spec`` (see the module docstring), in the camera's CRS."""
    cam_crs = camera_crs(camera)
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
        return plane_from_gcps(doc or {}, cam_crs, where)
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
