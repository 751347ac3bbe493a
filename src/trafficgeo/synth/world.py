"""The demo world: a SUMO-driven road scene with every file a user would have, and the truth behind them.

:func:`build_world` writes, into one folder:

* ``sumo/`` - the georeferenced SUMO network, demand and FCD of the traffic (:mod:`trafficgeo.synth.sumo_world`);
* ``ortho.tif`` - an orthophoto of the road (:mod:`trafficgeo.synth.orthophoto`), ``cloud.laz`` - lidar of it;
* ``video.mp4`` - H.264 frames through the true camera (:mod:`trafficgeo.synth.render`: vehicles as low-poly
  meshes of their class) with sensor noise, a slow illumination drift and a small camera shake;
* ``gcps.csv`` - lane-marking corners and pole bases/tops with pixel and survey noise; ``camera_truth.json``;
* ``truth_tracks.csv`` (and ``.gpkg``) - per vehicle and frame: world position, speed, lane, class, the image
  ground point and box (the silhouette box: the bounding box of the drawn vehicle) and the visible fraction;
  ``truth_counts.csv`` - per counting line, direction and lane, the vehicles crossing it (time, speed), with the
  lines in ``count_lines.gpkg``; ``lanes.gpkg`` - the lane polygons (named ``d<direction>_<lane>``).

Deterministic for a seed. The road is straight or a circular arc in plan, with a crowned cross-section, a grade
and an optional vertical crest: SUMO's network is 2-D, and z comes from
:class:`~trafficgeo.synth.gcp_scene.RoadSurface`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.io.atomic import atomic_path, write_csv_atomic, write_text_atomic
from trafficgeo.synth.gcp_scene import RoadSurface
from trafficgeo.synth.orthophoto import RoadMarkings, dash_corners, render_orthophoto
from trafficgeo.synth.sumo_scene import VEHICLE_CLASSES, Demand, RoadSpec
from trafficgeo.synth.sumo_world import Trajectories, run_sumo_world

CLASS_PALETTE = {"car": [(200, 40, 40), (40, 70, 160), (220, 220, 220), (30, 30, 30), (150, 150, 160)],
                 "van": [(235, 235, 235), (90, 90, 100)], "truck": [(230, 120, 30), (60, 110, 60)],
                 "bus": [(240, 200, 40)]}


@dataclass(frozen=True)
class WorldOptions:
    """Parameters of a demo world (metres, seconds, degrees, pixels)."""

    seed: int = 0
    lanes: int = 2
    two_way: bool = True
    length_m: float = 300.0
    lane_width: float = 3.5
    speed_limit_kmh: float = 50.0
    azimuth_deg: float = 30.0
    crossfall: float = 0.02
    grade: float = 0.0  # along the road (0.03 = 3 %); SUMO drives the 2-D plan, z follows the road surface
    crest_radius: float = 0.0  # vertical crest (m) with its apex at station 0; 0 = none
    curve_radius: float = 0.0  # horizontal curve (m): > 0 turns right, < 0 left, 0 = straight
    veh_per_hour_per_lane: float = 600.0
    mix: dict[str, float] = field(default_factory=lambda: {"car": 0.8, "van": 0.1, "truck": 0.07, "bus": 0.03})
    duration_s: float = 60.0
    fps: float = 25.0
    image_size: tuple[int, int] = (1920, 1080)
    camera_height: float = 8.0
    camera_setback: float = 5.0  # camera this far beyond the right edge of the road
    camera_station: float = -60.0
    heading_deg: float | None = None  # default: looking at the road axis 25 m past the origin
    tilt_deg: float | None = None
    focal_px: float | None = None  # default 0.9 x image width
    dist: tuple[float, float, float, float, float] = (-0.06, 0.012, 0.0, 0.0, 0.0)
    pixel_sigma: float = 1.0
    survey_sigma: float = 0.02
    n_outliers: int = 0  # control GCPs given a gross error (a wrong click, 15-40 px)
    count_stations: tuple[float, ...] = (0.0,)  # counting lines across the road at these stations (m)
    n_z_outliers: int = 0  # control GCPs on the ground given a Z 3-8 m too high (a tree or a vehicle in the lidar)
    sensor_noise: float = 2.0  # grey levels (1 sigma)
    shake_px: float = 0.3
    illumination_drift: float = 0.06  # peak relative change of brightness over the clip
    shadows: bool = True
    ortho_resolution: float = 0.05  # orthophoto pixel (m)
    view_half_size: float = 100.0  # orthophoto, DEM and lidar cover this far (m) around the road at station 20
    origin: tuple[float, float, float] = (245000.0, 5182600.0, 90.0)
    crs: str = "EPSG:2949"


def world_camera(road: RoadSurface, markings: RoadMarkings, opts: WorldOptions) -> Camera:
    """The roadside camera: on a pole beyond the right edge, looking along the road at station +25 on the axis."""
    w, _ = opts.image_size
    pos = road.points([opts.camera_station], [markings.right_edge + opts.camera_setback])[0]
    pos[2] += opts.camera_height
    target = road.points([25.0], [0.0])[0]
    d = target - pos
    heading = float(np.degrees(np.arctan2(d[0], d[1])) % 360.0) if opts.heading_deg is None else opts.heading_deg
    tilt = float(np.degrees(np.arctan2(-d[2], np.hypot(d[0], d[1])))) if opts.tilt_deg is None else opts.tilt_deg
    f = opts.focal_px or 0.9 * w
    return Camera.from_orientation(opts.image_size, f, pos, heading, tilt, 0.0, dist=list(opts.dist), crs=opts.crs)


def _vehicle_colours(ids: np.ndarray, vclass: np.ndarray, seed: int) -> np.ndarray:
    out = np.zeros((len(ids), 3))
    for i, (vid, cls) in enumerate(zip(ids, vclass, strict=True)):
        palette = CLASS_PALETTE.get(str(cls), [(128, 128, 128)])
        h = (sum(ord(ch) for ch in str(vid)) * 2654435761 + seed) % (2**32)
        out[i] = palette[h % len(palette)]
    return out


def make_gcps(camera: Camera, road: RoadSurface, markings: RoadMarkings, opts: WorldOptions,
              rng: np.random.Generator) -> tuple[list[dict[str, object]], np.ndarray]:
    """GCP rows (noisy pixels and world) at dash corners and pole bases/tops in the frame within 90 m of the camera
    (spread by farthest-point sampling in the image); returns the rows and the true world points."""
    corners = dash_corners(road, markings, (-40.0, 90.0))
    poles_s = np.arange(-30.0, 100.0, 25.0)
    bases = road.points(poles_s, np.full(poles_s.shape, markings.left_edge - markings.shoulder - 1.0))
    tops = bases + np.array([0.0, 0.0, 5.0])
    world = np.vstack([corners, bases, tops])
    return pick_gcps(camera, world, lambda x, y: road.z(x, y), opts, rng)


def pick_gcps(camera: Camera, world: np.ndarray, ground_z, opts, rng: np.random.Generator,
              ) -> tuple[list[dict[str, object]], np.ndarray]:
    """GCP rows from candidate world points (N, 3): those in the frame (10 px margin) within 90 m of the camera,
    up to 24 spread by farthest-point sampling in the image, with pixel (``opts.pixel_sigma``) and survey
    (``opts.survey_sigma``) noise, every fifth a check point, ``opts.n_outliers`` control points given a gross
    pixel error and ``opts.n_z_outliers`` control points on the ground (``ground_z(x, y)``) a Z 3-8 m too high.
    Returns the rows and the true world points."""
    uv = camera.project(world)
    ok = camera.in_image(uv, margin=10)
    dist = np.linalg.norm(world - camera.position, axis=1)
    ok &= dist < 90.0
    idx = np.flatnonzero(ok)
    # Spread the points over the frame: farthest-point sampling in the image, from a random first point.
    chosen = [int(rng.integers(idx.size))] if idx.size else []
    d2 = np.full(idx.size, np.inf)
    while len(chosen) < min(idx.size, 24):
        d2 = np.minimum(d2, np.sum((uv[idx] - uv[idx[chosen[-1]]]) ** 2, axis=1))
        chosen.append(int(np.argmax(d2)))
    idx = np.sort(idx[chosen])
    rows = []
    n_check = max(3, len(idx) // 5)
    for k, i in enumerate(idx):
        p = world[i] + rng.normal(0.0, opts.survey_sigma, 3)
        q = uv[i] + rng.normal(0.0, opts.pixel_sigma, 2)
        rows.append({"id": f"G{k + 1:02d}", "x": round(p[0], 3), "y": round(p[1], 3), "z": round(p[2], 3),
                     "u": round(q[0], 2), "v": round(q[1], 2), "role": "check" if k % 5 == 4 and
                     sum(r["role"] == "check" for r in rows) < n_check else "control",
                     "sigma_px": opts.pixel_sigma})
    control = [k for k, r in enumerate(rows) if r["role"] == "control"]
    picked = rng.permutation(control)
    for k in picked[: opts.n_outliers]:
        angle = rng.uniform(0, 2 * np.pi)
        size = rng.uniform(15.0, 40.0)
        rows[k]["u"] = round(float(rows[k]["u"]) + size * np.cos(angle), 2)
        rows[k]["v"] = round(float(rows[k]["v"]) + size * np.sin(angle), 2)
    on_ground = [k for k in picked[opts.n_outliers:]
                 if abs(world[idx[k], 2] - ground_z(world[idx[k], 0], world[idx[k], 1])) < 0.05]
    for k in on_ground[: opts.n_z_outliers]:
        rows[k]["z"] = round(float(rows[k]["z"]) + rng.uniform(3.0, 8.0), 3)
    return rows, world[idx]


def build_world(out_dir: str | Path, opts: WorldOptions | None = None, *, video: bool = True,
                progress=None) -> dict[str, object]:
    """Build the demo world into ``out_dir`` (see the module docstring); returns a summary dictionary."""
    import pandas as pd

    from trafficgeo.geo.pointcloud import write_point_cloud
    from trafficgeo.geo.raster import write_geotiff
    from trafficgeo.geo.surface import DEMSurface
    from trafficgeo.synth.terrain import road_point_cloud

    opts = opts or WorldOptions()
    # Every option is checked (RoadSpec, Demand) before anything is written.
    spec = RoadSpec(origin=opts.origin, azimuth_deg=opts.azimuth_deg, length_m=opts.length_m, lanes=opts.lanes,
                    two_way=opts.two_way, lane_width=opts.lane_width, speed_limit_kmh=opts.speed_limit_kmh,
                    crs=opts.crs, curve_radius=opts.curve_radius)
    demand = Demand(opts.veh_per_hour_per_lane, dict(opts.mix))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(opts.seed)
    road = RoadSurface(origin=np.array(opts.origin), azimuth_deg=opts.azimuth_deg, grade=opts.grade,
                       crossfall=opts.crossfall, crest_radius=opts.crest_radius, curve_radius=opts.curve_radius)
    markings = RoadMarkings(lanes_right=opts.lanes, lanes_left=opts.lanes if opts.two_way else 0,
                            lane_width=opts.lane_width)
    # SUMO steps are whole milliseconds: for frame rates like 30 fps simulate at 10 ms and resample to the frames.
    step = 1.0 / opts.fps
    exact = abs(1000.0 * step - round(1000.0 * step)) < 1e-9
    run = run_sumo_world(out / "sumo", spec, demand, duration_s=opts.duration_s,
                         step_s=round(1000.0 * step) / 1000.0 if exact else 0.01, seed=opts.seed)
    traj = run.trajectories if exact else resample_trajectories(run.trajectories, opts.fps, opts.duration_s)
    z = road.z(traj.x, traj.y)
    camera = world_camera(road, markings, opts)
    write_camera_json(out / "camera_truth.json", camera)
    # Orthophoto, DEM and lidar around what the camera sees.
    c = road.points([20.0], [0.0])[0]
    half = opts.view_half_size
    bounds = (c[0] - half, c[1] - half, c[0] + half, c[1] + half)
    ortho = render_orthophoto(road, markings, bounds, resolution=opts.ortho_resolution, seed=opts.seed)
    write_geotiff(out / "ortho.tif", ortho.data, ortho.transform, ortho.crs, descriptions=ortho.descriptions)
    res = 0.25
    n = int(2 * half / res)
    gx = bounds[0] + (np.arange(n) + 0.5) * res
    gy = bounds[3] - (np.arange(n) + 0.5) * res
    X, Y = np.meshgrid(gx, gy)
    dem = DEMSurface(road.z(X, Y), bounds[0], bounds[3], res, res, crs=ortho.crs)
    write_point_cloud(out / "cloud.laz", road_point_cloud(road, c[:2], half, density=4.0, seed=opts.seed,
                                                          crs=opts.crs))
    rows, _truth_gcps = make_gcps(camera, road, markings, opts, rng)
    gcp_df = pd.DataFrame(rows)
    write_csv_atomic(out / "gcps.csv", gcp_df)
    tracks = _truth_tracks(traj, z, camera, opts)
    counts = _truth_counts(traj, opts.count_stations)
    if video:
        tracks = render_video(out / "video.mp4", camera, dem, ortho, traj, z, tracks, opts, progress)
    write_csv_atomic(out / "truth_tracks.csv", tracks, float_format="%.4f")
    write_csv_atomic(out / "truth_counts.csv", counts)
    from trafficgeo.io.tables import write_point_table

    write_point_table(out / "truth_tracks.gpkg", tracks, ortho.crs, layer="truth_tracks")
    from trafficgeo.io.gis import write_gis

    write_gis(out / "count_lines.gpkg", [_count_lines_layer(road, markings, opts.count_stations)], ortho.crs)
    write_gis(out / "lanes.gpkg", [lanes_layer(spec)], ortho.crs)
    summary = {"options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(opts).items()},
               "vehicles": len(np.unique(traj.vehicle)), "frames": _frame_count(opts),
               "gcps": len(rows), "sumo_version": run.sumo_version}
    write_text_atomic(out / "world.json", json.dumps(summary, indent=2) + "\n")
    return summary


def _frame_count(opts: WorldOptions) -> int:
    """Frames in the clip: one every 1/fps seconds from 0 up to (not including) the duration."""
    return int(np.ceil(opts.duration_s * opts.fps - 1e-9))


def resample_trajectories(traj: Trajectories, fps: float, duration_s: float) -> Trajectories:
    """Trajectories at the frame times k / fps (linear in position, speed and unwrapped heading; lane, class and
    size from the sample before), for each vehicle within the span it was observed."""
    times = np.arange(_frame_count(WorldOptions(fps=fps, duration_s=duration_s))) / fps
    parts: dict[str, list[np.ndarray]] = {name: [] for name in type(traj).__dataclass_fields__}
    for vid in np.unique(traj.vehicle):
        idx = np.flatnonzero(traj.vehicle == vid)
        idx = idx[np.argsort(traj.time[idx])]
        t = traj.time[idx]
        tk = times[(times >= t[0]) & (times <= t[-1])]
        if tk.size == 0:
            continue
        before = np.clip(np.searchsorted(t, tk, side="right") - 1, 0, len(t) - 1)
        for name in parts:
            col = getattr(traj, name)[idx]
            if name == "time":
                parts[name].append(tk)
            elif name == "heading_deg":
                parts[name].append(np.degrees(np.interp(tk, t, np.unwrap(np.radians(col)))) % 360.0)
            elif name in ("x", "y", "z", "speed", "station", "offset"):
                parts[name].append(np.interp(tk, t, col))
            else:
                parts[name].append(col[before])
    if not parts["time"]:
        return traj
    cols = {name: np.concatenate(v) for name, v in parts.items()}
    order = np.lexsort((cols["vehicle"], cols["time"]))
    return type(traj)(**{name: v[order] for name, v in cols.items()})


def _truth_tracks(traj: Trajectories, z: np.ndarray, camera: Camera, opts: WorldOptions):
    import pandas as pd

    frame = np.rint(traj.time * opts.fps).astype(int)
    ground = camera.project(np.column_stack([traj.x, traj.y, z]))
    return pd.DataFrame({
        "frame": frame, "time": traj.time, "vehicle": traj.vehicle, "class": traj.vclass,
        "x": traj.x, "y": traj.y, "z": z, "speed_kmh": traj.speed * 3.6, "heading_deg": traj.heading_deg,
        "direction": traj.direction, "lane": traj.lane, "length": traj.length, "width": traj.width,
        "height": traj.height, "u": ground[:, 0], "v": ground[:, 1],
    })


def _truth_counts(traj: Trajectories, stations: tuple[float, ...]):
    """Vehicles crossing each counting line (station) per direction and lane (lane at the crossing), with the
    interpolated crossing time and speed."""
    import pandas as pd

    rows = []
    order = np.lexsort((traj.time, traj.vehicle))
    veh, s, t, lane, d, v = (traj.vehicle[order], traj.station[order], traj.time[order], traj.lane[order],
                             traj.direction[order], traj.speed[order])
    same = veh[1:] == veh[:-1]
    sign = np.where(d[1:] == 1, 1.0, -1.0)
    for k, line in enumerate(stations):
        rel = s - line
        cross = same & (rel[:-1] * sign < 0) & (rel[1:] * sign >= 0)
        for i in np.flatnonzero(cross):
            frac = -rel[i] / (rel[i + 1] - rel[i])
            rows.append({"line": k + 1, "station": float(line), "vehicle": veh[i], "direction": int(d[i]),
                         "lane": int(lane[i + 1]), "time": float(t[i] + frac * (t[i + 1] - t[i])),
                         "speed_kmh": float(3.6 * (v[i] + frac * (v[i + 1] - v[i])))})
    return pd.DataFrame(rows, columns=["line", "station", "vehicle", "direction", "lane", "time", "speed_kmh"])


def _count_lines_layer(road: RoadSurface, markings: RoadMarkings, stations: tuple[float, ...]):
    """The counting lines as a GIS layer: straight lines across the paved road at each station."""
    from shapely.geometry import LineString

    from trafficgeo.io.gis import Layer

    lo, hi = markings.left_edge - markings.shoulder, markings.right_edge + markings.shoulder
    geoms = [LineString(road.points([st, st], [lo, hi])) for st in stations]
    return Layer("count_lines", geoms, {"line": list(range(1, len(stations) + 1)), "station": list(stations)})


def truth_lane_name(direction: object, lane: object) -> np.ndarray:
    """The name of a SUMO direction/lane pair in ``lanes.gpkg``: ``d<direction>_<lane>`` (lane 1 = innermost)."""
    d = np.asarray(direction).astype(int).astype(str)
    k = np.asarray(lane).astype(int).astype(str)
    return np.char.add(np.char.add(np.char.add("d", d), "_"), k)


def lanes_layer(spec: RoadSpec):
    """Every lane of the road as a polygon named by :func:`truth_lane_name`, with its direction of travel
    (``bearing``, deg clockwise from north at station 0)."""
    from shapely.geometry import Polygon

    from trafficgeo.io.gis import Layer

    keys = [(d, k) for d in spec.directions for k in range(1, spec.lanes + 1)]
    geoms = [Polygon(spec.lane_polygon(d, k)[:, :2]) for d, k in keys]
    return Layer("lanes", geoms, {"lane": [str(truth_lane_name(d, k)) for d, k in keys],
                                  "direction": [d for d, _ in keys],
                                  "bearing": [spec.heading_deg(d) for d, _ in keys]})


def render_video(path: Path, camera: Camera, dem, ortho, traj, z: np.ndarray, tracks, opts, progress):
    """Render and encode the frames (H.264 via PyAV); adds the truth image boxes to ``tracks``.

    ``traj`` is any trajectory table with the fields of :class:`Trajectories` used here (``time`` sorted, ``vehicle``,
    ``vclass``, ``x``, ``y``, ``heading_deg``, ``length``, ``width``, ``height``), ``z`` (m) the ground height of
    each row and ``tracks`` the truth table with one row per trajectory row (``frame``, ``u``, ``v``). ``opts``
    gives ``seed``, ``fps``, ``duration_s``, ``sensor_noise``, ``shake_px``, ``illumination_drift`` and ``shadows``
    (:class:`WorldOptions` or :class:`~trafficgeo.synth.junction_sumo.JunctionOptions`)."""
    import av
    import cv2

    from trafficgeo.synth.render import Boxes, drape_orthophoto, render_frame

    rng = np.random.default_rng(opts.seed + 1)
    background = np.clip(np.rint(drape_orthophoto(camera, dem, ortho)), 0, 255).astype(np.uint8)
    w, h = camera.image_size
    frames = _frame_count(opts)
    colours = _vehicle_colours(traj.vehicle, traj.vclass, opts.seed)
    frame_of = np.rint(traj.time * opts.fps).astype(int)
    starts = np.searchsorted(frame_of, np.arange(frames + 1))
    boxes_out = np.full((len(traj), 4), np.nan)
    visible = np.zeros(len(traj))
    # Sensor noise: a small bank of grey noise frames, split into the parts added and subtracted (uint8, saturating).
    bank = []
    for _ in range(4):
        noise = np.rint(rng.normal(0.0, opts.sensor_noise, (h, w, 1))).astype(np.int16).repeat(3, axis=2)
        bank.append((np.clip(noise, 0, 255).astype(np.uint8), np.clip(-noise, 0, 255).astype(np.uint8)))
    # Camera shake: a mean-reverting random walk (AR(1), ~1 s memory) with a stationary RMS of shake_px per axis.
    a = float(np.exp(-1.0 / max(opts.fps, 1.0)))
    shake = np.zeros((frames, 2))
    kicks = rng.normal(0.0, opts.shake_px * np.sqrt(1 - a * a), (frames, 2))
    if frames:
        shake[0] = rng.normal(0.0, opts.shake_px, 2)
    for f in range(1, frames):
        shake[f] = a * shake[f - 1] + kicks[f]
    phase = rng.uniform(0, 2 * np.pi)
    import queue
    import threading

    with atomic_path(path) as tmp:
        container = av.open(str(tmp), mode="w", format="mp4")
        stream = container.add_stream("libx264", rate=round(opts.fps))
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        stream.options = {"crf": "23", "preset": "superfast"}
        # Encoding runs in a second thread (x264 and OpenCV release the GIL), overlapping the next frame's drawing.
        todo: queue.Queue = queue.Queue(maxsize=4)
        failure: list[BaseException] = []

        def encode() -> None:
            try:
                while (item := todo.get()) is not None:
                    for packet in stream.encode(av.VideoFrame.from_ndarray(item, format="rgb24")):
                        container.mux(packet)
                for packet in stream.encode():
                    container.mux(packet)
            except BaseException as exc:  # re-raised in the caller's thread
                failure.append(exc)
                while todo.get() is not None:
                    pass

        worker = threading.Thread(target=encode, name="encode", daemon=True)
        worker.start()
        try:
            for f in range(frames):
                if failure:
                    break
                sl = slice(starts[f], starts[f + 1])
                boxes = Boxes(centre=np.column_stack([traj.x[sl], traj.y[sl], z[sl]]),
                              heading_deg=traj.heading_deg[sl], length=traj.length[sl], width=traj.width[sl],
                              height=traj.height[sl], colour=colours[sl], kind=traj.vclass[sl])
                img, truth = render_frame(camera, background, boxes, shadows=opts.shadows)
                gain = 1.0 + opts.illumination_drift * np.sin(2 * np.pi * f / max(frames, 1) + phase)
                img = cv2.convertScaleAbs(img, alpha=gain)
                plus, minus = bank[f % len(bank)]
                img = cv2.subtract(cv2.add(img, plus), minus)
                dx, dy = shake[f]
                if opts.shake_px > 0:
                    img = cv2.warpAffine(img, np.float32([[1, 0, dx], [0, 1, dy]]), (w, h),
                                         borderMode=cv2.BORDER_REPLICATE)
                boxes_out[sl] = truth.box + np.array([dx, dy, dx, dy])
                visible[sl] = truth.visible_fraction
                todo.put(img)
                if progress is not None:
                    progress(f + 1, frames)
        finally:
            todo.put(None)
            worker.join()
        if failure:
            raise failure[0]
        container.close()
    tracks = tracks.copy()
    tracks["x1"], tracks["y1"], tracks["x2"], tracks["y2"] = boxes_out.T
    tracks["u"] = tracks["u"] + shake[np.clip(tracks["frame"].to_numpy(), 0, frames - 1), 0]
    tracks["v"] = tracks["v"] + shake[np.clip(tracks["frame"].to_numpy(), 0, frames - 1), 1]
    tracks["visible_fraction"] = visible
    return tracks


__all__ = ["VEHICLE_CLASSES", "WorldOptions", "build_world", "make_gcps", "pick_gcps", "render_video",
           "world_camera"]
