"""What the live calibration draws: the camera footprint on the orthophoto and the world grid on both images.

Grid lines run along constant world x (eastings) and constant world y (northings) at a round spacing, clipped to the
ground the camera sees (its footprint, within ``max_distance_m``) and to the orthophoto. On the orthophoto they are
straight (the raster transform is affine); on the frame they are sampled densely, lifted onto the ground surface
and projected through the calibrated camera (lens distortion included), so a wrong camera shows as a grid that does
not fit the road. Frame lines are in camera pixels (``(0, 0)`` = centre of the top-left pixel), orthophoto lines
and the footprint in raster positions ``(col, row)`` (``(0, 0)`` = top-left corner); world coordinates stay in
float64 on the server.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from shapely.geometry import LineString, MultiLineString, Polygon
from shapely.geometry.base import BaseGeometry

from trafficgeo.camera.model import Camera
from trafficgeo.site.layers import visible_footprint
from trafficgeo.ui.inputs import Orthophoto

#: Grid lines wanted across the larger side of the visible ground.
GRID_LINES = 12
#: Samples per grid spacing along a frame line.
SAMPLES_PER_SPACING = 24
MAX_LINES_PER_AXIS = 60


def nice_spacing(span: float, lines: int = GRID_LINES) -> float:
    """A round grid spacing (1, 2 or 5 x 10^k CRS units) giving about ``lines`` lines over ``span``."""
    if not (math.isfinite(span) and span > 0):
        return 1.0
    raw = span / lines
    base = 10.0 ** math.floor(math.log10(raw))
    return min((m * base for m in (1.0, 2.0, 5.0, 10.0)), key=lambda s: abs(math.log(s / raw)))


def _rings(geom: BaseGeometry) -> list[Polygon]:
    if geom.is_empty:
        return []
    if isinstance(geom, Polygon):
        return [geom]
    return [g for g in getattr(geom, "geoms", []) if isinstance(g, Polygon) and not g.is_empty]


def footprint(camera: Camera, surface: Any, ortho: Orthophoto, max_distance_m: float = 250.0
              ) -> tuple[BaseGeometry, list[list[list[list[float]]]]]:
    """The ground the camera sees (shapely geometry, world CRS units) and the same as polygons of rings of
    ``[col, row]`` orthophoto positions (first ring outer, then holes) for Leaflet."""
    geom = visible_footprint(camera, surface, max_distance_m=max_distance_m)
    polys = []
    for poly in _rings(geom):
        rings = []
        for ring in [poly.exterior, *poly.interiors]:
            xy = np.asarray(ring.coords, dtype=np.float64)
            col, row = ortho.map_to_pixel(xy[:, 0], xy[:, 1])
            rings.append(np.round(np.column_stack([col, row]), 3).tolist())
        polys.append(rings)
    return geom, polys


def _segments(geom: BaseGeometry) -> list[LineString]:
    if geom.is_empty:
        return []
    if isinstance(geom, LineString):
        return [geom]
    if isinstance(geom, MultiLineString):
        return list(geom.geoms)
    return [g for g in getattr(geom, "geoms", []) if isinstance(g, LineString) and not g.is_empty]


def _frame_polylines(camera: Camera, surface: Any, xy: np.ndarray) -> list[list[list[float]]]:
    """World points (N, 2) along a line, lifted onto ``surface`` and projected; split where a point is not seen."""
    z = surface.elevation(xy[:, 0], xy[:, 1])
    uv = camera.project(np.column_stack([xy, z]))
    ok = np.all(np.isfinite(uv), axis=1)
    ok[ok] = camera.in_image(uv[ok])
    out: list[list[list[float]]] = []
    run: list[list[float]] = []
    for good, p in zip(ok.tolist(), uv, strict=True):
        if good:
            run.append([round(float(p[0]), 2), round(float(p[1]), 2)])
        elif run:
            if len(run) >= 2:
                out.append(run)
            run = []
    if len(run) >= 2:
        out.append(run)
    return out


def grid(camera: Camera, surface: Any, ortho: Orthophoto, seen: BaseGeometry, unit: str = "m") -> dict[str, Any]:
    """World grid lines over the seen ground (``seen``, world CRS units), for the frame and the orthophoto.

    Returns ``{"spacing", "unit", "frame": [{"label", "points": [[u, v], ...]}], "ortho": [{"label", "points":
    [[col, row], [col, row]]}]}``.
    """
    area = seen.intersection(Polygon(ortho.world_corners())) if not seen.is_empty else seen
    result: dict[str, Any] = {"spacing": None, "unit": unit, "frame": [], "ortho": []}
    if area.is_empty:
        return result
    minx, miny, maxx, maxy = area.bounds
    spacing = nice_spacing(max(maxx - minx, maxy - miny))
    while (maxx - minx) / spacing > MAX_LINES_PER_AXIS or (maxy - miny) / spacing > MAX_LINES_PER_AXIS:
        spacing *= 2.0
    result["spacing"] = spacing
    step = spacing / SAMPLES_PER_SPACING
    lines: list[tuple[str, LineString]] = []
    for k in range(math.ceil(minx / spacing), math.floor(maxx / spacing) + 1):
        x = k * spacing
        lines.append((f"x = {x:.10g} {unit}", LineString([(x, miny), (x, maxy)])))
    for k in range(math.ceil(miny / spacing), math.floor(maxy / spacing) + 1):
        y = k * spacing
        lines.append((f"y = {y:.10g} {unit}", LineString([(minx, y), (maxx, y)])))
    for label, line in lines:
        for seg in _segments(area.intersection(line)):
            ends = np.asarray(seg.coords, dtype=np.float64)[[0, -1]]  # a piece of a straight line
            n = max(2, min(2000, math.ceil(seg.length / step) + 1))
            t = np.linspace(0.0, 1.0, n)[:, None]
            pts = ends[0] + t * (ends[1] - ends[0])
            for poly in _frame_polylines(camera, surface, pts):
                result["frame"].append({"label": label, "points": poly})
            col, row = ortho.map_to_pixel(ends[:, 0], ends[:, 1])
            result["ortho"].append({"label": label, "points": np.round(np.column_stack([col, row]), 3).tolist()})
    return result
