"""A run folder (as ``trafficgeo analyze`` writes it) from the true trajectories of a SUMO world: observed counts
without a video, to test and benchmark what consumes run folders (``sumo-demand``, ``sumo-validate``, reports).

The points are the world's vehicle footprint centres (:class:`~trafficgeo.synth.sumo_world.Trajectories`),
optionally reprojected into another projected CRS; the lanes are the road's lane polygons named
``d<direction>_<lane>`` (:func:`~trafficgeo.synth.world.lanes_layer`); the counting lines run straight across the
whole road at the given stations. Crossings and counts are computed by :mod:`trafficgeo.traffic.lines` exactly as
``analyze`` does, and written with :func:`~trafficgeo.traffic.analyze.write_analysis`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import shapely

from trafficgeo.camera.model import Camera
from trafficgeo.crs import parse_crs, transform_xy
from trafficgeo.errors import InputError
from trafficgeo.site.lanes import lanes_from_polygons
from trafficgeo.site.lines import CountLine
from trafficgeo.synth.sumo_scene import RoadSpec
from trafficgeo.synth.sumo_world import Trajectories
from trafficgeo.synth.world import lanes_layer
from trafficgeo.traffic.analyze import TrafficResult, write_analysis
from trafficgeo.traffic.counts import aggregate_counts, check_interval, find_crossings

__all__ = ["truth_run_folder"]


def _reproject_geometry(geom: shapely.Geometry, src, dst) -> shapely.Geometry:
    return shapely.transform(geom, lambda xy: np.column_stack(transform_xy(xy[:, 0], xy[:, 1], src, dst)))


def _reproject_headings(x: np.ndarray, y: np.ndarray, heading_deg: np.ndarray, src, dst
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points and headings (deg clockwise from grid north) in ``dst``'s grid."""
    if dst == src:
        return x, y, heading_deg
    tx, ty = transform_xy(x, y, src, dst)
    h = np.radians(heading_deg)
    ax, ay = transform_xy(x + np.sin(h), y + np.cos(h), src, dst)
    return tx, ty, np.mod(np.degrees(np.arctan2(ax - tx, ay - ty)), 360.0)


def truth_run_folder(out_dir: str | Path, traj: Trajectories, road: RoadSpec, *,
                     stations_m: tuple[float, ...] = (0.0,), interval_s: float = 60.0,
                     period_s: tuple[float, float] | None = None, crs: str | None = None) -> list[Path]:
    """Write a run folder of the true trajectories ``traj`` on ``road``: counting lines across the road at
    ``stations_m`` (m along the axis, named ``s<station>``), counts per ``interval_s`` seconds over ``period_s``
    (s; default 0 to the last trajectory time rounded up to a whole interval), in ``crs`` (default the road's CRS;
    another projected CRS reprojects everything). Returns the files written."""
    interval = check_interval(interval_s)
    src = parse_crs(road.crs)
    dst = parse_crs(crs) if crs is not None else src
    if not len(traj):
        raise InputError("traj: no trajectory points; simulate a longer or busier world")
    t_end = float(np.ceil(traj.time.max() / interval) * interval)
    t0, t1 = period_s if period_s is not None else (0.0, t_end)
    x, y, heading = _reproject_headings(traj.x, traj.y, traj.heading_deg, src, dst)
    layer = lanes_layer(road)
    polygons = [_reproject_geometry(g, src, dst) for g in layer.geometries]
    b = np.asarray(layer.attributes["bearing"], dtype=np.float64)
    bearings = list(_reproject_headings(np.full(b.size, road.origin[0]), np.full(b.size, road.origin[1]), b,
                                        src, dst)[2])
    lanes = lanes_from_polygons(polygons, list(layer.attributes["lane"]), bearings)
    half = road.lanes * road.lane_width + 1.0
    lines = []
    for st in stations_m:
        ends = road.surface.points(np.array([st, st]), np.array([-half, half]))[:, :2]
        lines.append(CountLine(f"s{st:g}", _reproject_geometry(shapely.LineString(ends), src, dst)))
    order = np.lexsort((traj.time, traj.vehicle))
    points = pd.DataFrame({
        "track_id": traj.vehicle[order].astype(str), "source_track": traj.vehicle[order].astype(str),
        "time": traj.time[order], "x": x[order], "y": y[order], "z": traj.z[order],
        "speed_kmh": traj.speed[order] * 3.6, "heading_deg": heading[order], "outlier": False,
        "class": traj.vclass[order].astype(str), "length_m": traj.length[order]})
    points["lane"] = lanes.assign(points["x"].to_numpy(), points["y"].to_numpy(), points["heading_deg"].to_numpy())
    crossings = find_crossings(points, lines, lanes)
    crossings = crossings[(crossings["time"] >= t0) & (crossings["time"] < t1)].reset_index(drop=True)
    crossings["hidden"] = False
    counts = aggregate_counts(crossings, interval, t0, t1)
    g = points.groupby("track_id", sort=True)
    vehicles = pd.DataFrame({"class": g["class"].first(), "first_time": g["time"].min(),
                             "last_time": g["time"].max(), "speed_kmh": g["speed_kmh"].mean(),
                             "length_m": g["length_m"].first(), "lane": g["lane"].agg(lambda s: s.mode().iat[0]),
                             "lane_changes": g["lane"].agg(lambda s: int((s.to_numpy()[1:] != s.to_numpy()[:-1])
                                                                         .sum()))}).reset_index()
    result = TrafficResult(points=points, vehicles=vehicles, crossings=crossings, counts=counts, period=(t0, t1),
                           dropped={}, lanes=lanes, lines=lines, options={"interval_s": interval})
    ox, oy = transform_xy(np.array([road.origin[0]]), np.array([road.origin[1]]), src, dst)
    camera = Camera.from_orientation((64, 48), 50.0, [float(ox[0]), float(oy[0]), road.origin[2] + 8.0], 0.0,
                                     10.0, crs=dst)
    return write_analysis(out_dir, result, camera)
