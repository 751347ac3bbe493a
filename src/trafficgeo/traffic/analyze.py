"""``analyze``: image tracks -> world trajectories, lanes, counting-line crossings and counts, written to a folder.

Outputs of :func:`write_analysis` (all written atomically):

* ``vehicles.csv`` - one row per vehicle (the fragments of its track joined: :mod:`trafficgeo.traffic.journeys`,
  with ``fragments``, ``tracker_ids`` and ``stationary``): class, lane(s), lane changes, first/last time,
  distance travelled and speed (km/h) over the time seen, path length, length where estimated (speeds as in
  :mod:`trafficgeo.traffic.trajectories`);
* ``counts.csv`` - per counting line, lane, direction and interval: counts (also per class), flow (veh/h),
  time-mean and space-mean speed, headways and gaps (:func:`trafficgeo.traffic.counts.aggregate_counts`);
* ``crossings.csv`` - every vehicle at every line: time, direction, lane, speed; ``hidden`` is true for a vehicle
  that passed the line out of sight behind a nearer one, carried on from where it vanished
  (:mod:`trafficgeo.traffic.occlusion`, ``TrajectoryOptions.coast_hidden_s``);
* ``trajectories.csv``, ``trajectories.parquet`` (GeoParquet points) and ``trajectories.gpkg`` (layers ``points``,
  ``paths`` - one line per vehicle - and, when given, ``lanes`` and ``count_lines``);
* with a junction's gates (:mod:`trafficgeo.site.gates`): ``movements.csv`` (one row per vehicle through the
  junction: origin and destination arm, movement, entry/exit times, travel and stopped time),
  ``movement_counts.csv`` (complete movements per interval, origin, destination and class) and
  ``turning_movements.csv`` (the turning-movement table per interval: approach x left/through/right/U, total and
  heavy vehicles) - :mod:`trafficgeo.traffic.movements`; the gates are a layer of ``trajectories.gpkg``;
* ``summary.json`` - totals and the options used (with gates: the junction's arms, complete and incomplete
  movements, the peak hour and its PHF).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import shapely

from trafficgeo.camera.calibrated import CalibratedCamera
from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.geo.mapping import Surface, camera_crs
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.site.gates import Gate, Junction
from trafficgeo.site.lanes import Lanes
from trafficgeo.site.lines import CountLine
from trafficgeo.traffic.counts import aggregate_counts, find_crossings
from trafficgeo.traffic.journeys import JOURNEY_COLUMNS, JourneyOptions, join_fragments
from trafficgeo.traffic.lane_changes import lane_visits, main_lane
from trafficgeo.traffic.movements import MOVEMENT_INTERVAL_S
from trafficgeo.traffic.occlusion import hidden_crossings
from trafficgeo.traffic.speed import ScaleKnowledge, SpeedOptions, scale_drift_warning
from trafficgeo.traffic.trajectories import TrajectoryOptions, WorldTracks, world_trajectories


@dataclass(frozen=True)
class TrafficResult:
    """Everything ``analyze`` computes from one set of image tracks: the tables of
    :mod:`trafficgeo.run.folder` (``points`` is ``trajectories.csv``), the ``period`` (s) the tracks span,
    the points dropped per reason, the lanes and lines used, the options, the warnings and ``links``, the pieces of
    track joined into vehicles (:class:`trafficgeo.traffic.journeys.Journeys`; not written to the run folder).
    With gates: the ``junction``, its ``movements``, ``movement_counts`` and ``turning`` table
    (:mod:`trafficgeo.traffic.movements`)."""

    points: pd.DataFrame
    vehicles: pd.DataFrame
    crossings: pd.DataFrame
    counts: pd.DataFrame
    period: tuple[float, float]  # s, first and last time in the input tracks
    dropped: dict[str, int]
    lanes: Lanes | None = None
    lines: list[CountLine] = field(default_factory=list)
    options: dict[str, object] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    links: pd.DataFrame | None = None
    junction: Junction | None = None
    movements: pd.DataFrame | None = None
    movement_counts: pd.DataFrame | None = None
    turning: pd.DataFrame | None = None


Analysis = TrafficResult  # the former name


@dataclass(frozen=True)
class AnalysisOptions:
    """How image tracks become traffic data (:func:`analyze`): counts per ``interval_s`` s, a junction's turning
    movements per ``movement_interval_s`` s, the smoother's options (``trajectory``; None: the defaults, at a
    junction :meth:`~trafficgeo.traffic.trajectories.TrajectoryOptions.at_junction`) and how the
    pieces of one vehicle's track are joined (``journeys``, :mod:`trafficgeo.traffic.journeys`; None: the defaults,
    at a junction :meth:`~trafficgeo.traffic.journeys.JourneyOptions.at_junction`).
    Checked when made: a bad interval fails before any work."""

    interval_s: float = 60.0
    movement_interval_s: float = MOVEMENT_INTERVAL_S
    trajectory: TrajectoryOptions | None = None
    journeys: JourneyOptions | None = None

    def __post_init__(self) -> None:
        from trafficgeo.traffic.counts import check_interval
        from trafficgeo.traffic.movements import check_movement_interval

        check_interval(self.interval_s)
        check_movement_interval(self.movement_interval_s)


def add_lanes(world: WorldTracks, lanes: Lanes, *, min_dwell_s: float = 1.0) -> None:
    """Lane of every point, and each vehicle's main lane, lane sequence and number of lane changes (in place)."""
    pts, veh = world.points, world.vehicles
    heading = pts["heading_deg"].to_numpy() if "heading_deg" in pts.columns else None
    pts["lane"] = lanes.assign(pts["x"].to_numpy(), pts["y"].to_numpy(), heading) if len(pts) else ""
    main, seq, changes = [], [], []
    groups = dict(tuple(pts.groupby("track_id", sort=False))) if len(pts) else {}
    for tid in veh["track_id"]:
        g = groups.get(tid)
        visits = lane_visits(g["time"], g["lane"], min_dwell_s=min_dwell_s) if g is not None else []
        main.append(main_lane(visits))
        seq.append(">".join(v.lane for v in visits))
        changes.append(max(len(visits) - 1, 0))
    veh["lane"], veh["lanes"], veh["lane_changes"] = main, seq, changes


CAR_HEIGHT_M = 1.5  # m, the height of the car in the occlusion warning
MAX_HIDDEN_M = 20.0  # m of road hidden behind a car at a counting line above which analyze warns


def _distance_and_height_m(camera: Camera, surface: Surface, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal distance from the camera and the camera's height above the ground (m) at ground positions
    ``xy`` (N, 2; CRS units; heights in the same unit)."""
    crs = camera_crs(camera)
    m = metres_per_unit(crs) if crs is not None else 1.0
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    z = np.asarray(surface.elevation(xy[:, 0], xy[:, 1]), dtype=np.float64)
    c = np.asarray(camera.position, dtype=np.float64)
    return np.hypot(xy[:, 0] - c[0], xy[:, 1] - c[1]) * m, (c[2] - z) * m


def hidden_behind_m(camera: Camera, surface: Surface, xy: np.ndarray, height_m: float = CAR_HEIGHT_M) -> np.ndarray:
    """Length of road (m) hidden behind a vehicle ``height_m`` high whose far end stands at each ground position
    ``xy`` (N, 2; CRS units; heights in the same unit), seen from ``camera``: over level ground, a roof edge ``D`` m
    away horizontally and ``H`` m below the camera hides the road from ``D`` to ``D H / (H - h)``, that is
    ``D h / (H - h)`` m behind it along the line of sight (inf where the camera is not higher than the roof)."""
    dist, height = _distance_and_height_m(camera, surface, xy)
    above = height - float(height_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(above > 1e-6, dist * float(height_m) / above, np.inf)


def line_warnings(camera: Camera, surface: Surface, lines: list[CountLine], options: TrajectoryOptions,
                  samples: int = 21) -> list[str]:
    """Warnings about counting lines where counts cannot be trusted:

    * more than 10 % of the line lies where track points are not used (too far away, or at the end of the
      surface): vehicles are not counted there;
    * seen from the camera, a car at the line hides more than :data:`MAX_HIDDEN_M` of road behind it
      (:func:`hidden_behind_m`, median over the line's usable part): the camera looks along the road at a grazing
      angle there, vehicles close behind one another (in one lane or the next) overlap in the image, often in one
      blob, and may go uncounted in dense traffic.
    """
    from trafficgeo.traffic.plausibility import line_out_of_view_warning
    from trafficgeo.traffic.trajectories import usable_positions

    out = []
    for line in lines:
        at = shapely.line_interpolate_point(line.geometry, np.linspace(0.0, 1.0, samples), normalized=True)
        xy = shapely.get_coordinates(at)
        unseen = line_out_of_view_warning(camera, surface, line.name, xy)
        if unseen is not None:  # "move it nearer" would mislead: the line is not in view at all
            out.append(unseen)
            continue
        status = usable_positions(camera, surface, xy, options)
        bad = status != "ok"
        if bad.mean() > 0.1:  # a line's ends often reach over the shoulders: those do not matter
            why = {"too_far": f"farther than where one pixel spans {options.max_metres_per_px:g} m of road",
                   "surface_edge": "at the end of the road surface"}
            reasons = " or ".join(why[r] for r in sorted(set(status[bad])))
            out.append(f"counting line {line.name}: {bad.mean():.0%} of it lies {reasons}, where track points are "
                       "not used: vehicles there are not counted; move the line nearer the camera (or raise "
                       "--max-metres-per-px)")
        if bad.all():
            continue
        hidden = float(np.median(hidden_behind_m(camera, surface, xy[~bad])))
        if hidden > MAX_HIDDEN_M:
            dist, height = (float(np.median(v)) for v in _distance_and_height_m(camera, surface, xy[~bad]))
            length = "all the road" if not np.isfinite(hidden) else f"{hidden:.0f} m of road"
            out.append(f"counting line {line.name}: seen from {height:.1f} m above the road and {dist:.0f} m away, "
                       f"a car {CAR_HEIGHT_M:g} m high hides {length} behind it: vehicles close behind it, in its lane "
                       "or the next, overlap it in the image there and may go uncounted in dense traffic; count "
                       "nearer the camera or film from higher up")
    return out


def uncrossed_warnings(lines: list[CountLine], crossings: pd.DataFrame, period: tuple[float, float]) -> list[str]:
    """One warning per counting line that no vehicle crossed in the ``period`` (s) observed: its counts are zeros,
    which may be true (no traffic) or a miss (the line is off the road, or vehicles there go undetected)."""
    crossed = set(crossings["line"].astype(str)) if len(crossings) else set()
    seconds = period[1] - period[0]
    return [f"counting line {line.name}: no vehicle crossed it in the {seconds:.1f} s observed (counts.csv lists it "
            "with zeros); if vehicles did pass, check that the line lies across the road where they drive and that "
            "they are detected there"
            for line in lines if line.name not in crossed]


BARE_CAMERA_WARNING = (
    "camera: a bare Camera carries no record of its calibration (no GCPs, no covariance), so each vehicle's "
    "speed_kmh is measured over the middle half of the time it is seen, not where the calibration knows the ground "
    "scale; pass the CalibratedCamera (tg.load_camera(path), Calibration.calibrated_camera()) or the camera JSON")


def warn_bare_camera(camera: object, knowledge: ScaleKnowledge | None = None, stacklevel: int = 3) -> None:
    """Say (:class:`UserWarning`, :data:`BARE_CAMERA_WARNING`) that a bare :class:`Camera` given to an entry point
    that measures speeds drops what a calibration knows, unless ``knowledge`` is given for it."""
    if isinstance(camera, Camera) and knowledge is None:
        import warnings

        warnings.warn(BARE_CAMERA_WARNING, UserWarning, stacklevel=stacklevel)


def analyze(camera: Camera, surface: Surface, tracks: ImageTracks, *, lanes: Lanes | None = None,
            lines: list[CountLine] | None = None, interval_s: float = 60.0,
            options: TrajectoryOptions | None = None, progress=None, knowledge: ScaleKnowledge | None = None,
            speed_options: SpeedOptions | None = None, journeys: JourneyOptions | None = None,
            gates: list[Gate] | None = None, movement_interval_s: float = MOVEMENT_INTERVAL_S) -> TrafficResult:
    """The whole analysis of one set of image tracks (see the module docstring). ``knowledge``: what the
    calibration knows of its ground scale (:meth:`ScaleKnowledge.from_camera` of the calibrated camera; None for
    a camera made by hand), which places each vehicle's headline speed (:mod:`trafficgeo.traffic.speed`);
    ``journeys``: how the fragments of one vehicle are joined (:mod:`trafficgeo.traffic.journeys`); ``gates``: a
    junction's gates, for turning movements counted per ``movement_interval_s`` s (``options`` then default to
    :meth:`TrajectoryOptions.at_junction`)."""
    from trafficgeo.site.checks import check_camera_above_surface
    from trafficgeo.traffic.counts import interval_edges
    from trafficgeo.traffic.plausibility import lanes_warning

    check_camera_above_surface(camera, surface)
    period = (float(tracks.time.min()), float(tracks.time.max())) if len(tracks) else (0.0, 0.0)
    interval_edges(*period, interval_s)  # checks the interval before the work
    junction = Junction.from_gates(gates) if gates else None
    opts = options or (TrajectoryOptions.at_junction() if junction is not None else TrajectoryOptions())
    if junction is not None:
        from trafficgeo.traffic.movements import check_movement_interval

        interval_edges(*period, check_movement_interval(movement_interval_s))
    speed_opts = speed_options or SpeedOptions()
    world = world_trajectories(camera, surface, tracks, opts, progress=progress, knowledge=knowledge,
                               speed_options=speed_opts)
    crs = camera_crs(camera)
    mpu = metres_per_unit(crs) if crs is not None else 1.0
    journey_opts = journeys or (JourneyOptions.at_junction() if junction is not None else JourneyOptions())
    joined = join_fragments(world, metres_per_unit=mpu, lanes=lanes, options=journey_opts, min_points=opts.min_points)
    dropped = dict(world.dropped)
    for reason, n in joined.dropped.items():
        dropped[reason] = dropped.get(reason, 0) + n
    world = WorldTracks(points=joined.points, vehicles=joined.vehicles, dropped=dropped)
    if lanes is not None:
        add_lanes(world, lanes)
    else:
        world.points["lane"] = ""
        world.vehicles["lane"], world.vehicles["lanes"], world.vehicles["lane_changes"] = "", "", 0
    later = [c for c in JOURNEY_COLUMNS if c in world.vehicles.columns]  # after the lanes, as in vehicles.csv
    world = WorldTracks(points=world.points, dropped=world.dropped,
                        vehicles=world.vehicles[[c for c in world.vehicles.columns if c not in later] + later])
    if "length_m" in world.vehicles.columns and len(world.points):
        world.points["length_m"] = world.points["track_id"].map(world.vehicles.set_index("track_id")["length_m"])
    if {"length_m", "length_std_m"} <= set(world.vehicles.columns) and len(world.vehicles):
        _classes_by_length(world)
    moving = _moving_points(world)  # stationary objects are not traffic: they count at no line
    crossings = find_crossings(moving, lines or [], lanes, metres_per_unit=mpu)
    hidden = hidden_crossings(moving, tracks, camera.image_size, lines or [], lanes, crossings,
                              coast_s=opts.coast_hidden_s, period=period, metres_per_unit=mpu)
    crossings = crossings.assign(hidden=False)
    if len(hidden):
        crossings = pd.concat([crossings, hidden.assign(hidden=True)], ignore_index=True).sort_values(
            ["line", "time"], kind="stable").reset_index(drop=True)
    counts = aggregate_counts(crossings, interval_s, *period, lines=lines, lanes=lanes)
    warnings = line_warnings(camera, surface, lines or [], opts) + uncrossed_warnings(lines or [], crossings, period)
    lane_problem = lanes_warning(camera, surface, lanes, world.points)
    if lane_problem is not None:
        warnings.append(lane_problem)
    drift = scale_drift_warning(camera, world.points, world.vehicles, speed_opts)
    if drift is not None:
        warnings.append(drift)
    movements = movement_counts = turning = None
    if junction is not None:
        movements, movement_counts, turning = _movements(world, junction, movement_interval_s, period, mpu)
    options = {**asdict(opts), "interval_s": interval_s,
               "speed_scale_knowledge": knowledge.describe() if knowledge is not None else "none",
               "journeys": asdict(journey_opts)}
    if junction is not None:
        options["movement_interval_s"] = movement_interval_s
    return TrafficResult(points=world.points, vehicles=world.vehicles, crossings=crossings, counts=counts,
                         period=period, dropped=world.dropped, lanes=lanes, lines=list(lines or []),
                         options=options, warnings=warnings, links=joined.links, junction=junction,
                         movements=movements, movement_counts=movement_counts, turning=turning)


def _movements(world: WorldTracks, junction: Junction, interval_s: float, period: tuple[float, float],
               metres_per_unit: float) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """The movements, their counts per interval and the turning-movement table (:mod:`trafficgeo.traffic.movements`)."""
    from trafficgeo.traffic.movements import movement_counts, turning_movement_table, vehicle_movements

    moves = vehicle_movements(world.points, world.vehicles, junction, metres_per_unit=metres_per_unit)
    first_seen = world.vehicles.set_index(world.vehicles["track_id"].astype(str))["first_time"]
    counts = movement_counts(moves, junction, interval_s, *period, first_seen=first_seen)
    return moves, counts, turning_movement_table(counts, junction)


def _classes_by_length(world: WorldTracks) -> None:
    """Vehicles whose class the detector could not tell (or called a car or van) given the class of their
    measured length (:func:`trafficgeo.traffic.measurements.classes_by_length`), in the points too (in place)."""
    from trafficgeo.traffic.measurements import classes_by_length

    veh = world.vehicles
    before = veh["class"].fillna("").astype(str).to_numpy(dtype=object)
    after = classes_by_length(before, veh["length_m"].to_numpy(dtype=np.float64),
                              veh["length_std_m"].to_numpy(dtype=np.float64))
    changed = after != before
    if not changed.any():
        return
    veh["class"] = after
    if len(world.points) and "class" in world.points.columns:
        new = dict(zip(veh.loc[changed, "track_id"], after[changed], strict=True))
        tid = world.points["track_id"]
        hit = tid.isin(set(new))
        world.points.loc[hit, "class"] = tid[hit].map(new)


def _moving_points(world: WorldTracks) -> pd.DataFrame:
    """The points of the vehicles that are not stationary."""
    veh = world.vehicles
    if "stationary" not in veh.columns or not veh["stationary"].any():
        return world.points
    still = set(veh.loc[veh["stationary"].astype(bool), "track_id"].astype(str))
    return world.points[~world.points["track_id"].astype(str).isin(still).to_numpy()]


def analyze_tracks(camera: CalibratedCamera | Camera | str | os.PathLike, surface: Surface | float | str | os.PathLike,
                   tracks: ImageTracks | pd.DataFrame | str | os.PathLike,
                   lanes: Lanes | str | os.PathLike | None = None,
                   lines: list[CountLine] | str | os.PathLike | None = None, *, interval_s: float = 60.0,
                   options: TrajectoryOptions | None = None, fps: float | None = None, resolution_m: float = 0.25,
                   progress=None, knowledge: ScaleKnowledge | None = None,
                   journeys: JourneyOptions | None = None, gates: list[Gate] | str | os.PathLike | None = None,
                   movement_interval_s: float = MOVEMENT_INTERVAL_S) -> TrafficResult:
    """Image tracks -> world trajectories, true speeds (km/h), lanes and counts at counting lines (``trafficgeo
    analyze``). Each input is an object or a path (:class:`trafficgeo.site.Site`): ``camera`` (camera JSON), ``surface``
    (number, ``"plane"``, DEM or point cloud gridded at ``resolution_m`` m), ``tracks`` (table, tracks CSV or MOT file;
    ``fps`` when it has no time column), ``lanes``, ``lines`` and a junction's ``gates`` (GIS files or image CSVs).
    Counts per ``interval_s`` seconds, turning movements per ``movement_interval_s``; ``options`` for the trajectory
    smoother, ``journeys`` for joining the fragments of one vehicle (:mod:`trafficgeo.traffic.journeys`). What the
    calibration knows of its ground scale (``knowledge``, which places the headline speeds) comes from a calibrated
    camera (its JSON or :class:`~trafficgeo.camera.calibrated.CalibratedCamera`); give it for a bare Camera, which
    is otherwise warned about (:data:`BARE_CAMERA_WARNING`). Nothing is written: see
    :func:`trafficgeo.traffic.outputs.write_traffic`.

    >>> import pandas as pd, trafficgeo as tg
    >>> boxes = pd.read_csv(world / "truth_tracks.csv").dropna(subset=["x1"]).rename(columns={"vehicle": "track_id"})
    >>> result = tg.analyze_tracks(world / "camera_truth.json", world / "cloud.laz",
    ...                            boxes[["frame", "time", "track_id", "x1", "y1", "x2", "y2", "class"]],
    ...                            lanes=world / "lanes.gpkg", lines=world / "count_lines.gpkg")
    >>> len(result.vehicles) > 0, list(result.counts.columns[:3])
    (True, ['line', 'lane', 'direction'])
    """
    from trafficgeo.site.site import Site
    from trafficgeo.traffic.tracks import load_tracks

    warn_bare_camera(camera, knowledge)
    site = Site.load(camera, surface, lanes, lines, gates=gates, resolution_m=resolution_m)
    if knowledge is None:
        knowledge = ScaleKnowledge.from_camera(site.camera)
    return analyze(site.camera.camera, site.surface, load_tracks(tracks, fps=fps), lanes=site.lanes,
                   lines=site.count_lines, interval_s=interval_s, options=options, progress=progress,
                   knowledge=knowledge, journeys=journeys, gates=list(site.gates) if site.gates else None,
                   movement_interval_s=movement_interval_s)


# ------------------------------------------------------------------------------------------------ writing
def write_analysis(out_dir: str | Path, analysis: TrafficResult, camera: Camera | CalibratedCamera, *,
                   command: str = "analyze") -> list[Path]:
    """Write the outputs (module docstring) into the run folder ``out_dir`` as one run of ``command``
    (:meth:`~trafficgeo.run.folder.RunFolder.writing`, :func:`~trafficgeo.traffic.outputs.write_traffic`); returns
    the paths written."""
    from trafficgeo.run.folder import RunFolder
    from trafficgeo.traffic.outputs import write_traffic

    with RunFolder(out_dir).writing(command) as run:
        return write_traffic(run, analysis, camera)
