"""The junction world: a signalised four-arm junction driven by SUMO, with every file a user would have and the
truth behind them (issue 39). Conventions (CRS, bearings, arms, movements) are in
:mod:`trafficgeo.synth.junction_sumo`.

:func:`build_junction_world` writes, into one folder:

* ``sumo/`` - the georeferenced network (traffic light at ``C``), demand, FCD and vehicle routes;
* ``ortho.tif`` - an orthophoto (``ortho_resolution`` m/px) of the centre +- ``view_half_size`` m: asphalt from
  SUMO's lane shapes (each buffered by half a lane width) and the junction's own shape, a paved 1.5 m verge, textured
  grass; markings: a solid yellow centre line, dashed white lane lines (3 m dash, 9 m period from 2 m behind the
  stop line), solid white edge lines and a 0.4 m white stop line across the incoming lanes where SUMO's lanes end;
* ``dem.tif`` (0.25 m) and ``cloud.laz`` - the ground: a plane through the origin with ``ground_slope`` (flat by
  default); the lidar adds 2 cm noise, trees and poles off the road. Vehicles and camera stand on the same plane;
* ``camera_truth.json`` - a pole at ``camera_corner``, ``camera_distance_m`` from the centre on the corner's
  diagonal, ``camera_height`` above the ground, looking at the centre, ``focal_px`` (default 0.6 x width);
* ``video.mp4`` (unless ``video=False``) rendered as the road world (:func:`trafficgeo.synth.world.render_video`);
* ``gcps.csv`` - stop-line corners, lane-line dash corners and signal-pole bases/tops in the frame, noisy, with
  control/check roles (:func:`trafficgeo.synth.world.pick_gcps`);
* ``truth_tracks.csv``/``.gpkg`` - the road world's columns; ``direction`` is the vehicle's origin arm, ``lane`` the
  SUMO lane id under its front bumper;
* ``gates.gpkg`` - per arm one line across the whole arm (both directions and 1 m beyond the edge lines),
  ``gate_distance_m`` from the centre (default 22 m: about 11 m behind the stop line, so queues reach it, and
  well inside the default camera's frame on every arm: at 30 m the near arms' gates lie at the frame's left and
  right edges, where vehicles are cut off and their boxes cannot be used), with
  ``arm`` (compass name), ``bearing_deg`` (centre to the gate's midpoint) and ``distance_m``;
* ``truth_movements.csv`` - per vehicle in the video's time span: ``vehicle, class, origin, destination,
  movement, entry_time, exit_time``: origin/destination arms from its SUMO route, ``movement`` from the arms'
  bearings (which matches SUMO's connection direction), the times (s, video clock) its footprint centre crossed
  the origin gate inbound and the destination gate outbound, ``''`` when that happened outside the video;
* ``world.json`` - options, vehicle/frame/GCP counts, the SUMO version and ``"kind": "junction"``.

Deterministic for a seed.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np

from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.io.atomic import write_csv_atomic, write_text_atomic
from trafficgeo.synth.junction_sumo import (
    ARM_NAMES,
    JunctionOptions,
    JunctionRun,
    JunctionTrajectories,
    arm_bearings,
    movement,
    run_junction_sumo,
    unit,
)

__all__ = ["build_junction_world", "gate_lines", "ground_z", "junction_camera",
           "truth_movements"]

EDGE_LINE = 0.15
LINE = 0.10
STOP_LINE = 0.40
DASH, PERIOD = 3.0, 9.0
VERGE = 1.5  # paved verge beyond the carriageway (m)


# ---------------------------------------------------------------------------------------------------- geometry
def ground_z(opts: JunctionOptions, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
    """Ground height (m) at world x, y: the plane through the origin rising ``ground_slope`` m/m towards
    ``ground_slope_bearing_deg``."""
    ox, oy, oz = opts.origin
    ux, uy = unit(opts.ground_slope_bearing_deg)
    return oz + opts.ground_slope * ((np.asarray(x) - ox) * ux + (np.asarray(y) - oy) * uy)


def _normal_in(bearing: float) -> np.ndarray:
    """Unit vector from an arm's axis towards its incoming lanes (left of the outward direction)."""
    b = math.radians(bearing)
    return np.array([-math.cos(b), math.sin(b)])


def gate_lines(opts: JunctionOptions) -> dict[str, np.ndarray]:
    """Arm -> gate end points (2, 2) in world x, y: across the arm ``gate_distance_m`` from the centre, from the
    outgoing side to the incoming side, 1 m beyond the edge lines."""
    c = np.array(opts.origin[:2])
    half = opts.lanes * opts.lane_width + 1.0
    out = {}
    for arm, b in arm_bearings(opts).items():
        m = c + opts.gate_distance_m * unit(b)
        n = _normal_in(b)
        out[arm] = np.array([m - half * n, m + half * n])
    return out


def junction_camera(opts: JunctionOptions) -> Camera:
    """The pole camera at ``camera_corner`` looking at the junction centre (module docstring)."""
    bearings = arm_bearings(opts)
    a, b = bearings[opts.camera_corner[0]], bearings[opts.camera_corner[1]]
    mid = math.degrees(math.atan2(math.sin(math.radians(a)) + math.sin(math.radians(b)),
                                  math.cos(math.radians(a)) + math.cos(math.radians(b))))
    xy = np.array(opts.origin[:2]) + opts.camera_distance_m * unit(mid)
    pos = np.array([xy[0], xy[1], float(ground_z(opts, xy[0], xy[1])) + opts.camera_height])
    d = np.array(opts.origin) - pos
    heading = float(np.degrees(np.arctan2(d[0], d[1])) % 360.0)
    tilt = float(np.degrees(np.arctan2(-d[2], np.hypot(d[0], d[1]))))
    f = opts.focal_px or 0.6 * opts.image_size[0]
    return Camera.from_orientation(opts.image_size, f, pos, heading, tilt, 0.0, dist=list(opts.dist), crs=opts.crs)


def _stop_distance(net_path: Path, opts: JunctionOptions) -> dict[str, float]:
    """Arm -> distance (m) from the centre to where SUMO's incoming lanes end (the stop line)."""
    import sumolib

    net = sumolib.net.readNet(str(net_path))
    out = {}
    for arm, b in arm_bearings(opts).items():
        ends = [np.array(lane.getShape()[-1]) for lane in net.getEdge(f"{arm}_in").getLanes()]
        out[arm] = float(min(np.dot(e, unit(b)) for e in ends))
    return out


def _paved_polygons(net_path: Path):
    """Shapely geometry (world coordinates minus the origin = SUMO's) of the carriageway: every lane's shape
    buffered by half its width (flat ends) and the junction's internal area."""
    import sumolib
    from shapely.geometry import LineString, Polygon
    from shapely.ops import unary_union

    net = sumolib.net.readNet(str(net_path), withInternal=True)
    parts = []
    for edge in net.getEdges():
        for lane in edge.getLanes():
            shape = lane.getShape()
            if len(shape) >= 2 and LineString(shape).length > 1e-3:
                parts.append(LineString(shape).buffer(0.5 * lane.getWidth(), cap_style="flat"))
    for node in net.getNodes():
        shape = node.getShape()
        if len(shape) >= 3:
            parts.append(Polygon(shape).buffer(0))
    return unary_union(parts)


def _markings(opts: JunctionOptions, stop: dict[str, float]) -> tuple[list[np.ndarray], list[np.ndarray],
                                                                     np.ndarray, np.ndarray]:
    """Marking polygons (world x, y minus the origin): white ones, yellow ones; and GCP candidates: stop-line
    corners (M, 2) and dash corners (K, 2)."""
    white, yellow, stop_pts, dash_pts = [], [], [], []
    w = opts.lane_width

    def rect(b: float, t0: float, t1: float, o0: float, o1: float) -> np.ndarray:
        u, n = unit(b), _normal_in(b)
        return np.array([t * u + o * n for t, o in ((t0, o0), (t1, o0), (t1, o1), (t0, o1))])

    for arm, b in arm_bearings(opts).items():
        t0, t1 = stop[arm], opts.arm_length_m
        yellow.append(rect(b, t0, t1, -0.5 * LINE, 0.5 * LINE))
        edge = opts.lanes * w
        for side in (1.0, -1.0):
            white.append(rect(b, t0, t1, side * (edge - EDGE_LINE), side * edge))
            for k in range(1, opts.lanes):
                starts = np.arange(t0 + 2.0, t1 - DASH, PERIOD)
                for s in starts:
                    r = rect(b, s, s + DASH, side * k * w - 0.5 * LINE, side * k * w + 0.5 * LINE)
                    white.append(r)
                    if s < t0 + 40.0:
                        dash_pts.append(r)
        sl = rect(b, t0, t0 + STOP_LINE, 0.5 * LINE, edge - EDGE_LINE)
        white.append(sl)
        stop_pts.append(sl)
    return white, yellow, np.vstack(stop_pts), np.vstack(dash_pts) if dash_pts else np.zeros((0, 2))


def _render_ortho(opts: JunctionOptions, net_path: Path, stop: dict[str, float]):
    """The orthophoto (GeoRaster, RGB uint8) and the marking GCP candidates (world x, y, (N, 2))."""
    import cv2
    from affine import Affine
    from shapely.geometry import MultiPolygon

    from trafficgeo.crs import parse_crs
    from trafficgeo.geo.raster import GeoRaster
    from trafficgeo.synth.orthophoto import ASPHALT, GRASS, SHOULDER, WHITE, YELLOW, texture

    res, half = opts.ortho_resolution, opts.view_half_size
    ox, oy, _ = opts.origin
    left, top = ox - half, oy + half
    n = int(np.ceil(2 * half / res))
    if n * n > 80_000_000:
        raise ValueError(f"an orthophoto of {n}x{n} pixels is too large; use a coarser resolution")
    rng = np.random.default_rng(opts.seed)
    shift = 4

    def to_px(xy: np.ndarray) -> np.ndarray:  # SUMO (origin-relative) x, y -> fixed-point pixel corners
        col = (xy[:, 0] + ox - left) / res - 0.5
        row = (top - (xy[:, 1] + oy)) / res - 0.5
        return np.rint(np.column_stack([col, row]) * (1 << shift)).astype(np.int32)

    def mask_of(polys: list[np.ndarray]) -> np.ndarray:
        m = np.zeros((n, n), np.uint8)
        cv2.fillPoly(m, [to_px(p) for p in polys], 255, lineType=cv2.LINE_AA, shift=shift)
        return m.astype(np.float32) / 255.0

    def rings(geom) -> tuple[list[np.ndarray], list[np.ndarray]]:
        polys = geom.geoms if isinstance(geom, MultiPolygon) else [geom]
        return ([np.array(p.exterior.coords) for p in polys],
                [np.array(r.coords) for p in polys for r in p.interiors])

    paved = _paved_polygons(net_path)
    outer, holes = rings(paved)
    road = mask_of(outer) * (1.0 - mask_of(holes)) if holes else mask_of(outer)
    v_outer, v_holes = rings(paved.buffer(VERGE, join_style="mitre"))
    verge = mask_of(v_outer) * (1.0 - mask_of(v_holes)) if v_holes else mask_of(v_outer)
    img = np.empty((n, n, 3), np.float32)
    img[:] = GRASS
    img += (SHOULDER - GRASS).astype(np.float32) * verge[..., None]
    img += (ASPHALT - SHOULDER).astype(np.float32) * road[..., None]
    tex = texture(rng, (n, n), 1.0).astype(np.float32)
    img += tex[..., None] * (14.0 - 8.0 * verge)[..., None]
    white, yellow, stop_pts, dash_pts = _markings(opts, stop)
    for polys, colour in ((yellow, YELLOW), (white, WHITE)):
        cover = mask_of(polys)[..., None]
        img = img * (1.0 - cover) + colour.astype(np.float32) * cover
    img += rng.normal(0.0, 2.0, img.shape).astype(np.float32)
    data = np.clip(np.rint(img), 0, 255).astype(np.uint8).transpose(2, 0, 1)
    ortho = GeoRaster(data=data, transform=Affine(res, 0.0, left, 0.0, -res, top), crs=parse_crs(opts.crs),
                      descriptions=("red", "green", "blue"))
    return ortho, np.vstack([stop_pts, dash_pts]) + np.array([ox, oy])


def _point_cloud(opts: JunctionOptions, poles: np.ndarray):
    """Lidar: ground points (4 per m^2, 2 cm noise) over the ortho area, trees off the road, the signal poles."""
    import pyproj

    from trafficgeo.geo.pointcloud import PointCloud

    rng = np.random.default_rng(opts.seed + 7)
    half = opts.view_half_size
    c = np.array(opts.origin[:2])
    n = int(4.0 * (2 * half) ** 2)
    xy = c + rng.uniform(-half, half, (n, 2))
    parts = [np.column_stack([xy, ground_z(opts, xy[:, 0], xy[:, 1]) + rng.normal(0.0, 0.02, n)])]
    classes = [np.full(n, 2, np.uint8)]
    clear = opts.lanes * opts.lane_width + VERGE + 4.0
    bearings = list(arm_bearings(opts).values())
    trees = []
    while len(trees) < 40:
        p = c + rng.uniform(-half, half, 2)
        if all(abs(float(np.dot(p - c, _normal_in(b)))) > clear for b in bearings[:2]):
            trees.append(p)
    for base in trees:
        k = 200
        d = rng.normal(0.0, rng.uniform(1.5, 3.5) / 2, (k, 2))
        parts.append(np.column_stack([base + d, ground_z(opts, *base) + rng.uniform(3.0, 10.0, k)]))
        classes.append(np.full(k, 5, np.uint8))
    for base in poles:
        h = np.linspace(0.3, 6.0, 30)
        parts.append(np.column_stack([np.tile(base[:2], (30, 1)), ground_z(opts, *base[:2]) + h]))
        classes.append(np.full(30, 1, np.uint8))
    return PointCloud(np.vstack(parts), np.concatenate(classes), None, pyproj.CRS.from_user_input(opts.crs))


def _signal_poles(opts: JunctionOptions, stop: dict[str, float]) -> np.ndarray:
    """Pole bases (N, 3): a signal pole beside each arm's stop line and lamp posts along the arms, 1.5 m beyond
    the edge of the incoming lanes."""
    c = np.array(opts.origin[:2])
    off = opts.lanes * opts.lane_width + VERGE
    pts = []
    for arm, b in arm_bearings(opts).items():
        for t in (stop[arm] + 1.0, 45.0, 70.0):
            pts.append(c + t * unit(b) + off * _normal_in(b))
    xy = np.array(pts)
    return np.column_stack([xy, ground_z(opts, xy[:, 0], xy[:, 1])])


# ---------------------------------------------------------------------------------------------------- truth
def truth_movements(traj: JunctionTrajectories, run: JunctionRun, opts: JunctionOptions):
    """One row per vehicle in the trajectories (see the module docstring)."""
    import pandas as pd

    bearings = arm_bearings(opts)
    c = np.array(opts.origin[:2])
    half = opts.lanes * opts.lane_width + 1.0
    rows = []
    order = np.lexsort((traj.time, traj.vehicle))
    vid_sorted = traj.vehicle[order]
    bounds = np.flatnonzero(np.r_[True, vid_sorted[1:] != vid_sorted[:-1], True])
    for a, b in itertools.pairwise(bounds if len(traj) else []):
        idx = order[a:b]
        vid = str(traj.vehicle[idx[0]])
        edges = run.vehicle_routes.get(vid)
        if not edges:
            raise ValueError(f"vehicle {vid} has no route in {run.vehroutes}")
        origin, dest = edges[0].removesuffix("_in"), edges[-1].removesuffix("_out")
        p = np.column_stack([traj.x[idx], traj.y[idx]]) - c
        t = traj.time[idx]

        def crossing(arm: str, inbound: bool, p=p, t=t) -> float | str:
            u, n = unit(bearings[arm]), _normal_in(bearings[arm])
            s = p @ u - opts.gate_distance_m
            lat = np.abs(p @ n)
            hit = (s[:-1] > 0) & (s[1:] <= 0) if inbound else (s[:-1] < 0) & (s[1:] >= 0)
            hit &= (lat[:-1] <= half) & (lat[1:] <= half)
            k = np.flatnonzero(hit)
            if not k.size:
                return ""
            i = int(k[0])
            frac = s[i] / (s[i] - s[i + 1])
            return round(float(t[i] + frac * (t[i + 1] - t[i])), 4)

        rows.append({"vehicle": vid, "class": str(traj.vclass[idx[0]]), "origin": origin, "destination": dest,
                     "movement": movement(bearings[origin], bearings[dest]),
                     "entry_time": crossing(origin, True), "exit_time": crossing(dest, False)})
    return pd.DataFrame(rows, columns=["vehicle", "class", "origin", "destination", "movement", "entry_time",
                                       "exit_time"])


def _truth_tracks(traj: JunctionTrajectories, z: np.ndarray, camera: Camera, run: JunctionRun, fps: float):
    import pandas as pd

    ground = camera.project(np.column_stack([traj.x, traj.y, z]))
    origin = np.array([run.vehicle_routes.get(str(v), ("?_in",))[0].removesuffix("_in") for v in traj.vehicle])
    return pd.DataFrame({
        "frame": np.rint(traj.time * fps).astype(int), "time": traj.time, "vehicle": traj.vehicle,
        "class": traj.vclass, "x": traj.x, "y": traj.y, "z": z, "speed_kmh": traj.speed * 3.6,
        "heading_deg": traj.heading_deg, "direction": origin, "lane": traj.lane, "length": traj.length,
        "width": traj.width, "height": traj.height, "u": ground[:, 0], "v": ground[:, 1],
    })


def _gates_layer(opts: JunctionOptions):
    from shapely.geometry import LineString

    from trafficgeo.io.gis import Layer

    gates = gate_lines(opts)
    c = np.array(opts.origin[:2])
    arms = [a for a in ARM_NAMES if a in gates]
    mids = [gates[a].mean(axis=0) - c for a in arms]
    return Layer("gates", [LineString(gates[a]) for a in arms],
                 {"arm": arms, "bearing_deg": [round(float(np.degrees(np.arctan2(m[0], m[1])) % 360.0), 6)
                                               for m in mids],
                  "distance_m": [opts.gate_distance_m] * len(arms)})


# ---------------------------------------------------------------------------------------------------- build
def build_junction_world(out_dir: str | Path, opts: JunctionOptions | None = None, *, video: bool = True,
                         progress=None) -> dict[str, object]:
    """Build the junction world into ``out_dir`` (see the module docstring); returns the ``world.json`` summary.

    The options are checked by :class:`JunctionOptions` before anything is written.

    Raises:
        InputError: SUMO missing. TrafficgeoError: netconvert/sumo failed. OutputError: a file could not be written.
    """
    import pandas as pd
    from affine import Affine

    from trafficgeo.geo.pointcloud import write_point_cloud
    from trafficgeo.geo.raster import write_geotiff
    from trafficgeo.geo.surface import DEMSurface
    from trafficgeo.io.gis import write_gis
    from trafficgeo.io.tables import write_point_table
    from trafficgeo.synth.world import pick_gcps, render_video, resample_trajectories

    opts = opts or JunctionOptions()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    run = run_junction_sumo(out / "sumo", opts)
    traj = run.trajectories
    if abs(opts.sumo_step * opts.fps - 1.0) > 1e-9:  # e.g. 30 fps simulated at 10 ms: positions at the frame times
        traj = resample_trajectories(traj, opts.fps, opts.duration_s)
    z = ground_z(opts, traj.x, traj.y)
    camera = junction_camera(opts)
    write_camera_json(out / "camera_truth.json", camera)
    stop = _stop_distance(run.net, opts)
    ortho, marking_pts = _render_ortho(opts, run.net, stop)
    write_geotiff(out / "ortho.tif", ortho.data, ortho.transform, ortho.crs, descriptions=ortho.descriptions)
    res, half = 0.25, opts.view_half_size
    n = int(2 * half / res)
    left, top = opts.origin[0] - half, opts.origin[1] + half
    gx, gy = left + (np.arange(n) + 0.5) * res, top - (np.arange(n) + 0.5) * res
    X, Y = np.meshgrid(gx, gy)
    dem_values = ground_z(opts, X, Y)
    dem = DEMSurface(dem_values, left, top, res, res, crs=ortho.crs)
    write_geotiff(out / "dem.tif", dem_values, Affine(res, 0.0, left, 0.0, -res, top), ortho.crs,
                  descriptions=("elevation",))
    poles = _signal_poles(opts, stop)
    write_point_cloud(out / "cloud.laz", _point_cloud(opts, poles))
    marks = np.column_stack([marking_pts, ground_z(opts, marking_pts[:, 0], marking_pts[:, 1])])
    candidates = np.vstack([marks, poles, poles + np.array([0.0, 0.0, 5.0])])
    rows, _ = pick_gcps(camera, candidates, lambda x, y: ground_z(opts, x, y), opts, np.random.default_rng(opts.seed))
    write_csv_atomic(out / "gcps.csv", pd.DataFrame(rows))
    tracks = _truth_tracks(traj, z, camera, run, opts.fps)
    if video:
        tracks = render_video(out / "video.mp4", camera, dem, ortho, traj, z, tracks, opts, progress)
    write_csv_atomic(out / "truth_tracks.csv", tracks, float_format="%.4f")
    write_point_table(out / "truth_tracks.gpkg", tracks, ortho.crs, layer="truth_tracks")
    write_csv_atomic(out / "truth_movements.csv", truth_movements(traj, run, opts))
    write_gis(out / "gates.gpkg", [_gates_layer(opts)], ortho.crs)
    summary = {"kind": "junction",
               "options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(opts).items()},
               "vehicles": len(np.unique(traj.vehicle)), "frames": opts.frame_count(), "gcps": len(rows),
               "sumo_version": run.sumo_version}
    write_text_atomic(out / "world.json", json.dumps(summary, indent=2) + "\n")
    return summary
