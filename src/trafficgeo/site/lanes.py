"""Lanes: polygons on the road and the lane of each point (a vehicle's lanes over time:
:mod:`trafficgeo.traffic.lane_changes`).

Lanes come from :func:`trafficgeo.site.layout.read_layout` as either

* **polygons** - one per lane, named by a ``lane``/``name``/``id`` column (else ``1, 2, ...`` in file order), or
* **boundary lines** - the lane lines and road edges, in any order and drawing direction. They are ordered across
  the road; lane ``k`` lies between the k-th and (k+1)-th boundary, numbered ``1, 2, ...`` from the left when
  looking along the first boundary's drawing direction.

A point outside every lane has lane ``""``; where polygons overlap, the first in file order wins.

Polygons may carry a ``bearing`` column: the lane's direction of travel in degrees clockwise from grid north (the
convention of ``heading_deg``). A moving point found in a lane whose bearing is more than 90 deg from its heading
(on a two-way road, a position error of a lane or two puts a vehicle on the other side of the centre line) is
given the nearest lane whose bearing fits, if that lane is within one lane width; otherwise it keeps the lane it
is in (a wrong-way driver stays visible).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj
import shapely
from numpy.typing import ArrayLike

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface
from trafficgeo.site.layout import feature_names, read_layout


@dataclass(frozen=True)
class Lanes:
    """Named lane polygons in the camera's CRS (units of that CRS)."""

    names: tuple[str, ...]
    polygons: tuple[shapely.Polygon, ...]
    bearings: tuple[float, ...] | None = None  # direction of travel, deg clockwise from grid north (NaN: unknown)

    def __post_init__(self) -> None:
        if len(self.names) != len(self.polygons) or not self.names:
            raise ValueError("Lanes needs one name per polygon and at least one lane")
        if len(set(self.names)) != len(self.names):
            raise InputError(f"lane names must be unique; got {', '.join(self.names)}")
        if self.bearings is not None and len(self.bearings) != len(self.names):
            raise ValueError("Lanes needs one bearing per lane (NaN where unknown)")

    def assign(self, x: ArrayLike, y: ArrayLike, heading_deg: ArrayLike = None) -> np.ndarray:
        """The lane name of each point (N,) object array; ``""`` outside every lane or for NaN points.

        With ``heading_deg`` (N,) (deg clockwise from grid north, NaN where not moving) and lane bearings, a point in
        a lane of the opposite direction goes to the nearest lane of its direction within one lane width (see the
        module docstring)."""
        out = self._contains(x, y)
        if heading_deg is None or self.bearings is None:
            return out
        xa = np.asarray(x, dtype=np.float64).reshape(-1)
        ya = np.asarray(y, dtype=np.float64).reshape(-1)
        heading = np.asarray(heading_deg, dtype=np.float64).reshape(-1)
        bearing_of = dict(zip(self.names, self.bearings, strict=True))
        lane_bearing = np.array([bearing_of.get(name, np.nan) for name in out], dtype=np.float64)
        with np.errstate(invalid="ignore"):
            wrong = angle_between(heading, lane_bearing) > 90.0
        rows = np.flatnonzero(wrong)
        if rows.size == 0:
            return out
        best = np.full(rows.size, np.inf)
        pts = shapely.points(xa[rows], ya[rows])
        for name, poly, bearing in zip(self.names, self.polygons, self.bearings, strict=True):
            with np.errstate(invalid="ignore"):
                fits = angle_between(heading[rows], bearing) <= 90.0
            if not fits.any():
                continue
            d = np.where(fits, shapely.distance(poly, pts), np.inf)
            width = 2.0 * poly.area / max(poly.length, 1e-12)  # a long strip's width
            better = (d < best) & (d <= width)
            out[rows[better]] = name
            best[better] = d[better]
        return out

    def _contains(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """The lane containing each point (``""`` outside every lane or for NaN points)."""
        xa = np.asarray(x, dtype=np.float64).reshape(-1)
        ya = np.asarray(y, dtype=np.float64).reshape(-1)
        out = np.full(xa.size, "", dtype=object)
        free = np.isfinite(xa) & np.isfinite(ya)
        for name, poly in zip(self.names, self.polygons, strict=True):
            if not free.any():
                break
            inside = np.zeros(xa.size, dtype=bool)
            inside[free] = shapely.contains_xy(poly, xa[free], ya[free])
            out[inside] = name
            free &= ~inside
        return out


def angle_between(a_deg: ArrayLike, b_deg: ArrayLike) -> np.ndarray:
    """Absolute difference (deg, in [0, 180]) of directions in degrees; NaN where either is NaN."""
    d = np.abs(np.asarray(a_deg, dtype=np.float64) - np.asarray(b_deg, dtype=np.float64)) % 360.0
    return np.minimum(d, 360.0 - d)


def lanes_from_polygons(polygons: list[shapely.Geometry], names: list[str],
                        bearings: list[float] | None = None) -> Lanes:
    """Lanes from (multi)polygons; multipolygons are merged into one lane shape. ``bearings``: each lane's
    direction of travel (deg clockwise from grid north; NaN where unknown), or None."""
    polys = []
    for name, geom in zip(names, polygons, strict=True):
        geom = shapely.make_valid(geom)
        if geom.is_empty or geom.area <= 0:
            raise InputError(f"lane {name}: the polygon has no area; redraw it")
        polys.append(geom)
    return Lanes(tuple(names), tuple(polys), None if bearings is None else tuple(float(b) for b in bearings))


def lanes_from_boundaries(lines: list[shapely.LineString]) -> Lanes:
    """Lanes between consecutive boundary lines ordered across the road (see the module docstring)."""
    if len(lines) < 2:
        raise InputError(f"lane boundaries: got {len(lines)} line; give at least 2 (the two edges of one lane)")
    ref = np.asarray(lines[0].coords, dtype=np.float64)
    direction = ref[-1, :2] - ref[0, :2]
    norm = np.hypot(*direction)
    if norm == 0:
        raise InputError("lane boundaries: the first line has no length; redraw it")
    direction /= norm
    left = np.array([-direction[1], direction[0]])
    oriented, offsets = [], []
    for line in lines:
        xy = np.asarray(line.coords, dtype=np.float64)[:, :2]
        if np.dot(xy[-1] - xy[0], direction) < 0:
            xy = xy[::-1]
        oriented.append(xy)
        offsets.append(float(np.dot(xy.mean(axis=0) - ref[0, :2], left)))
    order = np.argsort(offsets)[::-1]  # leftmost first
    polys = []
    for k in range(len(order) - 1):
        a, b = oriented[order[k]], oriented[order[k + 1]]
        if abs(offsets[order[k]] - offsets[order[k + 1]]) < 1e-9:
            raise InputError("lane boundaries: two lines lie on top of each other; remove one")
        poly = shapely.make_valid(shapely.Polygon(np.vstack([a, b[::-1]])))
        if poly.area <= 0:
            raise InputError(f"lane boundaries: lines {order[k] + 1} and {order[k + 1] + 1} enclose no area")
        polys.append(poly)
    return Lanes(tuple(str(k + 1) for k in range(len(polys))), tuple(polys))


def read_lanes(path: str | Path, *, crs: pyproj.CRS | None, camera: Camera | None = None,
               surface: Surface | None = None) -> Lanes:
    """Lanes from a GIS file of polygons or boundary lines, or a CSV of boundary lines drawn in the image."""
    gdf = read_layout(path, "lanes", crs=crs, camera=camera, surface=surface)
    kinds = set(gdf.geometry.geom_type)
    if kinds <= {"Polygon", "MultiPolygon"}:
        return lanes_from_polygons(list(gdf.geometry), feature_names(gdf, ("lane", "name", "id")),
                                   _bearings(gdf, path))
    if kinds <= {"LineString"}:
        return lanes_from_boundaries(list(gdf.geometry))
    if kinds <= {"LineString", "MultiLineString"}:
        raise InputError(f"lanes {path}: multi-part lines are ambiguous boundaries; draw each boundary as one line",
                         parameters=("lanes",))
    raise InputError(f"lanes {path}: geometries are {', '.join(sorted(kinds))}; give lane polygons or lane "
                     "boundary lines", parameters=("lanes",))


def _bearings(gdf, path: str | Path) -> list[float] | None:
    """The ``bearing`` column (deg clockwise from grid north; empty = unknown), or None without one."""
    cols = {str(c).lower(): c for c in gdf.columns}
    if "bearing" not in cols:
        return None
    values = pd.to_numeric(gdf[cols["bearing"]], errors="coerce").to_numpy(dtype=np.float64)
    raw = gdf[cols["bearing"]]
    bad = np.isnan(values) & raw.notna().to_numpy() & (raw.astype(str).str.strip() != "").to_numpy()
    bad |= np.isinf(values)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"lanes {path}: bearing {raw.iloc[k]!r} of feature {k + 1} is not a number; give each "
                         "lane's direction of travel in degrees clockwise from north (or leave it empty)",
                         parameters=("lanes",))
    return list(values % 360.0)
