"""SUMO network location (netOffset, projection) and the coordinate frames of FCD files.

A network's ``<location netOffset projParameter>`` says ``sumo_xy = projected_xy + netOffset`` (metres);
the helpers here turn that into a :class:`NetLocation`, compare and reproject CRSs and move points along
headings (degrees clockwise from grid north). Used by :mod:`trafficgeo.io.fcd_read` and
:mod:`trafficgeo.io.fcd_write`.
"""

from __future__ import annotations

import math
import os
import warnings
import xml.parsers.expat
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj

from trafficgeo.crs import crs_label, is_geographic, parse_crs, same_horizontal_crs, transform_xy
from trafficgeo.errors import InputError

_NO_PROJECTION = "!"
_SUMO_SPECIAL_PROJ = ("-", "UTM", "DHDN", "DHDN_UTM")


@dataclass(frozen=True)
class NetLocation:
    """The ``<location>`` of a SUMO network: ``sumo_xy = projected_xy + offset`` (network units, metres).

    ``crs`` is the network's projection (None when ``projParameter`` is ``"!"``: no projection).
    """

    offset: tuple[float, float]
    crs: pyproj.CRS | None
    proj_parameter: str


class _Stop(Exception):
    """Raised inside expat handlers to stop parsing early."""


def check_input_file(path: str | os.PathLike[str], what: str, hint: str) -> Path:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: {what} not found; {hint}")
    return p


def read_net_location(net: str | os.PathLike[str]) -> NetLocation:
    """Read ``<location netOffset projParameter>`` at the top of a SUMO ``.net.xml`` (stops parsing there)."""
    p = check_input_file(net, "SUMO network file", "give the .net.xml the simulation used")
    found: dict[str, str] = {}
    root: list[str] = []

    def start(name: str, attrs: dict[str, str]) -> None:
        root.append(name)
        if name == "location":
            found.update(attrs)
            raise _Stop
        if len(root) > 2:  # <location> comes right after <net>
            raise _Stop

    parser = xml.parsers.expat.ParserCreate()
    parser.StartElementHandler = start
    try:
        with open(p, "rb") as fh:
            parser.ParseFile(fh)
    except _Stop:
        pass
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(f"{p}: not readable XML ({exc}); give the .net.xml the simulation used") from None
    if not root or root[0] != "net" or "netOffset" not in found:
        raise InputError(f"{p}: no <net><location netOffset=...> found; give a SUMO network (.net.xml)")
    return NetLocation(_net_offset(p, found["netOffset"]), *_net_crs(p, found.get("projParameter", "!")))


def _net_offset(p: Path, text: str) -> tuple[float, float]:
    try:
        ox, oy = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"{p}: <location netOffset={text!r}> is not 'x,y'; give a valid SUMO network") from None
    if not (math.isfinite(ox) and math.isfinite(oy)):
        raise InputError(f"{p}: <location netOffset={text!r}> is not a finite 'x,y'; give a valid SUMO network "
                         "(rebuild it with netconvert)")
    return ox, oy


def _net_crs(p: Path, proj: str) -> tuple[pyproj.CRS | None, str]:
    proj = proj.strip()
    if proj == _NO_PROJECTION:
        return None, proj
    if proj in _SUMO_SPECIAL_PROJ:
        raise InputError(f"{p}: projParameter {proj!r} is a SUMO built-in projection trafficgeo cannot reproduce; "
                         "rebuild the network with netconvert --proj '<PROJ string>' (e.g. --proj.utm writes one)")
    try:
        return pyproj.CRS.from_user_input(proj), proj
    except pyproj.exceptions.CRSError:
        raise InputError(f"{p}: projParameter {proj!r} is not a PROJ string pyproj understands; "
                         "rebuild the network with netconvert --proj '<PROJ string>'") from None


def net_location(net: str | os.PathLike[str] | None, net_crs: str | pyproj.CRS | None,
              where: str) -> NetLocation | None:
    """The network's location, its CRS replaced by ``net_crs`` when given."""
    if net is None:
        if net_crs is not None:
            raise InputError(f"{where}: net_crs is given without net; pass the .net.xml too, or crs alone")
        return None
    loc = read_net_location(net)
    if net_crs is None:
        return loc
    return NetLocation(loc.offset, checked_world_crs(net_crs, f"{where}: net_crs"), loc.proj_parameter)


def net_crs_label(crs: pyproj.CRS) -> str:
    """:func:`crs_label`, or the PROJ string for a CRS without a name (as built from a SUMO projParameter)."""
    label = crs_label(crs)
    return " ".join(sorted(_proj_tokens(crs)))[:80] if label.startswith("unknown") else label


def _proj_tokens(crs: pyproj.CRS) -> frozenset[str]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "You will likely lose important projection information"
        text = crs.to_proj4() or ""
    return frozenset(text.split()) - {"+no_defs", "+type=crs", "+wktext"}


def same_projection(a: pyproj.CRS, b: pyproj.CRS) -> bool:
    """Same horizontal CRS, or the same PROJ projection (SUMO's PROJ strings carry no datum name)."""
    return same_horizontal_crs(a, b) or _proj_tokens(a) == _proj_tokens(b)


# ---------------------------------------------------------------------------------------------------- geometry
def reproject_with_headings(x: np.ndarray, y: np.ndarray, heading: np.ndarray, src: pyproj.CRS,
               dst: pyproj.CRS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Transform projected points and rotate headings (degrees clockwise from grid north) into ``dst``'s grid."""
    tx, ty = transform_xy(x, y, src, dst)
    h = np.radians(heading)
    ax, ay = transform_xy(x + np.sin(h), y + np.cos(h), src, dst)  # a point one source unit ahead
    new = np.mod(np.degrees(np.arctan2(ax - tx, ay - ty)), 360.0)
    return tx, ty, np.where(np.isfinite(heading), new, np.nan)


def geodetic_of(crs: pyproj.CRS) -> pyproj.CRS:
    geo = crs.geodetic_crs
    if geo is None:
        raise InputError(f"CRS {crs_label(crs)} has no geodetic CRS, so longitude/latitude cannot be used with it")
    return geo


def shift_along(x: np.ndarray, y: np.ndarray, heading: np.ndarray,
                 distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move points ``distance`` (their CRS units) along ``heading`` (degrees clockwise from grid north)."""
    h = np.radians(heading)
    return x + distance * np.sin(h), y + distance * np.cos(h)


def checked_world_crs(crs: str | pyproj.CRS | None, what: str) -> pyproj.CRS | None:
    parsed = parse_crs(crs)
    if parsed is not None and is_geographic(parsed):
        raise InputError(f"{what}: crs {crs_label(parsed)} is geographic; world coordinates need a projected CRS "
                         "(e.g. a UTM zone such as EPSG:32632)")
    return parsed


@dataclass
class FcdFrame:
    """Working coordinates of an FCD being read or written."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    heading: np.ndarray
    crs: pyproj.CRS | None  # CRS of x, y (None: local)
    notes: list[str]



def wkt_or_none(crs: pyproj.CRS | None) -> str | None:
    return None if crs is None else crs.to_wkt()

