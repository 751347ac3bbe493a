"""The scene of the synthetic demo world's SUMO traffic: the road (:class:`RoadSpec`: a straight or curved,
georeferenced road with lanes in one or two directions), the demand (:class:`Demand`) and the vehicle classes
(:data:`VEHICLE_CLASSES`). :mod:`trafficgeo.synth.sumo_world` builds the SUMO network and routes from them, runs SUMO
and reads its trajectories.

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
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from trafficgeo.crs import is_geographic, metres_per_unit, parse_crs
from trafficgeo.errors import InputError
from trafficgeo.synth.gcp_scene import RoadSurface

__all__ = ["VEHICLE_CLASSES", "Demand", "RoadSpec", "VehicleClass"]

EDGE_MARGIN_M = 40.0  # m of SUMO edge beyond each end of the road (insertion and exit zones, not in the trajectories)


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

    def vtype_xml(self) -> str:
        """The SUMO ``<vType>`` element of the class (id = its name), one indented line."""
        from trafficgeo.simulation.network import sumo_number as n

        return (f'    <vType id="{self.name}" vClass="{self.sumo_vclass}" guiShape="{self.gui_shape}" '
                f'length="{n(self.length)}" width="{n(self.width)}" height="{n(self.height)}" '
                f'minGap="{n(self.min_gap)}" maxSpeed="{n(self.max_speed)}" accel="{n(self.accel)}" '
                f'decel="{n(self.decel)}" speedFactor="{self.speed_factor_spec}"/>\n')


VEHICLE_CLASSES: dict[str, VehicleClass] = {
    "car": VehicleClass("car", 4.5, 1.8, 1.5, "passenger", "passenger", 50.0, 2.6, 4.5, (1.0, 0.1, 0.8, 1.2)),
    "van": VehicleClass("van", 5.4, 2.0, 2.4, "delivery", "delivery", 44.4, 2.0, 4.5, (1.0, 0.08, 0.8, 1.15)),
    "truck": VehicleClass("truck", 12.0, 2.55, 3.8, "truck", "truck", 25.0, 1.1, 4.0, (1.0, 0.05, 0.85, 1.1)),
    "bus": VehicleClass("bus", 12.0, 2.55, 3.1, "bus", "bus", 27.8, 1.2, 4.0, (1.0, 0.05, 0.85, 1.1)),
}


# ---------------------------------------------------------------------------------------------------- inputs
def finite_number(what: str, value: object, fix: str) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {value!r}; {fix}") from None
    if not math.isfinite(v):
        raise InputError(f"{what} must be finite, got {value!r}; {fix}")
    return v


def positive_number(what: str, value: object, fix: str) -> float:
    v = finite_number(what, value, fix)
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
                           finite_number("RoadSpec.azimuth_deg", self.azimuth_deg, "give degrees clockwise from north"))
        object.__setattr__(self, "length_m",
                           positive_number("RoadSpec.length_m", self.length_m, "give metres, e.g. 400"))
        lanes = self.lanes
        if isinstance(lanes, bool) or not isinstance(lanes, int | np.integer) or lanes < 1:
            raise InputError(f"RoadSpec.lanes must be an integer >= 1 (lanes per direction), got {lanes!r}")
        object.__setattr__(self, "lanes", int(lanes))
        object.__setattr__(self, "two_way", bool(self.two_way))
        object.__setattr__(self, "lane_width",
                           positive_number("RoadSpec.lane_width", self.lane_width, "give metres, e.g. 3.5"))
        object.__setattr__(self, "speed_limit_kmh",
                           positive_number("RoadSpec.speed_limit_kmh", self.speed_limit_kmh, "give km/h, e.g. 50"))
        radius = finite_number("RoadSpec.curve_radius", self.curve_radius,
                               "give metres (> 0 right, < 0 left, 0 straight)")
        if radius != 0.0 and abs(radius) < 2.0 * (self.lanes * self.lane_width + EDGE_MARGIN_M / 4):
            raise InputError(f"RoadSpec.curve_radius {radius:g} m is too tight for {self.lanes} lanes per direction; "
                             "give at least 50 m")
        if radius != 0.0 and (0.5 * self.length_m + EDGE_MARGIN_M) / abs(radius) > 0.9 * math.pi:
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
        q = finite_number("Demand.veh_per_hour_per_lane", self.veh_per_hour_per_lane,
                          "give vehicles per hour, e.g. 600")
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
            v = finite_number(f"Demand.mix[{name!r}]", share, "give a share between 0 and 1")
            if v < 0:
                raise InputError(f"Demand.mix[{name!r}] must be >= 0, got {share!r}; give a share between 0 and 1")
            mix[str(name)] = v
        total = sum(mix.values())
        if abs(total - 1.0) > 1e-6:
            raise InputError(f"Demand.mix shares must sum to 1, they sum to {total:g}; divide each share by {total:g}")
        object.__setattr__(self, "mix", mix)

    def __hash__(self) -> int:
        return hash((self.veh_per_hour_per_lane, tuple(sorted(self.mix.items()))))
