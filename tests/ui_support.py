"""Shared helper of the gcp-ui tests: a generated scene with known truth (frame, orthophoto, DEM, lidar).

A roadside camera looks along a crowned, graded four-lane road running 20 degrees east of north. The frame is the
orthophoto draped on the road surface and seen through the true camera, so the lane-marking corners in it lie
exactly where ``camera.project`` puts them. ``truth_world`` holds dash corners seen in the frame (spread over it by
farthest-point sampling), ``truth_pixels`` their true pixels, ``truth_ortho`` their orthophoto positions (col, row).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.geo.pointcloud import write_point_cloud
from trafficgeo.geo.raster import GeoRaster, write_geotiff
from trafficgeo.geo.surface import DEMSurface
from trafficgeo.synth.gcp_scene import RoadSurface
from trafficgeo.synth.orthophoto import RoadMarkings, dash_corners, render_orthophoto
from trafficgeo.synth.render import drape_orthophoto
from trafficgeo.synth.terrain import road_point_cloud

E0, N0, Z0 = 245000.0, 5182600.0, 90.0
CRS = "EPSG:2949"
FRAME_SIZE = (800, 450)
ORTHO_RES = 0.1
DEM_RES = 0.25


@dataclass(frozen=True)
class Scene:
    folder: Path
    frame: Path
    ortho: Path
    dem: Path
    cloud: Path
    camera: Camera
    road: RoadSurface
    ortho_raster: GeoRaster
    dem_surface: DEMSurface
    truth_world: np.ndarray  # (N, 3)
    truth_pixels: np.ndarray  # (N, 2) camera pixels, (0, 0) = centre of the top-left pixel
    truth_ortho: np.ndarray  # (N, 2) orthophoto (col, row), (0, 0) = top-left corner


def _farthest(uv: np.ndarray, k: int) -> list[int]:
    chosen = [int(np.argmin(uv[:, 0] + uv[:, 1]))]
    d = np.linalg.norm(uv - uv[chosen[0]], axis=1)
    while len(chosen) < min(k, len(uv)):
        nxt = int(np.argmax(d))
        chosen.append(nxt)
        d = np.minimum(d, np.linalg.norm(uv - uv[nxt], axis=1))
    return chosen


def build_scene(folder: Path, n_points: int = 12, cloud: bool = True) -> Scene:
    """Write frame.png, ortho.tif, dem.tif (and cloud.laz) into ``folder``; returns them with the truth."""
    folder.mkdir(parents=True, exist_ok=True)
    road = RoadSurface(origin=[E0, N0, Z0], azimuth_deg=20.0, grade=0.02, crossfall=0.02)
    marks = RoadMarkings(lanes_right=2, lanes_left=2)
    pos = road.points([-20.0], [marks.right_edge + 5.0])[0] + [0.0, 0.0, 8.0]
    target = road.points([22.0], [0.0])[0]
    d = target - pos
    heading = float(np.degrees(np.arctan2(d[0], d[1])))
    tilt = float(np.degrees(np.arctan2(-d[2], np.hypot(d[0], d[1]))))
    camera = Camera.from_orientation(FRAME_SIZE, 620.0, pos, heading, tilt, 0.0, dist=[-0.04, 0.0, 0, 0, 0], crs=CRS)
    corners = road.points(np.array([-30.0, -30.0, 90.0, 90.0]), np.array([-22.0, 22.0, -22.0, 22.0]))
    left, bottom = np.floor(corners[:, :2].min(axis=0))
    right, top = np.ceil(corners[:, :2].max(axis=0))
    ortho = render_orthophoto(road, marks, (left, bottom, right, top), resolution=ORTHO_RES, seed=3, crs=CRS)
    nx, ny = round((right - left) / DEM_RES), round((top - bottom) / DEM_RES)
    X, Y = np.meshgrid(left + (np.arange(nx) + 0.5) * DEM_RES, top - (np.arange(ny) + 0.5) * DEM_RES)
    dem = DEMSurface(road.z(X, Y), left, top, DEM_RES, DEM_RES, crs=ortho.crs)
    frame = np.clip(np.rint(drape_orthophoto(camera, dem, ortho)), 0, 255).astype(np.uint8)
    paths = {k: folder / n for k, n in (("frame", "frame.png"), ("ortho", "ortho.tif"), ("dem", "dem.tif"),
                                         ("cloud", "cloud.laz"))}
    cv2.imwrite(str(paths["frame"]), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    write_geotiff(paths["ortho"], ortho.data, ortho.transform, ortho.crs, descriptions=ortho.descriptions)
    from affine import Affine

    write_geotiff(paths["dem"], dem.values, Affine(DEM_RES, 0, left, 0, -DEM_RES, top), ortho.crs, nodata=-9999.0,
                  dtype=np.float64)
    if cloud:
        centre = road.points([25.0], [0.0])[0, :2]
        write_point_cloud(paths["cloud"], road_point_cloud(road, centre, 45.0, density=8.0, seed=1, crs=CRS))
    world = dash_corners(road, marks, (-5.0, 75.0))
    uv = camera.project(world)
    keep = camera.in_image(uv, margin=40) & (camera.world_to_camera(world)[:, 2] < 60.0)
    world, uv = world[keep], uv[keep]
    pick = _farthest(uv, n_points)
    world, uv = world[pick], uv[pick]
    col, row = ortho.map_to_pixel(world[:, 0], world[:, 1])
    return Scene(folder, paths["frame"], paths["ortho"], paths["dem"], paths["cloud"], camera, road, ortho, dem,
                 world, uv, np.column_stack([col, row]))


_SCENES: dict[str, Scene] = {}


def shared_scene(tmp_path_factory) -> Scene:
    """One scene per test session (its files are only read; tests copy them to write beside them)."""
    key = str(tmp_path_factory.getbasetemp())
    if key not in _SCENES:
        _SCENES[key] = build_scene(tmp_path_factory.mktemp("ui-scene"))
    return _SCENES[key]
