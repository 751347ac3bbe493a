"""The dataset a batch writes: one folder of partitioned (Geo)Parquet tables in one CRS, and its summary.

Layout (``camera=`` and ``date=`` are Hive partitions, read back as text columns)::

    DATASET/dataset.json                                   format, crs (WKT and label), trafficgeo version
    DATASET/detections/camera=<id>/<task>.parquet          detect stage: one row per detection box
    DATASET/frames/camera=<id>/<task>.parquet              detect stage: one row per frame read (boxes or not)
    DATASET/vehicles/camera=<id>/date=<YYYY-MM-DD>/part-0.parquet       track stage, GeoParquet
    DATASET/crossings/...  DATASET/counts/...  DATASET/trajectories/...   as vehicles
    DATASET/reports/camera=<id>/date=<YYYY-MM-DD>/report.html          track stage, the camera-day's HTML report

Stage 1 tables are plain Parquet (pixel boxes have no place on the map). ``frames`` holds every frame the
detector saw, so that the tracker of stage 2 advances over frames without a detection exactly as
:func:`trafficgeo.video.pipeline.detect_and_track` did; its Parquet metadata (key ``trafficgeo``) holds the frame
rate, the frame step and whether the video has a variable frame rate.

Stage 2 tables have the columns of the run folder schemas (:data:`trafficgeo.run.schema.SCHEMAS`) with
their times in **seconds since the camera's local midnight** of the partition's date, plus absolute times
(``first_utc``, ``last_utc``, ``time_utc``, ``start_utc``/``end_utc``; timestamp[us, UTC]), ``lon``/``lat``
(EPSG:4326) and a geometry in the dataset CRS: vehicles the smoothed path (LineString; a Point for a vehicle of one
position), crossings the crossing point, counts the counting line, trajectories the smoothed position. ``x``,
``y`` (and ``x_obs``, ``y_obs``) are in the dataset CRS too; ``z`` stays in the camera's vertical unit. Counts
always have ``count_<class>`` for the classes of :data:`~trafficgeo.geo.cuboids.VEHICLE_DIMENSIONS` and
``count_unknown`` (0 where none), so every file of a table has the same columns.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyproj

from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_path, write_json_atomic
from trafficgeo.io.json_text import loads_json

__all__ = ["DATASET_FILE", "FORMAT", "STAGE1_TABLES", "STAGE2_TABLES", "check_dataset", "day_tables",
           "ensure_dataset", "merge_day", "read_table", "summarize_dataset", "table_path", "write_geo_table",
           "write_table"]

FORMAT = "trafficgeo.dataset/1"
DATASET_FILE = "dataset.json"
STAGE1_TABLES = ("detections", "frames")
STAGE2_TABLES = ("vehicles", "crossings", "counts", "trajectories")
META_KEY = b"trafficgeo"


# ------------------------------------------------------------------------------------------------ dataset.json
def _crs_doc(crs: str | pyproj.CRS) -> pyproj.CRS:
    from trafficgeo.crs import parse_crs

    parsed = parse_crs(crs)
    if parsed is None or not parsed.is_projected:
        raise InputError(f"dataset CRS {crs}: give a projected CRS (e.g. EPSG:25832) for the dataset")
    return parsed


def check_dataset(dataset: str | os.PathLike, crs: str | pyproj.CRS) -> dict[str, Any] | None:
    """The ``dataset.json`` of ``dataset`` (None when it has none yet), having checked that it is a dataset of
    this format in ``crs``; :class:`InputError` in one line otherwise. Writes nothing."""
    path = Path(dataset) / DATASET_FILE
    if not path.is_file():
        return None
    try:
        doc = loads_json(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        raise InputError(f"{path}: not readable JSON; give another --out folder or remove it") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(f"{path}: not a {FORMAT} dataset; give another --out folder")
    want = _crs_doc(crs)
    try:
        have = pyproj.CRS.from_user_input(doc.get("crs_wkt") or doc.get("crs"))
    except pyproj.exceptions.CRSError:
        raise InputError(f"{path}: its crs is not readable; give another --out folder") from None
    if not have.equals(want):
        raise InputError(f"{Path(dataset)}: the dataset is in {doc.get('crs')}, the batch in {crs}; give the batch "
                         f"that CRS or write to another --out folder")
    return doc


def ensure_dataset(dataset: str | os.PathLike, crs: str | pyproj.CRS) -> Path:
    """Create ``dataset`` with its ``dataset.json`` (once; checked when it exists, see :func:`check_dataset`)."""
    from trafficgeo.version import __version__

    root = Path(dataset)
    if check_dataset(root, crs) is None:
        parsed = _crs_doc(crs)
        auth = parsed.to_authority(min_confidence=90)
        label = f"{auth[0]}:{auth[1]}" if auth else str(crs)
        root.mkdir(parents=True, exist_ok=True)
        write_json_atomic(root / DATASET_FILE, {"format": FORMAT, "crs": label, "crs_wkt": parsed.to_wkt(),
                                                "trafficgeo": __version__, "tables": [*STAGE1_TABLES,
                                                                                      *STAGE2_TABLES]})
    return root


def table_path(dataset: str | os.PathLike, table: str, camera_id: str, name: str, date: str | None = None) -> Path:
    """Where a part of ``table`` goes: ``DATASET/table/camera=<id>[/date=<day>]/<name>.parquet``."""
    folder = Path(dataset) / table / f"camera={camera_id}"
    if date is not None:
        folder = folder / f"date={date}"
    return folder / f"{name}.parquet"


# ------------------------------------------------------------------------------------------------ writing
def write_table(path: Path, table: pd.DataFrame, metadata: dict[str, Any] | None = None) -> Path:
    """Write a plain Parquet table atomically (``metadata`` as JSON under the schema key ``trafficgeo``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrow = pa.Table.from_pandas(table, preserve_index=False)
    if metadata is not None:
        arrow = arrow.replace_schema_metadata({**(arrow.schema.metadata or {}),
                                               META_KEY: json.dumps(metadata).encode()})
    with atomic_path(path) as tmp:
        pq.write_table(arrow, tmp)
    return path


def table_metadata(path: Path) -> dict[str, Any]:
    """The ``trafficgeo`` metadata :func:`write_table` stored in a Parquet file ({} if none)."""
    import pyarrow.parquet as pq

    meta = pq.read_schema(path).metadata or {}
    return json.loads(meta[META_KEY]) if META_KEY in meta else {}


def write_geo_table(path: Path, table: Any) -> Path:
    """Write a GeoDataFrame as GeoParquet atomically (temporary file in the same folder, then ``os.replace``)."""
    with atomic_path(path) as tmp:
        table.to_parquet(tmp, index=False)
    return path


def transform_to(x: np.ndarray, y: np.ndarray, src: pyproj.CRS | None, dst: pyproj.CRS,
                 where: str) -> tuple[np.ndarray, np.ndarray]:
    """``x, y`` from the camera CRS ``src`` to the dataset CRS ``dst`` (unchanged when they are equal)."""
    from trafficgeo.crs import transform_xy

    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if src is None:
        raise InputError(f"{where}: the camera has no CRS, so its positions cannot go into the dataset; calibrate it "
                         "in a projected CRS")
    if src.equals(dst):
        return x, y
    return transform_xy(x, y, src, dst)


def lonlat(x: np.ndarray, y: np.ndarray, crs: pyproj.CRS) -> tuple[np.ndarray, np.ndarray]:
    """lon, lat (EPSG:4326, degrees) of points in the projected ``crs`` (NaN where x or y is NaN)."""
    from trafficgeo.crs import projected_to_lonlat

    return projected_to_lonlat(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64), crs)


# ------------------------------------------------------------------------------------------------ reading
def read_table(dataset: str | os.PathLike, name: str, camera: str | None = None, date: str | None = None):
    """Table ``name`` of the dataset (all cameras and dates, or those given) as a GeoDataFrame (stage 2 tables)
    or a DataFrame (``detections``, ``frames``), with the partition columns ``camera`` and ``date`` as text.
    Files of a table whose columns differ (a class only some days have) are read with the union of them."""
    import pyarrow as pa
    import pyarrow.dataset as ds

    if name not in (*STAGE1_TABLES, *STAGE2_TABLES):
        raise InputError(f"{name}: not a table of a batch dataset; one of {', '.join(STAGE1_TABLES + STAGE2_TABLES)}")
    root = Path(dataset) / name
    keys = [("camera", pa.string())] + ([("date", pa.string())] if name in STAGE2_TABLES else [])
    partitioning = ds.partitioning(pa.schema(keys), flavor="hive")
    files = sorted(p for p in root.rglob("*.parquet") if not p.name.startswith(".")) if root.is_dir() else []
    if camera is not None:
        files = [p for p in files if f"camera={camera}" in p.relative_to(root).parts]
    if date is not None:
        files = [p for p in files if f"date={date}" in p.relative_to(root).parts]
    if not files:
        raise InputError(f"{root}: no {name} table{' for camera ' + camera if camera else ''}"
                         f"{' on ' + date if date else ''}; run the batch first")
    import pyarrow.parquet as pq

    schemas = [pq.read_schema(p) for p in files]
    schema = pa.unify_schemas([s.remove_metadata() for s in schemas])
    schema = pa.schema([*schema, *[pa.field(k, t) for k, t in keys]], metadata=schemas[0].metadata)
    data = ds.dataset([str(p) for p in files], schema=schema, partitioning=partitioning,
                      partition_base_dir=str(root), format="parquet")
    arrow = data.to_table()
    if name in STAGE1_TABLES:
        return arrow.to_pandas()
    import geopandas as gpd

    return gpd.GeoDataFrame.from_arrow(arrow) if "geometry" in arrow.column_names else arrow.to_pandas()


# ------------------------------------------------------------------------------------------------ summary
def summarize_dataset(dataset: str | os.PathLike, output_gpkg: str | os.PathLike) -> Path:
    """A GeoPackage of the dataset (written atomically): layer ``counts`` (per camera, line, lane, direction and
    interval: ``start_utc``, ``end_utc``, ``count`` and ``count_<class>``, summed over the rows of that interval;
    geometry the counting line) and layer ``cameras`` (camera position points: ``camera_id``, ``days`` (camera-days
    tracked, empty ones too), ``vehicles``), in the dataset CRS."""
    import geopandas as gpd
    import shapely

    root = Path(dataset)
    if not (root / DATASET_FILE).is_file():
        raise InputError(f"{root}: not a batch dataset (no {DATASET_FILE}); give the --out folder of 'batch run'")
    out = Path(output_gpkg)
    if out.suffix.lower() != ".gpkg":
        raise InputError(f"{out}: write the summary as .gpkg", parameters=("output_gpkg",))
    doc = loads_json((root / DATASET_FILE).read_text(encoding="utf-8"))
    crs = pyproj.CRS.from_user_input(doc.get("crs_wkt") or doc["crs"])
    counts = read_table(root, "counts")
    keys = ["camera", "line", "lane", "direction", "start_utc", "end_utc"]
    class_cols = sorted(c for c in counts.columns if c.startswith("count_"))
    geometry = counts.groupby(["camera", "line"], sort=False)["geometry"].first()
    table = counts.drop(columns="geometry").groupby(keys, as_index=False, sort=True)[["count", *class_cols]].sum()
    table["geometry"] = [geometry[(c, ln)] for c, ln in zip(table["camera"], table["line"], strict=True)]
    for c in ("start_utc", "end_utc"):
        table[c] = table[c].dt.strftime("%Y-%m-%dT%H:%M:%S.%fZ").str.replace(".000000Z", "Z", regex=False)
    layer_counts = gpd.GeoDataFrame(table, geometry="geometry", crs=crs)
    vehicles = read_table(root, "vehicles")
    per_camera = vehicles.groupby("camera").size()
    cams = []
    for folder in sorted((root / "vehicles").glob("camera=*")):
        cam = folder.name.split("=", 1)[1]
        pos = _camera_position(root, cam)
        cams.append({"camera_id": cam, "days": len(list(folder.glob("date=*"))),
                     "vehicles": int(per_camera.get(cam, 0)),
                     "geometry": shapely.Point(pos) if pos is not None else None})
    layer_cams = gpd.GeoDataFrame(pd.DataFrame(cams, columns=["camera_id", "days", "vehicles", "geometry"]),
                                  geometry="geometry", crs=crs)
    with atomic_path(out) as tmp:
        layer_counts.to_file(tmp, layer="counts", driver="GPKG")
        layer_cams.to_file(tmp, layer="cameras", driver="GPKG", mode="a")
    return out


def _camera_position(root: Path, camera_id: str) -> tuple[float, float] | None:
    """The camera position (dataset CRS) its track tasks recorded in their ``_SUCCESS.json``."""
    for p in sorted((root / "_tasks").glob("*/_SUCCESS.json")):
        try:
            doc = loads_json(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            continue
        if doc.get("camera_id") == camera_id and doc.get("camera_position") is not None:
            return float(doc["camera_position"][0]), float(doc["camera_position"][1])
    return None


# ------------------------------------------------------------------------------------------------ day tables
def camera_position(camera: Any, crs: str, camera_id: str) -> list[float]:
    """The camera's ground position (x, y) in the dataset CRS."""
    dst = _crs_doc(crs)
    x, y = transform_to(camera.position[:1], camera.position[1:2], camera.crs, dst, f"camera {camera_id}")
    return [float(x[0]), float(y[0])]


def _conform(table: pd.DataFrame, schema_name: str) -> pd.DataFrame:
    """``table`` with every column of the run folder schema (missing ones empty), in its dtypes."""
    from trafficgeo.run.schema import SCHEMAS

    schema = SCHEMAS[schema_name]
    out = {}
    family = [c for c in table.columns if c not in schema.names and schema._known(c)]
    for name in [*schema.names, *family]:
        kind = schema.column(name).dtype
        col = table[name] if name in table.columns else pd.Series([None] * len(table), index=table.index)
        if kind == "str":
            out[name] = col.fillna("").astype(str).astype(object)
        elif kind == "int":
            out[name] = pd.to_numeric(col).astype("Int64")
        elif kind == "bool":
            out[name] = col.astype("boolean")
        else:
            out[name] = pd.to_numeric(col).astype("float64")
    return pd.DataFrame(out, index=table.index).reset_index(drop=True)


def _class_counts(counts: pd.DataFrame) -> pd.DataFrame:
    """``count_<class>`` for every class of ``VEHICLE_DIMENSIONS`` and ``unknown`` (0 where none; all vehicles
    ``unknown`` when the analysis gave no class columns), extra classes kept."""
    from trafficgeo.geo.cuboids import VEHICLE_DIMENSIONS

    have = [c for c in counts.columns if c.startswith("count_")]
    out = counts.copy()
    for c in [*VEHICLE_DIMENSIONS, "unknown"]:
        name = f"count_{c}"
        if name not in out.columns:
            out[name] = out["count"] if (c == "unknown" and not have) else 0
    return out


def _times_utc(midnight: Any, seconds: pd.Series) -> pd.Series:
    micro = np.round(pd.to_numeric(seconds).to_numpy(dtype=np.float64) * 1e6)
    ok = np.isfinite(micro)
    values = pd.Timestamp(midnight).as_unit("us") + pd.to_timedelta(np.where(ok, micro, 0).astype(np.int64),
                                                                     unit="us")
    out = pd.Series(values, dtype="datetime64[us, UTC]")
    out[~ok] = pd.NaT
    return out


def _on_day_clock(table: pd.DataFrame, file: str, shift_s: float) -> pd.DataFrame:
    """A copy of ``table`` (of the run folder table ``file``) with every column that is a moment on the run's
    clock (:attr:`~trafficgeo.run.folder.TableSchema.clock_columns`) moved by ``shift_s`` seconds."""
    from trafficgeo.run.schema import SCHEMAS

    out = table.copy()
    for name in SCHEMAS[file].clock_columns:
        if name in out.columns:
            out[name] = pd.to_numeric(out[name]) + shift_s
    return out


def merge_day(results: list, midnight: Any, lanes: Any = None, lines: list | None = None) -> Any:
    """One :class:`~trafficgeo.traffic.analyze.TrafficResult` of a camera-day from the analyses of its segments
    (``(TrafficResult, origin, tracks)``, times in seconds from ``origin``): times in **seconds since local
    ``midnight``**, positions in the camera's CRS, trajectory ``frame`` the frame in its video file, every table
    with the columns of its run folder schema and counts with ``count_<class>`` for every class."""
    from trafficgeo.traffic.analyze import TrafficResult

    parts: dict[str, list[pd.DataFrame]] = {n: [] for n in STAGE2_TABLES}
    period = [np.inf, -np.inf]
    dropped: dict[str, int] = {}
    warnings: list[str] = []
    options: dict[str, object] = {}
    for result, origin, tracks in results:
        shift = (origin - midnight).total_seconds()
        veh = _on_day_clock(result.vehicles, "vehicles.csv", shift)
        cross = _on_day_clock(result.crossings, "crossings.csv", shift)
        counts = _on_day_clock(_class_counts(result.counts), "counts.csv", shift)
        pts = _on_day_clock(result.points, "trajectories.csv", shift)
        frame_of = dict(zip(tracks["frame"].to_numpy(), tracks["file_frame"].to_numpy(), strict=False))
        pts["frame"] = pts["frame"].map(frame_of).astype("Int64")
        for name, table in zip(STAGE2_TABLES, (veh, cross, counts, pts), strict=True):
            parts[name].append(table)
        period = [min(period[0], result.period[0] + shift), max(period[1], result.period[1] + shift)]
        for reason, n in result.dropped.items():
            dropped[reason] = dropped.get(reason, 0) + int(n)
        warnings += [w for w in result.warnings if w not in warnings]
        options = options or dict(result.options)
    schema_of = {"vehicles": "vehicles.csv", "crossings": "crossings.csv", "counts": "counts.csv",
                 "trajectories": "trajectories.csv"}
    tables = {}
    for name in STAGE2_TABLES:
        merged = pd.concat(parts[name], ignore_index=True) if parts[name] else pd.DataFrame()
        if name == "counts" and not parts[name]:
            merged = _class_counts(pd.DataFrame({"count": pd.Series(dtype="Int64")}))
        tables[name] = _conform(merged, schema_of[name])
    if not results:
        period = [0.0, 0.0]
    return TrafficResult(points=tables["trajectories"], vehicles=tables["vehicles"], crossings=tables["crossings"],
                         counts=tables["counts"], period=(float(period[0]), float(period[1])), dropped=dropped,
                         lanes=lanes, lines=list(lines or []), options=options, warnings=warnings)


def day_tables(day: Any, camera: Any, crs: str, midnight: Any, camera_id: str) -> dict:
    """The four GeoDataFrames of a camera-day from its merged analysis (:func:`merge_day`): positions to the
    dataset CRS, UTC times, lon/lat and geometry (see the module docstring); ``day`` is not changed."""
    import geopandas as gpd
    import shapely

    dst = _crs_doc(crs)
    where = f"camera {camera_id}"
    tables = {"vehicles": day.vehicles.copy(), "crossings": day.crossings.copy(), "counts": day.counts.copy(),
              "trajectories": day.points.copy()}
    lines = day.lines
    out = {}
    # trajectories: smoothed points
    pts = tables["trajectories"]
    for xc, yc in (("x", "y"), ("x_obs", "y_obs")):
        pts[xc], pts[yc] = transform_to(pts[xc].to_numpy(), pts[yc].to_numpy(), camera.crs, dst, where)
    pts["lon"], pts["lat"] = lonlat(pts["x"], pts["y"], dst) if len(pts) else (pts["x"], pts["y"])
    pts["time_utc"] = _times_utc(midnight, pts["time"])
    out["trajectories"] = gpd.GeoDataFrame(pts, geometry=_points(pts), crs=dst)
    # vehicles: the smoothed path
    veh = tables["vehicles"]
    ok = np.isfinite(pts["x"].to_numpy()) & np.isfinite(pts["y"].to_numpy())
    paths = {tid: g[["x", "y"]].to_numpy() for tid, g in pts[ok].groupby("track_id", sort=False)}
    geoms = []
    for tid in veh["track_id"]:
        xy = paths.get(tid)
        geoms.append(None if xy is None else shapely.Point(xy[0]) if len(xy) == 1 else shapely.LineString(xy))
    starts = np.array([paths[t][0] if t in paths else (np.nan, np.nan) for t in veh["track_id"]]).reshape(-1, 2)
    veh["lon"], veh["lat"] = lonlat(starts[:, 0], starts[:, 1], dst) if len(veh) else (veh["lane"], veh["lane"])
    veh["first_utc"], veh["last_utc"] = _times_utc(midnight, veh["first_time"]), _times_utc(midnight,
                                                                                             veh["last_time"])
    out["vehicles"] = gpd.GeoDataFrame(veh, geometry=geoms, crs=dst)
    # crossings: the crossing point
    cross = tables["crossings"]
    cross["x"], cross["y"] = transform_to(cross["x"].to_numpy(), cross["y"].to_numpy(), camera.crs, dst, where)
    cross["lon"], cross["lat"] = lonlat(cross["x"], cross["y"], dst) if len(cross) else (cross["x"], cross["y"])
    cross["time_utc"] = _times_utc(midnight, cross["time"])
    out["crossings"] = gpd.GeoDataFrame(cross, geometry=_points(cross), crs=dst)
    # counts: the counting line
    counts = tables["counts"]
    line_geom = {ln.name: _to_crs(ln.geometry, camera.crs, dst, where) for ln in lines}
    geoms = [line_geom.get(n) for n in counts["line"]]
    mid = np.array([shapely.get_coordinates(shapely.line_interpolate_point(g, 0.5, normalized=True))[0]
                    if g is not None else (np.nan, np.nan) for g in geoms]).reshape(-1, 2)
    counts["lon"], counts["lat"] = lonlat(mid[:, 0], mid[:, 1], dst) if len(counts) else (counts["count"],) * 2
    counts["start_utc"] = _times_utc(midnight, counts["interval_start"])
    counts["end_utc"] = _times_utc(midnight, counts["interval_end"])
    out["counts"] = gpd.GeoDataFrame(counts, geometry=geoms, crs=dst)
    for table in out.values():
        for c in ("lon", "lat"):
            table[c] = pd.to_numeric(table[c]).astype("float64")
    return out


def _points(table: pd.DataFrame):
    import geopandas as gpd

    return gpd.points_from_xy(table["x"].to_numpy(dtype=np.float64), table["y"].to_numpy(dtype=np.float64))


def _to_crs(geometry: Any, src: pyproj.CRS | None, dst: pyproj.CRS, where: str):
    import shapely

    def move(xy: np.ndarray) -> np.ndarray:
        x, y = transform_to(xy[:, 0], xy[:, 1], src, dst, where)
        return np.column_stack([x, y])

    return shapely.transform(geometry, move)


def write_day_tables(dataset: str | os.PathLike, camera_id: str, day: str, tables: dict) -> list[Path]:
    """Write the four tables of a camera-day (``part-0.parquet`` in their partitions); returns the paths."""
    return [write_geo_table(table_path(dataset, name, camera_id, "part-0", date=day), tables[name])
            for name in STAGE2_TABLES]
