"""Likely causes of empty results: a surface in another unit or datum than the camera, and lanes or counting lines
that are not where the camera looks (a wrong CRS label, mirrored coordinates, another site).

Each check names what it measured, so that the message says what is wrong rather than leaving an empty table:

* :func:`check_camera_above_surface` - the ground under and in front of the camera must be below the camera;
  a DEM in feet read as metres (or on another vertical datum) puts it above, and no pixel reaches it;
* :func:`line_out_of_view_warning` - a counting line behind the camera's image plane, or kilometres away, is
  never in view;
* :func:`lanes_warning` - almost no track point lies in any lane, and the lanes lie far from every vehicle path.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import shapely

from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs

AHEAD_M = (0.0, 5.0, 10.0, 20.0, 40.0, 80.0)  # m along the camera's viewing direction where the ground is sampled
FAR_FROM_PATHS_M = 20.0  # m: lanes farther than this from every vehicle path are not where the camera looks
NO_LANE_SHARE = 0.9  # share of track points in no lane above which the lanes are checked
FEET_PER_METRE = 1.0 / 0.3048
MAX_MOUNT_M = 60.0  # m: the highest a fixed traffic camera is usually mounted above the road
MAX_VIEW_M = 2000.0  # m: a counting line farther than this from the camera cannot be where it looks


def _mpu(camera: Camera) -> float:
    crs = camera_crs(camera)
    return metres_per_unit(crs) if crs is not None else 1.0


def ground_ahead_z(camera: Camera, surface: Surface) -> np.ndarray:
    """Surface elevations (CRS units; NaN where it has none) under the camera and at :data:`AHEAD_M` m in front of
    it along its horizontal viewing direction."""
    c = np.asarray(camera.position, dtype=np.float64)
    axis = np.asarray(camera.optical_axis, dtype=np.float64)[:2]
    norm = float(np.hypot(*axis))
    direction = axis / norm if norm > 1e-6 else np.zeros(2)
    d = np.asarray(AHEAD_M) / _mpu(camera)
    x, y = c[0] + d * direction[0], c[1] + d * direction[1]
    return np.asarray(surface.elevation(x, y), dtype=np.float64).reshape(-1)


def check_camera_above_surface(camera: Camera, surface: Surface) -> None:
    """Raise :class:`InputError` when the surface under and in front of the camera is all above it (no pixel can
    reach the ground), naming the likely cause: heights in another unit (feet read as metres) or datum."""
    z = ground_ahead_z(camera, surface)
    z = z[np.isfinite(z)]
    cam_z = float(camera.position[2])
    if not z.size or not np.all(z >= cam_z):
        return
    mpu = _mpu(camera)
    ground = float(np.median(z))
    above_m = (ground - cam_z) * mpu
    hint = ""
    if 0 < (cam_z - ground / FEET_PER_METRE) * mpu <= MAX_MOUNT_M:  # read as feet, the camera would stand on it
        hint = (f" read as feet, {ground:.1f} would be {ground / FEET_PER_METRE:.1f}, "
                f"{(cam_z - ground / FEET_PER_METRE) * mpu:.1f} m below the camera, so its heights are probably in "
                "feet;")
    raise InputError(f"surface {surface.describe()}: the ground under and in front of the camera is at {ground:.1f} "
                     f"(CRS units), {above_m:.1f} m above the camera ({cam_z:.1f}), so no pixel can reach it;{hint} "
                     "its heights are in another unit or vertical datum than the camera's; give the surface in the "
                     "camera CRS's units and vertical datum (or calibrate the camera against it)")


def behind_camera(camera: Camera, surface: Surface, xy: np.ndarray) -> np.ndarray:
    """True for ground positions ``xy`` (N, 2; CRS units) behind the camera's image plane (never in view). Where
    the surface has no height, the camera's own height less 1 m is used."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    z = np.asarray(surface.elevation(xy[:, 0], xy[:, 1]), dtype=np.float64).reshape(-1)
    z = np.where(np.isfinite(z), z, float(camera.position[2]) - 1.0 / _mpu(camera))
    depth = camera.world_to_camera(np.column_stack([xy, z]))[:, 2]
    return ~(depth > 0)


def _bearing_deg(camera: Camera, xy: np.ndarray) -> float:
    c = np.asarray(camera.position, dtype=np.float64)
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2).mean(axis=0)
    return float(np.degrees(np.arctan2(p[0] - c[0], p[1] - c[1])) % 360.0)


def _distance(m: float) -> str:
    return f"{m / 1000:.0f} km" if m >= 10_000 else f"{m:.0f} m"


def line_out_of_view_warning(camera: Camera, surface: Surface, name: str, xy: np.ndarray) -> str | None:
    """A warning when the whole counting line ``name`` (samples ``xy``, CRS units) lies behind the camera, or
    farther than :data:`MAX_VIEW_M` from it: not in view at all."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    dist = float(np.min(np.hypot(xy[:, 0] - camera.position[0], xy[:, 1] - camera.position[1]))) * _mpu(camera)
    axis = np.asarray(camera.optical_axis, dtype=np.float64)
    look = float(np.degrees(np.arctan2(axis[0], axis[1])) % 360.0)
    where = f"{_distance(dist)} away towards {_bearing_deg(camera, xy):.0f} deg, while the camera looks towards " \
            f"{look:.0f} deg"
    if np.all(behind_camera(camera, surface, xy)):
        what = f"lies behind the camera ({where})"
    elif dist > MAX_VIEW_M:
        what = f"lies {where}, far beyond what the camera can resolve"
    else:
        return None
    return (f"counting line {name} {what}: nobody can be counted there; its coordinates are probably not in the CRS "
            "its file declares, or have a sign or axis order swapped - check the lines file")


def lanes_warning(camera: Camera, surface: Surface, lanes, points: pd.DataFrame) -> str | None:
    """A warning when almost no track point lies in any lane and the lanes lie far from every vehicle path (or
    behind the camera): they are not where the camera looks."""
    if lanes is None or not len(points) or "lane" not in points.columns:
        return None
    share = float((points["lane"].astype(str) == "").mean())
    if share < NO_LANE_SHARE:
        return None
    xy = points[["x", "y"]].to_numpy(dtype=np.float64)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if not len(xy):
        return None
    union = shapely.union_all(list(lanes.polygons))
    paths = shapely.convex_hull(shapely.multipoints(xy))
    dist_m = float(shapely.distance(union, paths)) * _mpu(camera)
    centres = shapely.get_coordinates(shapely.centroid(np.asarray(lanes.polygons, dtype=object)))
    behind = bool(np.all(behind_camera(camera, surface, centres)))
    if dist_m <= FAR_FROM_PATHS_M and not behind:
        return None
    where = "behind the camera, " if behind else ""
    return (f"{share:.0%} of the track points lie in no lane: the lanes lie {where}{_distance(dist_m)} from the "
            "nearest vehicle path, so they are not where the camera looks; their coordinates are probably not in the "
            "CRS their file declares (or belong to another site) - check the lanes file's CRS")
