"""The typed records of a run folder's JSON files (:mod:`trafficgeo.run.records`): ``RunFolder`` writes
them and reads them back equal, refuses a damaged or foreign file with one line naming it, and a real run's files
(``analyze``, ``process``'s writer, a comparison) read back typed, as the files hold them."""

from __future__ import annotations

import importlib.util
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyproj
import pytest
import shapely.affinity

import trafficgeo as tg
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import to_json_safe
from trafficgeo.io.run_manifest import COMPARE_MANIFEST, publish_outputs
from trafficgeo.run.folder import RunFolder
from trafficgeo.run.records import (
    SIMULATION_RECORD,
    CompareSummary,
    CountSummary,
    LineCount,
    ProcessRecord,
    ProcessSettings,
    RunSummary,
    SimulationRecord,
    TravelTimeSummary,
    VideoRead,
)
from trafficgeo.traffic.analyze import write_analysis

REF = Path(__file__).parent / "data" / "api-reference"


def _summary() -> RunSummary:
    return RunSummary(period_s=(0.04, 27.4), vehicles=10, points=2460, dropped_points={"too_far": 12, "short_track": 3},
                      outlier_points=7, mean_speed_kmh=38.25, classes={"car": 9, "": 1}, lane_changes=2,
                      crossings=(LineCount("across", "", -1, 0), LineCount("across", "d1_2", 1, 3)),
                      hidden_crossings=1, options={"pixel_sigma": 2.0, "interval_s": 10.0, "box_correction": True},
                      warnings=("a warning",), crs=pyproj.CRS.from_epsg(2240).to_wkt())


def _process() -> ProcessRecord:
    return ProcessRecord(video="clip.mp4", camera="camera.json",
                         options=ProcessSettings("nanodet", "auto", 0.0, None, 2, True, "squares", "auto", "auto"),
                         detector={"tiling": {"tiles": [[0, 0, 320, 180]], "passes_per_frame": 2, "warnings": []},
                                   "backend": {"backend": "onnxruntime", "ms_per_pass": 41.5}},
                         read=VideoRead(0.0, 7.96, 100, False), seconds=12.5, detections=480, track_rows=455)


def _compare() -> CompareSummary:
    nan = float("nan")
    return CompareSummary(
        CountSummary(rows=4, share_geh_below_5=0.75, mean_geh=2.1, total_observed=22, total_simulated=25,
                     geh_total=0.62, groups=({"line": "A", "lane": "1", "observed": 22, "simulated": 25,
                                              "observed_flow_veh_h": 660.0, "simulated_flow_veh_h": 750.0,
                                              "geh": 3.4},)),
        TravelTimeSummary("A", "B", 0, nan, nan, nan, 3, 14.2, 14.0, 15.1, nan, nan, nan), "EPSG:2949 (MTM 7)")


def _simulation() -> SimulationRecord:
    return SimulationRecord(scenario="/data/scenario", net="/data/scenario/road.net.xml", net_crs=None,
                            interval_s=60.0, begin_s=0.0, end_s=600.0, time_offset_s=-3.5, step_s=0.5, seed=7,
                            vehicles=212, build_s=float("nan"), run_s=4.25, counts=48, share_geh_below_5=0.875,
                            mean_geh=1.9, target_share=0.85, target_met=True, max_abs_speed_difference_kmh=6.1,
                            travel_time_difference_s=float("nan"), unobserved=("line B direction -1",),
                            warnings=("a warning",))


def _write_in_run(kind: str):
    def write(folder: RunFolder, record) -> Path:
        with folder.writing("test") as run:
            return getattr(run, kind)(record)
    return write


# how each record is written, published (by which command) and read back
WRITE = {"summary": (_write_in_run("summary"), "run.json", RunFolder.summary, _summary),
         "process": (_write_in_run("process"), "run.json", RunFolder.process, _process),
         "compare": (_write_in_run("compare_summary"), COMPARE_MANIFEST, RunFolder.compare_summary, _compare),
         "simulation": (_write_in_run("simulation"), COMPARE_MANIFEST, RunFolder.simulation_record, _simulation)}
COMMAND = {"simulation": "sumo-validate"}  # the others: any


def _written(folder: Path, kind: str, record) -> Path:
    write, manifest, _, _ = WRITE[kind]
    path = write(RunFolder(folder), record)
    publish_outputs(folder, [path.name], command=COMMAND.get(kind, "test"), name=manifest)
    return path


@pytest.mark.parametrize("kind", sorted(WRITE))
def test_a_record_reads_back_equal_to_what_was_written(kind: str, tmp_path: Path) -> None:
    record = WRITE[kind][3]()
    path = _written(tmp_path / "run", kind, record)
    back = WRITE[kind][2](RunFolder(tmp_path / "run"))
    assert type(back) is type(record) and back == record
    assert json.loads(path.read_text()) == to_json_safe(record.to_dict())  # the file is the record's document
    changed = {"summary": lambda r: replace(r, crossings=r.crossings[:1]),
               "process": lambda r: replace(r, read=replace(r.read, frames=99)),
               "compare": lambda r: replace(r, travel_times=None),
               "simulation": lambda r: replace(r, unobserved=())}[kind](record)
    assert back != changed  # equality looks at every part


def test_the_records_are_typed_and_keep_what_older_files_lack_as_defaults(tmp_path: Path) -> None:
    _written(tmp_path / "run", "summary", _summary())
    back = RunFolder(tmp_path / "run").summary()
    assert back.crossings[1] == LineCount("across", "d1_2", 1, 3) and back.interval_s == 10.0
    assert isinstance(back.period_s, tuple) and isinstance(back.warnings, tuple)
    old = {k: v for k, v in _summary().to_dict().items() if k not in ("hidden_crossings", "warnings", "crs")}
    assert RunSummary.from_dict(old) == replace(_summary(), hidden_crossings=0, warnings=(), crs=None)
    # a process.json of an older trafficgeo (no read, detector, timings; fewer options), as stitch reads it
    info = ProcessRecord.from_dict({"video": "/data/video.mp4", "camera": "camera.json",
                                    "options": {"start_s": 2, "end_s": 6.5}, "extra": 1})
    assert info.options.start_s == 2.0 and isinstance(info.options.start_s, float) and info.options.every is None
    assert info.read is None and info.seconds is None and info.tiling is None
    _written(tmp_path / "cmp", "compare", _compare())
    cmp = RunFolder(tmp_path / "cmp").compare_summary()
    assert math.isnan(cmp.travel_times.observed_mean_s) and cmp.travel_times.simulated_n == 3
    assert RunFolder(tmp_path / "run").compare_summary() is None  # no comparison in a plain run


DAMAGED = [
    ("summary", "summary.json", "{not json", "not readable JSON"),
    ("summary", "summary.json", "[1, 2]", "the document is not a JSON object"),
    ("summary", "summary.json", {"vehicles": "ten"}, "'vehicles' is not a whole number"),
    ("summary", "summary.json", {"period_s": [0.0]}, "'period_s' has 1 values, expected 2"),
    ("summary", "summary.json", {"crossings": [{"line": "a", "lane": "", "direction": 1}]},
     "key 'crossings[0].count' is missing"),
    ("summary", "summary.json", {"format": "trafficgeo.camera/1", "focal_px": 1500.0}, "key 'period_s' is missing"),
    ("process", "process.json", {"video": None}, "'video' is not text"),
    ("process", "process.json", {"read": {"start_s": 0.0, "end_s": 1.0, "frames": "x", "complete": True}},
     "'read.frames' is not a whole number"),
    ("process", "process.json", {"options": {"tiles": "yes"}}, "'options.tiles' is not true or false"),
    ("compare", "compare_summary.json", {"counts": {"rows": 2}}, "key 'counts.share_geh_below_5' is missing"),
    ("compare", "compare_summary.json", {"travel_times": {"from_line": "A"}}, "key 'travel_times.to_line' is"),
    ("compare", "compare_summary.json", {"counts": [1]}, "'counts' is not an object"),
    ("simulation", "compare_simulation.json", {"format": "something else"},
     "('format' is not trafficgeo-sumo-validation/1); run 'trafficgeo sumo-validate' again"),
    ("simulation", "compare_simulation.json", {"counts": 4.5}, "'counts' is not a whole number"),
    ("simulation", "compare_simulation.json", {"unobserved": [1]}, "'unobserved[0]' is not text"),
    ("simulation", "compare_simulation.json", {"target_met": "yes"}, "'target_met' is not true or false"),
]


@pytest.mark.parametrize(("kind", "name", "content", "said"), DAMAGED, ids=[d[3] for d in DAMAGED])
def test_a_damaged_or_foreign_file_is_refused_naming_it(kind: str, name: str, content, said: str,
                                                        tmp_path: Path) -> None:
    folder = tmp_path / "run"
    path = _written(folder, kind, WRITE[kind][3]())
    if isinstance(content, dict):  # a document of the right file with one part wrong (or another file's)
        doc = content if "format" in content else {**json.loads(path.read_text()), **content}
        text = json.dumps(doc)
    else:
        text = content
    path.write_text(text)
    publish_outputs(folder, [name], command=COMMAND.get(kind, "test"), name=WRITE[kind][1])  # the reader refuses
    with pytest.raises(InputError) as err:
        WRITE[kind][2](RunFolder(folder))
    message = str(err.value)
    assert message.startswith(str(path)) and said in message and "\n" not in message, message


def test_a_summary_without_its_interval_is_refused_by_the_observed_run_reader(tmp_path: Path) -> None:
    from trafficgeo.traffic.validation import read_observed_run

    folder = tmp_path / "run"
    with RunFolder(folder).writing("analyze") as run:
        run.summary(replace(_summary(), options={"pixel_sigma": 2.0}))
        for name in ("counts.csv", "crossings.csv"):
            (folder / name).write_text("line\n")
        run.adopt("counts.csv", "crossings.csv")
    with pytest.raises(InputError, match=r"summary\.json: no options\.interval_s"):
        read_observed_run(folder)


# ------------------------------------------------------------------------------------------------ real runs
@pytest.fixture(scope="module")
def reference_run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """An analysis of the API reference's tracks (tests/data/api-reference) written as a run folder."""
    spec = importlib.util.spec_from_file_location("make_reference", REF / "make_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    cam, surface, _table, lines = module.scene()
    result = tg.analyze_tracks(cam, surface, REF / "input_tracks.csv", lines=lines, interval_s=10.0)
    folder = tmp_path_factory.mktemp("records") / "run"
    write_analysis(folder, result, cam)
    return {"folder": folder, "result": result, "camera": cam, "line": lines[0]}


def test_an_analysis_summary_reads_back_typed(reference_run: dict) -> None:
    folder, result = reference_run["folder"], reference_run["result"]
    s = RunFolder(folder).summary()
    assert isinstance(s, RunSummary) and all(isinstance(c, LineCount) for c in s.crossings)
    assert s.to_dict() == json.loads((folder / "summary.json").read_text())
    assert s.vehicles == len(result.vehicles) and s.points == len(result.points)
    assert sum(c.count for c in s.crossings) == int(result.counts["count"].sum()) == 3
    assert s.period_s == tuple(float(t) for t in result.period) and s.interval_s == 10.0
    assert pyproj.CRS.from_wkt(s.crs) == pyproj.CRS.from_epsg(2240)
    assert RunFolder(folder).process() is None  # an analyze run has no process.json


def test_a_comparison_summary_reads_back_typed(reference_run: dict) -> None:
    """The run against its own trajectories as the simulation, at its line and a second one downstream."""
    from trafficgeo.traffic.validation import compare_with_simulation, read_observed_run, write_comparison

    folder = reference_run["folder"]
    observed = read_observed_run(folder)
    line = reference_run["line"]
    (x0, y0), (x1, y1) = line.geometry.coords
    along = np.array([y1 - y0, x0 - x1]) / math.hypot(x1 - x0, y1 - y0)
    second = tg.CountLine("second", shapely.affinity.translate(line.geometry, *(30.0 * along)), ())
    comparison = compare_with_simulation(observed, RunFolder(folder).trajectories(), lines=[line, second])
    write_comparison(folder, comparison, observed.crs)
    back = RunFolder(folder).compare_summary()
    assert isinstance(back, CompareSummary) and isinstance(back.counts, CountSummary)
    assert to_json_safe(back.to_dict()) == json.loads((folder / "compare_summary.json").read_text())
    assert back.counts.rows == len(comparison.counts) == 6
    assert back.counts.share_geh_below_5 == comparison.count_summary["share_geh_below_5"]
    tt = back.travel_times
    assert (tt.from_line, tt.to_line, tt.observed_n, tt.simulated_n) == ("across", "second", 0, 3)
    assert math.isnan(tt.observed_mean_s) and tt.simulated_mean_s > 0  # null in the file, NaN in memory
    assert back.crs.startswith("EPSG:2240")
    # its tables read back through the folder, text columns as text; no simulation record for a plain comparison
    run = RunFolder(folder)
    counts = run.comparison_table("compare_counts.csv")
    assert counts[["line", "lane", "direction", "observed", "simulated"]].astype(str).values.tolist() == \
        comparison.counts[["line", "lane", "direction", "observed", "simulated"]].astype(str).values.tolist()
    np.testing.assert_allclose(counts["geh"], comparison.counts["geh"], atol=1e-4)  # written with 4 decimals
    assert run.comparison.command == "compare-sumo" and run.simulation_record() is None
    with pytest.raises(InputError, match="not a table of a comparison"):
        run.comparison_table("counts.csv")


def test_a_simulation_record_joins_the_comparison_and_a_new_comparison_drops_it(reference_run: dict,
                                                                                 tmp_path: Path) -> None:
    import shutil

    from trafficgeo.traffic.validation import compare_with_simulation, read_observed_run, write_comparison

    folder = tmp_path / "run"
    shutil.copytree(reference_run["folder"], folder)
    observed = read_observed_run(folder)
    comparison = compare_with_simulation(observed, RunFolder(folder).trajectories(), lines=[reference_run["line"]])
    written = write_comparison(folder, comparison, observed.crs)
    assert RunFolder(folder).comparison_table("compare_speeds.csv") is not None
    assert RunFolder(folder).comparison.command == "compare-sumo"
    with_record = write_comparison(folder, comparison, observed.crs, simulation=_simulation())
    path = folder / SIMULATION_RECORD
    run = RunFolder(folder)
    assert run.comparison.command == "sumo-validate" and path in with_record
    assert set(run.comparison.files) == {p.name for p in written} | {path.name}
    assert run.simulation_record() == _simulation() and run.compare_summary() is not None
    assert json.loads(path.read_text())["build_s"] is None  # NaN in memory: null in the file
    write_comparison(folder, comparison, observed.crs)  # compare-sumo again: the record is no longer its part
    run = RunFolder(folder)
    assert run.comparison.command == "compare-sumo" and run.simulation_record() is None and path.is_file()
    (folder / COMPARE_MANIFEST).unlink()  # the tables left without their manifest are not read
    assert (folder / "compare_counts.csv").is_file()
    assert RunFolder(folder).comparison_table("compare_counts.csv") is None
    assert RunFolder(folder).simulation_record() is None and RunFolder(folder).compare_summary() is None


def test_process_json_of_the_pipeline_writer_reads_back_typed(tmp_path: Path) -> None:
    from trafficgeo.pipeline.run import run_info
    from trafficgeo.video.pipeline import ProcessOptions

    opts = ProcessOptions(detector="background", start_s=1.5, end_s=6.0, every=2)
    read = {"start_s": 1.5, "end_s": 5.0, "frames": 88, "complete": False}
    with RunFolder(tmp_path).writing("process") as run:
        run.process(run_info(video="clip.mp4", camera="camera.json", options=opts, seconds=3.25, detections=120,
                             track_rows=96, read=read, detector={"tiling": {"tiles": [], "warnings": ["far line"]}}))
    info = RunFolder(tmp_path).process()
    assert isinstance(info, ProcessRecord) and info.read == VideoRead(1.5, 5.0, 88, False)
    assert info.options == ProcessSettings("background", "auto", 1.5, 6.0, 2, True, "squares", "auto", "auto")
    assert (info.video, info.camera, info.seconds, info.detections, info.track_rows) == (
        "clip.mp4", "camera.json", 3.25, 120, 96)
    assert info.tiling == {"tiles": [], "warnings": ["far line"]}
    assert info.to_dict() == json.loads((tmp_path / "process.json").read_text())


def test_process_json_records_the_tracker_the_run_settled_on(tmp_path: Path) -> None:
    """A junction run (gates) and a road run track differently (video.pipeline.JUNCTION_TRACKER): process.json says
    which; a file written before the key reads as None."""
    from dataclasses import asdict

    from trafficgeo.pipeline.run import run_info
    from trafficgeo.video.pipeline import JUNCTION_TRACKER, LEARNED_TRACKER, ProcessOptions, settled_options

    read = {"start_s": 0.0, "end_s": 4.0, "frames": 100, "complete": True}
    seen = {}
    for junction in (True, False):
        opts = settled_options(ProcessOptions(), 25.0, junction=junction)
        folder = tmp_path / f"junction{junction}"
        with RunFolder(folder).writing("process") as run:
            run.process(run_info(video="clip.mp4", camera="camera.json", options=opts, seconds=1.0, detections=0,
                                 track_rows=0, read=read))
        seen[junction] = RunFolder(folder).process().options.tracker
        assert json.loads((folder / "process.json").read_text())["options"]["tracker"] == seen[junction]
    assert seen[True] == asdict(JUNCTION_TRACKER) and seen[True]["min_iou"] == 0.3
    assert seen[False] == asdict(LEARNED_TRACKER) and seen[False]["min_iou"] == 0.1
    doc = _process().to_dict()
    doc["options"].pop("tracker")
    assert ProcessRecord.from_dict(doc).options.tracker is None


def test_a_table_is_written_only_under_its_schema(reference_run: dict, tmp_path: Path) -> None:
    tracks = RunFolder(reference_run["folder"]).trajectories()
    folder = RunFolder(tmp_path / "run")
    with pytest.raises(InputError, match=r"tracks\.csv: columns \[.*'track_id'.*\] missing"):
        folder.write_table("tracks.csv", tracks[["frame", "time"]])
    with pytest.raises(ValueError, match="not a table of a run folder"):
        folder.write_table("notes.csv", tracks)
    assert not (tmp_path / "run" / "tracks.csv").exists()
    path = folder.write_table("trajectories.csv", tracks, float_format="%.6f")
    publish_outputs(folder.path, [path.name], command="test")
    back = RunFolder(folder.path).trajectories()
    assert back["track_id"].tolist() == tracks["track_id"].tolist()
    np.testing.assert_allclose(back["x"], tracks["x"], atol=1e-6)


def test_the_video_room_writes_its_two_tables_under_the_run_schema() -> None:
    """detections.csv and tracks.csv are written by video.pipeline as it finishes (ImageTracks.to_table for the
    tracks): their columns are the run folder's schema, in order."""
    from trafficgeo.run.folder import DETECTIONS, TRACKS
    from trafficgeo.run.tracks import TRACK_COLUMNS
    from trafficgeo.video.pipeline import DETECTION_COLUMNS

    assert DETECTION_COLUMNS == DETECTIONS.names and list(TRACK_COLUMNS) == TRACKS.names
