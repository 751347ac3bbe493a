"""A run's output folder: the one writer and reader of its files (the schema of its tables:
:mod:`trafficgeo.run.schema`).

``analyze``, ``process`` and ``stitch`` write a run folder; ``compare-sumo``, ``export-fcd``, ``stitch`` (its chunks),
the HTML report and the demo read one. All of them go through :class:`RunFolder`: a run is written in one
``with RunFolder(out).writing(command) as run:`` block (lock, manifest removed first and written last; the
:class:`RunWriter` checks every table against its schema), and every table's columns, dtypes and units are
defined once (:data:`SCHEMAS`, :mod:`trafficgeo.run.schema`):

============================  =========================================================================
``vehicles.csv``              one row per vehicle (track): class, times, speed, length, lane (:data:`VEHICLES`)
``crossings.csv``             one row per counting-line crossing (:data:`CROSSINGS`)
``counts.csv``                every line x lane x direction x interval, zeros too: counts, flow, speeds (:data:`COUNTS`)
``trajectories.csv``          one row per vehicle and frame, on the ground (:data:`TRAJECTORIES`)
``trajectories.gpkg/.parquet``the same as GIS layers (paths, points, lanes, count lines) when the camera has a CRS
``summary.json``              totals, the options used and the CRS (WKT) (:class:`~trafficgeo.run.records.RunSummary`)
``detections.csv``            ``process``: every detection box (:data:`DETECTIONS`)
``tracks.csv``                ``process``/``stitch``: the tracker's boxes (:data:`TRACKS`)
``process.json``              ``process``: the video, options, what was read, the detector's tile plan
                              (:class:`~trafficgeo.run.records.ProcessRecord`)
``run.json``                  the manifest (:mod:`trafficgeo.io.run_manifest`): written last, checked by readers
``compare_counts.csv``,       ``compare-sumo``/``sumo-validate``: observed against simulated counts (GEH), spot
``compare_speeds.csv``,       speeds and the simulated crossings (:data:`COMPARE_TABLES`), under the comparison's
``simulated_crossings.csv``   own manifest (``compare_run.json``)
``compare_summary.json``      the comparison's GEH and travel times (:class:`~trafficgeo.run.records.CompareSummary`)
``compare_simulation.json``   ``sumo-validate``: the scenario simulated and the headline figures
                              (:class:`~trafficgeo.run.records.SimulationRecord`); its manifest's command is then
                              ``sumo-validate``
============================  =========================================================================

The JSON files are typed records (:mod:`trafficgeo.run.records`): a run's :class:`RunWriter` writes them
(:meth:`RunWriter.summary`, :meth:`~RunWriter.process`, :meth:`~RunWriter.compare_summary`,
:meth:`~RunWriter.simulation`; a comparison in one block: :meth:`~RunFolder.write_comparison`); :class:`RunFolder`
reads them back (:meth:`RunFolder.summary`, :meth:`~RunFolder.process`, :meth:`~RunFolder.compare_summary`,
:meth:`~RunFolder.simulation_record`); the
comparison's tables are read by :meth:`RunFolder.comparison_table`.

Units: times in seconds of video (``time``, ``first_time``... from the video's start), speeds in km/h, lengths and
distances in metres, ``x, y, z`` in the camera's CRS and its units (``"crs"`` below), pixel boxes in full-frame px
(pixel-centre convention, :mod:`trafficgeo.video.detections`), headings in degrees clockwise from grid north. Text
columns read back as ``""`` where empty (an unknown class, no lane), never NaN.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd

from trafficgeo.errors import InputError
from trafficgeo.io.json_text import loads_json
from trafficgeo.io.run_manifest import COMPARE_MANIFEST, MANIFEST, RunManifest, verify_outputs
from trafficgeo.run.records import (
    SIMULATION_RECORD,
    CompareSummary,
    ProcessRecord,
    RunSummary,
    SimulationRecord,
)
from trafficgeo.run.schema import (  # the tables' schema, defined in its own module
    COUNTS,
    CROSSINGS,
    DETECTIONS,
    MOVEMENT_COUNTS,
    MOVEMENTS,
    SCHEMAS,
    TRACKS,
    TRAJECTORIES,
    VEHICLES,
    Column,
    TableSchema,
)

if TYPE_CHECKING:
    from trafficgeo.site.gates import Junction

__all__ = ["COMPARE_TABLES", "COUNTS", "CROSSINGS", "DETECTIONS", "MOVEMENTS", "MOVEMENT_COUNTS", "SCHEMAS", "TRACKS",
           "TRAJECTORIES", "VEHICLES", "Column", "RunFolder", "RunWriter", "TableSchema"]


RUN_HINT = "give the output folder of 'trafficgeo analyze' or 'trafficgeo process'"
COMPARE_TABLES = ("compare_counts.csv", "compare_speeds.csv", "simulated_crossings.csv",  # compare-sumo's tables
                  "compare_movements.csv", "simulated_movements.csv")  # sumo-validate at a junction's gates
COMPARE_TEXT_COLUMNS = ("track_id", "class", "lane", "line", "source_track", "origin", "destination", "movement",
                        "origin_by", "destination_by")  # read as text ("" where empty)
# written without a schema: the turning-movement table (a column per arm and movement) and a comparison's tables
FREE_TABLES = ("turning_movements.csv", *COMPARE_TABLES)


class RunWriter:
    """The files of a run being written (:meth:`RunFolder.writing`): each table checked against its schema and
    written atomically, the GIS layers, the JSON records; :attr:`written` is what the manifest will list.
    Units and conventions: the module docstring."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.written: list[Path] = []

    def __repr__(self) -> str:
        return f"RunWriter({str(self.path)!r}, {len(self.written)} files)"

    def adopt(self, *files: str | Path) -> None:
        """List ``files`` (names in the folder, or paths) in the manifest: files written by another writer of the
        run (``process``'s detections and tracks, written as the video is read: :meth:`RunFolder.write_table`)."""
        for f in files:
            p = self.path / Path(f).name
            if p not in self.written:
                self.written.append(p)

    def table(self, name: str, table: pd.DataFrame, *, float_format: str = "%.4f") -> Path:
        """Write table ``name`` (a key of :data:`SCHEMAS`: no column it does not know, and the schema's columns the
        table lacks written empty, :meth:`~trafficgeo.run.schema.TableSchema.conformed`; or one of
        :data:`FREE_TABLES`) as CSV, atomically; returns its path."""
        from trafficgeo.io.atomic import write_csv_atomic

        if name in SCHEMAS:
            table = SCHEMAS[name].conformed(table)
        elif name not in FREE_TABLES:
            raise ValueError(f"{name}: not a table of a run folder; one of {', '.join([*SCHEMAS, *FREE_TABLES])}")
        write_csv_atomic(self.path / name, table, float_format=float_format)
        self.adopt(name)
        return self.path / name

    def points(self, name: str, points: pd.DataFrame, crs: Any) -> Path:
        """Write a table of ground points (``trajectories.csv``: as :meth:`table`, with ``lon, lat`` to 1e-9 degrees
        where ``crs`` is known; :func:`~trafficgeo.io.tables.write_point_table`); returns its path."""
        from trafficgeo.io.tables import write_point_table

        table = SCHEMAS[name].conformed(points)
        table = table.drop(columns=[c for c in ("lon", "lat") if c not in points.columns])  # from the CRS, or none
        write_point_table(self.path / name, table, crs)
        self.adopt(name)
        return self.path / name

    def layers(self, name: str, layers: list, crs: Any) -> Path:
        """Write GIS ``layers`` (:class:`~trafficgeo.io.gis.Layer`) as ``name`` (.gpkg, or .parquet for the first
        layer alone) in ``crs``; returns its path."""
        from trafficgeo.io.gis import write_gis

        write_gis(self.path / name, layers, crs)
        self.adopt(name)
        return self.path / name

    def summary(self, summary: RunSummary) -> Path:
        """Write ``summary.json``; returns its path."""
        return self._json("summary.json", summary.to_dict())

    def process(self, record: ProcessRecord) -> Path:
        """Write ``process.json``; returns its path."""
        return self._json("process.json", record.to_dict())

    def compare_summary(self, summary: CompareSummary) -> Path:
        """Write ``compare_summary.json``; returns its path."""
        return self._json("compare_summary.json", summary.to_dict())

    def simulation(self, record: SimulationRecord) -> Path:
        """Write ``compare_simulation.json`` (``sumo-validate``'s record of the scenario); returns its path."""
        return self._json(SIMULATION_RECORD, record.to_dict())

    def remove(self, names: Iterable[str]) -> None:
        """Remove the files ``names`` that this run did not write (left by an earlier run into the folder)."""
        keep = {p.name for p in self.written}
        for n in names:
            if n not in keep:
                (self.path / n).unlink(missing_ok=True)

    def _json(self, name: str, doc: dict[str, Any]) -> Path:
        from trafficgeo.io.atomic import write_json_atomic

        write_json_atomic(self.path / name, doc)
        self.adopt(name)
        return self.path / name


class RunFolder:
    """The output folder ``path`` of a run: write a run's results into it, or read a finished run's tables and its
    JSON files as typed records (checked against the run's manifest: a folder whose run did not finish, or whose
    files changed since, is refused). The one writer and reader of a run's files (:meth:`writing`;
    ``process``'s detections and tracks through :meth:`write_table` as the video is read)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._manifest: RunManifest | None = None
        self._comparison: RunManifest | None = None

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    # ------------------------------------------------------------------------------------------------ writing
    @contextmanager
    def writing(self, command: str, *, manifest: str = MANIFEST) -> Iterator[RunWriter]:
        """Write a run into the folder: ``with RunFolder(out).writing("analyze") as run: run.table(...)``.

        Holds the folder's lock for the block (:func:`~trafficgeo.io.folder_lock.hold_folder`: one run at a time),
        removes the manifest ``manifest`` first (from then on readers refuse the folder) and, when the block ends
        without an error, writes it last, listing every file the :class:`RunWriter` wrote or adopted, under
        ``command``. A block that raises leaves the folder unpublished: never half a run that reads as whole."""
        from trafficgeo.io.folder_lock import hold_folder
        from trafficgeo.io.run_manifest import begin_outputs, publish_outputs

        self._manifest = self._comparison = None
        with hold_folder(self.path):
            begin_outputs(self.path, manifest)
            writer = RunWriter(self.path)
            yield writer
            publish_outputs(self.path, writer.written, command=command, name=manifest)
        self._manifest = self._comparison = None

    def write_table(self, name: str, table: pd.DataFrame, *, float_format: str = "%.3f") -> Path:
        """Write output table ``name`` (a key of :data:`SCHEMAS`; ``table`` must follow its schema) as CSV,
        atomically, outside a :meth:`writing` block (``process`` writes its detections and tracks so as the video is
        read; the run's writer then adopts them: :meth:`RunWriter.adopt`); returns its path."""
        from trafficgeo.io.atomic import write_csv_atomic

        if name not in SCHEMAS:
            raise ValueError(f"{name}: not a table of a run folder; one of {', '.join(SCHEMAS)}")
        SCHEMAS[name].check(table)
        self.path.mkdir(parents=True, exist_ok=True)
        write_csv_atomic(self.path / name, table, float_format=float_format)
        return self.path / name

    def write_comparison(self, tables: Mapping[str, pd.DataFrame], summary: CompareSummary,
                         simulation: SimulationRecord | None = None) -> list[Path]:
        """Write a comparison with a simulation in one :meth:`writing` block: ``tables`` (:data:`COMPARE_TABLES` by
        name) as CSV, ``compare_summary.json`` and, from ``sumo-validate``, the ``simulation`` record of its
        scenario (``compare_simulation.json``), then the comparison's manifest (``compare_run.json``, command
        ``sumo-validate`` with a record, else ``compare-sumo``); returns the paths written. Until the manifest is
        written, readers refuse the comparison."""
        unknown = sorted(set(tables) - set(COMPARE_TABLES))
        if unknown:
            raise ValueError(f"{unknown}: not tables of a comparison; one of {', '.join(COMPARE_TABLES)}")
        command = "sumo-validate" if simulation is not None else "compare-sumo"
        with self.writing(command, manifest=COMPARE_MANIFEST) as run:
            for name, table in tables.items():
                run.table(name, table, float_format="%.4f")
            run.compare_summary(summary)
            if simulation is not None:
                run.simulation(simulation)
        return run.written

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
