"""A run's output folder, and the one schema of every table trafficgeo writes into it.

``analyze``, ``process`` and ``stitch`` write a run folder; ``compare-sumo``, ``export-fcd``, ``stitch`` (its chunks),
the HTML report and the demo read one. All of them go through :class:`RunFolder` (but ``process``'s detections and
tracks, which the video room writes under the same schemas), and every table's columns, dtypes and units are
defined once here (:data:`SCHEMAS`):

============================  =========================================================================
``vehicles.csv``              one row per vehicle (track): class, times, speed, length, lane (:data:`VEHICLES`)
``crossings.csv``             one row per counting-line crossing (:data:`CROSSINGS`)
``counts.csv``                every line x lane x direction x interval, zeros too: counts, flow, speeds (:data:`COUNTS`)
``trajectories.csv``          one row per vehicle and frame, on the ground (:data:`TRAJECTORIES`)
``trajectories.gpkg/.parquet``the same as GIS layers (paths, points, lanes, count lines) when the camera has a CRS
``summary.json``              totals, the options used and the CRS (WKT) (:class:`~.run_records.RunSummary`)
``detections.csv``            ``process``: every detection box (:data:`DETECTIONS`)
``tracks.csv``                ``process``/``stitch``: the tracker's boxes (:data:`TRACKS`)
``process.json``              ``process``: the video, options, what was read, the detector's tile plan
                              (:class:`~.run_records.ProcessRecord`)
``run.json``                  the manifest (:mod:`trafficgeo.io.run_manifest`): written last, checked by readers
``compare_counts.csv``,       ``compare-sumo``/``sumo-validate``: observed against simulated counts (GEH), spot
``compare_speeds.csv``,       speeds and the simulated crossings (:data:`COMPARE_TABLES`), under the comparison's
``simulated_crossings.csv``   own manifest (``compare_run.json``)
``compare_summary.json``      the comparison's GEH and travel times (:class:`~.run_records.CompareSummary`)
``compare_simulation.json``   ``sumo-validate``: the scenario simulated and the headline figures
                              (:class:`~.run_records.SimulationRecord`); its manifest's command is then
                              ``sumo-validate``
============================  =========================================================================

The JSON files are typed records (:mod:`trafficgeo.traffic.run_records`): :class:`RunFolder` writes them
(:meth:`RunFolder.write_summary`, :meth:`~RunFolder.write_process`, :meth:`~RunFolder.write_comparison`,
:meth:`~RunFolder.write_simulation_record`) and reads them back (:meth:`RunFolder.summary`,
:meth:`~RunFolder.process`, :meth:`~RunFolder.compare_summary`, :meth:`~RunFolder.simulation_record`); the
comparison's tables are read by :meth:`RunFolder.comparison_table`.

Units: times in seconds of video (``time``, ``first_time``... from the video's start), speeds in km/h, lengths and
distances in metres, ``x, y, z`` in the camera's CRS and its units (``"crs"`` below), pixel boxes in full-frame px
(pixel-centre convention, :mod:`trafficgeo.video.detections`), headings in degrees clockwise from grid north. Text
columns read back as ``""`` where empty (an unknown class, no lane), never NaN.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.io.json_text import loads_json
from trafficgeo.io.run_manifest import COMPARE_MANIFEST, RunManifest, verify_outputs
from trafficgeo.traffic.run_records import (
    SIMULATION_RECORD,
    CompareSummary,
    ProcessRecord,
    RunSummary,
    SimulationRecord,
)

if TYPE_CHECKING:
    from trafficgeo.camera.calibrated import CalibratedCamera
    from trafficgeo.camera.model import Camera
    from trafficgeo.site.gates import Junction
    from trafficgeo.traffic.analyze import TrafficResult

__all__ = ["COMPARE_TABLES", "COUNTS", "CROSSINGS", "DETECTIONS", "SCHEMAS", "TRACKS", "TRAJECTORIES", "VEHICLES",
           "Column", "RunFolder", "TableSchema"]


@dataclass(frozen=True)
class Column:
    """One column: ``dtype`` one of ``"str"``, ``"int"``, ``"float"``, ``"bool"``; ``unit`` as in the module
    docstring (``""`` for none); ``added``: when a column joined a table that run folders already held (e.g.
    ``"2026-12-04"``, the day it joined): a file written before it still reads, with the column empty (NaN);
    ``clock``: the column is a moment on the run's clock (seconds from the video's start; a batch day's tables
    move every such column to seconds since local midnight), not a duration."""

    name: str
    dtype: str
    unit: str = ""
    description: str = ""
    added: str = ""
    clock: bool = False  # a moment on the run's clock (s), moved with it; a duration (``_s``) is not


_PANDAS = {"str": str, "int": "Int64", "float": "float64", "bool": "boolean"}


@dataclass(frozen=True)
class TableSchema:
    """The columns of one output table, in order; ``families`` are column name prefixes with a shared meaning
    (``count_`` + a class name)."""

    file: str
    columns: tuple[Column, ...]
    families: tuple[Column, ...] = ()
    what: str = ""

    @property
    def clock_columns(self) -> tuple[str, ...]:
        """The names of the columns that are moments on the run's clock (:attr:`Column.clock`)."""
        return tuple(c.name for c in self.columns if c.clock)

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.columns]

    def column(self, name: str) -> Column:
        """The column called ``name`` (a family member such as ``count_car`` included); KeyError if none."""
        for c in self.columns:
            if c.name == name:
                return c
        for f in self.families:
            if name.startswith(f.name):
                return Column(name, f.dtype, f.unit, f"{f.description} ({name[len(f.name):]})")
        raise KeyError(f"{self.file} has no column {name!r}")

    def check(self, table: pd.DataFrame) -> None:
        """InputError unless ``table`` has every column of the schema and only schema columns."""
        missing = [n for n in self.names if n not in table.columns]
        extra = [n for n in table.columns if not self._known(n)]
        if missing or extra:
            raise InputError(f"{self.file}: columns {missing} missing and {extra} unknown; the table does not follow "
                             f"the {self.file} schema of trafficgeo.traffic.run_folder")

    def _known(self, name: str) -> bool:
        try:
            self.column(name)
        except KeyError:
            return False
        return True

    def read(self, path: Path, *, required: Iterable[str] | None = None) -> pd.DataFrame:
        """The table at ``path`` with the schema's dtypes (text columns ``""`` where empty); ``required``: the
        columns that must be there (default: all of the schema's but those ``added`` later, which a file written
        before them lacks: they are read as empty)."""
        try:
            head = pd.read_csv(path, nrows=0)
        except (OSError, UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
            raise InputError(f"{path}: not a readable {self.file} ({type(exc).__name__}); run trafficgeo again to "
                             "write it") from None
        need = [c.name for c in self.columns if not c.added] if required is None else list(required)
        missing = [n for n in need if n not in head.columns]
        if missing:
            raise InputError(f"{path}: no column {', '.join(missing)}; not a {self.file} written by trafficgeo")
        with open(path, "rb") as fh:  # trafficgeo ends every table with a newline: one without was cut short
            size = fh.seek(0, os.SEEK_END)
            last = fh.seek(size - 1) >= 0 and fh.read(1) if size else b"\n"
        if last != b"\n":
            raise InputError(f"{path}: the file ends in the middle of a row (cut short); run trafficgeo again to "
                             "write it")
        text = {c: str for c in head.columns if self._known(c) and self.column(c).dtype == "str"}
        table = pd.read_csv(path, dtype=text, keep_default_na=False, na_values=[""])
        for c in text:
            table[c] = table[c].fillna("")
        for c in table.columns:
            if not self._known(c) or c in text:
                continue
            kind = self.column(c).dtype
            if kind == "bool" and table[c].dtype == object:
                table[c] = table[c].map({"True": True, "False": False, "true": True, "false": False})
                continue
            if kind not in ("int", "float"):
                continue
            values = pd.to_numeric(table[c], errors="coerce")
            bad = (values.isna() & table[c].notna()) | (kind == "int" and ~(values.isna() | (
                np.isfinite(values) & (values == np.round(values)) & (values.abs() < 2**53))))
            if bad.any():
                row = int(np.flatnonzero(bad.to_numpy())[0])
                raise InputError(f"{path} row {row + 2}: column {c} is {str(table[c].iloc[row])[:40]!r}, not "
                                 f"{'an integer' if kind == 'int' else 'a number'}; run trafficgeo again to write it")
            table[c] = values.astype("Int64") if kind == "int" and values.isna().any() else (
                values.astype(np.int64) if kind == "int" else values.astype(np.float64))
        later = [c for c in self.columns if c.added and c.name not in table.columns]
        if later:  # a file written before these columns joined the table: empty, in the schema's place
            for c in later:  # as an empty column of the file would read
                table[c.name] = ("" if c.dtype == "str" else pd.Series(pd.NA, index=table.index, dtype="Int64")
                                 if c.dtype == "int" else float("nan"))
            order = [n for n in self.names if n in table.columns]
            table = table[order + [n for n in table.columns if n not in order]]
        return table


S, KMH, M, CRS_UNITS, PX, DEG = "s", "km/h", "m", "crs", "px", "deg"

VEHICLES = TableSchema("vehicles.csv", (
    Column("track_id", "str", "", "vehicle id (the id of its first piece of track: the tracker's id, with a "
           "suffix where that id was split)"),
    Column("source_track", "str", "", "the tracker's id the vehicle came from"),
    Column("class", "str", "", "vehicle class (car, van, truck, bus, motorcycle, bicycle; '' unknown)"),
    Column("first_time", "float", S, "first time seen", clock=True),
    Column("last_time", "float", S, "last time seen", clock=True),
    Column("duration_s", "float", S, "time seen"),
    Column("points", "int", "", "trajectory points used"),
    Column("outliers", "int", "", "points rejected as outliers"),
    Column("path_length_m", "float", M, "length of the smoothed path"),
    Column("travel_m", "float", M, "distance travelled along the direction of travel over the time seen"),
    Column("speed_kmh", "float", KMH, "distance travelled along the direction of travel / time, over the part of "
           "the time seen where the calibration knows the ground scale best (the middle half without a "
           "calibration's covariance or GCPs)"),
    Column("speed_std_kmh", "float", KMH, "standard uncertainty of speed_kmh (position noise and the calibration's "
           "scale uncertainty)"),
    Column("speed_start_time", "float", S, "start of the window speed_kmh is measured over", added="2026-12-04",
           clock=True),
    Column("speed_end_time", "float", S, "end of the window speed_kmh is measured over", added="2026-12-04",
           clock=True),
    Column("travel_speed_kmh", "float", KMH, "travel_m / duration_s: the former headline speed, over all the time "
           "seen (reads the calibration's scale errors at the edges of the view)", added="2026-12-04"),
    Column("mean_speed_kmh", "float", KMH, "path_length_m / duration_s (reads high under position noise)"),
    Column("median_speed_kmh", "float", KMH, "median of the point speeds"),
    Column("point_speed_std_kmh", "float", KMH, "standard deviation of the point speeds"),
    Column("min_distance_m", "float", M, "nearest horizontal distance to the camera"),
    Column("length_m", "float", M, "vehicle length measured from its boxes (NaN: not measurable)"),
    Column("length_std_m", "float", M, "standard uncertainty of length_m"),
    Column("lane", "str", "", "main lane ('' none)"),
    Column("lanes", "str", "", "lanes in order of visit, '>'-separated"),
    Column("lane_changes", "int", "", "lane changes"),
    Column("fragments", "int", "", "the pieces of track joined into this vehicle (1: seen without a break)",
           added="2026-12-06"),
    Column("tracker_ids", "str", "", "the tracker's ids of those pieces, ';'-separated, in time order",
           added="2026-12-06"),
    Column("stationary", "bool", "", "never moved (a parked vehicle, a billboard): counted at no line and left out of "
           "the speed statistics (its own near-zero speeds kept)", added="2026-12-06"),
), what="one row per vehicle")

CROSSINGS = TableSchema("crossings.csv", (
    Column("line", "str", "", "counting line name"),
    Column("track_id", "str", "", "vehicle id (vehicles.csv)"),
    Column("class", "str", "", "vehicle class"),
    Column("lane", "str", "", "lane at the crossing ('' none)"),
    Column("direction", "int", "", "+1 / -1: side of the line crossed to (left to right of the line's direction: +1)"),
    Column("time", "float", S, "time of the crossing", clock=True),
    Column("speed_kmh", "float", KMH, "speed at the crossing"),
    Column("x", "float", CRS_UNITS, "crossing point x"),
    Column("y", "float", CRS_UNITS, "crossing point y"),
    Column("length_m", "float", M, "vehicle length"),
    Column("hidden", "bool", "", "crossed while hidden behind a nearer vehicle (carried on)"),
), what="one row per crossing of a counting line")

COUNTS = TableSchema("counts.csv", (
    Column("line", "str", "", "counting line name"),
    Column("lane", "str", "", "lane ('' none)"),
    Column("direction", "int", "", "+1 / -1, as in crossings.csv"),
    Column("interval_start", "float", S, "interval start", clock=True),
    Column("interval_end", "float", S, "interval end", clock=True),
    Column("observed_s", "float", S, "seconds of the interval observed (interval_end - interval_start)",
           added="2026-12-04"),
    Column("count", "int", "", "vehicles"),
    Column("flow_veh_h", "float", "veh/h", "count / observed_s; empty when less than half the interval was observed"),
    Column("time_mean_speed_kmh", "float", KMH, "mean speed at the line"),
    Column("space_mean_speed_kmh", "float", KMH, "harmonic mean speed at the line"),
    Column("mean_headway_s", "float", S, "mean time between successive vehicles"),
    Column("min_headway_s", "float", S, "shortest time between successive vehicles"),
    Column("mean_gap_s", "float", S, "mean time from a vehicle's rear to the next one's front"),
), families=(Column("count_", "int", "", "vehicles of a class"),),
    what="per line, lane, direction and interval")

TRAJECTORIES = TableSchema("trajectories.csv", (
    Column("track_id", "str", "", "vehicle id"),
    Column("source_track", "str", "", "the tracker's id"),
    Column("frame", "int", "", "video frame index"),
    Column("time", "float", S, "time", clock=True),
    Column("u", "float", PX, "image point used (bottom centre or the fitted footprint centre)"),
    Column("v", "float", PX, "image point used"),
    Column("x_obs", "float", CRS_UNITS, "ground point of the observation"),
    Column("y_obs", "float", CRS_UNITS, "ground point of the observation"),
    Column("x", "float", CRS_UNITS, "smoothed position"),
    Column("y", "float", CRS_UNITS, "smoothed position"),
    Column("speed_kmh", "float", KMH, "smoothed speed"),
    Column("speed_std_kmh", "float", KMH, "standard uncertainty of speed_kmh"),
    Column("heading_deg", "float", DEG, "direction of travel, clockwise from grid north"),
    Column("accel_mps2", "float", "m/s^2", "acceleration along the path"),
    Column("position_std_m", "float", M, "standard uncertainty of the position"),
    Column("outlier", "bool", "", "observation rejected by the smoother"),
    Column("distance_m", "float", M, "horizontal distance to the camera"),
    Column("class", "str", "", "vehicle class"),
    Column("z", "float", CRS_UNITS, "ground height"),
    Column("lon", "float", DEG, "longitude (EPSG:4326; absent without a projected CRS)"),
    Column("lat", "float", DEG, "latitude (EPSG:4326)"),
    Column("lane", "str", "", "lane ('' none)"),
    Column("length_m", "float", M, "vehicle length"),
    Column("fragment", "str", "", "the piece of track the point belongs to (vehicles.csv tracker_ids)",
           added="2026-12-06"),
), what="one row per vehicle and frame")

MOVEMENTS = TableSchema("movements.csv", (
    Column("track_id", "str", "", "vehicle id (vehicles.csv)"),
    Column("class", "str", "", "vehicle class"),
    Column("origin", "str", "", "the arm it came in by ('' unknown)"),
    Column("destination", "str", "", "the arm it left by ('' unknown)"),
    Column("movement", "str", "", "left, through, right or U from the arms' bearings ('' when an end is unknown)"),
    Column("entry_time", "float", S, "when it crossed its origin's gate inwards (empty: not seen there)",
           clock=True),
    Column("exit_time", "float", S, "when it crossed its destination's gate outwards (empty: not seen there)",
           clock=True),
    Column("travel_time_s", "float", S, "exit_time - entry_time"),
    Column("stopped_s", "float", S, "time at a speed below 5 km/h between entering (else first seen) and leaving "
           "(else last seen)"),
    Column("origin_by", "str", "", "how the origin is known: gate, path (first seen inside the gates, on that "
           "arm's approach, heading in) or '' (unknown)"),
    Column("destination_by", "str", "", "how the destination is known: gate, path or ''"),
    Column("complete", "bool", "", "origin and destination known: counted in movement_counts.csv"),
    Column("track_ids", "str", "", "the vehicles (vehicles.csv) whose tracks make the movement, ';'-separated: two "
           "where a vehicle's track broke inside the junction and its halves were joined"),
), what="one row per vehicle through the junction")

MOVEMENT_COUNTS = TableSchema("movement_counts.csv", (
    Column("interval_start", "float", S, "interval start", clock=True),
    Column("interval_end", "float", S, "interval end", clock=True),
    Column("observed_s", "float", S, "seconds of the interval observed"),
    Column("origin", "str", "", "arm the vehicles came in by"),
    Column("destination", "str", "", "arm they left by"),
    Column("movement", "str", "", "left, through, right or U"),
    Column("class", "str", "", "vehicle class"),
    Column("count", "int", "", "complete movements that entered in the interval (by the entry crossing, else "
           "the time first seen)"),
), what="per interval, origin, destination and class")

_BOX = (Column("frame", "int", "", "video frame index"), Column("time", "float", S, "frame time", clock=True),
        Column("x1", "float", PX, "box left"), Column("y1", "float", PX, "box top"),
        Column("x2", "float", PX, "box right"), Column("y2", "float", PX, "box bottom"))
DETECTIONS = TableSchema("detections.csv", (
    *_BOX, Column("score", "float", "", "detector score in [0, 1]"), Column("class", "str", "", "vehicle class"),
), what="one row per detection box")
TRACKS = TableSchema("tracks.csv", (
    *_BOX[:2], Column("track_id", "str", "", "the tracker's id"), *_BOX[2:],
    Column("score", "float", "", "detector score"), Column("class", "str", "", "vehicle class"),
), what="one row per tracked box")

SCHEMAS: dict[str, TableSchema] = {s.file: s for s in (VEHICLES, CROSSINGS, COUNTS, TRAJECTORIES, DETECTIONS,
                                                      TRACKS, MOVEMENTS, MOVEMENT_COUNTS)}
RUN_HINT = "give the output folder of 'trafficgeo analyze' or 'trafficgeo process'"
COMPARE_TABLES = ("compare_counts.csv", "compare_speeds.csv", "simulated_crossings.csv",  # compare-sumo's tables
                  "compare_movements.csv", "simulated_movements.csv")  # sumo-validate at a junction's gates
COMPARE_TEXT_COLUMNS = ("track_id", "class", "lane", "line", "source_track", "origin", "destination", "movement",
                        "origin_by", "destination_by")  # read as text ("" where empty)


class RunFolder:
    """The output folder ``path`` of a run: write a run's results into it, or read a finished run's tables and its
    JSON files as typed records (checked against the run's manifest: a folder whose run did not finish, or whose
    files changed since, is refused). The one writer and reader of a run's files, but for ``detections.csv`` and
    ``tracks.csv`` of ``process``, which :func:`trafficgeo.video.pipeline.detect_and_track` writes (under
    :data:`DETECTIONS` and :data:`TRACKS`) as it finishes."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._manifest: RunManifest | None = None
        self._comparison: RunManifest | None = None

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    # ------------------------------------------------------------------------------------------------ writing
    def write_traffic(self, result: TrafficResult, camera: Camera | CalibratedCamera, *, publish: bool = True
                      ) -> list[Path]:
        """Write ``result`` (vehicles, crossings, counts, trajectories as CSV and GIS layers, summary.json); returns
        the paths written. With ``publish=False`` the manifest is left for the caller, which adds files of its own
        (``process``)."""
        from trafficgeo.camera.calibrated import as_camera
        from trafficgeo.traffic.analyze import write_analysis

        camera = as_camera(camera)

        self._manifest = self._comparison = None
        return write_analysis(self.path, result, camera, publish=publish)

    def write_table(self, name: str, table: pd.DataFrame, *, float_format: str = "%.3f") -> Path:
        """Write output table ``name`` (a key of :data:`SCHEMAS`; ``table`` must follow its schema) as CSV,
        atomically; returns its path. The manifest is the caller's (:meth:`publish`)."""
        from trafficgeo.io.atomic import write_csv_atomic

        if name not in SCHEMAS:
            raise ValueError(f"{name}: not a table of a run folder; one of {', '.join(SCHEMAS)}")
        SCHEMAS[name].check(table)
        self.path.mkdir(parents=True, exist_ok=True)
        write_csv_atomic(self.path / name, table, float_format=float_format)
        return self.path / name

    def write_summary(self, summary: RunSummary) -> Path:
        """Write ``summary.json`` (atomically); returns its path."""
        return self._write_json("summary.json", summary.to_dict())

    def write_process(self, record: ProcessRecord) -> Path:
        """Write ``process.json`` (atomically); returns its path."""
        return self._write_json("process.json", record.to_dict())

    def write_comparison(self, tables: Mapping[str, pd.DataFrame], summary: CompareSummary) -> list[Path]:
        """Write a comparison with a simulation (``compare-sumo``): ``tables`` (:data:`COMPARE_TABLES` by name) as
        CSV, ``compare_summary.json``, then the comparison's manifest (``compare_run.json``); returns the paths
        written. Until the manifest is written, readers refuse the comparison."""
        from trafficgeo.io.atomic import write_csv_atomic
        from trafficgeo.io.folder_lock import hold_folder
        from trafficgeo.io.run_manifest import begin_outputs, publish_outputs

        unknown = sorted(set(tables) - set(COMPARE_TABLES))
        if unknown:
            raise ValueError(f"{unknown}: not tables of a comparison; one of {', '.join(COMPARE_TABLES)}")
        self._comparison = None
        with hold_folder(self.path):
            begin_outputs(self.path, COMPARE_MANIFEST)
            written = []
            for name, table in tables.items():
                write_csv_atomic(self.path / name, table, float_format="%.4f")
                written.append(self.path / name)
            written.append(self.write_compare_summary(summary))
            publish_outputs(self.path, written, command="compare-sumo", name=COMPARE_MANIFEST)
        return written

    def write_compare_summary(self, summary: CompareSummary) -> Path:
        """Write ``compare_summary.json`` (atomically); returns its path. The comparison's manifest is the
        caller's (:meth:`write_comparison` writes it)."""
        return self._write_json("compare_summary.json", summary.to_dict())

    def write_simulation_record(self, record: SimulationRecord) -> Path:
        """Write ``compare_simulation.json`` beside the comparison written last (:meth:`write_comparison`) and
        publish the comparison's manifest again with it, its command ``sumo-validate``; returns the record's path.
        """
        from trafficgeo.io.folder_lock import hold_folder
        from trafficgeo.io.run_manifest import publish_outputs

        with hold_folder(self.path):
            files = list(verify_outputs(self.path, name=COMPARE_MANIFEST).files)
            self._comparison = None
            path = self._write_json(SIMULATION_RECORD, record.to_dict())
            publish_outputs(self.path, [*(f for f in files if f != SIMULATION_RECORD), SIMULATION_RECORD],
                            command="sumo-validate", name=COMPARE_MANIFEST)
        return path

    def _write_json(self, name: str, doc: dict[str, Any]) -> Path:
        from trafficgeo.io.atomic import write_json_atomic

        self.path.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.path / name, doc)
        return self.path / name

    def publish(self, files: Iterable[str | Path], *, command: str) -> None:
        """Write the manifest listing ``files`` (names in the folder): the run is finished."""
        from trafficgeo.io.folder_lock import hold_folder
        from trafficgeo.io.run_manifest import publish_outputs

        with hold_folder(self.path):
            publish_outputs(self.path, files, command=command)
        self._manifest = self._comparison = None

    # ------------------------------------------------------------------------------------------------ reading
    @property
    def manifest(self) -> RunManifest:
        """The run's manifest, checked (InputError for an unfinished or changed run)."""
        if self._manifest is None:
            if not self.path.is_dir():
                raise InputError(f"{self.path}: not a folder; {RUN_HINT}")
            self._manifest = verify_outputs(self.path)
        return self._manifest

    def has(self, name: str) -> bool:
        """Whether the finished run has the output ``name``."""
        return self.manifest.has(name)

    def _require(self, name: str) -> Path:
        if not self.has(name):
            verify_outputs(self.path, require=(name,))  # "has no NAME (its outputs are from 'analyze'); ..."
            raise InputError(f"{self.path}: no {name}; {RUN_HINT}")
        return self.path / name

    def table(self, name: str, *, required: Iterable[str] | None = None) -> pd.DataFrame:
        """Output table ``name`` (a key of :data:`SCHEMAS`) with the schema's dtypes."""
        if name not in SCHEMAS:
            raise InputError(f"{name}: not a table of a run folder; one of {', '.join(SCHEMAS)}")
        return SCHEMAS[name].read(self._require(name), required=required)

    def _json(self, p: Path) -> Any:
        try:
            return loads_json(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            raise InputError(f"{p}: not readable JSON; run trafficgeo again to write it") from None

    def summary(self) -> RunSummary:
        """``summary.json``: totals, options (``interval_s``, ...), ``period_s`` and ``crs`` (WKT or None)."""
        p = self._require("summary.json")
        return RunSummary.from_dict(self._json(p), str(p))

    def process(self) -> ProcessRecord | None:
        """``process.json`` of a ``process`` run (None for an ``analyze`` or ``stitch`` run)."""
        if not self.has("process.json"):
            return None
        p = self.path / "process.json"
        return ProcessRecord.from_dict(self._json(p), str(p))

    @property
    def comparison(self) -> RunManifest | None:
        """The manifest of the comparison with a simulation in the folder (``compare_run.json``), checked
        (:class:`~trafficgeo.io.run_manifest.RunIncompleteError` when its files are incomplete or changed); None
        without one."""
        if self._comparison is None:
            if not (self.path / COMPARE_MANIFEST).is_file():
                return None
            self._comparison = verify_outputs(self.path, name=COMPARE_MANIFEST)
        return self._comparison

    def compare_summary(self) -> CompareSummary | None:
        """``compare_summary.json`` of the comparison in the folder (:attr:`comparison`); None without a
        comparison, or one whose manifest does not list the file."""
        found = self.comparison
        if found is None or not found.has("compare_summary.json"):
            return None
        p = self.path / "compare_summary.json"
        return CompareSummary.from_dict(self._json(p), str(p))

    def simulation_record(self) -> SimulationRecord | None:
        """``compare_simulation.json``: what ``sumo-validate`` simulated, when the folder's comparison is from it
        (its manifest's command is ``sumo-validate`` and lists the record); None for a plain ``compare-sumo``
        comparison or none."""
        found = self.comparison
        if found is None or found.command != "sumo-validate" or not found.has(SIMULATION_RECORD):
            return None
        p = self.path / SIMULATION_RECORD
        return SimulationRecord.from_dict(self._json(p), str(p))

    def comparison_table(self, name: str) -> pd.DataFrame | None:
        """Table ``name`` of the comparison in the folder (one of :data:`COMPARE_TABLES`), its text columns
        ``""`` where empty; None without a comparison, or one whose manifest does not list the table."""
        if name not in COMPARE_TABLES:
            raise InputError(f"{name}: not a table of a comparison; one of {', '.join(COMPARE_TABLES)}")
        found = self.comparison
        if found is None or not found.has(name):
            return None
        path = self.path / name
        text = dict.fromkeys(COMPARE_TEXT_COLUMNS, str)
        try:
            table = pd.read_csv(path, dtype=text, keep_default_na=False, na_values=[""])
        except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
            raise InputError(f"{path}: not a table trafficgeo wrote ({' '.join(str(exc).split())[:80]}); run the "
                             "comparison again") from None
        for c in COMPARE_TEXT_COLUMNS:
            if c in table.columns:
                table[c] = table[c].fillna("").astype(str)
        return table

    def vehicles(self) -> pd.DataFrame:
        return self.table("vehicles.csv")

    def crossings(self) -> pd.DataFrame:
        return self.table("crossings.csv")

    def counts(self) -> pd.DataFrame:
        return self.table("counts.csv")

    def trajectories(self) -> pd.DataFrame:
        return self.table("trajectories.csv", required=[c for c in TRAJECTORIES.names if c not in ("lon", "lat")])

    def tracks(self) -> pd.DataFrame:
        return self.table("tracks.csv")

    def detections(self) -> pd.DataFrame:
        return self.table("detections.csv")

    def movements(self) -> pd.DataFrame:
        """``movements.csv`` of a run with a junction's gates."""
        return self.table("movements.csv")

    def movement_counts(self) -> pd.DataFrame:
        """``movement_counts.csv`` of a run with a junction's gates."""
        return self.table("movement_counts.csv")

    def junction(self, crs: Any = None) -> Junction | None:
        """The junction of a run with gates: the ``gates`` layer of ``trajectories.gpkg`` (in ``crs`` when given);
        None for a run without one."""
        gpkg = self.path / "trajectories.gpkg"
        if not gpkg.is_file():
            return None
        from trafficgeo.io.gis import gis_layers, read_gis
        from trafficgeo.site.gates import Gate, Junction

        if "gates" not in gis_layers(gpkg):
            return None
        g = read_gis(gpkg, layer="gates")
        if crs is not None and g.crs is not None:
            g = g.to_crs(crs)
        return Junction.from_gates([Gate(str(a), geom) for a, geom in zip(g["arm"], g.geometry, strict=True)])

    def turning_movements(self) -> pd.DataFrame:
        """``turning_movements.csv`` of a run with a junction's gates: ``interval_start, interval_end``, then
        ``<arm>_left, <arm>_through, <arm>_right, <arm>_U`` per approach arm, ``total``, ``heavy``, ``heavy_pct``."""
        p = self._require("turning_movements.csv")
        try:
            return pd.read_csv(p)
        except (UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
            raise InputError(f"{p}: not a readable turning_movements.csv ({type(exc).__name__}); run trafficgeo "
                             "again to write it") from None
