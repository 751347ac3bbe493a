"""Counting lines: named lines on the road (CRS units), from a GIS file or drawn in the image."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pyproj
import shapely

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface
from trafficgeo.site.layout import feature_names, read_layout


@dataclass(frozen=True)
class CountLine:
    """A named counting line (CRS units); ``lanes`` limits it to those lanes (empty: all)."""

    name: str
    geometry: shapely.LineString
    lanes: tuple[str, ...] = ()


def read_count_lines(path: str | Path, *, crs: pyproj.CRS | None, camera: Camera | None = None,
                     surface: Surface | None = None) -> list[CountLine]:
    """Counting lines from a GIS file of lines or a CSV of lines drawn in the image."""
    gdf = read_layout(path, "lines", crs=crs, camera=camera, surface=surface)
    kinds = set(gdf.geometry.geom_type)
    if not kinds <= {"LineString"}:
        raise InputError(f"lines {path}: geometries are {', '.join(sorted(kinds))}; counting lines must be "
                         "single lines (LineString)", parameters=("lines",))
    names = feature_names(gdf, ("name", "line", "id"))
    if len(set(names)) != len(names):
        raise InputError(f"lines {path}: line names must be unique; got {', '.join(names)}", parameters=("lines",))
    lanes = [tuple(s.strip() for s in str(v).split(",") if s.strip()) if isinstance(v, str) else ()
             for v in (gdf["lanes"] if "lanes" in gdf.columns else [None] * len(gdf))]
    return [CountLine(n, g, ln) for n, g, ln in zip(names, gdf.geometry, lanes, strict=True)]
