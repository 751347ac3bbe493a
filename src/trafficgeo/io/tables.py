"""Point tables in and out: CSV with named coordinate columns (other columns pass through), or a GIS file.

Outputs are written atomically. Coordinates are rounded for readability only where that loses nothing a user could
measure: projected x, y, z to 0.1 mm of the CRS unit, lon/lat to 1e-9 degree, pixels to 1e-4 px.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj

from trafficgeo.errors import InputError
from trafficgeo.io.atomic import write_csv_atomic

TABLE_SUFFIXES = (".csv", ".txt")
_ROUNDING = {"x": 4, "y": 4, "z": 4, "lon": 9, "lat": 9, "u": 4, "v": 4}


def read_point_table(path: str | Path, columns: Sequence[str], what: str, hint: str) -> pd.DataFrame:
    """Read a CSV that must have numeric ``columns`` (other columns are kept as read).

    ``what`` names the table in messages ("pixels"), ``hint`` says what a valid file looks like.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: {what} file not found; {hint}")
    try:
        df = pd.read_csv(p, skipinitialspace=True, comment="#")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not a readable CSV ({' '.join(str(exc).split())}); {hint}") from None
    df.columns = [str(c).strip() for c in df.columns]
    lower = {c.lower(): c for c in df.columns}
    missing = [c for c in columns if c not in lower]
    if missing:
        raise InputError(f"{p}: missing column(s) {', '.join(missing)} (found: {', '.join(df.columns) or 'none'}); "
                         f"{hint}")
    df = df.rename(columns={lower[c]: c for c in columns})
    if df.empty:
        raise InputError(f"{p}: no rows; {hint}")
    for c in columns:
        values = pd.to_numeric(df[c], errors="coerce")
        bad = values.isna() & df[c].notna()
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"{p}: row {row + 2}: column {c} = {df[c].iloc[row]!r} is not a number; {hint}")
        df[c] = values.astype(np.float64)
    return df


def check_table_output(path: str | Path) -> None:
    """Refuse an output name :func:`write_point_table` cannot write (call it before any work)."""
    from trafficgeo.io.gis import GIS_SUFFIXES

    p = Path(path)
    if p.suffix.lower() not in (*TABLE_SUFFIXES, "", *GIS_SUFFIXES):
        raise InputError(f"{p}: unknown output format '{p.suffix}'; use .csv, .gpkg, .geojson or .parquet")


def write_point_table(path: str | Path, table: pd.DataFrame, crs: pyproj.CRS | None, *, layer: str = "points",
                      xyz: tuple[str, str, str] = ("x", "y", "z")) -> None:
    """Write a table as CSV, or as GeoPackage/GeoJSON/GeoParquet points (by suffix) with geometry from ``xyz``.

    Rows without coordinates keep their attributes (empty geometry in GIS formats).
    """
    p = Path(path)
    check_table_output(p)
    suffix = p.suffix.lower()
    out = table.copy()
    for col, digits in _ROUNDING.items():
        if col in out.columns and pd.api.types.is_float_dtype(out[col]):
            out[col] = out[col].round(digits)
    if suffix not in (*TABLE_SUFFIXES, ""):
        from trafficgeo.io.gis import points_layer, write_gis

        if crs is None:
            raise InputError(f"{p}: a GIS file needs a CRS but the data have none; write a .csv instead or "
                             "give the data a CRS (calibrate --crs, or --crs for the cloud/DEM)")
        x, y, z = (out[c].to_numpy(dtype=np.float64) if c in out.columns else None for c in xyz)
        attrs = {c: out[c].to_numpy() for c in out.columns}
        write_gis(p, [points_layer(layer, x, y, z, attributes=attrs, crs=crs, lonlat=False)], crs)
        return
    write_csv_atomic(p, out)
