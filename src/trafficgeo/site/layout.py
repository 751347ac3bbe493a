"""The road layout a user draws - lane polygons, lane boundaries, counting lines - read into the camera's CRS.

Two ways to give it:

* **World coordinates**: a GIS file (GeoPackage, GeoJSON, GeoParquet, ...; e.g. drawn in QGIS over the
  orthophoto). Its features are reprojected to the camera's CRS (GeoJSON is lon/lat by definition); a file
  without a CRS is taken to be in the camera's CRS.
* **Image coordinates**: a CSV with columns ``line, u, v`` - the vertices of each polyline in drawing order, in
  pixels (OpenCV pixel-centre convention) - mapped to the road through the camera and the surface. An optional
  ``name`` column (or the ``line`` value) names each line.

Attribute columns of a GIS file pass through (``lane``, ``name``, ``lanes``, ...).
"""

from __future__ import annotations

from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pyproj
import shapely

from trafficgeo.camera.model import Camera
from trafficgeo.crs import crs_label
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs, pixels_to_world

IMAGE_LINES_HINT = "give a CSV with columns line,u,v (the vertices of each line in pixels, in drawing order)"


def read_layout(path: str | Path, what: str, *, crs: pyproj.CRS | None, camera: Camera | None = None,
                surface: Surface | None = None) -> gpd.GeoDataFrame:
    """Features of a GIS file, or image polylines from a CSV, as a GeoDataFrame in ``crs`` (the camera's).

    ``what`` names the input in messages (e.g. ``"--lanes"``). ``camera`` and ``surface`` are needed for image
    CSVs only.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{what} {p}: file not found; give a GIS file (.gpkg, .geojson, .parquet) or a CSV of "
                         "image lines", parameters=(what,))
    if p.suffix.lower() == ".csv":
        if camera is None or surface is None:
            raise InputError(f"{what} {p}: lines drawn in the image need the camera and a surface; give the lines "
                             "in world coordinates (a GIS file)", parameters=(what,))
        return image_lines_to_world(p, camera, surface, what)
    from trafficgeo.io.gis import read_gis

    gdf = read_gis(p)
    if gdf.crs is not None and crs is not None:
        try:
            gdf = gdf.to_crs(crs)
        except Exception as exc:  # pyproj raises several types for impossible transforms
            raise InputError(f"{what} {p}: cannot reproject from {crs_label(gdf.crs)} to the camera's "
                             f"{crs_label(crs)} ({' '.join(str(exc).split())})", parameters=(what,)) from None
    gdf = gdf[~(gdf.geometry.isna() | gdf.geometry.is_empty)].reset_index(drop=True)
    if gdf.empty:
        raise InputError(f"{what} {p}: no features with a geometry; draw at least one", parameters=(what,))
    return gdf


def image_lines_to_world(path: Path, camera: Camera, surface: Surface, what: str) -> gpd.GeoDataFrame:
    """Polylines drawn in the image (CSV ``line, u, v``) mapped to the surface; one LineString per line."""
    try:
        df = pd.read_csv(path, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{what} {path}: not a readable CSV ({' '.join(str(exc).split())}); "
                         f"{IMAGE_LINES_HINT}", parameters=(what,)) from None
    df.columns = [str(c).strip().lower() for c in df.columns]
    missing = [c for c in ("line", "u", "v") if c not in df.columns]
    if missing or df.empty:
        raise InputError(f"{what} {path}: missing column(s) {', '.join(missing) or '(no rows)'}; {IMAGE_LINES_HINT}",
                         parameters=(what,))
    uv = df[["u", "v"]].apply(pd.to_numeric, errors="coerce").to_numpy(dtype=np.float64)
    bad = ~np.all(np.isfinite(uv), axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise InputError(f"{what} {path}: row {row + 2}: u,v must be numbers (pixels); {IMAGE_LINES_HINT}",
                         parameters=(what,))
    ground = pixels_to_world(camera, uv, surface, with_lonlat=False)
    if not ground.ok.all():
        row = int(np.flatnonzero(~ground.ok)[0])
        raise InputError(f"{what} {path}: row {row + 2}: pixel ({uv[row, 0]:g}, {uv[row, 1]:g}) does not map to the "
                         f"road ({ground.status[row]}); move the vertex onto the road surface", parameters=(what,))
    keys = df["line"].astype(str).str.strip().to_numpy()
    names, geoms = [], []
    for key in pd.unique(keys):
        idx = np.flatnonzero(keys == key)
        if idx.size < 2:
            raise InputError(f"{what} {path}: line {key} has {idx.size} vertex; a line needs at least 2",
                             parameters=(what,))
        names.append(str(df["name"].iloc[idx[0]]) if "name" in df.columns else key)
        geoms.append(shapely.LineString(ground.xyz[idx, :2]))
    return gpd.GeoDataFrame({"name": names, "line": pd.unique(keys)}, geometry=geoms, crs=camera_crs(camera))


def feature_names(gdf: gpd.GeoDataFrame, columns: tuple[str, ...], default_prefix: str = "") -> list[str]:
    """A name for each feature from the first of ``columns`` present (numbers written without ``.0``), else
    ``1, 2, ...`` in file order."""
    for col in columns:
        if col in gdf.columns:
            names = [_as_name(v) for v in gdf[col]]
            if all(names):
                return names
    return [f"{default_prefix}{k + 1}" for k in range(len(gdf))]


def _as_name(value: object) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return ""
    if isinstance(value, float | np.floating) and float(value).is_integer():
        return str(int(value))
    return str(value).strip()
