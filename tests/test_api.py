"""The Python API: the curated top-level namespace, the docstring example of every entry point run on a small
generated world, the loaders taking paths or objects alike, and RunFolder reading back what the API wrote."""

from __future__ import annotations

import doctest
import importlib
import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj
import pytest

import trafficgeo as tg
from reference_values import TRAFFIC, assert_csv_close


@pytest.fixture(scope="module")
def world(small_world: Path) -> Path:
    """The shared small generated world (tests/conftest.py; read only)."""
    return small_world


def test_namespace_is_curated_lazy_and_complete() -> None:
    code = "import sys, trafficgeo as tg; print(sorted(m for m in sys.modules if m.startswith('trafficgeo.')))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert eval(loaded) == ["trafficgeo.errors", "trafficgeo.version"]  # nothing heavy on import
    assert set(tg.__all__) == set(tg._API) | {"CalibrationError", "InputError", "OutputError", "TrafficgeoError",
                                              "__version__"}
    for name, module in tg._API.items():
        assert getattr(tg, name) is getattr(importlib.import_module(module), name), name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        tg.nope  # noqa: B018
    for name in ("georeference", "analyze_tracks", "process_video", "compare_with_sumo", "stitch", "export_fcd",
                 "load_camera", "load_surface", "RunFolder"):
        assert getattr(tg, name).__doc__, name


def _run_examples(func: object, globs: dict) -> None:
    tests = doctest.DocTestFinder(recurse=False).find(func, globs=globs)
    assert tests and tests[0].examples, f"{func.__name__} has no example"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for t in tests:
        runner.run(t)
    assert runner.failures == 0, f"the example of {func.__name__} failed (see the output above)"


@pytest.mark.slow
def test_every_entry_point_example_runs(world: Path, tmp_path: Path) -> None:
    globs = {"world": world, "out": tmp_path}
    for func in (tg.georeference, tg.analyze_tracks, tg.process_video, tg.compare_with_sumo):  # in this order
        _run_examples(func, dict(globs))


@pytest.mark.slow
def test_loaders_take_paths_or_objects_and_give_the_same_analysis(world: Path) -> None:
    cam = tg.load_camera(world / "camera_truth.json")
    assert tg.load_camera(cam) is cam
    surf = tg.load_surface(world / "cloud.laz", world / "camera_truth.json")
    assert tg.load_surface(surf, cam) is surf
    flat = tg.load_surface(90.0, cam)
    assert float(flat.elevation(np.array([0.0]), np.array([0.0]))[0]) == 90.0
    lanes = tg.load_lanes(world / "lanes.gpkg", cam, surf)
    lines = tg.load_lines(world / "count_lines.gpkg", cam, surf)
    assert tg.load_lanes(lanes, cam) is lanes and tg.load_lines(lines, cam) == lines
    boxes = pd.read_csv(world / "truth_tracks.csv").dropna(subset=["x1"]).rename(columns={"vehicle": "track_id"})
    table = boxes[["frame", "time", "track_id", "x1", "y1", "x2", "y2", "class"]]
    by_path = tg.analyze_tracks(world / "camera_truth.json", world / "cloud.laz", table,
                                lanes=world / "lanes.gpkg", lines=world / "count_lines.gpkg")
    by_object = tg.analyze_tracks(cam, surf, tg.load_tracks(table), lanes=lanes, lines=lines)
    pd.testing.assert_frame_equal(by_path.counts, by_object.counts)
    pd.testing.assert_frame_equal(by_path.vehicles, by_object.vehicles)
    # truth: every true vehicle that crossed the line in the period is counted (ideal boxes)
    truth = pd.read_csv(world / "truth_counts.csv")
    assert int(by_path.counts["count"].sum()) == pytest.approx(len(truth), abs=1)
    with pytest.raises(tg.InputError, match="surface 'plane'"):
        tg.load_surface("plane", cam.camera)  # the GCP plane needs the camera JSON's GCPs: a bare camera has none
    with pytest.raises(tg.InputError, match="surface plane needs the GCPs"):
        tg.load_surface("plane", cam)  # this one has none kept as inliers
    with pytest.raises(tg.InputError, match="tracks: list"):
        tg.load_tracks([1, 2])


@pytest.mark.slow
def test_run_folder_reads_back_what_was_written_with_the_schema(world: Path, tmp_path: Path) -> None:
    boxes = pd.read_csv(world / "truth_tracks.csv").dropna(subset=["x1"]).rename(columns={"vehicle": "track_id"})
    result = tg.analyze_tracks(world / "camera_truth.json", world / "cloud.laz",
                               boxes[["frame", "time", "track_id", "x1", "y1", "x2", "y2", "class"]],
                               lanes=world / "lanes.gpkg", lines=world / "count_lines.gpkg")
    run = tg.RunFolder(tmp_path / "run")
    tg.write_analysis(run.path, result, tg.load_camera(world / "camera_truth.json"))
    for name, table in (("vehicles.csv", result.vehicles), ("crossings.csv", result.crossings),
                        ("counts.csv", result.counts), ("trajectories.csv", result.points)):
        schema = tg.SCHEMAS[name]
        schema.check(table)  # what analyze computes follows the schema: no column missing or unknown
        back = run.table(name)
        assert list(back.columns) == list(table.columns)
        for col in back.columns:
            kind = schema.column(col).dtype
            if kind == "str":
                assert back[col].tolist() == table[col].fillna("").astype(str).tolist(), col
            elif kind == "float":
                np.testing.assert_allclose(back[col].to_numpy(float), table[col].to_numpy(float), rtol=1e-3,
                                           atol=1e-3 if col not in ("lon", "lat") else 1e-8, err_msg=col)
            else:
                assert back[col].tolist() == table[col].tolist(), col
    assert run.summary().vehicles == len(result.vehicles) and run.process() is None
    (tmp_path / "run" / "counts.csv").write_text("changed")
    with pytest.raises(tg.InputError, match=r"counts\.csv"):
        tg.RunFolder(tmp_path / "run").counts()  # the manifest catches a changed output
    with pytest.raises(tg.InputError, match="not a table"):
        run.table("nope.csv")


def test_library_errors_name_parameters_and_the_cli_names_flags(tmp_path: Path, capsys) -> None:
    from trafficgeo.cli import FLAGS, main

    with pytest.raises(tg.InputError, match=r"^start_s 5.0 / end_s 2.0: need 0 <= start_s < end_s") as info:
        tg.ProcessOptions(start_s=5.0, end_s=2.0)
    assert info.value.parameters == ("start_s", "end_s")
    assert info.value.in_terms_of(FLAGS).startswith("--start 5.0 / --end 2.0: need 0 <= --start < --end")
    # a plain word is renamed only where it opens the message (elsewhere it may be prose)
    prose = tg.InputError("lines x.csv: counting lines must be single lines", parameters=("lines",))
    assert prose.in_terms_of(FLAGS) == "--lines x.csv: counting lines must be single lines"
    with pytest.raises(tg.InputError, match=r"^lanes .*nope\.gpkg: file not found") as info:
        tg.load_lanes(tmp_path / "nope.gpkg", tg.Camera.from_orientation((64, 48), 50.0, [0, 0, 5], 0.0, 10.0))
    assert info.value.in_terms_of(FLAGS).startswith("--lanes ")
    with pytest.raises(tg.InputError, match=r"^every 0: must be a whole number"):
        tg.ProcessOptions(every=0)
    video = tmp_path / "v.mp4"
    video.write_bytes(b"")
    with pytest.raises(SystemExit) as done:
        main(["process", str(video), "--camera", "c.json", "--surface", "0", "--out", str(tmp_path / "o"),
              "--start", "5", "--end", "2"])
    assert done.value.code == 2
    assert "error: --start 5.0 / --end 2.0: need 0 <= --start < --end" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.reference
def test_analyze_outputs_equal_those_of_the_release_before_the_api(tmp_path: Path) -> None:
    # tests/data/api-reference: outputs written by the code before the Python API (see its SOURCE.txt; vehicles,
    # counts and summary written again for issue 29's deliberate changes), from the same deterministic input; the API
    # and RunFolder must give the same values.
    import importlib.util

    ref = Path(__file__).parent / "data" / "api-reference"
    spec = importlib.util.spec_from_file_location("make_reference", ref / "make_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    cam, surface, _table, lines = module.scene()
    with pytest.warns(UserWarning, match="a bare Camera"):  # the reference scene's camera is made by hand
        result = tg.analyze_tracks(cam, surface, ref / "input_tracks.csv", lines=lines, interval_s=10.0)
    run = tg.RunFolder(tmp_path / "run")
    tg.write_analysis(run.path, result, cam)
    for name in ("vehicles.csv", "crossings.csv", "counts.csv", "trajectories.csv"):  # by value: reference_values.py
        assert_csv_close(tmp_path / "run" / name, ref / name, name, TRAFFIC)
    assert len(result.vehicles) == 10 and len(result.crossings) == 3
    old_summary = json.loads((ref / "summary.json").read_text())
    new_summary = run.summary().to_dict()  # the typed record writes what the file holds
    assert new_summary == json.loads((tmp_path / "run" / "summary.json").read_text())
    for key in ("period_s", "vehicles", "points", "dropped_points", "options", "classes", "crossings"):
        assert new_summary[key] == old_summary[key], key
    assert pyproj.CRS.from_wkt(new_summary["crs"]) == pyproj.CRS.from_wkt(old_summary["crs"])


@pytest.mark.slow
def test_the_loaded_camera_carries_its_calibration_to_the_speeds_and_a_bare_one_says_so(world: Path,
                                                                                       tmp_path: Path) -> None:
    """The README's API example: ``tg.load_camera`` gives the CalibratedCamera, whose covariance and GCPs place the
    headline speeds; the bare projection (``.camera``) is accepted and the result says what it lacks."""
    from trafficgeo.traffic.analyze import BARE_CAMERA_WARNING

    truth = tg.load_camera(world / "camera_truth.json").camera
    cal = tg.calibrate(tg.read_gcps(world / "gcps.csv", crs=truth.crs), truth.image_size)
    cal.calibrated_camera().write(tmp_path / "camera.json")  # as `trafficgeo calibrate` writes it
    camera = tg.load_camera(tmp_path / "camera.json")
    assert isinstance(camera, tg.CalibratedCamera) and camera.covariance is not None
    boxes = pd.read_csv(world / "truth_tracks.csv").dropna(subset=["x1"]).rename(columns={"vehicle": "track_id"})
    table = boxes[["frame", "time", "track_id", "x1", "y1", "x2", "y2", "class"]]
    surface = tg.load_surface(world / "cloud.laz", camera)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning for the calibrated camera
        known = tg.analyze_tracks(camera, surface, table, lanes=world / "lanes.gpkg",
                                  lines=world / "count_lines.gpkg")
    assert known.options["speed_scale_knowledge"] == "covariance+gcps"
    with pytest.warns(UserWarning, match="a bare Camera carries no record of its calibration") as said:
        bare = tg.analyze_tracks(camera.camera, surface, table, lanes=world / "lanes.gpkg",
                                 lines=world / "count_lines.gpkg")
    assert str(said[0].message) == BARE_CAMERA_WARNING and said[0].filename == __file__  # names the caller's line
    assert bare.options["speed_scale_knowledge"] == "none"
    # the projection-only functions take either
    pixel = [[960.0, 700.0]]
    np.testing.assert_allclose(tg.georeference(camera, pixel, surface).xyz,
                               tg.georeference(camera.camera, pixel, surface).xyz)
