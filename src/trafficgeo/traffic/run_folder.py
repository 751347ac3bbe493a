"""A run's output folder: the one writer and reader of its files (the schema of its tables:
:mod:`trafficgeo.traffic.schema`).

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
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

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
from trafficgeo.traffic.schema import (  # the tables' schema, defined in its own module
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
    from trafficgeo.camera.calibrated import CalibratedCamera
    from trafficgeo.camera.model import Camera
    from trafficgeo.site.gates import Junction
    from trafficgeo.traffic.analyze import TrafficResult

__all__ = ["COMPARE_TABLES", "COUNTS", "CROSSINGS", "DETECTIONS", "MOVEMENTS", "MOVEMENT_COUNTS", "SCHEMAS", "TRACKS",
           "TRAJECTORIES", "VEHICLES", "Column", "RunFolder", "TableSchema"]


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
        """Write ``result`` (vehicles, crossings, counts, trajectories as CSV and GIS layers, a junction's movements,
        summary.json; :mod:`trafficgeo.traffic.analyze`); returns the paths written. The folder's manifest is
        removed first and, with ``publish``, written last; a caller that adds files of its own (``process``)
        passes ``publish=False`` and publishes them all. The folder is locked while it is written
        (:func:`~trafficgeo.io.folder_lock.hold_folder`)."""
        from trafficgeo.camera.calibrated import as_camera
        from trafficgeo.geo.mapping import camera_crs
        from trafficgeo.io.atomic import write_csv_atomic
        from trafficgeo.io.folder_lock import hold_folder
        from trafficgeo.io.gis import write_gis
        from trafficgeo.io.run_manifest import begin_outputs, publish_outputs
        from trafficgeo.io.tables import write_point_table
        from trafficgeo.traffic.outputs import OUTPUT_FILES, gis_layers, summary

        self._manifest = self._comparison = None
        with hold_folder(self.path):  # one run at a time in a folder
            out = begin_outputs(self.path)
            crs = camera_crs(as_camera(camera))
            written = []
            for name, table in (("vehicles.csv", result.vehicles), ("counts.csv", result.counts),
                                ("crossings.csv", result.crossings)):
                write_csv_atomic(out / name, table, float_format="%.4f")
                written.append(out / name)
            write_point_table(out / "trajectories.csv", result.points, crs)  # lon/lat to 1e-9 degrees
            written.append(out / "trajectories.csv")
            if result.movements is not None:
                for name in ("movements.csv", "movement_counts.csv"):
                    SCHEMAS[name].check(getattr(result, name.removesuffix(".csv")))
                for name, table in (("movements.csv", result.movements),
                                    ("movement_counts.csv", result.movement_counts),
                                    ("turning_movements.csv", result.turning)):
                    write_csv_atomic(out / name, table, float_format="%.4f")
                    written.append(out / name)
            if crs is not None and len(result.points):
                layers = gis_layers(result, crs)
                write_gis(out / "trajectories.gpkg", layers, crs)
                write_gis(out / "trajectories.parquet", layers[:1], crs)
                written += [out / "trajectories.gpkg", out / "trajectories.parquet"]
            written.append(self.write_summary(summary(result, crs)))
            for stale in {out / n for n in OUTPUT_FILES} - set(written):  # e.g. no GeoPackage without a CRS
                stale.unlink(missing_ok=True)
            if publish:
                publish_outputs(out, written, command="analyze")
            return written

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
