"""A run folder's outputs as one unit (manifest written last, checked by every reader), a full disk, an unwritable
``--out`` found before the work, range checks of numeric options, and stitching chunks in any order."""

from __future__ import annotations

import errno
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cli_support import invoke
from test_cli_traffic import FPS, Z0, scene  # noqa: F401  (scene is a fixture)
from trafficgeo.errors import InputError
from trafficgeo.io.run_manifest import MANIFEST, publish_outputs, verify_outputs


class Killed(BaseException):
    """Stands for SIGKILL in the middle of writing the outputs."""


def _analyze(scene: dict[str, Path], out: Path, *extra: object) -> tuple[int, str, str]:  # noqa: F811
    return invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0, "--lanes",
                  scene["lanes"], "--lines", scene["lines"], "--out", out, *extra)


def _page_text(path: Path) -> str:
    """An HTML report's text without its embedded images (base64 PNG data holds any three letters by chance: a
    changed figure once spelled "GEH")."""
    import re

    return re.sub(r"data:image/[a-z+]+;base64,[A-Za-z0-9+/=]+", "", path.read_text(encoding="utf-8"))


def _one_line(stderr: str) -> bool:
    return len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr


# ------------------------------------------------------------------------------------------------ manifest
@pytest.mark.slow
def test_a_killed_rerun_leaves_a_folder_every_reader_refuses(scene: dict[str, Path], tmp_path: Path,  # noqa: F811
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    run = tmp_path / "run"
    code, _, stderr = _analyze(scene, run, "--interval", 60)
    assert code == 0, stderr
    doc = json.loads((run / MANIFEST).read_text())
    assert doc["format"] == "trafficgeo-run/1" and doc["command"] == "analyze"
    assert {"vehicles.csv", "trajectories.csv", "summary.json", "trajectories.gpkg"} <= set(doc["files"])
    assert invoke("export-fcd", run, "-o", tmp_path / "a.fcd.xml")[0] == 0  # (report on it: test_report_html)
    old_vehicles = (run / "vehicles.csv").read_bytes()

    # a rerun on fewer tracks, killed after vehicles/counts/crossings.csv but before trajectories.csv
    fewer = tmp_path / "fewer.csv"
    tracks = pd.read_csv(scene["tracks"])
    tracks[tracks["track_id"] != 3].to_csv(fewer, index=False)

    def kill(*args: object, **kwargs: object) -> None:
        raise Killed

    monkeypatch.setattr("trafficgeo.io.tables.write_point_table", kill)
    with pytest.raises(Killed):
        invoke("analyze", scene["camera"], fewer, "--fps", FPS, "--surface", Z0, "--lines", scene["lines"],
               "--out", run)
    monkeypatch.undo()
    assert (run / "vehicles.csv").read_bytes() != old_vehicles  # the mix the readers must not trust
    for args in (("report", run, "-o", tmp_path / "b.html"), ("export-fcd", run, "-o", tmp_path / "b.fcd.xml"),
                 ("compare-sumo", run, tmp_path / "a.fcd.xml", "--out", tmp_path / "cmp")):
        code, _, stderr = invoke(*args)
        assert code == 2 and _one_line(stderr), (args[0], stderr)
        assert "outputs incomplete or from different runs" in stderr and "run the command" in stderr, stderr
    assert not (tmp_path / "b.html").exists() and not (tmp_path / "b.fcd.xml").exists()
    code, _, stderr = _analyze(scene, run)  # running it again repairs the folder
    assert code == 0, stderr
    assert invoke("export-fcd", run, "-o", tmp_path / "c.fcd.xml")[0] == 0


@pytest.mark.slow
def test_a_file_changed_after_the_run_or_a_legacy_folder_is_refused(scene: dict[str, Path],  # noqa: F811
                                                                    tmp_path: Path) -> None:
    run = tmp_path / "run"
    assert _analyze(scene, run)[0] == 0
    vehicles = pd.read_csv(run / "vehicles.csv")
    vehicles.iloc[:1].to_csv(run / "vehicles.csv", index=False)  # new vehicles.csv only, beside the old files
    code, _, stderr = invoke("report", run, "-o", tmp_path / "r.html")
    assert code == 2 and _one_line(stderr)
    assert "(vehicles.csv changed after the run)" in stderr
    (run / MANIFEST).unlink()  # as a folder written before manifests existed
    code, _, stderr = invoke("export-fcd", run, "-o", tmp_path / "x.fcd.xml")
    assert code == 2 and _one_line(stderr) and f"no {MANIFEST}" in stderr, stderr


@pytest.mark.slow
def test_compare_results_from_an_earlier_run_are_left_out_of_the_report(scene: dict[str, Path],  # noqa: F811
                                                                        tmp_path: Path) -> None:
    run = tmp_path / "run"
    assert _analyze(scene, run, "--interval", 2)[0] == 0
    assert invoke("export-fcd", run, "-o", tmp_path / "o.fcd.xml")[0] == 0
    assert invoke("compare-sumo", run, tmp_path / "o.fcd.xml")[0] == 0
    code, stdout, stderr = invoke("report", run, "-o", tmp_path / "a.html")
    assert code == 0, stderr
    assert "GEH" in _page_text(tmp_path / "a.html")
    assert _analyze(scene, run, "--interval", 3)[0] == 0  # a new run: the comparison is of the old one
    code, stdout, stderr = invoke("report", run, "-o", tmp_path / "b.html")
    assert code == 0, stderr
    assert "compare-sumo results incomplete or from an earlier run" in " ".join(stdout.split())
    assert "GEH" not in _page_text(tmp_path / "b.html")


def test_manifest_unit(tmp_path: Path) -> None:
    (tmp_path / "a.csv").write_text("x\n1\n")
    publish_outputs(tmp_path, ["a.csv"], command="test")
    assert verify_outputs(tmp_path, ["a.csv"]).has("a.csv")
    with pytest.raises(InputError, match=r"has no b\.csv"):
        verify_outputs(tmp_path, ["b.csv"])
    (tmp_path / "a.csv").write_text("x\n2\n")  # same size, other content
    with pytest.raises(InputError, match=r"a\.csv changed after the run"):
        verify_outputs(tmp_path)
    (tmp_path / MANIFEST).write_text("{not json")
    with pytest.raises(InputError, match="damaged"):
        verify_outputs(tmp_path)


# ------------------------------------------------------------------------------------------------ full disk
@pytest.mark.slow
def test_a_full_disk_while_writing_the_geopackage_is_one_line_exit_1(scene: dict[str, Path],  # noqa: F811
                                                                     tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from pyogrio.errors import DataSourceError

    def full(path: Path, *args: object, **kwargs: object) -> None:
        Path(path).write_bytes(b"\0" * 4096)  # GDAL had begun the file
        Path(str(path) + "-journal").write_bytes(b"\0" * 512)
        raise DataSourceError("Failed to commit transaction")

    run = tmp_path / "run"
    monkeypatch.setattr("trafficgeo.io.gis._write_gpkg_layer", full)
    code, _, stderr = _analyze(scene, run)
    assert code == 1 and _one_line(stderr), stderr
    assert "could not write" in stderr and "trajectories.gpkg" in stderr and "Failed to commit transaction" in stderr
    assert "free space" in stderr
    # no temporary file left (the folder's lock file stays, unlocked, as process's does)
    assert sorted(p.name for p in run.iterdir() if p.name.startswith(".")) == [".lock"]
    assert not (run / "trajectories.gpkg").exists() and not (run / MANIFEST).exists()
    monkeypatch.undo()
    code, _, stderr = _analyze(scene, run)  # room to retry
    assert code == 0, stderr
    verify_outputs(run, ["trajectories.gpkg"])


def test_a_full_disk_while_writing_a_table_is_one_line_exit_1(scene: dict[str, Path], tmp_path: Path,  # noqa: F811
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    def full(self: pd.DataFrame, path: Path, *args: object, **kwargs: object) -> None:
        Path(path).write_text("track_id,x\n1,")
        raise OSError(errno.ENOSPC, "No space left on device")

    run = tmp_path / "run"
    monkeypatch.setattr(pd.DataFrame, "to_csv", full)
    code, _, stderr = _analyze(scene, run)
    assert code == 1 and _one_line(stderr), stderr
    assert "could not write" in stderr and "No space left on device" in stderr
    assert not run.exists()  # the folder the run made is gone with its lock: nothing half-written


# ------------------------------------------------------------------------------------------------ --out checked first
@pytest.mark.parametrize("command", ["analyze", "process", "stitch", "compare-sumo"])
def test_an_unwritable_out_is_found_before_any_work(command: str, scene: dict[str, Path],  # noqa: F811
                                                    tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    out = blocker / "run"  # its parent is a file: even root cannot make it

    def no_work(*args: object, **kwargs: object) -> None:
        raise AssertionError("the work started before --out was checked")

    # the modules that bind these names at import are patched first (and so restored to the real functions):
    # otherwise the first import, made while patched, would keep the stand-in for the rest of the session
    for target in ("trafficgeo.pipeline.run.analyze", "trafficgeo.traffic.analyze.analyze",
                   "trafficgeo.traffic.tracks.read_tracks",
                   "trafficgeo.video.pipeline.detect_and_track", "trafficgeo.traffic.validation.read_observed_run"):
        monkeypatch.setattr(target, no_work)
    common = ["--camera", scene["camera"], "--surface", Z0]
    args = {"analyze": ["analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0],
            "process": ["process", tmp_path / "video.mp4", *common],
            "stitch": ["stitch", tmp_path, *common],
            "compare-sumo": ["compare-sumo", tmp_path, tmp_path / "x.fcd.xml"]}[command]
    code, _, stderr = invoke(*args, "--out", out)
    assert code == 2 and _one_line(stderr), stderr
    assert f"--out {out}" in stderr and "is a file" in stderr


@pytest.mark.parametrize("command", ["export-fcd", "report", "synth", "demo"])
def test_output_paths_under_a_file_are_found_before_any_work(command: str, tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    args = {"export-fcd": ["export-fcd", tmp_path, "-o", blocker / "o.fcd.xml"],
            "report": ["report", tmp_path, "-o", blocker / "r.html"],
            "synth": ["synth", "--out", blocker / "world"],
            "demo": ["demo", "--out", blocker / "demo"]}[command]
    code, _, stderr = invoke(*args)
    assert code == 2 and _one_line(stderr), stderr
    assert f"{blocker} is a file" in stderr


def test_a_folder_that_cannot_take_a_file_is_found_first(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from trafficgeo.io.run_manifest import check_writable_folder

    def refuse(*args: object, **kwargs: object) -> None:
        raise PermissionError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr("tempfile.mkstemp", refuse)
    with pytest.raises(InputError, match=r"cannot write in .*Read-only file system"):
        check_writable_folder(tmp_path / "new" / "run")
    assert not (tmp_path / "new").exists()


# ------------------------------------------------------------------------------------------------ ranges
@pytest.mark.parametrize(("extra", "expect"), [
    (["--interval", 0.5], "--interval 0.5: the counting interval"),
    (["--interval", 1e-7], "--interval 1e-07: the counting interval"),
    (["--interval", "inf"], "--interval inf: the counting"),
    (["--fps", 1e-300], "--fps 1e-300 is not a video frame rate"),
    (["--fps", 5000], "--fps 5000 is not a video frame rate"),
    (["--coast-hidden", 1e9], "trajectory option --coast-hidden=1e+09 is more than 30 s"),
    (["--pixel-sigma", "inf"], "trajectory option --pixel-sigma=inf must be a finite number"),
    (["--resolution", "inf"], "--resolution inf: must be a positive cell size"),
])
def test_numeric_options_out_of_range_are_one_line_errors(extra: list, expect: str,
                                                          scene: dict[str, Path], tmp_path: Path) -> None:  # noqa: F811
    out = tmp_path / "out"
    args = ["analyze", scene["camera"], scene["tracks"], "--surface", Z0, "--out", out]
    code, _, stderr = invoke(*args, *(["--fps", FPS] if "--fps" not in extra else []), *extra)
    assert code == 2 and _one_line(stderr), stderr
    assert expect in stderr
    assert not out.exists()


def test_range_checks_in_the_library(scene: dict[str, Path]) -> None:  # noqa: F811
    from trafficgeo.traffic.counts import check_interval, interval_edges
    from trafficgeo.traffic.tracks import read_tracks

    with pytest.raises(InputError, match="at least 1"):
        interval_edges(0.0, 6.0, 1e-7)
    assert check_interval(60) == 60.0
    with pytest.raises(InputError, match=r"^fps 1e-300 is not a video frame rate") as info:
        read_tracks(scene["tracks"], fps=1e-300)
    assert info.value.parameters == ("fps",)
    assert read_tracks(scene["tracks"], fps=0.1).time.max() > 100  # a time-lapse camera's rate is fine


@pytest.mark.slow
def test_compare_sumo_time_offset_must_be_finite(scene: dict[str, Path], tmp_path: Path) -> None:  # noqa: F811
    run = tmp_path / "run"
    assert _analyze(scene, run)[0] == 0
    assert invoke("export-fcd", run, "-o", tmp_path / "o.fcd.xml")[0] == 0
    code, _, stderr = invoke("compare-sumo", run, tmp_path / "o.fcd.xml", "--time-offset", "nan")
    assert code == 2 and _one_line(stderr) and "--time-offset nan" in stderr, stderr


# ------------------------------------------------------------------------------------------------ NaN in messages
def test_nan_in_messages_is_a_plain_number(tmp_path: Path) -> None:
    import shapely

    from trafficgeo.io.fcd_write import write_fcd
    from trafficgeo.io.gis import Layer, write_gis

    layer = Layer("p", [shapely.Point(500000.0, 5000001.0), shapely.Point(np.nan, 5000000.0)], {})
    with pytest.raises(InputError) as err:
        write_gis(tmp_path / "p.gpkg", [layer], "EPSG:32633")
    assert "x=nan, y=5e+06" in str(err.value) and "np." not in str(err.value)
    pts = pd.DataFrame({"track_id": ["1"], "time": [np.nan], "x": [1.0], "y": [2.0], "speed_kmh": [50.0],
                        "heading_deg": [0.0]})
    with pytest.raises(InputError) as err:
        write_fcd(tmp_path / "a.xml", pts, crs="EPSG:32633")
    assert "time = nan is not a finite number" in str(err.value) and "np." not in str(err.value)


# ------------------------------------------------------------------------------------------------ stitch
def _chunk(folder: Path, tracks: pd.DataFrame, lo: float, hi: float, prefix: str) -> Path:
    """A finished 'process' run's folder holding the tracks seen from ``lo`` to ``hi`` s (ids renamed)."""
    folder.mkdir(parents=True)
    part = tracks[(tracks["time"] >= lo) & (tracks["time"] <= hi)].copy()
    part["track_id"] = [f"{prefix}{i}" for i in part["track_id"]]
    part.to_csv(folder / "tracks.csv", index=False)
    (folder / "process.json").write_text(json.dumps({"video": "/data/video.mp4", "camera": "camera.json",
                                                      "options": {"start_s": lo, "end_s": hi}}))
    publish_outputs(folder, ["tracks.csv", "process.json"], command="process")
    return folder


@pytest.fixture
def chunks(scene: dict[str, Path], tmp_path: Path) -> dict[str, Path]:  # noqa: F811
    tracks = pd.read_csv(scene["tracks"])
    tracks["time"] = tracks["frame"] / FPS
    tracks["score"] = 1.0
    return {"a": _chunk(tmp_path / "a", tracks, 0.0, 3.5, "a"), "b": _chunk(tmp_path / "b", tracks, 2.5, 6.0, "b"),
            "inner": _chunk(tmp_path / "inner", tracks, 1.0, 2.0, "i"),
            "late": _chunk(tmp_path / "late", tracks, 4.0, 6.0, "l")}


def _stitch(scene: dict[str, Path], out: Path, *folders: Path) -> tuple[int, str, str]:  # noqa: F811
    return invoke("stitch", *folders, "--camera", scene["camera"], "--surface", Z0, "--lines", scene["lines"],
                  "--out", out)


@pytest.mark.slow
def test_stitch_in_any_order_gives_the_same_crossings(scene: dict[str, Path], chunks: dict[str, Path],  # noqa: F811
                                                      tmp_path: Path) -> None:
    for name, order in (("ab", ("a", "b")), ("ba", ("b", "a"))):
        code, _, stderr = _stitch(scene, tmp_path / name, *(chunks[k] for k in order))
        assert code == 0, stderr
    ab = pd.read_csv(tmp_path / "ab" / "crossings.csv")
    ba = pd.read_csv(tmp_path / "ba" / "crossings.csv")
    assert len(ab) == 3 == len(ba)  # every vehicle of the scene crosses the line once
    pd.testing.assert_frame_equal(ab, ba)
    verify_outputs(tmp_path / "ab", ["tracks.csv", "crossings.csv"])


@pytest.mark.parametrize(("case", "expect"), [
    ("twice", "given twice"),
    ("copy", "are the same chunk (video.mp4, 0 s to 3.5 s)"),
    ("inside", "lies inside"),
    ("unfinished", "outputs incomplete or from different runs"),
    ("not_process", "has no tracks.csv"),
    ("other_video", "is of video.mp4 but"),
])
def test_stitch_refuses_chunks_that_would_count_twice(case: str, expect: str, scene: dict[str, Path],  # noqa: F811
                                                      chunks: dict[str, Path], tmp_path: Path) -> None:
    a = chunks["a"]
    if case == "twice":
        folders = [a, chunks["b"], tmp_path / "." / "a"]
    elif case == "copy":
        shutil.copytree(a, tmp_path / "copy")
        folders = [a, tmp_path / "copy"]
    elif case == "inside":
        folders = [chunks["inner"], a, chunks["b"]]
    elif case == "other_video":
        info = json.loads((chunks["b"] / "process.json").read_text())
        (chunks["b"] / "process.json").write_text(json.dumps({**info, "video": "/data/other.mp4"}))
        publish_outputs(chunks["b"], ["tracks.csv", "process.json"], command="process")
        folders = [a, chunks["b"]]
    elif case == "unfinished":
        (chunks["b"] / MANIFEST).unlink()
        folders = [a, chunks["b"]]
    else:
        (tmp_path / "other").mkdir()
        (tmp_path / "other" / "x.csv").write_text("x\n")
        publish_outputs(tmp_path / "other", ["x.csv"], command="analyze")
        folders = [a, tmp_path / "other"]
    out = tmp_path / "out"
    code, _, stderr = _stitch(scene, out, *folders)
    assert code == 2 and _one_line(stderr), stderr
    assert expect in stderr
    assert not out.exists()


@pytest.mark.slow
def test_stitch_warns_about_a_gap(scene: dict[str, Path], chunks: dict[str, Path], tmp_path: Path) -> None:  # noqa: F811
    from trafficgeo.video.stitch import plan_chunks

    code, stdout, stderr = _stitch(scene, tmp_path / "out", chunks["late"], chunks["a"])
    assert code == 0, stderr
    words = " ".join(stdout.split())
    assert "ends at 3.5 s but" in words and "starts at 4 s" in words and "vehicles passing in between" in words
    order, warnings = plan_chunks([(10.0, 20.0), (0.0, 11.0), (19.0, 30.0)])
    assert order == [1, 0, 2] and warnings == []


def test_stitch_tracks_sorts_tables_by_time() -> None:
    from trafficgeo.video.stitch import stitch_tracks

    def table(t0: float, ids: list[int]) -> pd.DataFrame:
        t = np.arange(t0, t0 + 4.0, 0.5)
        rows = [{"frame": round(ti * 2), "time": ti, "track_id": i, "x1": 100.0 * i, "y1": 0.0, "x2": 100.0 * i + 50,
                 "y2": 50.0, "score": 1.0, "class": "car"} for ti in t for i in ids]
        return pd.DataFrame(rows)

    early, late = table(0.0, [1, 2]), table(3.0, [7, 8])  # ids 7/8 share boxes... none with 1/2: new vehicles
    forward = stitch_tracks([early, late])
    backward = stitch_tracks([late, early])
    assert len(forward) == len(backward) == len(early[early["time"] < 3.25]) + len(late[late["time"] >= 3.25])
    assert sorted(backward["time"]) == sorted(forward["time"])
    with pytest.raises(InputError, match="same chunk"):
        stitch_tracks([early, early])


def test_tables_written_before_a_column_joined_still_read(tmp_path: Path) -> None:
    # vehicles.csv gained travel_speed_kmh and counts.csv observed_s (issue 29): run folders written before read on,
    # the new column empty; a column that was always there is still required
    from trafficgeo.run.folder import COUNTS, VEHICLES

    ref = Path(__file__).parent / "data" / "api-reference"
    for schema, column in ((VEHICLES, "travel_speed_kmh"), (COUNTS, "observed_s")):
        now = schema.read(ref / schema.file)
        old = tmp_path / schema.file
        now.drop(columns=column).to_csv(old, index=False)
        back = schema.read(old)
        assert list(back.columns) == list(now.columns) and back[column].isna().all()
        pd.testing.assert_frame_equal(back.drop(columns=column), now.drop(columns=column))
        now.drop(columns="count" if schema is COUNTS else "speed_kmh").to_csv(old, index=False)
        with pytest.raises(InputError, match=r"no column (count|speed_kmh);"):
            schema.read(old)
