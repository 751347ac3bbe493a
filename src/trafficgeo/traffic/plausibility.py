"""Likely causes of empty results: a surface in another unit or datum than the camera, and lanes or counting lines
that are not where the camera looks (a wrong CRS label, mirrored coordinates, another site).

Each check names what it measured, so that the message says what is wrong rather than leaving an empty table:

* :func:`trafficgeo.site.checks.check_camera_above_surface` (where a site is loaded) - the ground under and in
  front of the camera must be below the camera; a DEM in feet read as metres puts it above;
* :func:`line_out_of_view_warning` - a counting line behind the camera's image plane, or kilometres away, is
  never in view;
* :func:`lanes_warning` - almost no track point lies in any lane, and the lanes lie far from every vehicle path.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import shapely

from trafficgeo.camera.model import Camera
from trafficgeo.geo.mapping import Surface
from trafficgeo.site.checks import camera_metres_per_unit

FAR_FROM_PATHS_M = 20.0  # m: lanes farther than this from every vehicle path are not where the camera looks
NO_LANE_SHARE = 0.9  # share of track points in no lane above which the lanes are checked
MAX_VIEW_M = 2000.0  # m: a counting line farther than this from the camera cannot be where it looks


def behind_camera(camera: Camera, surface: Surface, xy: np.ndarray) -> np.ndarray:
    """True for ground positions ``xy`` (N, 2; CRS units) behind the camera's image plane (never in view). Where
    the surface has no height, the camera's own height less 1 m is used."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    z = np.asarray(surface.elevation(xy[:, 0], xy[:, 1]), dtype=np.float64).reshape(-1)
    z = np.where(np.isfinite(z), z, float(camera.position[2]) - 1.0 / camera_metres_per_unit(camera))
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
    gaps = np.hypot(xy[:, 0] - camera.position[0], xy[:, 1] - camera.position[1])
    dist = float(np.min(gaps)) * camera_metres_per_unit(camera)
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
    dist_m = float(shapely.distance(union, paths)) * camera_metres_per_unit(camera)
    centres = shapely.get_coordinates(shapely.centroid(np.asarray(lanes.polygons, dtype=object)))
    behind = bool(np.all(behind_camera(camera, surface, centres)))
    if dist_m <= FAR_FROM_PATHS_M and not behind:
        return None
    where = "behind the camera, " if behind else ""
    return (f"{share:.0%} of the track points lie in no lane: the lanes lie {where}{_distance(dist_m)} from the "
            "nearest vehicle path, so they are not where the camera looks; their coordinates are probably not in the "
            "CRS their file declares (or belong to another site) - check the lanes file's CRS")
