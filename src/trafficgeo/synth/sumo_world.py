"""Traffic of the synthetic demo world: a real SUMO simulation on a straight, georeferenced road.

The trajectories are ground truth for rendering videos of the scene: every vehicle's footprint centre, heading,
speed, lane and size at every simulation step, in world coordinates of a projected CRS (EPSG:2949 by default).
The road, its lanes, the demand and the vehicle classes (and their conventions) are in
:mod:`trafficgeo.synth.sumo_scene`; this module builds the SUMO network and routes, runs SUMO and reads its output.

SUMO network and georeferencing
-------------------------------
One SUMO edge per direction (ids ``d1``, ``d2``), ``lanes`` lanes of ``lane_width`` each, speed = limit, between
two dead-end nodes. The edges run 40 m (``EDGE_MARGIN_M``) beyond each end of the road so that vehicles are inserted
at their desired speed before they reach the road and leave it without meeting the dead-end geometry; trajectory
points outside the road span are dropped.

Node coordinates are written *relative to the origin* (metres) and netconvert keeps them as they are
(``--offset.disable-normalization``). The node file carries the ``<location>`` of the net, which netconvert copies
into the ``.net.xml``: ``netOffset = -origin_xy`` and ``projParameter`` = the CRS's PROJ string (via pyproj).
SUMO's convention is ``sumo_xy = world_xy + netOffset``, so ::

    world_xy = sumo_xy - netOffset = sumo_xy + origin_xy

and ``sumolib.net.Net.convertXY2LonLat`` gives the right longitude/latitude. Note that SUMO only *projects*: its
longitude/latitude are on the CRS's own geodetic datum (NAD83(CSRS) for EPSG:2949), which differs from WGS 84 by
up to a metre or two; trafficgeo's :func:`~trafficgeo.crs.projected_to_lonlat` does transform to WGS 84.

Demand and behaviour
--------------------
One flow per direction and vehicle class with Poisson arrivals (``period="exp(rate)"``, rate =
``veh_per_hour_per_lane * lanes * share / 3600`` per second), ``departLane="random"``,
``departSpeed="desired"``. Vehicle types (:data:`~trafficgeo.synth.sumo_scene.VEHICLE_CLASSES`) have realistic
sizes, a truncated normal speed factor and SUMO's default car-following (Krauss with driver imperfection
``sigma = 0.5``) and lane-change (LC2013, instantaneous lane changes: positions snap to lane centres) models.
Teleporting is disabled (``--time-to-teleport -1``) so that no vehicle ever jumps.

Trajectories
------------
SUMO's FCD position is the middle of the *front bumper*; :class:`Trajectories` gives the **centre of the vehicle
footprint on the ground**, shifted back by ``length / 2`` along the heading, with ``z`` the road surface height
there (a flat road: ``origin_z``). Times are relative to the end of the warm-up (``0 <= time < duration``).

Determinism
-----------
SUMO is run with a fixed ``--seed``, no step log and ``--precision 3`` (mm, ms). SUMO writes a comment with the
current date and the full configuration (including temporary file names) at the top of each output; it is
replaced by a fixed comment naming the SUMO version, so the same inputs give byte-identical ``.net.xml`` and
``fcd.xml`` files.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.io.atomic import write_text_atomic
from trafficgeo.simulation.network import copy_without_sumo_header as _copy_without_header
from trafficgeo.simulation.network import proj_parameter
from trafficgeo.simulation.network import sumo_number as _num
from trafficgeo.simulation.tools import run_sumo_program, sumo_binary
from trafficgeo.synth.sumo_scene import EDGE_MARGIN_M, VEHICLE_CLASSES, Demand, RoadSpec, finite_number, positive_number

__all__ = [
    "SumoRun",
    "Trajectories",
    "read_fcd",
    "run_sumo_world",
    "sumo_binary",
]

_EDGE_IDS = {1: "d1", 2: "d2"}
_NET_PRECISION = 6  # digits after the comma in the .net.xml (netOffset must keep the origin's precision)
_FCD_PRECISION = 3  # digits after the comma in fcd.xml: mm, ms
_FCD_ATTRIBUTES = ("x", "y", "angle", "type", "speed", "pos", "lane", "signals")  # signals: brake lights, blinkers
_NETCONVERT_TIMEOUT_S = 120.0


# ---------------------------------------------------------------------------------------------------- outputs
@dataclass(frozen=True, eq=False)
class Trajectories:
    """SUMO FCD as arrays, one row per vehicle per time step, sorted by time then vehicle id (string order).

    ``x, y, z`` (world CRS metres) are the centre of the vehicle footprint on the road surface (not SUMO's
    front bumper). Only points whose centre lies on the road span (``|station| <= length/2``) are kept.
    """

    time: np.ndarray  # s since the end of the warm-up
    vehicle: np.ndarray  # str, SUMO vehicle id (e.g. "d1_car.12")
    vclass: np.ndarray  # str, key of VEHICLE_CLASSES
    x: np.ndarray  # m, world easting of the footprint centre
    y: np.ndarray  # m, world northing of the footprint centre
    z: np.ndarray  # m, road surface height under the footprint centre
    heading_deg: np.ndarray  # degrees clockwise from north, [0, 360)
    speed: np.ndarray  # m/s
    direction: np.ndarray  # int, 1 (along the azimuth) or 2
    lane: np.ndarray  # int, 1..lanes from the centre line outwards, the lane under the footprint centre
    length: np.ndarray  # m
    width: np.ndarray  # m
    height: np.ndarray  # m
    station: np.ndarray  # m along the road axis from the origin
    offset: np.ndarray  # m right of the road axis

    def __post_init__(self) -> None:
        n = len(self.time)
        for name in self.__dataclass_fields__:
            if len(getattr(self, name)) != n:
                raise ValueError(f"Trajectories.{name} has {len(getattr(self, name))} rows, time has {n}")

    def __len__(self) -> int:
        return len(self.time)


@dataclass(frozen=True, eq=False)
class SumoRun:
    """The files of a SUMO run and its trajectories."""

    folder: Path
    net: Path  # road.net.xml, georeferenced
    routes: Path  # demand.rou.xml
    fcd: Path  # fcd.xml, from the end of the warm-up
    trajectories: Trajectories
    sumo_version: str  # e.g. "1.28.0"


# ---------------------------------------------------------------------------------------------------- SUMO tools
WARMUP_S = 60.0  # simulated before the trajectories start: SUMO time = trajectory time + WARMUP_S
LANE_CHANGE_DURATION_S = 3.0  # lane changes drift across over this time (SUMO's default is an instant jump)


def _run_tool(name: str, args: list[str], timeout_s: float) -> None:
    """Run a SUMO program headless; TrafficgeoError with its output tail on failure or timeout."""
    run_sumo_program(name, args, timeout_s)


# ---------------------------------------------------------------------------------------------------- network
def _proj_parameter(road: RoadSpec) -> str:
    """The PROJ string of the road's CRS, as SUMO wants it in ``projParameter``."""
    return proj_parameter(road.crs, "RoadSpec.crs")


def _axis_xy(road: RoadSpec, stations: np.ndarray) -> np.ndarray:
    """Axis points (N, 2) relative to the origin (the SUMO network's own coordinates)."""
    return road.surface.points(stations, np.zeros_like(stations))[:, :2] - np.array(road.origin[:2])


def _nodes_xml(road: RoadSpec) -> str:
    half = 0.5 * road.length_m + EDGE_MARGIN_M
    a, b = _axis_xy(road, np.array([-half, half]))
    ox, oy, _ = road.origin
    pts = _axis_xy(road, np.linspace(-half, half, 201))
    (xmin, ymin), (xmax, ymax) = pts.min(axis=0), pts.max(axis=0)
    location = (f'netOffset="{_num(-ox)},{_num(-oy)}" '
                f'convBoundary="{_num(xmin)},{_num(ymin)},{_num(xmax)},{_num(ymax)}" '
                f'origBoundary="{_num(xmin + ox)},{_num(ymin + oy)},{_num(xmax + ox)},{_num(ymax + oy)}" '
                f"projParameter={quoteattr(_proj_parameter(road))}")
    return ("<nodes>\n"
            f"    <location {location}/>\n"
            f'    <node id="A" x="{_num(a[0])}" y="{_num(a[1])}" type="dead_end"/>\n'
            f'    <node id="B" x="{_num(b[0])}" y="{_num(b[1])}" type="dead_end"/>\n'
            "</nodes>\n")


def _edges_xml(road: RoadSpec) -> str:
    ends = {1: ("A", "B"), 2: ("B", "A")}
    shape = ""
    if road.curve_radius != 0.0:  # the axis as a polyline (2 m chords: < 1 cm from the arc for R >= 50 m)
        half = 0.5 * road.length_m + EDGE_MARGIN_M
        pts = _axis_xy(road, np.linspace(-half, half, int(np.ceil(2 * half / 2.0)) + 1))
        shape = " ".join(f"{_num(x)},{_num(y)}" for x, y in pts)
    rows = []
    for d in road.directions:
        d_shape = shape if d == 1 else " ".join(reversed(shape.split()))
        rows.append(f'    <edge id="{_EDGE_IDS[d]}" from="{ends[d][0]}" to="{ends[d][1]}" numLanes="{road.lanes}" '
                    f'speed="{_num(road.speed_limit)}" width="{_num(road.lane_width)}" spreadType="right"'
                    + (f' shape="{d_shape}"' if d_shape else "") + "/>\n")
    return "<edges>\n" + "".join(rows) + "</edges>\n"


def _build_net(folder: Path, work: Path, road: RoadSpec) -> tuple[Path, str | None]:
    nod, edg, net = folder / "road.nod.xml", folder / "road.edg.xml", folder / "road.net.xml"
    write_text_atomic(nod, _nodes_xml(road))
    write_text_atomic(edg, _edges_xml(road))
    raw = work / "road.net.xml"
    _run_tool("netconvert", ["--node-files", str(nod), "--edge-files", str(edg), "--offset.disable-normalization",
                             "--no-turnarounds", "--precision", str(_NET_PRECISION), "--output-file", str(raw)],
              _NETCONVERT_TIMEOUT_S)
    return net, _copy_without_header(raw, net)


# ---------------------------------------------------------------------------------------------------- demand
def _routes_xml(road: RoadSpec, demand: Demand, end_s: float) -> str:
    lines = ["<routes>\n"]
    for name in demand.mix:
        lines.append(VEHICLE_CLASSES[name].vtype_xml())
    for d in road.directions:
        lines.append(f'    <route id="r{d}" edges="{_EDGE_IDS[d]}"/>\n')
    for d in road.directions:
        for name, share in demand.mix.items():
            rate = demand.veh_per_hour_per_lane * road.lanes * share / 3600.0  # vehicles per second
            if rate <= 0:
                continue
            lines.append(f'    <flow id="{_EDGE_IDS[d]}_{name}" type="{name}" route="r{d}" begin="0" '
                         f'end="{_num(end_s)}" period="exp({_num(rate)})" departLane="random" departSpeed="desired" '
                         'departPos="base"/>\n')
    lines.append("</routes>\n")
    return "".join(lines)


# ---------------------------------------------------------------------------------------------------- FCD
def _sumolib():
    try:
        import sumolib
    except ImportError:
        raise InputError("sumolib is not installed; install it with: pip install sumolib") from None
    return sumolib


def _empty_trajectories() -> Trajectories:
    f, i, s = np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=str)
    return Trajectories(f, s, s, f, f, f, f, f, i, i, f, f, f, f, f)


def read_fcd(path: str | os.PathLike[str], road: RoadSpec, net_path: str | os.PathLike[str], *,
             t0: float | None = None) -> Trajectories:
    """Parse the FCD output of a :func:`run_sumo_world` run into :class:`Trajectories`.

    ``net_path`` is the run's ``.net.xml`` (its ``netOffset`` maps SUMO to world coordinates and must match
    ``road.origin``). ``t0`` (s) is the simulation time that becomes time 0; None takes the first time step in the
    file (the end of the warm-up for a run's fcd.xml).
    """
    path, net_path = Path(path), Path(net_path)
    for what, p in (("FCD file", path), ("network file", net_path)):
        if not p.is_file():
            raise InputError(f"{what} {p} does not exist; give the file written by run_sumo_world")
    from trafficgeo.io.fcd_read import read_fcd as read_sumo_fcd
    from trafficgeo.io.sumo_net import read_net_location

    off_x, off_y = read_net_location(net_path).offset
    ox, oy, _ = road.origin
    if abs(off_x + ox) > 1e-3 or abs(off_y + oy) > 1e-3:
        raise InputError(f"{net_path} was built for origin ({-off_x}, {-off_y}), not RoadSpec.origin ({ox}, {oy}); "
                         "pass the RoadSpec used for the run")
    fcd = read_sumo_fcd(path, crs=road.crs, geo=False)  # SUMO's own network coordinates, front bumpers
    if t0 is None:
        first = next(iter(_sumolib().xml.parse_fast(str(path), "timestep", ["time"])), None)
        t0 = float(first.time) if first is not None else 0.0
    if not len(fcd):
        return _empty_trajectories()

    time = np.round(fcd["time"].to_numpy(dtype=np.float64) - t0, 6)
    heading = fcd["heading_deg"].to_numpy(dtype=np.float64)
    vehicle = fcd["track_id"].to_numpy(dtype=str)
    cols = {"x": fcd["x"].to_numpy(), "y": fcd["y"].to_numpy(), "speed": fcd["speed_kmh"].to_numpy() / 3.6,
            "type": fcd["class"].to_numpy(dtype=str), "lane": fcd["sumo_lane"].to_numpy(dtype=str)}
    # vehicle class -> sizes
    types, type_idx = np.unique(np.asarray(cols["type"], dtype=str), return_inverse=True)
    unknown = [t for t in types if t not in VEHICLE_CLASSES]
    if unknown:
        raise InputError(f"{path}: vehicle type {unknown[0]!r} is not in VEHICLE_CLASSES; "
                         "read only FCD files written by run_sumo_world")
    sizes = np.array([[VEHICLE_CLASSES[t].length, VEHICLE_CLASSES[t].width, VEHICLE_CLASSES[t].height]
                      for t in types])[type_idx]
    # SUMO lane id "d<direction>_<index>" -> direction and our lane number
    lane_ids, lane_idx = np.unique(np.asarray(cols["lane"], dtype=str), return_inverse=True)
    edge_dir = {e: d for d, e in _EDGE_IDS.items() if d in road.directions}
    dir_lane = []
    for lid in lane_ids:
        edge, _, index = str(lid).rpartition("_")
        if edge not in edge_dir or not index.isdigit() or int(index) >= road.lanes:
            raise InputError(f"{path}: lane {lid!r} is not a lane of this RoadSpec ({road.lanes} lanes, "
                             f"directions {road.directions}); pass the RoadSpec used for the run")
        dir_lane.append((edge_dir[edge], road.lanes - int(index)))
    direction, lane = np.array(dir_lane, dtype=np.int64).T[:, lane_idx]
    # front bumper (SUMO) -> footprint centre, world coordinates
    half = 0.5 * sizes[:, 0]
    h = np.radians(heading)
    x = np.asarray(cols["x"], dtype=np.float64) - off_x - half * np.sin(h)
    y = np.asarray(cols["y"], dtype=np.float64) - off_y - half * np.cos(h)
    surface = road.surface
    station, offset = surface.station_offset(x, y)

    # The lane is where the footprint centre is (during a lane change SUMO's lane attribute switches early).
    lane = np.clip(np.ceil(np.abs(offset) / road.lane_width), 1, road.lanes).astype(np.int64)

    keep = np.abs(station) <= 0.5 * road.length_m
    order = np.lexsort((vehicle[keep], time[keep]))
    sel = np.flatnonzero(keep)[order]
    return Trajectories(
        time=time[sel], vehicle=vehicle[sel], vclass=types[type_idx][sel], x=x[sel], y=y[sel],
        z=surface.z(x[sel], y[sel]), heading_deg=heading[sel],
        speed=np.asarray(cols["speed"], dtype=np.float64)[sel], direction=direction[sel], lane=lane[sel],
        length=sizes[sel, 0], width=sizes[sel, 1], height=sizes[sel, 2], station=station[sel], offset=offset[sel],
    )


# ---------------------------------------------------------------------------------------------------- run
def _check_run_options(duration_s: float, step_s: float, warmup_s: float, seed: int) -> tuple[float, float, float]:
    duration = positive_number("duration_s", duration_s, "give seconds, e.g. 60")
    step = positive_number("step_s", step_s, "give seconds, e.g. 0.04 for 25 fps")
    warmup = finite_number("warmup_s", warmup_s, "give seconds, e.g. 60")
    if warmup < 0:
        raise InputError(f"warmup_s must be >= 0, got {warmup_s!r}; give seconds, e.g. 60")
    for what, v in (("step_s", step), ("warmup_s", warmup), ("duration_s", duration)):
        if abs(v * 1000.0 - round(v * 1000.0)) > 1e-6:
            raise InputError(f"{what} = {v!r} is not a whole number of milliseconds (SUMO's clock resolution); "
                             "round it, e.g. step 0.04 s for 25 fps or 0.05 s for 20 fps")
    if step > 1.0:
        raise InputError(f"step_s must be <= 1 s, got {step_s!r}; give e.g. 0.04 for 25 fps")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not 0 <= seed < 2**31:
        raise InputError(f"seed must be an integer in [0, 2^31), got {seed!r}")
    return duration, step, warmup


def run_sumo_world(out_dir: str | os.PathLike[str], road: RoadSpec, demand: Demand, *, duration_s: float = 60.0,
                   step_s: float = 0.04, warmup_s: float = WARMUP_S, seed: int = 0) -> SumoRun:
    """Simulate ``warmup_s + duration_s`` seconds of traffic on ``road`` with SUMO; trajectories of the last
    ``duration_s`` seconds every ``step_s`` seconds (0.04 s = 25 fps).

    Writes to ``out_dir``: road.nod.xml, road.edg.xml (netconvert input), road.net.xml, demand.rou.xml and
    fcd.xml. Deterministic: the same inputs give byte-identical files.

    Raises:
        InputError: bad options or SUMO not installed.
        TrafficgeoError: netconvert or sumo failed (message with the tail of their error output).
    """
    duration, step, warmup = _check_run_options(duration_s, step_s, warmup_s, seed)
    folder = Path(out_dir)
    folder.mkdir(parents=True, exist_ok=True)
    end = warmup + duration
    routes, fcd = folder / "demand.rou.xml", folder / "fcd.xml"
    work = Path(tempfile.mkdtemp(prefix=".sumo-", dir=folder))
    try:
        net, _ = _build_net(folder, work, road)
        write_text_atomic(routes, _routes_xml(road, demand, end))
        raw = work / "fcd.xml"
        n_steps = end / step
        _run_tool("sumo", ["--net-file", str(net), "--route-files", str(routes), "--begin", "0", "--end", repr(end),
                           "--step-length", repr(step), "--seed", str(int(seed)), "--no-step-log",
                           "--time-to-teleport", "-1", "--precision", str(_FCD_PRECISION),
                           "--lanechange.duration", repr(LANE_CHANGE_DURATION_S),
                           "--fcd-output", str(raw), "--fcd-output.attributes", ",".join(_FCD_ATTRIBUTES),
                           "--device.fcd.begin", repr(warmup)],
                  60.0 + 0.01 * n_steps)
        version = _copy_without_header(raw, fcd)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    trajectories = read_fcd(fcd, road, net, t0=warmup)
    return SumoRun(folder=folder, net=net, routes=routes, fcd=fcd, trajectories=trajectories,
                   sumo_version=version or "unknown")
