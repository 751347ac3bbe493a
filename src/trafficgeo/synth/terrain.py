"""Synthetic lidar of a road scene: ground points on the road surface and its verges, plus trees and poles.

Ground points (ASPRS class 2) sample :class:`~trafficgeo.synth.gcp_scene.RoadSurface` with vertical noise; trees
(class 5) are points scattered in crowns 3-10 m above the ground; poles (class 1) are thin vertical lines. The
cloud is what an airborne survey of the site would give, for ``trafficgeo dem`` and ``trafficgeo gcp-z``.
"""

from __future__ import annotations

import numpy as np
import pyproj
from numpy.typing import ArrayLike

from trafficgeo.geo.pointcloud import PointCloud
from trafficgeo.synth.gcp_scene import RoadSurface


def road_point_cloud(road: RoadSurface, centre: ArrayLike, half_size: float, *, density: float = 4.0,
                     noise: float = 0.02, n_trees: int = 40, n_poles: int = 10, seed: int = 0,
                     crs: str | pyproj.CRS | None = None) -> PointCloud:
    """A point cloud over the square ``centre +- half_size`` (metres) with ``density`` ground points per m^2.

    Trees and poles stand off the carriageway (at least 8 m from the road axis) so they occlude the verges, not
    the lanes.
    """
    rng = np.random.default_rng(seed)
    c = np.asarray(centre, dtype=np.float64).reshape(-1)[:2]
    n_ground = int(density * (2 * half_size) ** 2)
    xy = c + rng.uniform(-half_size, half_size, (n_ground, 2))
    z = road.z(xy[:, 0], xy[:, 1]) + rng.normal(0.0, noise, n_ground)
    parts = [np.column_stack([xy, z])]
    classes = [np.full(n_ground, 2, dtype=np.uint8)]

    def off_road(n: int) -> np.ndarray:
        pts = np.zeros((0, 2))
        while len(pts) < n:
            cand = c + rng.uniform(-half_size, half_size, (4 * n, 2))
            _, offset = road.station_offset(cand[:, 0], cand[:, 1])
            pts = np.vstack([pts, cand[np.abs(offset) > 8.0]])
        return pts[:n]

    for base in off_road(n_trees):
        k = 200
        crown = rng.uniform(1.5, 3.5)
        d = rng.normal(0.0, crown / 2, (k, 2))
        h = rng.uniform(3.0, 10.0, k)
        pts = np.column_stack([base + d, road.z(base[0], base[1]) + h])
        parts.append(pts)
        classes.append(np.full(k, 5, dtype=np.uint8))
    for base in off_road(n_poles):
        k = 30
        h = np.linspace(0.3, 8.0, k)
        pts = np.column_stack([np.tile(base, (k, 1)), road.z(base[0], base[1]) + h])
        parts.append(pts)
        classes.append(np.full(k, 1, dtype=np.uint8))
    xyz = np.vstack(parts)
    cls = np.concatenate(classes)
    crs_obj = pyproj.CRS.from_user_input(crs) if crs is not None else None
    return PointCloud(xyz, cls, None, crs_obj)
