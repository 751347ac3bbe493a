"""The one schema of every table trafficgeo writes into a run folder (:mod:`trafficgeo.run.folder`): each
table's columns, dtypes, units and meaning, defined once (:data:`SCHEMAS`), with the reader that gives a table
those dtypes back (:meth:`TableSchema.read`) and the check a writer makes (:meth:`TableSchema.check`).

Units: times in seconds of video (``time``, ``first_time``... from the video's start), speeds in km/h, lengths and
distances in metres, ``x, y, z`` in the camera's CRS and its units (``"crs"``), pixel boxes in full-frame px
(pixel-centre convention, :mod:`trafficgeo.video.detections`), headings in degrees clockwise from grid north. Text
columns read back as ``""`` where empty (an unknown class, no lane), never NaN.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from trafficgeo.errors import InputError

__all__ = ["COUNTS", "CROSSINGS", "DETECTIONS", "MOVEMENTS", "MOVEMENT_COUNTS", "SCHEMAS", "TRACKS", "TRAJECTORIES",
           "VEHICLES", "Column", "TableSchema"]


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
                             f"the {self.file} schema of trafficgeo.run.folder")

    def conformed(self, table: pd.DataFrame) -> pd.DataFrame:
        """``table`` with the schema's columns it lacks added empty (NaN, ``""`` for text), after its own, as a
        reader reads a file without them (a run whose tracks had no boxes measures no ``length_m``); InputError
        for a column the schema does not know."""
        extra = [n for n in table.columns if not self._known(n)]
        if extra:
            self.check(table)
        missing = [c for c in self.columns if c.name not in table.columns]
        if not missing:
            return table
        return table.assign(**{c.name: "" if c.dtype == "str" else float("nan") for c in missing})

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
            if size:
                fh.seek(size - 1)
            last = fh.read(1) if size else b"\n"
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
            if kind in ("int", "float"):
                table[c] = _numbers(table[c], kind, f"{path} column {c}")
        later = [c for c in self.columns if c.added and c.name not in table.columns]
        if later:  # a file written before these columns joined the table: empty, in the schema's place
            for c in later:  # as an empty column of the file would read
                table[c.name] = ("" if c.dtype == "str" else pd.Series(pd.NA, index=table.index, dtype="Int64")
                                 if c.dtype == "int" else float("nan"))
            order = [n for n in self.names if n in table.columns]
            table = table[order + [n for n in table.columns if n not in order]]
        return table


def _numbers(values: pd.Series, kind: str, where: str) -> pd.Series:
    """A column read from CSV as the schema's ``kind`` ("int": int64, or Int64 with NA where empty; "float":
    float64); a value that is not such a number (a word, a huge or fractional value in an integer column) is an
    InputError naming its row."""
    if pd.api.types.is_integer_dtype(values) or (kind == "float" and pd.api.types.is_float_dtype(values)):
        return values  # as pandas read it: nothing to check
    numbers = pd.to_numeric(values, errors="coerce")
    bad = numbers.isna() & values.notna()
    if kind == "int":
        bad |= numbers.notna() & ~(np.isfinite(numbers) & (numbers == np.round(numbers)) & (numbers.abs() < 2**53))
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        raise InputError(f"{where} row {row + 2} is {str(values.iloc[row])[:40]!r}, not "
                         f"{'an integer' if kind == 'int' else 'a number'}; run trafficgeo again to write it")
    if kind == "float":
        return numbers.astype(np.float64)
    return numbers.astype("Int64") if numbers.isna().any() else numbers.astype(np.int64)


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
