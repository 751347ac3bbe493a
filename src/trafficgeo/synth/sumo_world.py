"""Traffic of the synthetic demo world: a real SUMO simulation on a straight, georeferenced road.

The trajectories are ground truth for rendering videos of the scene: every vehicle's footprint centre, heading,
speed, lane and size at every simulation step, in world coordinates of a projected CRS (EPSG:2949 by default).

Road and lanes
--------------
The road axis runs through :attr:`RoadSpec.origin` with azimuth ``a`` (degrees clockwise from north); station
``s`` is measured along the axis and the lateral offset ``o`` to the right of it (as in
:class:`~trafficgeo.synth.gcp_scene.RoadSurface`). The road covers ``-length/2 <= s <= length/2``.

* **Direction 1** drives along the azimuth on the right of the axis (``o > 0``); **direction 2** (only with
  ``two_way``) drives the opposite way (heading ``a + 180``) on the left of the axis (``o < 0``): right-hand
  traffic. A one-way road keeps its single carriageway right of the axis, so the axis is its left edge.
* Lanes are numbered **1..lanes from the centre line outwards** in each direction: lane 1 is the inner (fast,
  overtaking) lane, lane ``lanes`` the outer (kerb) lane. SUMO numbers the lanes of an edge from the right, so
  SUMO lane index ``i`` is our lane ``lanes - i``.
* Lane ``k`` of direction ``d`` is centred at ``o = +-(k - 1/2) * lane_width`` (``+`` for direction 1).

SUMO network and georeferencing
-------------------------------
One SUMO edge per direction (ids ``d1``, ``d2``), ``lanes`` lanes of ``lane_width`` each, speed = limit, between
two dead-end nodes. The edges run 40 m (``_MARGIN_M``) beyond each end of the road so that vehicles are inserted
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
``departSpeed="desired"``. Vehicle types (:data:`VEHICLE_CLASSES`) have realistic sizes, a truncated normal
speed factor and SUMO's default car-following (Krauss with driver imperfection ``sigma = 0.5``) and lane-change
(LC2013, instantaneous lane changes: positions snap to lane centres) models. Teleporting is disabled
(``--time-to-teleport -1``) so that no vehicle ever jumps.

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

import math
import os
import re
import shutil
import subprocess
import tempfile
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from trafficgeo.crs import is_geographic, metres_per_unit, parse_crs
from trafficgeo.errors import InputError, TrafficgeoError
from trafficgeo.io.atomic import atomic_open, write_text_atomic
from trafficgeo.synth.gcp_scene import RoadSurface

__all__ = [
    "VEHICLE_CLASSES",
    "Demand",
    "RoadSpec",
    "SumoRun",
    "Trajectories",
    "VehicleClass",
    "read_fcd",
    "run_sumo_world",
    "sumo_binary",
]

_MARGIN_M = 40.0  # m of SUMO edge beyond each end of the road (insertion and exit zones, not in the trajectories)
_EDGE_IDS = {1: "d1", 2: "d2"}
_NET_PRECISION = 6  # digits after the comma in the .net.xml (netOffset must keep the origin's precision)
_FCD_PRECISION = 3  # digits after the comma in fcd.xml: mm, ms
_FCD_ATTRIBUTES = ("x", "y", "angle", "type", "speed", "pos", "lane", "signals")  # signals: brake lights, blinkers
_NETCONVERT_TIMEOUT_S = 120.0
_GENERATED = re.compile(r"^\s*<!-- generated on .*? by Eclipse SUMO (\S+) (\S+)")


# ---------------------------------------------------------------------------------------------------- vehicles
@dataclass(frozen=True)
class VehicleClass:
    """A vehicle class: footprint and height (m), SUMO vClass/guiShape and driving parameters.

    ``speed_factor`` is SUMO's truncated normal ``normc(mean, deviation, min, max)`` multiplier of the speed limit
    giving each driver's desired speed; ``max_speed`` (m/s) caps it.
    """

    name: str
    length: float  # m, bumper to bumper
    width: float  # m, without mirrors
    height: float  # m
    sumo_vclass: str  # SUMO vClass
    gui_shape: str  # SUMO guiShape
    max_speed: float  # m/s
    accel: float  # m/s^2
    decel: float  # m/s^2, comfortable braking
    speed_factor: tuple[float, float, float, float]  # (mean, deviation, min, max)
    min_gap: float = 2.5  # m, standstill gap to the leader

    @property
    def speed_factor_spec(self) -> str:
        """The speed factor distribution as SUMO text, e.g. ``normc(1,0.1,0.8,1.2)``."""
        return "normc({})".format(",".join(f"{v:g}" for v in self.speed_factor))


VEHICLE_CLASSES: dict[str, VehicleClass] = {
    "car": VehicleClass("car", 4.5, 1.8, 1.5, "passenger", "passenger", 50.0, 2.6, 4.5, (1.0, 0.1, 0.8, 1.2)),
    "van": VehicleClass("van", 5.4, 2.0, 2.4, "delivery", "delivery", 44.4, 2.0, 4.5, (1.0, 0.08, 0.8, 1.15)),
    "truck": VehicleClass("truck", 12.0, 2.55, 3.8, "truck", "truck", 25.0, 1.1, 4.0, (1.0, 0.05, 0.85, 1.1)),
    "bus": VehicleClass("bus", 12.0, 2.55, 3.1, "bus", "bus", 27.8, 1.2, 4.0, (1.0, 0.05, 0.85, 1.1)),
}


# ---------------------------------------------------------------------------------------------------- inputs
def _finite(what: str, value: object, fix: str) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {value!r}; {fix}") from None
    if not math.isfinite(v):
        raise InputError(f"{what} must be finite, got {value!r}; {fix}")
    return v


def _positive(what: str, value: object, fix: str) -> float:
    v = _finite(what, value, fix)
    if v <= 0:
        raise InputError(f"{what} must be > 0, got {value!r}; {fix}")
    return v


@dataclass(frozen=True)
class RoadSpec:
    """A road with ``lanes`` lanes per direction (see the module docstring for the conventions).

    ``origin`` is the world point (CRS units, metres) of the road centre line at station 0; the road runs from
    station ``-length_m/2`` to ``+length_m/2`` along ``azimuth_deg`` (degrees clockwise from north at station 0),
    straight or, with ``curve_radius``, on a circular arc turning right (> 0) or left (< 0); see
    :class:`~trafficgeo.synth.gcp_scene.RoadSurface`.
    """

    origin: tuple[float, float, float] = (245000.0, 5182600.0, 90.0)
    azimuth_deg: float = 30.0
    length_m: float = 400.0
    lanes: int = 2
    two_way: bool = True
    lane_width: float = 3.5
    speed_limit_kmh: float = 50.0
    crs: str = "EPSG:2949"
    curve_radius: float = 0.0

    def __post_init__(self) -> None:
        try:
            origin = tuple(float(v) for v in self.origin)  # type: ignore[union-attr]
        except (TypeError, ValueError):
            origin = ()
        if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
            raise InputError(f"RoadSpec.origin must be 3 finite numbers (x, y, z in metres), got {self.origin!r}")
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "azimuth_deg",
                           _finite("RoadSpec.azimuth_deg", self.azimuth_deg, "give degrees clockwise from north"))
        object.__setattr__(self, "length_m", _positive("RoadSpec.length_m", self.length_m, "give metres, e.g. 400"))
        lanes = self.lanes
        if isinstance(lanes, bool) or not isinstance(lanes, int | np.integer) or lanes < 1:
            raise InputError(f"RoadSpec.lanes must be an integer >= 1 (lanes per direction), got {lanes!r}")
        object.__setattr__(self, "lanes", int(lanes))
        object.__setattr__(self, "two_way", bool(self.two_way))
        object.__setattr__(self, "lane_width",
                           _positive("RoadSpec.lane_width", self.lane_width, "give metres, e.g. 3.5"))
        object.__setattr__(self, "speed_limit_kmh",
                           _positive("RoadSpec.speed_limit_kmh", self.speed_limit_kmh, "give km/h, e.g. 50"))
        radius = _finite("RoadSpec.curve_radius", self.curve_radius, "give metres (> 0 right, < 0 left, 0 straight)")
        if radius != 0.0 and abs(radius) < 2.0 * (self.lanes * self.lane_width + _MARGIN_M / 4):
            raise InputError(f"RoadSpec.curve_radius {radius:g} m is too tight for {self.lanes} lanes per direction; "
                             "give at least 50 m")
        if radius != 0.0 and (0.5 * self.length_m + _MARGIN_M) / abs(radius) > 0.9 * math.pi:
            raise InputError(f"RoadSpec.curve_radius {radius:g} m bends a {self.length_m:g} m road (plus margins) "
                             "by more than 160 deg; use a larger radius or a shorter road")
        object.__setattr__(self, "curve_radius", radius)
        crs = parse_crs(self.crs)
        if crs is None or is_geographic(crs) or not math.isclose(metres_per_unit(crs), 1.0):
            raise InputError(f"RoadSpec.crs {self.crs!r} must be a projected CRS in metres (SUMO works in "
                             "metres); give one such as EPSG:2949 or a UTM zone")

    @property
    def speed_limit(self) -> float:
        """Speed limit in m/s."""
        return self.speed_limit_kmh / 3.6

    @property
    def directions(self) -> tuple[int, ...]:
        """The driving directions present: ``(1, 2)`` or ``(1,)``."""
        return (1, 2) if self.two_way else (1,)

    @property
    def surface(self) -> RoadSurface:
        """The road surface (flat) with the road's origin, azimuth and curve: ``station_offset``, ``points``, ``z``."""
        return RoadSurface(np.array(self.origin), self.azimuth_deg, curve_radius=self.curve_radius)

    def _check_lane(self, direction: int, lane: int) -> None:
        if direction not in self.directions:
            raise InputError(f"direction {direction!r} does not exist on this road; use one of {self.directions}")
        if not 1 <= lane <= self.lanes:
            raise InputError(f"lane {lane!r} does not exist; lanes are numbered 1..{self.lanes} from the centre")

    def heading_deg(self, direction: int, station: float = 0.0) -> float:
        """Driving heading of ``direction`` at ``station`` in degrees clockwise from north, in [0, 360)."""
        self._check_lane(direction, 1)
        return float((self.surface.heading_at(station) + (0.0 if direction == 1 else 180.0)) % 360.0)

    def lane_centre_offset(self, direction: int, lane: int) -> float:
        """Lateral offset (m, right of the axis positive) of the centre of ``lane`` (1 = innermost)."""
        self._check_lane(direction, lane)
        o = (lane - 0.5) * self.lane_width
        return o if direction == 1 else -o

    def lane_polygon(self, direction: int, lane: int, step_m: float = 2.0) -> np.ndarray:
        """World outline (2n, 3) of a lane over the road span: its inner edge from station -length/2 to
        +length/2, then its outer edge back. On a straight road n = 2 (four corners); on a curve the edges are
        sampled every ``step_m`` metres."""
        c = self.lane_centre_offset(direction, lane)
        half = 0.5 * self.lane_width
        inner, outer = (c - half, c + half) if direction == 1 else (c + half, c - half)
        n = 2 if self.curve_radius == 0 else max(2, int(np.ceil(self.length_m / step_m)) + 1)
        st = np.linspace(-0.5 * self.length_m, 0.5 * self.length_m, n)
        return self.surface.points(np.concatenate([st, st[::-1]]),
                                   np.concatenate([np.full(n, inner), np.full(n, outer)]))


@dataclass(frozen=True)
class Demand:
    """Traffic demand: vehicles per hour per lane (each direction) and the shares of the vehicle classes.

    ``mix`` maps class names of :data:`VEHICLE_CLASSES` to shares that must sum to 1 (they are not normalised).
    Above a lane's capacity (about 1800-2200 veh/h) SUMO cannot insert every vehicle in time and the flow falls
    short of the demand.
    """

    veh_per_hour_per_lane: float = 600.0
    mix: dict[str, float] = field(default_factory=lambda: {"car": 0.8, "van": 0.1, "truck": 0.07, "bus": 0.03})

    def __post_init__(self) -> None:
        q = _finite("Demand.veh_per_hour_per_lane", self.veh_per_hour_per_lane, "give vehicles per hour, e.g. 600")
        if q < 0:
            raise InputError(f"Demand.veh_per_hour_per_lane must be >= 0, got {self.veh_per_hour_per_lane!r}; "
                             "give vehicles per hour, e.g. 600")
        object.__setattr__(self, "veh_per_hour_per_lane", q)
        if not isinstance(self.mix, Mapping) or not self.mix:
            raise InputError(f"Demand.mix must be a non-empty mapping of class name to share, got {self.mix!r}; "
                             f"e.g. {{'car': 0.9, 'truck': 0.1}}")
        mix: dict[str, float] = {}
        for name, share in self.mix.items():
            if name not in VEHICLE_CLASSES:
                raise InputError(f"Demand.mix: unknown vehicle class {name!r}; use one of {sorted(VEHICLE_CLASSES)}")
            v = _finite(f"Demand.mix[{name!r}]", share, "give a share between 0 and 1")
            if v < 0:
                raise InputError(f"Demand.mix[{name!r}] must be >= 0, got {share!r}; give a share between 0 and 1")
            mix[str(name)] = v
        total = sum(mix.values())
        if abs(total - 1.0) > 1e-6:
            raise InputError(f"Demand.mix shares must sum to 1, they sum to {total:g}; divide each share by {total:g}")
        object.__setattr__(self, "mix", mix)

    def __hash__(self) -> int:
        return hash((self.veh_per_hour_per_lane, tuple(sorted(self.mix.items()))))


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


def _sumo_home() -> Path:
    try:
        import sumo  # the eclipse-sumo wheel
    except ImportError:
        raise InputError("SUMO is not installed (Python package eclipse-sumo missing); "
                         "install it with: pip install eclipse-sumo") from None
    return Path(sumo.SUMO_HOME)


def sumo_binary(name: str) -> str:
    """Path of a SUMO program (``sumo``, ``netconvert``, ``duarouter``, ...) from the eclipse-sumo wheel."""
    folder = _sumo_home() / "bin"
    exe = folder / (f"{name}.exe" if os.name == "nt" else name)
    if not exe.is_file():
        raise InputError(f"SUMO program {name!r} not found in {folder}; "
                         "reinstall SUMO with: pip install --force-reinstall eclipse-sumo")
    return str(exe)


def _sumo_env() -> dict[str, str]:
    """Environment for SUMO subprocesses: SUMO_HOME of the wheel, and its own PROJ database (PROJ_LIB)."""
    home = _sumo_home()
    env = dict(os.environ)
    env["SUMO_HOME"] = str(home)
    proj = home / "data" / "proj"
    if (proj / "proj.db").is_file():
        env["PROJ_LIB"] = str(proj)  # otherwise SUMO's PROJ prints "Cannot find proj.db"
    return env


def _tail(text: str, lines: int = 4) -> str:
    kept = [ln.strip() for ln in text.splitlines() if ln.strip()][-lines:]
    return " | ".join(kept) if kept else "(no output)"


def _run_tool(name: str, args: list[str], timeout_s: float) -> None:
    """Run a SUMO program headless; TrafficgeoError with its output tail on failure or timeout."""
    cmd = [sumo_binary(name), *args]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, env=_sumo_env(), timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        raise TrafficgeoError(f"SUMO {name} did not finish within {timeout_s:.0f} s") from None
    except OSError as exc:
        raise TrafficgeoError(f"cannot start SUMO {name} ({cmd[0]}): {exc}") from exc
    if proc.returncode != 0:
        raise TrafficgeoError(f"SUMO {name} failed with exit code {proc.returncode}: "
                              f"{_tail(proc.stderr or proc.stdout)}")


def _copy_without_header(src: Path, dst: Path) -> str | None:
    """Copy a SUMO output to ``dst`` (atomically), replacing the dated "generated on" comment (which also lists
    the configuration and temporary file names) by a fixed one. Returns the SUMO version found in it."""
    version = None
    with open(src, encoding="utf-8") as fin, atomic_open(dst, "w") as fout:
        in_header = False
        for line in fin:
            if version is None and not in_header:
                m = _GENERATED.match(line)
                if m:
                    version = m.group(2)
                    fout.write(f"<!-- Eclipse SUMO {m.group(1)} {version}; date and configuration removed by "
                               "trafficgeo for reproducible output -->\n")
                    in_header = "-->" not in line
                    continue
            if in_header:
                in_header = "-->" not in line
                continue
            fout.write(line)
    return version


# ---------------------------------------------------------------------------------------------------- network
def _num(value: float) -> str:
    """A float as exact, round-trip text for SUMO XML (no numpy repr)."""
    return repr(float(value))


def _proj_parameter(road: RoadSpec) -> str:
    """The PROJ string of the road's CRS, as SUMO wants it in ``projParameter``."""
    crs = parse_crs(road.crs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "You will likely lose important projection information"
        text = crs.to_proj4() if crs is not None else None
    if not text:
        raise InputError(f"RoadSpec.crs {road.crs!r} has no PROJ string for SUMO; use an EPSG projected CRS")
    return text.replace("+type=crs", "").strip()


def _axis_xy(road: RoadSpec, stations: np.ndarray) -> np.ndarray:
    """Axis points (N, 2) relative to the origin (the SUMO network's own coordinates)."""
    return road.surface.points(stations, np.zeros_like(stations))[:, :2] - np.array(road.origin[:2])


def _nodes_xml(road: RoadSpec) -> str:
    half = 0.5 * road.length_m + _MARGIN_M
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
        half = 0.5 * road.length_m + _MARGIN_M
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
        vc = VEHICLE_CLASSES[name]
        lines.append(f'    <vType id="{name}" vClass="{vc.sumo_vclass}" guiShape="{vc.gui_shape}" '
                     f'length="{_num(vc.length)}" width="{_num(vc.width)}" height="{_num(vc.height)}" '
                     f'minGap="{_num(vc.min_gap)}" '
                     f'maxSpeed="{_num(vc.max_speed)}" accel="{_num(vc.accel)}" decel="{_num(vc.decel)}" '
                     f'speedFactor="{vc.speed_factor_spec}"/>\n')
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
    from trafficgeo.io.sumo import read_fcd as read_sumo_fcd
    from trafficgeo.io.sumo import read_net_location

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
    duration = _positive("duration_s", duration_s, "give seconds, e.g. 60")
    step = _positive("step_s", step_s, "give seconds, e.g. 0.04 for 25 fps")
    warmup = _finite("warmup_s", warmup_s, "give seconds, e.g. 60")
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
