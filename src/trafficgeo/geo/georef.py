"""Table-level jobs behind ``georef``, ``project`` and ``gcp-z``: pixels -> world, world -> pixels, GCP heights.

Input tables are pandas DataFrames whose other columns pass through unchanged. Coordinates are in the camera's CRS
units; distances and height differences the user reads are also given in metres (``*_m`` columns).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pyproj
from numpy.typing import ArrayLike

from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs, lonlat_of, pixels_to_world, world_to_pixels
from trafficgeo.geo.surface import DEFAULT_MIN_INCIDENCE_DEG


def _make_room(table: pd.DataFrame, names: tuple[str, ...]) -> pd.DataFrame:
    """The table with input columns that the output adds renamed ``<name>_in`` (e.g. a round trip's old u, v)."""
    clash = {c: f"{c}_in" for c in names if c in table.columns}
    return table.rename(columns=clash) if clash else table


def georeference_table(camera: Camera, table: pd.DataFrame, surface: Surface, *, height: float = 0.0,
                       min_incidence_deg: float = DEFAULT_MIN_INCIDENCE_DEG) -> pd.DataFrame:
    """Add ``x, y, z`` (camera CRS), ``lon, lat`` (when the CRS is known), ``distance_m``, ``incidence_deg`` and
    ``status`` to a table with pixel columns ``u, v``. Input columns with those names are kept as ``<name>_in``."""
    uv = table[["u", "v"]].to_numpy(dtype=np.float64)
    g = pixels_to_world(camera, uv, surface, height=height, min_incidence_deg=min_incidence_deg)
    out = _make_room(table, ("x", "y", "z", "lon", "lat", "status", "distance_m", "incidence_deg")).copy()
    out["x"], out["y"], out["z"] = g.xyz[:, 0], g.xyz[:, 1], g.xyz[:, 2]
    if g.lon is not None:
        out["lon"], out["lat"] = g.lon, g.lat
    out["distance_m"] = g.distance_m
    out["incidence_deg"] = g.incidence_deg
    out["status"] = g.status
    return out


def project_table(camera: Camera, table: pd.DataFrame, surface: Surface | None = None) -> pd.DataFrame:
    """Add pixel ``u, v``, ``depth_m`` (along the optical axis) and ``status`` to a table with ``x, y, z``.

    With a surface, points hidden behind it get status ``occluded``. Input columns with the added names are kept as
    ``<name>_in``.
    """
    xyz = table[["x", "y", "z"]].to_numpy(dtype=np.float64)
    img = world_to_pixels(camera, xyz, surface)
    crs = camera_crs(camera)
    m = metres_per_unit(crs) if crs is not None else 1.0
    out = _make_room(table, ("u", "v", "status", "depth_m")).copy()
    out["u"], out["v"] = img.uv[:, 0], img.uv[:, 1]
    out["depth_m"] = img.depth * m
    out["status"] = img.status
    return out


@dataclass(frozen=True)
class GroundCheckOptions:
    """Thresholds of :func:`check_gcp_heights` (metres).

    ``radius_m``: neighbourhood for the point-cloud median; ``tolerance_m``: largest accepted |z - ground|;
    ``roughness_m``: largest accepted local spread of the ground (a kerb, a verge, vegetation); ``replace``: replace
    every z by the ground z (otherwise only missing z are filled and given z are checked).
    """

    radius_m: float = 0.5
    tolerance_m: float = 0.3
    roughness_m: float = 0.15
    replace: bool = False


def _dem_lookup(surface: Surface, x: np.ndarray, y: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Ground z at (x, y) and the robust spread of the surface within ``radius`` (CRS units), from a surface."""
    z = surface.elevation(x, y)
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    rings = [(r * np.cos(a), r * np.sin(a)) for r in (radius / 2, radius) for a in ang]
    samples = np.stack([surface.elevation(x + dx, y + dy) for dx, dy in rings] + [z], axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: points outside the DEM
        med = np.nanmedian(samples, axis=1)
        spread = 1.4826 * np.nanmedian(np.abs(samples - med[:, None]), axis=1)
    return z, spread


def check_gcp_heights(table: pd.DataFrame, ground: ArrayLike, crs: pyproj.CRS | None,
                      options: GroundCheckOptions | None = None) -> pd.DataFrame:
    """Fill or check the ``z`` of GCPs against the ground (a :class:`trafficgeo.geo.pointcloud.GroundIndex` or a
    surface with ``elevation``), in the table's CRS units.

    Adds ``z_ground`` (ground z), ``dz_m`` (given z minus ground, metres), ``ground_spread_m`` (local roughness,
    metres), ``ground_points`` (neighbours used; point clouds only) and ``z_check``: ``filled`` (z was missing),
    ``replaced``, ``ok``, ``disagrees`` (|dz| > tolerance: a tree, a vehicle or a typo - or a feature that is not on
    the ground, such as a pole top), ``rough`` (the ground varies more than ``roughness_m`` around the point),
    ``outside`` (no ground data there) or ``empty`` (no ground points within the radius).
    """
    opts = options or GroundCheckOptions()
    m = metres_per_unit(crs) if crs is not None else 1.0
    x = table["x"].to_numpy(dtype=np.float64)
    y = table["y"].to_numpy(dtype=np.float64)
    z_given = np.full(x.shape, np.nan)
    if "z" in table.columns:
        z_num = pd.to_numeric(table["z"], errors="coerce")
        bad = z_num.isna() & table["z"].notna() & (table["z"].astype(str).str.strip() != "")
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"GCP row {row + 2}: z = {table['z'].iloc[row]!r} is not a number; leave it empty to "
                             "fill it from the ground")
        z_given = z_num.to_numpy(dtype=np.float64)
    n = x.size
    count = np.full(n, -1)
    if hasattr(ground, "lookup"):
        res = ground.lookup(x, y, radius_m=opts.radius_m)  # type: ignore[attr-defined]
        z_ground, spread, count = res.z, res.spread, res.count
        outside = ~res.inside
    else:
        z_ground, spread = _dem_lookup(ground, x, y, opts.radius_m / m)  # type: ignore[arg-type]
        outside = ~np.isfinite(z_ground)
    dz_m = (z_given - z_ground) * m
    spread_m = spread * m
    check = np.full(n, "ok", dtype=object)
    check[np.abs(dz_m) > opts.tolerance_m] = "disagrees"
    check[(check == "ok") & (spread_m > opts.roughness_m)] = "rough"
    missing = ~np.isfinite(z_given)
    z_out = z_given.copy()
    fill = missing | opts.replace
    z_out[fill] = z_ground[fill]
    check[missing] = "filled"
    check[~missing & opts.replace] = np.where(check[~missing & opts.replace] == "ok", "replaced",
                                              check[~missing & opts.replace])
    check[missing & (spread_m > opts.roughness_m)] = "rough"
    empty = ~np.isfinite(z_ground)
    check[empty] = "empty"
    check[outside] = "outside"
    out = table.copy()
    out["z"] = z_out
    out["z_ground"] = z_ground
    out["dz_m"] = dz_m
    out["ground_spread_m"] = spread_m
    if (count >= 0).any():
        out["ground_points"] = count
    out["z_check"] = check
    return out


def lonlat_columns(table: pd.DataFrame, crs: pyproj.CRS | None) -> pd.DataFrame:
    """Add ``lon, lat`` from ``x, y`` when the CRS is projected (no-op otherwise or if they exist)."""
    if crs is None or "lon" in table.columns:
        return table
    lon, lat = lonlat_of(table["x"].to_numpy(dtype=np.float64), table["y"].to_numpy(dtype=np.float64), crs)
    if lon is None:
        return table
    out = table.copy()
    out["lon"], out["lat"] = lon, lat
    return out
