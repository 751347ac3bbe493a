"""Georeferenced vector output that QGIS opens directly: GeoPackage, GeoJSON (RFC 7946) and GeoParquet.

A :class:`Layer` is a named table of shapely geometries plus attribute columns. Geometries are in the *projected*
CRS of the data (X east, Y north[, Z up], in the CRS's own unit, e.g. international feet for EPSG:2994).
:func:`write_gis` picks the format from the file suffix:

* ``.gpkg``: GeoPackage, one table per layer, in the projected CRS as given (units unchanged).
* ``.geojson`` / ``.json``: one RFC 7946 FeatureCollection in WGS 84 longitude/latitude (degrees, lon first,
  8 decimals, about 1 mm) holding the features of every layer, each with a ``"layer"`` property naming its layer.
  Z is kept and converted to metres, the unit RFC 7946 prescribes (it stays a height in the vertical datum of the
  data: no vertical datum shift is applied).
* ``.parquet``: GeoParquet (needs pyarrow), one layer, in the projected CRS.

Every write is atomic (:func:`trafficgeo.io.atomic.atomic_path`): an existing target is replaced as a whole, never
appended to, and a failed write leaves it untouched. NaN (and infinite) attribute values are written as null.
Empty geometries (e.g. points of unknown position) are written as null geometries.
"""

from __future__ import annotations

import contextlib
import json
import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import pyogrio
import pyproj
import shapely
from numpy.typing import ArrayLike
from pyogrio.errors import CRSError, DataLayerError, DataSourceError
from shapely.geometry import mapping

from trafficgeo.crs import crs_label, is_geographic, metres_per_unit, parse_crs, projected_to_lonlat
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_path, write_failed, write_text_atomic

__all__ = ["GIS_SUFFIXES", "Layer", "points_layer", "read_gis", "write_gis"]

#: File suffixes :func:`write_gis` understands (lower case).
GIS_SUFFIXES: tuple[str, ...] = (".gpkg", ".geojson", ".json", ".parquet")

#: Attribute names that would clash with a geometry, feature-id or layer column in one of the formats.
_RESERVED_COLUMNS = frozenset({"geometry", "geom", "fid", "layer"})

_LONLAT_DECIMALS = 8  # degrees: 1e-8 degree is about 1.1 mm on the ground
_Z_DECIMALS = 4  # metres
_GEOJSON_TYPES = frozenset(
    {"Point", "MultiPoint", "LineString", "MultiLineString", "Polygon", "MultiPolygon", "GeometryCollection"}
)


def _one_line(text: object, limit: int = 200) -> str:
    """Collapse ``text`` to one line of at most ``limit`` characters (for error messages)."""
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


@dataclass(frozen=True)
class Layer:
    """A named table of geometries and attribute columns, ready to be written by :func:`write_gis`.

    Attributes:
        name: layer (table) name, e.g. ``"points"``, ``"gcps"``, ``"camera"``, ``"footprint"``.
        geometries: shapely geometries (or ``None``) in the projected CRS of the data, x/y (and optional z) in the
            CRS's unit. Empty geometries are written as null geometries.
        attributes: column name -> one value per geometry (numbers, strings, bools; NaN/None mean null).

    Raises:
        InputError: empty name, a non-geometry in ``geometries``, a column whose length differs from the number
            of geometries, or a reserved / duplicate column name.
    """

    name: str
    geometries: Sequence[shapely.Geometry]
    attributes: Mapping[str, Sequence | np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _validate_layer(self)


def _validate_layer(layer: Layer) -> None:
    """Check a layer's name, geometries and attribute columns; raise :class:`InputError` on the first problem."""
    if not isinstance(layer.name, str) or not layer.name.strip():
        raise InputError(f"GIS layer name {layer.name!r} is empty or not text; give each layer a name such as 'points'")
    where = f"GIS layer '{layer.name}'"
    n = len(layer.geometries)
    for i, geom in enumerate(layer.geometries):
        if geom is not None and not isinstance(geom, shapely.Geometry):
            raise InputError(
                f"{where}: geometry {i} is a {type(geom).__name__}, not a shapely geometry; "
                "build geometries with shapely (e.g. shapely.Point(x, y))"
            )
    seen: dict[str, str] = {}
    for column, values in layer.attributes.items():
        if not isinstance(column, str) or not column.strip():
            raise InputError(f"{where}: attribute name {column!r} is empty or not text; name every column")
        if column.lower() in _RESERVED_COLUMNS:
            raise InputError(
                f"{where}: attribute name '{column}' is reserved by GIS formats "
                f"({', '.join(sorted(_RESERVED_COLUMNS))}); rename the column"
            )
        if column.lower() in seen:
            raise InputError(
                f"{where}: attribute names '{seen[column.lower()]}' and '{column}' differ only in case, which "
                "GeoPackage cannot store; rename one of them"
            )
        seen[column.lower()] = column
        if isinstance(values, str | bytes) or np.ndim(values) != 1:
            raise InputError(
                f"{where}: attribute '{column}' is not a 1-D column of values; give a list or 1-D array with one "
                "value per geometry"
            )
        if len(values) != n:
            raise InputError(
                f"{where}: attribute '{column}' has {len(values)} values but the layer has {n} geometries; "
                "give one value per geometry"
            )


def _geometry_array(layer: Layer) -> np.ndarray:
    """The layer's geometries as a 1-D object array, with empty geometries replaced by ``None``."""
    geoms = np.empty(len(layer.geometries), dtype=object)
    geoms[:] = list(layer.geometries)
    geoms[shapely.is_empty(geoms)] = None
    return geoms


def _check_finite_xy(geoms: np.ndarray, where: str, hint: str) -> None:
    """Raise :class:`InputError` when any geometry in ``geoms`` has a non-finite x or y coordinate."""
    coords, index = shapely.get_coordinates(geoms, include_z=False, return_index=True)
    bad = ~np.all(np.isfinite(coords), axis=1)
    if np.any(bad):
        first = int(np.argmax(bad))
        x, y = coords[first]
        raise InputError(f"{where} feature {int(index[first])} has coordinates x={float(x):g}, y={float(y):g}; "
                         f"{hint}")


# ----------------------------------------------------------------------------------------------------------------
# Writing


def write_gis(path: str | Path, layers: Sequence[Layer] | Layer, crs: pyproj.CRS | str | None) -> None:
    """Write ``layers`` (geometries in the projected ``crs``) to a GIS file whose format follows the suffix.

    ``.gpkg`` -> GeoPackage (one table per layer, projected ``crs``); ``.geojson``/``.json`` -> one RFC 7946
    FeatureCollection in lon/lat degrees with a ``"layer"`` property, z in metres; ``.parquet`` -> GeoParquet
    (one layer, needs pyarrow). The write is atomic and replaces any existing file as a whole.

    Raises:
        InputError: unknown suffix, no layers or duplicate layer names, ``crs`` missing or not projected,
            non-finite coordinates, several layers for GeoParquet, or pyarrow missing for GeoParquet.
    """
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix not in GIS_SUFFIXES:
        shown = f"'{target.suffix}'" if target.suffix else "(no suffix)"
        raise InputError(f"{target}: unknown GIS format {shown}; use .gpkg, .geojson or .parquet")
    layer_list = [layers] if isinstance(layers, Layer) else list(layers)
    _check_layers(target, layer_list)
    projected = _require_projected_crs(target, crs)
    for layer in layer_list:
        _check_finite_xy(
            _geometry_array(layer),
            f"{target}: layer '{layer.name}'",
            "every coordinate must be finite; use an empty geometry (as points_layer does) for unknown positions",
        )
    if suffix == ".gpkg":
        _write_gpkg(target, layer_list, projected)
    elif suffix == ".parquet":
        _write_parquet(target, layer_list, projected)
    else:
        write_text_atomic(target, _geojson_text(target, layer_list, projected))


def _check_layers(target: Path, layers: list[Layer]) -> None:
    """At least one :class:`Layer`, with names unique regardless of case."""
    if not layers:
        raise InputError(f"{target}: no layers to write; give at least one Layer")
    seen: dict[str, str] = {}
    for layer in layers:
        if not isinstance(layer, Layer):
            raise InputError(f"{target}: {type(layer).__name__} is not a Layer; wrap geometries in trafficgeo Layer")
        key = layer.name.lower()
        if key in seen:
            raise InputError(
                f"{target}: two layers are named '{seen[key]}' and '{layer.name}' (names must differ regardless of "
                "case); rename one of them"
            )
        seen[key] = layer.name


def _require_projected_crs(target: Path, crs: pyproj.CRS | str | None) -> pyproj.CRS:
    """Parse ``crs`` and insist that it is a projected CRS (the frame every Layer's geometries are in)."""
    parsed = parse_crs(crs)
    if parsed is None or is_geographic(parsed) or parsed.is_geocentric:
        raise InputError(
            f"{target}: GIS output needs the projected CRS of the data but got {crs_label(parsed)}; "
            "give the projected CRS the x, y coordinates are in (e.g. EPSG:32610)"
        )
    return parsed


def _is_missing(value: Any) -> bool:
    """True for None, NaN, NaT and pandas NA (scalars only; text is never missing)."""
    if value is None:
        return True
    return np.ndim(value) == 0 and not isinstance(value, str | bytes) and bool(pd.isna(value))


def _column(values: Sequence | np.ndarray) -> pd.Series:
    """One attribute column with a GIS-friendly dtype.

    Object columns and Python lists (which may hold ``None``) of only bools, only integers or only numbers become
    nullable boolean, nullable Int64 or float64 columns, so missing values are NULL and the rest is not written as
    text; all-missing columns become float64 NaN (NULL). Typed numpy arrays are passed through unchanged.
    """
    series = pd.Series(values) if isinstance(values, np.ndarray) else pd.Series(list(values), dtype=object)
    if series.dtype != object:
        return series
    present = [v for v in series if not _is_missing(v)]
    if not present:
        return pd.Series(np.full(len(series), np.nan))
    if all(isinstance(v, bool | np.bool_) for v in present):
        return pd.Series([None if _is_missing(v) else bool(v) for v in series], dtype="boolean")
    if any(isinstance(v, bool | np.bool_) or not isinstance(v, numbers.Real) for v in present):
        return series
    if all(isinstance(v, numbers.Integral) for v in present):
        return pd.Series([None if _is_missing(v) else int(v) for v in series], dtype="Int64")
    return pd.Series([np.nan if _is_missing(v) else float(v) for v in series], dtype=np.float64)


def _geodataframe(layer: Layer, crs: pyproj.CRS) -> gpd.GeoDataFrame:
    """The layer as a GeoDataFrame in ``crs``; empty geometries become ``None`` (null)."""
    geometry = gpd.GeoSeries(_geometry_array(layer), crs=crs)
    data = {column: _column(values) for column, values in layer.attributes.items()}
    return gpd.GeoDataFrame(data, geometry=geometry, crs=crs)


def _write_gpkg_layer(path: Path, layer: Layer, crs: pyproj.CRS) -> None:
    """Add ``layer`` as a new table to the GeoPackage at ``path`` (created if missing); NaN -> NULL."""
    pyogrio.write_dataframe(
        _geodataframe(layer, crs), path, layer=layer.name, driver="GPKG", nan_as_null=True, use_arrow=False
    )


def _write_gpkg(target: Path, layers: list[Layer], crs: pyproj.CRS) -> None:
    """Write all layers into one fresh temporary GeoPackage, then move it over ``target``."""
    with atomic_path(target) as tmp:
        try:
            tmp.unlink()  # GDAL creates a fresh GeoPackage; never open an existing (empty) file in update mode
            for layer in layers:
                _write_gpkg_layer(tmp, layer, crs)
        except BaseException as exc:
            for sidecar in ("-journal", "-wal", "-shm"):
                with contextlib.suppress(FileNotFoundError):
                    tmp.with_name(tmp.name + sidecar).unlink()
            if isinstance(exc, DataSourceError | DataLayerError) and not isinstance(exc, CRSError):
                # GDAL reports a full or failing disk as e.g. "Failed to commit transaction"
                raise write_failed(target, str(exc)) from exc
            raise


def _write_parquet(target: Path, layers: list[Layer], crs: pyproj.CRS) -> None:
    """Write one layer as GeoParquet (projected ``crs``); NaN -> null."""
    if len(layers) != 1:
        names = ", ".join(f"'{layer.name}'" for layer in layers)
        raise InputError(
            f"{target}: GeoParquet holds one layer but {len(layers)} were given ({names}); "
            "write each layer to its own .parquet file or use .gpkg"
        )
    try:
        import pyarrow  # noqa: F401
    except ImportError as exc:
        raise InputError(
            f"{target}: writing GeoParquet needs pyarrow, which is not installed; pip install pyarrow, or use .gpkg"
        ) from exc
    frame = _geodataframe(layers[0], crs)
    with atomic_path(target) as tmp:
        frame.to_parquet(tmp)


# ----------------------------------------------------------------------------------------------------------------
# GeoJSON (RFC 7946)
# Written here, not by GDAL's GeoJSON driver: that gives every feature every layer's fields, drops the position of
# a 3-D point with NaN z and rounds float attributes (0.1 + 0.2 -> 0.3); see tests/test_io_gis_geojson.py.


def _to_lonlat(geoms: np.ndarray, crs: pyproj.CRS) -> np.ndarray:
    """Transform projected geometries to (lon, lat) degrees; z from CRS units to metres. ``None`` stays ``None``."""
    z_scale = metres_per_unit(crs)

    def transform(coords: np.ndarray) -> np.ndarray:
        out = np.array(coords, dtype=np.float64)
        out[:, 0], out[:, 1] = projected_to_lonlat(coords[:, 0], coords[:, 1], crs)
        if out.shape[1] == 3:
            out[:, 2] = coords[:, 2] * z_scale
        return out

    has_z = shapely.has_z(geoms)
    result = geoms.copy()
    if np.any(has_z):
        result[has_z] = shapely.transform(geoms[has_z], transform, include_z=True)
    if np.any(~has_z):
        result[~has_z] = shapely.transform(geoms[~has_z], transform, include_z=False)
    return result


def _orient_ccw(geoms: np.ndarray) -> np.ndarray:
    """Polygons with counter-clockwise exteriors and clockwise holes (the RFC 7946 right-hand rule)."""
    orient_polygons = getattr(shapely, "orient_polygons", None)
    if orient_polygons is not None:  # shapely >= 2.1
        return orient_polygons(geoms, exterior_cw=False)
    from shapely.geometry.polygon import orient

    def fix(geom: shapely.Geometry | None) -> shapely.Geometry | None:
        if isinstance(geom, shapely.Polygon):
            return orient(geom, sign=1.0)
        if isinstance(geom, shapely.MultiPolygon):
            return shapely.MultiPolygon([orient(part, sign=1.0) for part in geom.geoms])
        if isinstance(geom, shapely.GeometryCollection):
            return shapely.GeometryCollection([fix(part) for part in geom.geoms])
        return geom

    out = np.empty(len(geoms), dtype=object)
    out[:] = [fix(geom) for geom in geoms]
    return out


def _position(coords: Sequence[float]) -> list[float]:
    """One GeoJSON position: lon, lat rounded to 8 decimals, z (metres) kept only when finite."""
    position = [round(float(coords[0]), _LONLAT_DECIMALS), round(float(coords[1]), _LONLAT_DECIMALS)]
    if len(coords) > 2 and math.isfinite(coords[2]):
        position.append(round(float(coords[2]), _Z_DECIMALS))
    return position


def _positions(coords: Any) -> Any:
    """Round a (nested) GeoJSON coordinates array."""
    if len(coords) and isinstance(coords[0], numbers.Real):
        return _position(coords)
    return [_positions(part) for part in coords]


def _geojson_geometry(geom: shapely.Geometry | None) -> dict[str, Any] | None:
    """RFC 7946 geometry object of a lon/lat geometry (``None`` -> null)."""
    if geom is None:
        return None
    if isinstance(geom, shapely.LinearRing):
        geom = shapely.LineString(geom)
    if geom.geom_type == "GeometryCollection":
        return {"type": "GeometryCollection", "geometries": [_geojson_geometry(part) for part in geom.geoms]}
    if geom.geom_type not in _GEOJSON_TYPES:
        raise InputError(f"{geom.geom_type} geometries cannot be written to GeoJSON; convert them or use .gpkg")
    return {"type": geom.geom_type, "coordinates": _positions(mapping(geom)["coordinates"])}


def _json_value(value: Any) -> Any:
    """A JSON-safe scalar: NaN/inf/None/NA -> None, numpy scalars -> Python, other objects -> ISO text or str."""
    if _is_missing(value):
        return None
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        number = float(value)
        return number if math.isfinite(number) else None
    if isinstance(value, str):
        return str(value)
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    isoformat = getattr(value, "isoformat", None)
    return isoformat() if callable(isoformat) else str(value)


def _geojson_text(target: Path, layers: list[Layer], crs: pyproj.CRS) -> str:
    """The RFC 7946 FeatureCollection text (UTF-8, compact) of all layers, one ``"layer"`` property per feature."""
    features: list[dict[str, Any]] = []
    for layer in layers:
        lonlat = _to_lonlat(_geometry_array(layer), crs)
        _check_finite_xy(
            lonlat,
            f"{target}: layer '{layer.name}'",
            f"it cannot be converted from {crs_label(crs)} to longitude/latitude; check the CRS of the data",
        )
        lonlat = _orient_ccw(lonlat)
        columns = {name: [_json_value(v) for v in values] for name, values in layer.attributes.items()}
        for i, geom in enumerate(lonlat):
            properties: dict[str, Any] = {"layer": layer.name}
            properties.update({name: values[i] for name, values in columns.items()})
            features.append({"type": "Feature", "properties": properties, "geometry": _geojson_geometry(geom)})
    collection = {"type": "FeatureCollection", "features": features}
    return json.dumps(collection, ensure_ascii=False, allow_nan=False, separators=(",", ":")) + "\n"


# ----------------------------------------------------------------------------------------------------------------
# Convenience constructors and reading


def _float_column(values: ArrayLike, what: str, where: str) -> np.ndarray:
    """``values`` as a 1-D float64 array, or :class:`InputError`."""
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {what} must be numbers ({_one_line(exc)}); give numeric coordinates") from exc
    if array.ndim != 1:
        raise InputError(f"{where}: {what} must be a 1-D array of coordinates, got shape {array.shape}")
    return array


def points_layer(
    name: str,
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike | None = None,
    attributes: Mapping[str, Sequence | np.ndarray] | None = None,
    crs: pyproj.CRS | str | None = None,
    lonlat: bool = True,
) -> Layer:
    """A point layer from coordinate arrays in the projected ``crs`` (float64, CRS units; z optional, 3-D points).

    Rows with a non-finite x or y get an empty point (written as a null geometry) but keep their attributes, so
    the layer has one feature per input row. A non-finite z with finite x, y gives a 3-D point with NaN z (GeoJSON
    output then omits its z). When ``lonlat`` and ``crs`` is given, ``"lon"`` and ``"lat"`` columns (WGS 84
    degrees) are added, NaN where x or y is not finite.

    Raises:
        InputError: coordinate arrays of different lengths or not numeric, attribute length mismatch, a ``lon`` /
            ``lat`` attribute clashing with the added columns, or a non-projected ``crs``.
    """
    where = f"GIS layer '{name}'"
    xa = _float_column(x, "x", where)
    ya = _float_column(y, "y", where)
    if xa.shape != ya.shape:
        raise InputError(f"{where}: x has {xa.size} values but y has {ya.size}; give one x and one y per point")
    columns = [xa, ya]
    if z is not None:
        za = np.asarray(z, dtype=np.float64)
        if za.ndim == 0:
            za = np.full(xa.shape, float(za))
        za = _float_column(za, "z", where)
        if za.shape != xa.shape:
            raise InputError(f"{where}: x has {xa.size} values but z has {za.size}; give one z per point")
        columns.append(za)
    finite = np.isfinite(xa) & np.isfinite(ya)
    empty = shapely.from_wkt("POINT Z EMPTY" if z is not None else "POINT EMPTY")
    geoms = np.full(xa.size, empty, dtype=object)
    if np.any(finite):
        geoms[finite] = shapely.points(np.column_stack(columns)[finite])
    attrs: dict[str, Sequence | np.ndarray] = dict(attributes or {})
    parsed = parse_crs(crs)
    if lonlat and parsed is not None:
        clash = sorted({"lon", "lat"} & set(attrs))
        if clash:
            raise InputError(
                f"{where}: attribute {clash[0]!r} clashes with the lon/lat columns added from the CRS; rename it "
                "or pass lonlat=False"
            )
        attrs["lon"], attrs["lat"] = projected_to_lonlat(xa, ya, parsed)
    return Layer(name=name, geometries=list(geoms), attributes=attrs)


def gis_layers(path: str | Path) -> list[str]:
    """The layer names of a GIS vector file (GeoPackage, GeoJSON, ...).

    Raises:
        InputError: the file is not a vector file GDAL reads (damaged, cut short, another format).
    """
    try:
        return [str(name) for name in pyogrio.list_layers(path)[:, 0]]
    except (DataSourceError, DataLayerError) as exc:
        raise InputError(
            f"{path}: not a GIS vector file GDAL can read ({_one_line(exc)}); give a .gpkg, .geojson or .parquet "
            "file"
        ) from None


def read_gis(path: str | Path, layer: str | None = None) -> gpd.GeoDataFrame:
    """Read one layer of a GIS vector file (GeoPackage, GeoJSON, GeoParquet, ...) as a GeoDataFrame.

    ``layer=None`` reads the first layer. Coordinates and CRS are as stored in the file.

    Raises:
        InputError: the file does not exist or is not a vector file GDAL reads, or ``layer`` is not in it (the
            message lists the layers that are).
    """
    target = Path(path)
    if not target.is_file():
        raise InputError(f"{target}: no such GIS file; check the path")
    if target.suffix.lower() == ".parquet":
        return _read_parquet(target, layer)
    names = gis_layers(target)
    if not names:
        raise InputError(f"{target}: the file has no layers; write it again or give another file")
    if layer is None:
        layer = names[0]
    elif layer not in names:
        raise InputError(f"{target}: no layer '{layer}'; the layers are {', '.join(repr(n) for n in names)}")
    try:
        return gpd.read_file(target, layer=layer)
    except (DataSourceError, DataLayerError, shapely.errors.GEOSException, ValueError) as exc:  # damaged, impossible
        raise InputError(f"{target}: layer '{layer}' cannot be read ({_one_line(exc)}); write the file again from "
                         "your GIS") from None


def _read_parquet(target: Path, layer: str | None) -> gpd.GeoDataFrame:
    """Read a GeoParquet file (one layer, named after the file stem)."""
    if layer is not None and layer != target.stem:
        raise InputError(f"{target}: no layer '{layer}'; a GeoParquet file has one layer, '{target.stem}'")
    try:
        import pyarrow  # noqa: F401
    except ImportError as exc:
        raise InputError(
            f"{target}: reading GeoParquet needs pyarrow, which is not installed; pip install pyarrow"
        ) from exc
    return gpd.read_parquet(target)
