"""Junction gates: one line across each arm of a junction, named by its ``arm``, for turning-movement counts.

Conventions
-----------
* A gate is a line (CRS units) across the whole arm, both directions. A vehicle crossing it towards the junction
  *enters* by that arm (its origin); crossing it away from the junction, it *leaves* by it (its destination).
* The **junction centre** is where the arms' axes meet: each arm's axis runs through its gate's midpoint,
  perpendicular to the gate; the centre is the least-squares intersection of those axes (the mean of the gate
  midpoints where the axes are near parallel, e.g. two gates on one straight road).
* An arm's **bearing** (``bearing_deg``) is the direction from the centre to its gate's midpoint, degrees
  clockwise from grid north. Vehicles entering by an arm of bearing ``b`` head ``b + 180``: an arm to the south
  (bearing 180) is the northbound approach.
* The **movement** from arm ``o`` to arm ``d`` follows from the turn between the heading in (``bearing(o) + 180``)
  and the heading out (``bearing(d)``), positive clockwise: ``through`` within 45 degrees of straight on, ``right``
  beyond 45 clockwise, ``left`` beyond 45 anticlockwise, ``U`` back out by the arm it came in by. Left and right
  are geometric (the driver's left), the same for right- and left-hand traffic.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj
import shapely

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface
from trafficgeo.site.layout import feature_names, read_layout

MOVEMENTS = ("left", "through", "right", "U")
THROUGH_DEG = 45.0  # |turn| below this is through
COMPASS_BOUNDS = ("NB", "NEB", "EB", "SEB", "SB", "SWB", "WB", "NWB")  # by heading, 45-degree sectors


@dataclass(frozen=True)
class Gate:
    """The gate of one junction arm: its name ``arm`` and ``geometry`` (a LineString in CRS units)."""

    arm: str
    geometry: shapely.LineString

    @property
    def midpoint(self) -> np.ndarray:
        """The middle of the gate (x, y)."""
        p = self.geometry.interpolate(0.5, normalized=True)
        return np.array([p.x, p.y])

    @property
    def direction(self) -> np.ndarray:
        """Unit vector from the gate's first point to its last."""
        c = np.asarray(self.geometry.coords, dtype=np.float64)[:, :2]
        d = c[-1] - c[0]
        return d / np.linalg.norm(d)


@dataclass(frozen=True)
class Junction:
    """The gates of one junction with its ``centre`` (x, y, CRS units) and each arm's ``bearings_deg``."""

    gates: tuple[Gate, ...]
    centre: np.ndarray
    bearings_deg: dict[str, float]

    @classmethod
    def from_gates(cls, gates: list[Gate] | tuple[Gate, ...]) -> Junction:
        """The junction of ``gates`` (at least two, unique arm names), its centre and bearings (module docstring)."""
        gates = tuple(gates)
        if len(gates) < 2:
            raise InputError(f"gates: {len(gates)} gate(s); a junction needs a gate across each of at least two arms",
                             parameters=("gates",))
        names = [g.arm for g in gates]
        if len(set(names)) != len(names):
            raise InputError(f"gates: arm names must be unique; got {', '.join(names)}", parameters=("gates",))
        centre = junction_centre(gates)
        bearings = {}
        for g in gates:
            d = g.midpoint - centre
            if np.hypot(*d) < 1e-9:
                raise InputError(f"gates: the gate of arm {g.arm} passes through the junction centre; draw each gate "
                                 "across its arm, away from the middle of the junction", parameters=("gates",))
            bearings[g.arm] = float(np.degrees(np.arctan2(d[0], d[1])) % 360.0)
        return cls(gates, centre, bearings)

    @property
    def arms(self) -> list[str]:
        """Arm names in the order of the gates."""
        return [g.arm for g in self.gates]

    def movement(self, origin: str, destination: str) -> str:
        """``left``, ``through``, ``right`` or ``U`` from arm ``origin`` to arm ``destination`` ('' if either is
        unknown)."""
        if origin not in self.bearings_deg or destination not in self.bearings_deg:
            return ""
        if origin == destination:
            return "U"
        turn = turn_deg(self.bearings_deg[origin], self.bearings_deg[destination])
        if abs(turn) < THROUGH_DEG:
            return "through"
        return "right" if turn > 0 else "left"

    def approach_bound(self, arm: str) -> str:
        """The compass bound of the traffic entering by ``arm`` (an arm to the south: ``NB``)."""
        heading = (self.bearings_deg[arm] + 180.0) % 360.0
        return COMPASS_BOUNDS[int(np.floor((heading + 22.5) / 45.0)) % 8]


def turn_deg(origin_bearing_deg: float, destination_bearing_deg: float) -> float:
    """The turn (degrees, clockwise positive, in (-180, 180]) from entering by an arm of bearing
    ``origin_bearing_deg`` to leaving by one of bearing ``destination_bearing_deg``."""
    heading_in = origin_bearing_deg + 180.0
    t = (destination_bearing_deg - heading_in) % 360.0
    return t - 360.0 if t > 180.0 else t


def junction_centre(gates: tuple[Gate, ...] | list[Gate]) -> np.ndarray:
    """Least-squares intersection of the arms' axes (through each gate's midpoint, perpendicular to the gate);
    the mean of the midpoints where the axes are near parallel."""
    mids = np.array([g.midpoint for g in gates])
    a = np.zeros((2, 2))
    b = np.zeros(2)
    for g, m in zip(gates, mids, strict=True):
        u = g.direction  # the axis is perpendicular to the gate: its normal is the gate's direction
        n = np.outer(u, u)
        a += n
        b += n @ m
    w = np.linalg.eigvalsh(a)
    if w[0] < 1e-3 * w[1]:  # axes near parallel: no unique meeting point
        return mids.mean(axis=0)
    return np.linalg.solve(a, b)


def read_gates(path: str | Path, *, crs: pyproj.CRS | None, camera: Camera | None = None,
               surface: Surface | None = None) -> list[Gate]:
    """Gates from a GIS file of lines with an ``arm`` attribute (else ``name``), in any CRS (reprojected to
    ``crs``), or from a CSV of lines drawn in the image (``line, u, v``: the line name is the arm)."""
    gdf = read_layout(path, "gates", crs=crs, camera=camera, surface=surface)
    kinds = set(gdf.geometry.geom_type)
    if not kinds <= {"LineString"}:
        raise InputError(f"gates {path}: geometries are {', '.join(sorted(kinds))}; a gate must be a single line "
                         "(LineString) across its arm", parameters=("gates",))
    if not any(c in gdf.columns for c in ("arm", "name", "line")):
        raise InputError(f"gates {path}: no 'arm' attribute; give each gate line the name of its arm (e.g. N, E, "
                         "S, W or the street's name) in a column 'arm'", parameters=("gates",))
    names = feature_names(gdf, ("arm", "name", "line"))
    gates = []
    for name, geom in zip(names, gdf.geometry, strict=True):
        if not geom.length > 0:
            raise InputError(f"gates {path}: the gate of arm {name} has no length; draw it across the arm",
                             parameters=("gates",))
        gates.append(Gate(name, geom))
    Junction.from_gates(gates)  # checks names and geometry
    return gates
