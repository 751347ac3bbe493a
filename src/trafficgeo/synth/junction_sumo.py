"""Traffic of the synthetic junction world: a SUMO simulation of a signalised four-arm junction.

Conventions (used by :mod:`trafficgeo.synth.junction_world` too)
-------------------------------------------------------------
* World coordinates are metres in the projected CRS ``crs`` (EPSG:2949 by default); the junction centre is
  ``origin`` (x, y, z). Bearings and headings are degrees clockwise from north.
* Four straight arms leave the centre at bearings ``azimuth_deg + 90 k`` (k = 0..3), each ``arm_length_m`` long.
  An arm is named by the nearest compass name of its bearing (``N``, ``E``, ``S``, ``W``); consecutive arms are
  90 degrees apart, so the four names are always distinct.
* SUMO network: centre node ``C`` (type ``traffic_light``: netconvert's fixed-time programme), one dead-end node per
  arm named like the arm, and per arm an edge ``<arm>_in`` (towards the centre) and ``<arm>_out`` (away from it),
  ``lanes`` lanes of ``lane_width`` each at the speed limit. Both edges of an arm lie right of the node-to-node
  line (right-hand traffic), which is the centre line of the arm. netconvert makes the connections (no
  U-turns: ``--no-turnarounds``); with two lanes the right lane takes through + right, the left lane left + through.
* Node coordinates are relative to the origin and the net carries ``<location>`` with ``netOffset = -origin_xy``
  and the CRS's PROJ string, exactly as :mod:`trafficgeo.synth.sumo_world` does: ``world_xy = sumo_xy + origin_xy``.
* Movements: a vehicle entering from arm ``o`` drives heading ``bearing(o) + 180``; leaving on arm ``d`` it drives
  ``bearing(d)``. The turn ``(bearing(d) - bearing(o) - 180) mod 360`` is 0 = ``through``, 90 = ``right``,
  270 = ``left`` (right-hand traffic), 180 = ``U`` (not generated).

Demand
------
One flow per origin arm, destination arm and vehicle class with Poisson arrivals: rate =
``veh_per_hour_per_arm * turning[movement] * mix[class] / 3600`` per second, ``departLane="best"`` (the lane that
leads to the vehicle's destination), ``departSpeed="desired"``. Vehicle ids are ``<origin>_<destination>_<class>.<n>``.
Teleporting is off, the seed fixed, and SUMO's headers replaced (byte-identical outputs for the same inputs).

Trajectories
------------
:class:`JunctionTrajectories` holds every vehicle's **footprint centre** (FCD front bumper moved back by
``length / 2`` along the heading), heading, speed and SUMO lane id for every step of ``[0, duration)`` s; time 0
is the end of the warm-up (``warmup_s`` simulated seconds) and the first video frame.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from trafficgeo.crs import is_geographic, metres_per_unit, parse_crs
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import write_text_atomic
from trafficgeo.simulation.network import copy_without_sumo_header, proj_parameter
from trafficgeo.simulation.network import sumo_number as _num
from trafficgeo.simulation.tools import run_sumo_program
from trafficgeo.synth.sumo_scene import VEHICLE_CLASSES, Demand, finite_number, positive_number

__all__ = ["ARM_NAMES", "MOVEMENTS", "JunctionOptions", "JunctionRun", "JunctionTrajectories", "arm_bearings",
           "compass_name", "movement", "run_junction_sumo"]

ARM_NAMES = ("N", "E", "S", "W")
MOVEMENTS = ("left", "through", "right")
CORNERS = ("NE", "SE", "SW", "NW")
_NET_PRECISION = 6
_FCD_PRECISION = 3
_FCD_ATTRIBUTES = ("x", "y", "angle", "type", "speed", "pos", "lane", "signals")


def compass_name(bearing_deg: float) -> str:
    """The nearest of N, E, S, W to a bearing (degrees clockwise from north)."""
    return ARM_NAMES[int(((float(bearing_deg) % 360.0) + 45.0) // 90.0) % 4]


def movement(origin_bearing: float, destination_bearing: float) -> str:
    """``left``/``through``/``right``/``U`` of a vehicle entering from the arm at ``origin_bearing`` and leaving on
    the arm at ``destination_bearing`` (bearings of the arms from the centre, right-hand traffic)."""
    turn = (destination_bearing - origin_bearing - 180.0) % 360.0
    return {0: "through", 1: "right", 2: "U", 3: "left"}[round(turn / 90.0) % 4]


@dataclass(frozen=True)
class JunctionOptions:
    """Parameters of a junction world (metres, seconds, degrees, pixels; see the module docstring).

    ``camera_corner``: the corner between two arms the camera pole stands at (``NE``, ``SE``, ``SW``, ``NW`` by the
    arms' compass names), ``camera_distance_m`` from the centre on the corner's diagonal, ``camera_height`` above
    the ground, looking at the centre. ``gate_distance_m``: the gates cross each arm this far from the centre.
    """

    seed: int = 0
    duration_s: float = 60.0
    fps: float = 25.0
    image_size: tuple[int, int] = (1920, 1080)
    camera_height: float = 12.0
    camera_corner: str = "SE"
    camera_distance_m: float = 45.0
    focal_px: float | None = None  # default 0.6 x image width (about 80 deg horizontal field of view)
    dist: tuple[float, float, float, float, float] = (-0.06, 0.012, 0.0, 0.0, 0.0)
    azimuth_deg: float = 20.0  # bearing of the first (northern) arm
    arm_length_m: float = 120.0
    lanes: int = 2
    lane_width: float = 3.5
    speed_limit_kmh: float = 50.0
    veh_per_hour_per_arm: float = 400.0
    turning: dict[str, float] = field(default_factory=lambda: {"left": 0.2, "through": 0.6, "right": 0.2})
    mix: dict[str, float] = field(default_factory=lambda: {"car": 0.8, "van": 0.1, "truck": 0.07, "bus": 0.03})
    gate_distance_m: float = 22.0  # 11 m behind the stop line: in the frame of the default camera on every arm
    warmup_s: float = 90.0  # simulated before the first frame (one signal cycle and more): traffic is present
    origin: tuple[float, float, float] = (245000.0, 5182600.0, 90.0)
    crs: str = "EPSG:2949"
    ground_slope: float = 0.0  # rise per metre of the ground plane towards ground_slope_bearing_deg (0.01 = 1 %)
    ground_slope_bearing_deg: float = 0.0
    ortho_resolution: float = 0.05
    view_half_size: float = 130.0  # orthophoto, DEM and lidar cover the centre +- this (m): the arms and more
    pixel_sigma: float = 1.0
    survey_sigma: float = 0.02
    n_outliers: int = 0
    n_z_outliers: int = 0
    sensor_noise: float = 2.0
    shake_px: float = 0.3
    illumination_drift: float = 0.06
    shadows: bool = True

    def __post_init__(self) -> None:
        def fix(name: str, value: object) -> None:
            object.__setattr__(self, name, value)

        def positive(name: str, hint: str) -> None:
            fix(name, positive_number(name, getattr(self, name), hint))

        def integer(name: str, lo: int, hi: int) -> None:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or not lo <= v <= hi:
                raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {v!r}", parameters=(name,))
            fix(name, int(v))

        integer("seed", 0, 2**31 - 1)
        for name, hint in (("duration_s", "give seconds, e.g. 60"), ("fps", "give e.g. 25"),
                           ("camera_height", "give metres, e.g. 12"), ("camera_distance_m", "give metres, e.g. 45"),
                           ("arm_length_m", "give metres, e.g. 120"), ("lane_width", "give metres, e.g. 3.5"),
                           ("speed_limit_kmh", "give km/h, e.g. 50"), ("gate_distance_m", "give metres, e.g. 22"),
                           ("ortho_resolution", "give metres, e.g. 0.05"), ("view_half_size", "give metres")):
            try:
                positive(name, hint)
            except InputError as exc:
                raise InputError(str(exc), parameters=(name,)) from None
        if self.fps > 100:
            raise InputError(f"fps {self.fps:g} must be <= 100; give e.g. 25 or 30", parameters=("fps",))
        if abs(self.duration_s * 1000 - round(self.duration_s * 1000)) > 1e-6:
            raise InputError(f"duration_s {self.duration_s!r} must be whole milliseconds", parameters=("duration_s",))
        integer("lanes", 1, 4)
        for name in ("azimuth_deg", "ground_slope", "ground_slope_bearing_deg", "warmup_s", "veh_per_hour_per_arm",
                     "pixel_sigma", "survey_sigma", "sensor_noise", "shake_px", "illumination_drift"):
            fix(name, finite_number(name, getattr(self, name), "give a finite number"))
            if name not in ("azimuth_deg", "ground_slope", "ground_slope_bearing_deg") and getattr(self, name) < 0:
                raise InputError(f"{name} must be >= 0, got {getattr(self, name)!r}", parameters=(name,))
        if abs(self.warmup_s * 1000 - round(self.warmup_s * 1000)) > 1e-6:
            raise InputError(f"warmup_s {self.warmup_s!r} must be whole milliseconds", parameters=("warmup_s",))
        integer("n_outliers", 0, 1000)
        integer("n_z_outliers", 0, 1000)
        try:
            size = tuple(int(v) for v in self.image_size)  # type: ignore[union-attr]
        except (TypeError, ValueError):
            size = ()
        if len(size) != 2 or min(size) < 16:
            raise InputError(f"image_size must be (width, height) in pixels, got {self.image_size!r}",
                             parameters=("image_size",))
        fix("image_size", size)
        if self.focal_px is not None:
            fix("focal_px", positive_number("focal_px", self.focal_px, "give pixels, e.g. 0.6 x width"))
        try:
            dist = tuple(float(v) for v in self.dist)  # type: ignore[union-attr]
        except (TypeError, ValueError):
            dist = ()
        if len(dist) != 5 or not all(math.isfinite(v) for v in dist):
            raise InputError(f"dist must be 5 distortion coefficients (k1, k2, p1, p2, k3), got {self.dist!r}",
                             parameters=("dist",))
        fix("dist", dist)
        corner = str(self.camera_corner).upper()
        if corner not in CORNERS:
            raise InputError(f"camera_corner {self.camera_corner!r} must be one of {', '.join(CORNERS)}",
                             parameters=("camera_corner",))
        fix("camera_corner", corner)
        half_road = self.lanes * self.lane_width + 2.0
        if self.camera_distance_m / math.sqrt(2.0) < half_road:
            raise InputError(f"camera_distance_m {self.camera_distance_m:g} puts the pole on the road; give at least "
                             f"{math.ceil(half_road * math.sqrt(2.0))} m", parameters=("camera_distance_m",))
        if not 2.0 * half_road <= self.gate_distance_m <= self.arm_length_m - 10.0:
            raise InputError(f"gate_distance_m {self.gate_distance_m:g} must lie between {2 * half_road:g} m (outside "
                             f"the junction) and arm_length_m - 10 = {self.arm_length_m - 10:g} m",
                             parameters=("gate_distance_m",))
        if not isinstance(self.turning, Mapping) or not self.turning:
            raise InputError(f"turning must map left/through/right to shares, got {self.turning!r}",
                             parameters=("turning",))
        turning = {}
        for k, v in self.turning.items():
            if k not in MOVEMENTS:
                raise InputError(f"turning: unknown movement {k!r}; use left, through and right (no U-turns)",
                                 parameters=("turning",))
            share = finite_number(f"turning[{k!r}]", v, "give a share between 0 and 1")
            if share < 0:
                raise InputError(f"turning[{k!r}] must be >= 0, got {v!r}", parameters=("turning",))
            turning[str(k)] = share
        if abs(sum(turning.values()) - 1.0) > 1e-6:
            raise InputError(f"turning shares must sum to 1, they sum to {sum(turning.values()):g}",
                             parameters=("turning",))
        fix("turning", {m: turning.get(m, 0.0) for m in MOVEMENTS})
        try:
            fix("mix", Demand(self.veh_per_hour_per_arm, dict(self.mix) if isinstance(self.mix, Mapping)
                              else self.mix).mix)
        except InputError as exc:
            raise InputError(str(exc).replace("Demand.veh_per_hour_per_lane", "veh_per_hour_per_arm")
                             .replace("Demand.mix", "mix"), parameters=("mix",)) from None
        try:
            origin = tuple(float(v) for v in self.origin)  # type: ignore[union-attr]
        except (TypeError, ValueError):
            origin = ()
        if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
            raise InputError(f"origin must be 3 finite numbers (x, y, z in metres), got {self.origin!r}",
                             parameters=("origin",))
        fix("origin", origin)
        crs = parse_crs(self.crs)
        if crs is None or is_geographic(crs) or not math.isclose(metres_per_unit(crs), 1.0):
            raise InputError(f"`crs` {self.crs!r} must be a projected CRS in metres, e.g. EPSG:2949",
                             parameters=("crs",))

    @property
    def speed_limit(self) -> float:
        """m/s."""
        return self.speed_limit_kmh / 3.6

    @property
    def sumo_step(self) -> float:
        """SUMO's step (s): one frame when that is whole milliseconds (SUMO's clock), else 10 ms (the trajectories
        are then resampled to the frames)."""
        step = 1.0 / self.fps
        return round(1000.0 * step) / 1000.0 if abs(1000.0 * step - round(1000.0 * step)) < 1e-9 else 0.01

    def frame_count(self) -> int:
        """Frames of the clip: one every 1/fps s from 0 up to (not including) the duration."""
        return int(np.ceil(self.duration_s * self.fps - 1e-9))


def arm_bearings(opts: JunctionOptions) -> dict[str, float]:
    """Arm name -> bearing (degrees clockwise from north, [0, 360)) from the centre along the arm."""
    out = {}
    for k in range(4):
        b = (opts.azimuth_deg + 90.0 * k) % 360.0
        out[compass_name(b)] = b
    return out


def unit(bearing_deg: float) -> np.ndarray:
    """The horizontal unit vector (east, north) of a bearing."""
    b = math.radians(bearing_deg)
    return np.array([math.sin(b), math.cos(b)])


# ---------------------------------------------------------------------------------------------------- network
def _nodes_xml(opts: JunctionOptions) -> str:
    ox, oy, _ = opts.origin
    ends = {a: opts.arm_length_m * unit(b) for a, b in arm_bearings(opts).items()}
    pts = np.array([(0.0, 0.0), *ends.values()])
    (xmin, ymin), (xmax, ymax) = pts.min(axis=0), pts.max(axis=0)
    location = (f'netOffset="{_num(-ox)},{_num(-oy)}" '
                f'convBoundary="{_num(xmin)},{_num(ymin)},{_num(xmax)},{_num(ymax)}" '
                f'origBoundary="{_num(xmin + ox)},{_num(ymin + oy)},{_num(xmax + ox)},{_num(ymax + oy)}" '
                f"projParameter={quoteattr(proj_parameter(opts.crs, 'JunctionOptions.crs'))}")
    rows = [f"    <location {location}/>\n", '    <node id="C" x="0" y="0" type="traffic_light"/>\n']
    rows += [f'    <node id="{a}" x="{_num(p[0])}" y="{_num(p[1])}" type="dead_end"/>\n' for a, p in ends.items()]
    return "<nodes>\n" + "".join(rows) + "</nodes>\n"


def _edges_xml(opts: JunctionOptions) -> str:
    rows = []
    for a in arm_bearings(opts):
        for eid, fr, to in ((f"{a}_in", a, "C"), (f"{a}_out", "C", a)):
            rows.append(f'    <edge id="{eid}" from="{fr}" to="{to}" numLanes="{opts.lanes}" '
                        f'speed="{_num(opts.speed_limit)}" width="{_num(opts.lane_width)}" spreadType="right"/>\n')
    return "<edges>\n" + "".join(rows) + "</edges>\n"


def _routes_xml(opts: JunctionOptions, end_s: float) -> str:
    lines = ["<routes>\n"]
    for name in opts.mix:
        lines.append(VEHICLE_CLASSES[name].vtype_xml())
    bearings = arm_bearings(opts)
    pairs = [(o, d) for o in bearings for d in bearings if o != d]
    for o, d in pairs:
        lines.append(f'    <route id="{o}_{d}" edges="{o}_in {d}_out"/>\n')
    for o, d in pairs:
        share = opts.turning[movement(bearings[o], bearings[d])]
        for name, cls_share in opts.mix.items():
            rate = opts.veh_per_hour_per_arm * share * cls_share / 3600.0
            if rate <= 0:
                continue
            lines.append(f'    <flow id="{o}_{d}_{name}" type="{name}" route="{o}_{d}" begin="0" end="{_num(end_s)}" '
                         f'period="exp({_num(rate)})" departLane="best" departSpeed="desired" departPos="base"/>\n')
    lines.append("</routes>\n")
    return "".join(lines)


# ---------------------------------------------------------------------------------------------------- outputs
@dataclass(frozen=True, eq=False)
class JunctionTrajectories:
    """SUMO FCD as arrays, one row per vehicle per time step, sorted by time then vehicle id.

    Field names match :class:`trafficgeo.synth.sumo_world.Trajectories` where they mean the same, so the road
    world's resampling and video rendering take them as they are.
    """

    time: np.ndarray  # s, video clock (0 = first frame)
    vehicle: np.ndarray  # str, SUMO vehicle id "<origin>_<destination>_<class>.<n>"
    vclass: np.ndarray  # str, key of VEHICLE_CLASSES
    x: np.ndarray  # m, world easting of the footprint centre
    y: np.ndarray  # m, world northing of the footprint centre
    heading_deg: np.ndarray  # degrees clockwise from north
    speed: np.ndarray  # m/s
    lane: np.ndarray  # str, SUMO lane id under the front bumper (":C_..." inside the junction)
    length: np.ndarray  # m
    width: np.ndarray  # m
    height: np.ndarray  # m

    def __len__(self) -> int:
        return len(self.time)


@dataclass(frozen=True, eq=False)
class JunctionRun:
    """The files of a junction SUMO run, its trajectories and each vehicle's route (edge ids)."""

    folder: Path
    net: Path
    routes: Path
    fcd: Path
    vehroutes: Path
    trajectories: JunctionTrajectories
    vehicle_routes: dict[str, tuple[str, ...]]  # every vehicle that departed: its route's edges
    sumo_version: str


def read_junction_fcd(path: Path, opts: JunctionOptions, t0: float) -> JunctionTrajectories:
    """Parse a junction run's fcd.xml (SUMO network coordinates, front bumpers) into footprint centres in the
    world CRS; ``t0`` (s, SUMO clock) becomes time 0."""
    from trafficgeo.io.fcd_read import read_fcd as read_sumo_fcd

    fcd = read_sumo_fcd(path, crs=opts.crs, geo=False)
    vtype = fcd["class"].to_numpy(dtype=str)
    unknown = sorted(set(vtype) - set(VEHICLE_CLASSES))
    if unknown:
        raise InputError(f"{path}: vehicle type {unknown[0]!r} is not in VEHICLE_CLASSES")
    sizes = np.array([[VEHICLE_CLASSES[t].length, VEHICLE_CLASSES[t].width, VEHICLE_CLASSES[t].height]
                      for t in vtype]).reshape(-1, 3)
    heading = fcd["heading_deg"].to_numpy(dtype=np.float64)
    h = np.radians(heading)
    half = 0.5 * sizes[:, 0]
    x = fcd["x"].to_numpy(dtype=np.float64) + opts.origin[0] - half * np.sin(h)
    y = fcd["y"].to_numpy(dtype=np.float64) + opts.origin[1] - half * np.cos(h)
    time = np.round(fcd["time"].to_numpy(dtype=np.float64) - t0, 6)
    vehicle = fcd["track_id"].to_numpy(dtype=str)
    order = np.lexsort((vehicle, time))
    return JunctionTrajectories(time=time[order], vehicle=vehicle[order], vclass=vtype[order], x=x[order],
                                y=y[order], heading_deg=heading[order],
                                speed=fcd["speed_kmh"].to_numpy(dtype=np.float64)[order] / 3.6,
                                lane=fcd["sumo_lane"].to_numpy(dtype=str)[order], length=sizes[order, 0],
                                width=sizes[order, 1], height=sizes[order, 2])


def read_vehicle_routes(path: Path) -> dict[str, tuple[str, ...]]:
    """Vehicle id -> route edges from SUMO's ``--vehroute-output``."""
    import xml.etree.ElementTree as ET

    out = {}
    for veh in ET.parse(path).getroot().iter("vehicle"):
        route = veh.find("route")
        if route is not None:
            out[veh.get("id", "")] = tuple(route.get("edges", "").split())
    return out


def run_junction_sumo(out_dir: str | os.PathLike[str], opts: JunctionOptions) -> JunctionRun:
    """Build the network and demand into ``out_dir``, simulate ``warmup_s + duration_s`` seconds at one step per
    frame (:attr:`JunctionOptions.sumo_step`) and read the trajectories of the last ``duration_s`` seconds.

    Writes junction.nod.xml, junction.edg.xml, junction.net.xml, demand.rou.xml, fcd.xml and vehroutes.xml
    (byte-identical for the same options).

    Raises:
        InputError: SUMO not installed. TrafficgeoError: netconvert or sumo failed.
    """
    folder = Path(out_dir)
    folder.mkdir(parents=True, exist_ok=True)
    step = opts.sumo_step
    end = opts.warmup_s + opts.duration_s
    nod, edg, net = folder / "junction.nod.xml", folder / "junction.edg.xml", folder / "junction.net.xml"
    routes, fcd, vehroutes = folder / "demand.rou.xml", folder / "fcd.xml", folder / "vehroutes.xml"
    work = Path(tempfile.mkdtemp(prefix=".sumo-", dir=folder))
    try:
        write_text_atomic(nod, _nodes_xml(opts))
        write_text_atomic(edg, _edges_xml(opts))
        raw_net = work / "junction.net.xml"
        run_sumo_program("netconvert", ["--node-files", str(nod), "--edge-files", str(edg),
                                        "--offset.disable-normalization", "--no-turnarounds",
                                        "--precision", str(_NET_PRECISION), "--output-file", str(raw_net)], 120.0)
        copy_without_sumo_header(raw_net, net)
        write_text_atomic(routes, _routes_xml(opts, end))
        raw_fcd, raw_routes = work / "fcd.xml", work / "vehroutes.xml"
        run_sumo_program("sumo", ["--net-file", str(net), "--route-files", str(routes), "--begin", "0",
                                  "--end", repr(end), "--step-length", repr(step), "--seed", str(opts.seed),
                                  "--no-step-log", "--time-to-teleport", "-1", "--precision", str(_FCD_PRECISION),
                                  "--fcd-output", str(raw_fcd), "--fcd-output.attributes", ",".join(_FCD_ATTRIBUTES),
                                  "--device.fcd.begin", repr(opts.warmup_s), "--vehroute-output", str(raw_routes),
                                  "--vehroute-output.write-unfinished"], 60.0 + 0.01 * end / step)
        version = copy_without_sumo_header(raw_fcd, fcd)
        copy_without_sumo_header(raw_routes, vehroutes)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    traj = read_junction_fcd(fcd, opts, opts.warmup_s)
    keep = traj.time < opts.duration_s - 1e-9  # SUMO writes the step at --end too
    traj = JunctionTrajectories(**{k: getattr(traj, k)[keep] for k in JunctionTrajectories.__dataclass_fields__})
    return JunctionRun(folder=folder, net=net, routes=routes, fcd=fcd, vehroutes=vehroutes, trajectories=traj,
                       vehicle_routes=read_vehicle_routes(vehroutes), sumo_version=version or "unknown")
