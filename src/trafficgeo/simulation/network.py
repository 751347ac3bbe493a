"""A SUMO network from a lanes layer: ``trafficgeo sumo-net`` (for a user without a ``.net.xml``).

Lanes are polygons with a direction of travel (``bearing``, deg clockwise from grid north; see
:mod:`trafficgeo.traffic.lanes`) in a projected CRS in metres. Each lane must be a strip: an outline with four
sharp corners (turns of more than :data:`CORNER_DEG`), two long sides and two short ends; its sides may curve.

* Lanes of the same direction (bearings within 45 deg) that touch side by side (gap at most :data:`GAP_M`) form a
  carriageway: one SUMO edge, its lanes ordered from the right in the direction of travel (SUMO lane 0 is the
  rightmost), ``numLanes`` the lanes, ``width`` their mean width (area / centreline length), ``speed`` the limit.
  Lanes of unequal widths (by more than 1 cm) keep their own widths. Lanes of an edge must start and end together
  (within :data:`END_TOLERANCE_M`). The lanes of the demo world ``d1_1, d1_2`` give edge ``d1`` (the common part
  of the names before their last ``_``; else ``e1, e2, ...``).
* The edge's ``shape`` (``spreadType="center"``) is the midline between the carriageway's outer boundaries (the
  right side of its rightmost lane and the left side of its leftmost), sampled every :data:`STEP_M` metres and
  simplified to within 1 cm; each edge has its own two dead-end nodes at the ends of that line. One-way roads give
  one edge.

Georeferencing as :mod:`trafficgeo.synth.sumo_world`: node coordinates relative to a local origin (whole metres near
the lanes' centre), ``netconvert --offset.disable-normalization``, the ``<location>`` of the node file with
``netOffset = -origin`` and ``projParameter`` = the CRS's PROJ string, so ``sumo_xy = projected_xy + netOffset`` and
sumolib's ``convertXY2LonLat`` projects with the CRS's own datum. The date SUMO writes at the top of the network is
replaced by a fixed comment: the same lanes give the same bytes.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import pyproj
import shapely

from trafficgeo.crs import crs_label, is_geographic, metres_per_unit, parse_crs, utm_crs_for
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_open, atomic_path, write_text_atomic
from trafficgeo.simulation.tools import run_sumo_program
from trafficgeo.site.lanes import Lanes, angle_between

__all__ = ["CORNER_DEG", "GAP_M", "STEP_M", "NetEdge", "SumoNet", "build_sumo_net", "copy_without_sumo_header",
           "proj_parameter", "sumo_number"]

CORNER_DEG = 30.0  # a turn of the outline sharper than this is a corner of the lane strip
GAP_M = 0.5  # lanes of one direction at most this far apart are side by side on one edge
STEP_M = 2.0  # sampling of the edge's centreline (m) before simplifying it to within SHAPE_TOLERANCE_M
SHAPE_TOLERANCE_M = 0.01
END_TOLERANCE_M = 5.0  # lanes of one edge start and end within this distance (m) of each other
WIDTH_TOLERANCE_M = 0.01  # lanes of an edge whose widths differ by more get their own widths in the network
NET_PRECISION = 6  # digits after the comma in the .net.xml
NETCONVERT_TIMEOUT_S = 120.0
_GENERATED = re.compile(r"^\s*<!-- generated on .*? by Eclipse SUMO (\S+) (\S+)")
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9.:-]*$")


# ---------------------------------------------------------------------------------------------------- shared
def sumo_number(value: float) -> str:
    """A float as exact, round-trip text for SUMO XML (no numpy repr)."""
    return repr(float(value))


def proj_parameter(crs: pyproj.CRS | str, what: str) -> str:
    """The PROJ string of a projected CRS as SUMO wants it in ``projParameter``; ``what`` names it in errors."""
    parsed = parse_crs(crs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "You will likely lose important projection information"
        text = parsed.to_proj4() if parsed is not None else None
    if not text:
        raise InputError(f"{what} {crs_label(parsed)} has no PROJ string for SUMO; use an EPSG projected CRS")
    return text.replace("+type=crs", "").strip()


def copy_without_sumo_header(src: Path, dst: Path) -> str | None:
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


# ---------------------------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class NetEdge:
    """One edge of the built network: a carriageway of lanes of one direction."""

    id: str
    lanes: tuple[str, ...]  # lane names, rightmost first (SUMO lane i = lanes[i])
    lane_width_m: float  # mean of the lanes' widths
    lane_widths_m: tuple[float, ...]  # each lane's (area / centreline length), rightmost first
    length_m: float  # of the centreline
    bearing_deg: float  # direction of travel at the middle, deg clockwise from grid north
    shape: np.ndarray  # (N, 2) centreline in the CRS (world coordinates, m)


@dataclass(frozen=True)
class SumoNet:
    """:func:`build_sumo_net`: the network file, its edges, CRS and local origin (``netOffset = -origin``)."""

    path: Path
    edges: tuple[NetEdge, ...]
    crs: pyproj.CRS
    origin: tuple[float, float]
    sumo_version: str


@dataclass(frozen=True)
class _Strip:
    """A lane as a strip: its left and right sides (N, 2) in the direction of travel, width and centreline."""

    name: str
    bearing: float
    left: np.ndarray
    right: np.ndarray
    centre: shapely.LineString
    width_m: float


# ---------------------------------------------------------------------------------------------------- geometry
def _resample(xy: np.ndarray, n: int) -> np.ndarray:
    """``n`` points evenly spaced along the polyline ``xy`` (N, 2), ends included."""
    seg = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(t, s, xy[:, 0]), np.interp(t, s, xy[:, 1])])


def _midline(a: np.ndarray, b: np.ndarray, step_m: float = STEP_M) -> np.ndarray:
    """The line halfway between two polylines running the same way, matched by fraction of their lengths."""
    length = 0.5 * (shapely.LineString(a).length + shapely.LineString(b).length)
    n = max(2, int(np.ceil(length / step_m)) + 1)
    return 0.5 * (_resample(a, n) + _resample(b, n))


def _bearing_at_middle(xy: np.ndarray) -> float:
    """Direction (deg clockwise from grid north) of the polyline at half its length."""
    line = shapely.LineString(xy)
    half = 0.5 * line.length
    p, q = line.interpolate(max(half - 1.0, 0.0)), line.interpolate(min(half + 1.0, line.length))
    return float(np.degrees(np.arctan2(q.x - p.x, q.y - p.y)) % 360.0)


def _strip(name: str, polygon: shapely.Geometry, bearing: float) -> _Strip:
    """A lane polygon as a strip (see the module docstring)."""
    if not isinstance(polygon, shapely.Polygon):
        raise InputError(f"lanes: lane {name} is in {len(getattr(polygon, 'geoms', []))} parts; draw each lane as "
                         "one polygon", parameters=("lanes",))
    ring = np.asarray(polygon.exterior.coords, dtype=np.float64)[:-1, :2]
    keep = np.hypot(*(ring - np.roll(ring, 1, axis=0)).T) > 1e-6
    ring = ring[keep]
    d_in = ring - np.roll(ring, 1, axis=0)
    d_out = np.roll(ring, -1, axis=0) - ring
    turn = np.degrees(np.abs(np.arctan2(d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0],
                                        np.sum(d_in * d_out, axis=1))))
    corners = np.flatnonzero(turn > CORNER_DEG)
    if corners.size != 4:
        raise InputError(f"lanes: lane {name} has {corners.size} sharp corners; draw each lane as a strip with 4 "
                         "corners (two ends, two sides along the road)", parameters=("lanes",))
    chains = []
    for k in range(4):
        i, j = corners[k], corners[(k + 1) % 4]
        idx = np.arange(i, j + 1) if j > i else np.concatenate([np.arange(i, len(ring)), np.arange(0, j + 1)])
        chains.append(ring[idx])
    lengths = [shapely.LineString(c).length for c in chains]
    first = 0 if lengths[0] + lengths[2] >= lengths[1] + lengths[3] else 1
    a, b = chains[first], chains[first + 2][::-1]  # the two long sides, running the same way
    if angle_between(_bearing_at_middle(_midline(a, b)), bearing) > 90.0:
        a, b = a[::-1], b[::-1]
    mid = _midline(a, b)
    n = len(mid) // 2
    tangent = mid[min(n + 1, len(mid) - 1)] - mid[max(n - 1, 0)]
    to_b = _resample(b, len(mid))[n] - _resample(a, len(mid))[n]
    left, right = (b, a) if tangent[0] * to_b[1] - tangent[1] * to_b[0] > 0 else (a, b)
    centre = shapely.LineString(_midline(left, right))
    return _Strip(name, bearing, left, right, centre, float(polygon.area / max(centre.length, 1e-9)))


def _offset_along(ref: shapely.LineString, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Station (m along ``ref``) and signed offset (m, left positive) of points ``xy`` (N, 2)."""
    pts = shapely.points(xy)
    s = shapely.line_locate_point(ref, pts)
    p = shapely.get_coordinates(shapely.line_interpolate_point(ref, np.maximum(s - 0.5, 0.0)))
    q = shapely.get_coordinates(shapely.line_interpolate_point(ref, np.minimum(s + 0.5, ref.length)))
    t = q - p
    foot = shapely.get_coordinates(shapely.line_interpolate_point(ref, s))
    d = xy - foot
    side = np.sign(t[:, 0] * d[:, 1] - t[:, 1] * d[:, 0])
    return s, side * np.hypot(d[:, 0], d[:, 1])


# ---------------------------------------------------------------------------------------------------- grouping
def _check_overlaps(names: tuple[str, ...], polygons: tuple[shapely.Geometry, ...]) -> None:
    tree = shapely.STRtree(polygons)
    for i, j in zip(*tree.query(polygons, predicate="intersects"), strict=True):
        if i >= j:
            continue
        area = polygons[i].intersection(polygons[j]).area
        if area > 0.01 * min(polygons[i].area, polygons[j].area):
            raise InputError(f"lanes: lanes {names[i]} and {names[j]} overlap by {area:.1f} m2; redraw them so that "
                             "they only share their common edge", parameters=("lanes",))


def _groups(strips: list[_Strip], polygons: tuple[shapely.Geometry, ...]) -> list[list[int]]:
    """Carriageways: lanes of the same direction side by side (connected components), in file order."""
    n = len(strips)
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    tree = shapely.STRtree(polygons)
    for i, j in zip(*tree.query(polygons, predicate="dwithin", distance=GAP_M), strict=True):
        if i >= j or angle_between(strips[i].bearing, strips[j].bearing) > 45.0:
            continue
        a, b = strips[i], strips[j]
        s, _ = _offset_along(a.centre, shapely.get_coordinates(b.centre)[[0, -1]])
        overlap = min(s.max(), a.centre.length) - max(s.min(), 0.0)
        if overlap < 0.5 * min(a.centre.length, b.centre.length):
            raise InputError(f"lanes: lanes {a.name} and {b.name} of the same direction meet end to end, not side "
                             "by side; draw each lane as one polygon along the whole road", parameters=("lanes",))
        parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    return sorted(groups.values(), key=min)


def _edge_ids(groups: list[list[str]]) -> list[str]:
    """The common head of each group's lane names before their last ``_`` (``d1`` of ``d1_1, d1_2``) when every
    group has one, unique and a clean SUMO id; else ``e1, e2, ...``."""
    ids = []
    for names in groups:
        heads = {name.rpartition("_")[0] for name in names}
        ids.append(heads.pop() if len(heads) == 1 else "")
    if len(set(ids)) == len(ids) and all(_ID.match(i) for i in ids):
        return ids
    return [f"e{k + 1}" for k in range(len(groups))]


def _edge(edge_id: str, group: list[_Strip]) -> NetEdge:
    """The edge of a carriageway: lanes ordered from the right, shape between the outer boundaries."""
    ref = group[0].centre
    mids = np.array([shapely.get_coordinates(s.centre.interpolate(0.5, normalized=True))[0] for s in group])
    _, offset = _offset_along(ref, mids)
    order = np.argsort(offset, kind="stable")  # rightmost (most negative: right of the reference) first
    lanes = [group[k] for k in order]
    ends = np.array([_offset_along(ref, shapely.get_coordinates(s.centre)[[0, -1]])[0] for s in lanes])
    far = np.abs(ends - ends[order == 0]).max(axis=1) if len(lanes) > 1 else np.zeros(1)
    if far.max() > END_TOLERANCE_M:
        k = int(np.argmax(far))
        raise InputError(f"lanes: lane {lanes[k].name} starts or ends {far[k]:.0f} m away from lane {group[0].name} "
                         "beside it; the lanes of one edge run the same stretch: draw them to the same ends (a "
                         f"turning pocket as its own stretch of road), within {END_TOLERANCE_M:g} m",
                         parameters=("lanes",))
    shape = _midline(lanes[-1].left, lanes[0].right)
    line = shapely.LineString(shape).simplify(SHAPE_TOLERANCE_M)
    widths = tuple(float(s.width_m) for s in lanes)
    return NetEdge(edge_id, tuple(s.name for s in lanes), float(np.mean(widths)), widths, float(line.length),
                   _bearing_at_middle(shape), shapely.get_coordinates(line))


# ---------------------------------------------------------------------------------------------------- XML
def _nodes_xml(edges: list[NetEdge], origin: np.ndarray, proj: str) -> str:
    pts = np.vstack([e.shape for e in edges]) - origin
    (xmin, ymin), (xmax, ymax) = pts.min(axis=0), pts.max(axis=0)
    ox, oy = origin
    num = sumo_number
    location = (f'netOffset="{num(-ox)},{num(-oy)}" '
                f'convBoundary="{num(xmin)},{num(ymin)},{num(xmax)},{num(ymax)}" '
                f'origBoundary="{num(xmin + ox)},{num(ymin + oy)},{num(xmax + ox)},{num(ymax + oy)}" '
                f"projParameter={quoteattr(proj)}")
    rows = [f"    <location {location}/>\n"]
    for e in edges:
        for end, (x, y) in (("start", e.shape[0] - origin), ("end", e.shape[-1] - origin)):
            rows.append(f'    <node id="{e.id}_{end}" x="{num(x)}" y="{num(y)}" type="dead_end"/>\n')
    return "<nodes>\n" + "".join(rows) + "</nodes>\n"


def _edges_xml(edges: list[NetEdge], origin: np.ndarray, speed_mps: float) -> str:
    rows = []
    for e in edges:
        shape = " ".join(f"{sumo_number(x)},{sumo_number(y)}" for x, y in e.shape - origin)
        head = (f'    <edge id="{e.id}" from="{e.id}_start" to="{e.id}_end" numLanes="{len(e.lanes)}" '
                f'speed="{sumo_number(speed_mps)}" width="{sumo_number(e.lane_width_m)}" spreadType="center" '
                f'shape="{shape}"')
        if max(e.lane_widths_m) - min(e.lane_widths_m) <= WIDTH_TOLERANCE_M:
            rows.append(head + "/>\n")
            continue
        rows.append(head + ">\n" + "".join(f'        <lane index="{i}" width="{sumo_number(w)}"/>\n'
                                            for i, w in enumerate(e.lane_widths_m)) + "    </edge>\n")
    return "<edges>\n" + "".join(rows) + "</edges>\n"


# ---------------------------------------------------------------------------------------------------- inputs
def _read_lanes(lanes: Lanes | str | os.PathLike[str], crs: str | pyproj.CRS | None) -> tuple[Lanes, pyproj.CRS]:
    """Lanes and their projected CRS: a Lanes object needs ``crs``; a file is reprojected to ``crs`` if given."""
    target = parse_crs(crs) if crs is not None else None
    if isinstance(lanes, Lanes):
        if target is None:
            raise InputError("crs: Lanes objects carry no CRS; give crs, the projected CRS of their coordinates",
                             parameters=("crs",))
        return lanes, _check_projected(target, "crs")
    if not isinstance(lanes, str | os.PathLike):
        raise InputError(f"lanes: {type(lanes).__name__} is neither Lanes nor the path of a lanes file",
                         parameters=("lanes",))
    path = Path(lanes)
    if not path.is_file():
        raise InputError(f"lanes {path}: file not found; give a GIS file of lane polygons (.gpkg, .geojson)",
                         parameters=("lanes",))
    if path.suffix.lower() == ".csv":
        raise InputError(f"lanes {path}: lanes drawn in the image need a camera; give lane polygons in world "
                         "coordinates (a GIS file)", parameters=("lanes",))
    from trafficgeo.io.gis import read_gis
    from trafficgeo.site.lanes import read_lanes

    gdf = read_gis(path)
    file_crs = parse_crs(gdf.crs) if gdf.crs is not None else None
    if target is None and file_crs is None:
        raise InputError(f"lanes {path}: the file has no CRS; give `crs`, the projected CRS of its coordinates "
                         "(e.g. EPSG:32633), or save the layer with its CRS", parameters=("lanes", "crs"))
    if target is None:
        target = file_crs
        if is_geographic(target):
            b = gdf.total_bounds
            utm = utm_crs_for(0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3]))
            raise InputError(f"lanes {path}: the lanes are in {crs_label(target)} (degrees); SUMO works in metres: "
                             f"give `crs`, a projected CRS such as {crs_label(utm)}", parameters=("lanes", "crs"))
    return read_lanes(path, crs=target), _check_projected(target, "crs")


def _check_projected(crs: pyproj.CRS, what: str) -> pyproj.CRS:
    if is_geographic(crs) or not np.isclose(metres_per_unit(crs), 1.0):
        raise InputError(f"{what} {crs_label(crs)}: SUMO works in metres; give a projected CRS in metres (a UTM "
                         "zone or the national grid)", parameters=(what,))
    return crs


# ---------------------------------------------------------------------------------------------------- build
def build_sumo_net(lanes: Lanes | str | os.PathLike[str], out_path: str | os.PathLike[str], *,
                   crs: str | pyproj.CRS | None = None, speed_kmh: float = 50.0) -> SumoNet:
    """Build a georeferenced SUMO network (``out_path``, a ``.net.xml``) from lane polygons with directions.

    ``lanes``: a lanes file (GIS polygons with a ``bearing`` column, the layer ``trafficgeo`` reads) or
    :class:`~trafficgeo.site.lanes.Lanes`; ``crs``: the projected CRS (metres) of the network (a file is
    reprojected to it; default the file's CRS; required for a Lanes object); ``speed_kmh``: the speed limit of
    every edge. See the module docstring for the rules. Nothing is written on error; the file appears whole.

    Raises:
        InputError: unreadable lanes, no CRS, a lane without direction, overlapping or ungroupable lanes.
        TrafficgeoError: netconvert failed.
    """
    out = Path(out_path)
    if out.is_dir():
        raise InputError(f"out_path {out}: is a folder; give the network file to write, e.g. {out / 'road.net.xml'}",
                         parameters=("out_path",))
    try:
        speed = float(speed_kmh)
    except (TypeError, ValueError):
        speed = float("nan")
    if not (0.0 < speed < 1000.0):
        raise InputError(f"speed_kmh {speed_kmh!r}: give the speed limit in km/h, e.g. 50", parameters=("speed_kmh",))
    layer, net_crs = _read_lanes(lanes, crs)
    bearings = layer.bearings if layer.bearings is not None else (float("nan"),) * len(layer.names)
    for name, b in zip(layer.names, bearings, strict=True):
        if not np.isfinite(b):
            raise InputError(f"lanes: lane {name} has no direction of travel; add a 'bearing' column to the lane "
                             "polygons (degrees clockwise from north)", parameters=("lanes",))
    _check_overlaps(layer.names, layer.polygons)
    strips = [_strip(n, p, b) for n, p, b in zip(layer.names, layer.polygons, bearings, strict=True)]
    groups = _groups(strips, layer.polygons)
    ids = _edge_ids([[strips[k].name for k in g] for g in groups])
    edges = [_edge(i, [strips[k] for k in g]) for i, g in zip(ids, groups, strict=True)]
    proj = proj_parameter(net_crs, "crs")
    every = np.vstack([e.shape for e in edges])
    origin = np.round(0.5 * (every.min(axis=0) + every.max(axis=0)))
    work = Path(tempfile.mkdtemp(prefix=".sumo-net-"))
    try:
        nod, edg, raw = work / "lanes.nod.xml", work / "lanes.edg.xml", work / "lanes.net.xml"
        write_text_atomic(nod, _nodes_xml(edges, origin, proj))
        write_text_atomic(edg, _edges_xml(edges, origin, speed / 3.6))
        run_sumo_program("netconvert", ["--node-files", str(nod), "--edge-files", str(edg),
                                        "--offset.disable-normalization", "--no-turnarounds", "--precision",
                                        str(NET_PRECISION), "--output-file", str(raw)], NETCONVERT_TIMEOUT_S)
        with atomic_path(out) as tmp:
            version = copy_without_sumo_header(raw, tmp)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return SumoNet(out, tuple(edges), net_crs, (float(origin[0]), float(origin[1])), version or "unknown")
