"""Tests of the command line (trafficgeo.cli): exit codes, messages, the files written and what they contain.

Most tests call ``trafficgeo.cli.main(argv)`` in-process (fast); one test runs the installed console script.
Exit codes: 0 success, 1 the calibration ran but gave no trustworthy camera, 2 bad input (one line on stderr, no
traceback, nothing written).
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import re
import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from cli_support import invoke
from trafficgeo import cli
from trafficgeo.camera import read_camera_json
from trafficgeo.camera.opencv_yaml import Intrinsics, read_intrinsics_yaml, write_intrinsics_yaml
from trafficgeo.synth import make_gcp_scene

DATA = Path(__file__).parent / "data"
PAPER = DATA / "paper_table2_gcps.csv"
PAPER_SIZE = "848x464"
I24 = DATA / "i24-camera-gcps" / "camera_calibration_points_I24_validation_system.csv"
I24_SIZE = "3840x2160"
BOARDS = sorted((DATA / "opencv-chessboard").glob("left*.jpg"))
SCENE_SEED = 3
SCENE_SIZE = (1920, 1080)
SCENE_SIZE_TEXT = "1920x1080"
CAMERA_KEYS = ("format", "image_size", "K", "dist", "R", "position", "crs", "orientation", "rvec", "tvec", "gcps",
               "stats")
GCP_KEYS = ("id", "role", "x", "y", "z", "u", "v", "u_proj", "v_proj", "error_px", "inlier", "loo_error_px")
STATS_KEYS = ("n_control", "n_inliers", "mean_px", "rmse_px", "loo_rmse_px")


# ------------------------------------------------------------------------------------------------ helpers




def read_json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def calibrate_args(gcps: Path, out: Path, size: str = SCENE_SIZE_TEXT, *extra: object,
                   report: Path | None = None) -> list[object]:
    args: list[object] = ["calibrate", gcps, "--image-size", size, "-o", out]
    if report is not None:
        args += ["--report", report]
    return args + list(extra)


def files_under(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


@contextlib.contextmanager
def umask(mask: int) -> Iterator[None]:
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def i24_camera_csv(folder: Path, camera: str) -> Path:
    """One I-24 camera's GCPs as id,x,y,z,u,v with x = longitude, y = latitude, z = 0 (read with EPSG:4326)."""
    with open(I24, newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh) if r["Camera"].strip() == camera]
    assert len(rows) == 4, camera
    path = folder / f"i24_{camera}.csv"
    lines = ["id,x,y,z,u,v"]
    lines += [f"{camera}_{k},{r['GPS Long']},{r['GPS Lat']},0,{r['Camera X']},{r['Camera Y']}"
              for k, r in enumerate(rows)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def edit_csv(src: Path, dst: Path, edit: Callable[[list[list[str]]], list[list[str]]]) -> Path:
    with open(src, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    with open(dst, "w", newline="", encoding="utf-8") as fh:
        csv.writer(fh, lineterminator="\n").writerows(edit(rows))
    return dst


# ------------------------------------------------------------------------------------------------ fixtures


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("scene")


@pytest.fixture(scope="module")
def scene(scene_dir: Path):
    sc = make_gcp_scene(SCENE_SEED, image_size=SCENE_SIZE, n_control=12, n_check=4, n_outliers=1)
    sc.gcps.to_csv(scene_dir / "gcps.csv")
    return sc


@pytest.fixture(scope="module")
def scene_csv(scene, scene_dir: Path) -> Path:
    return scene_dir / "gcps.csv"


@pytest.fixture(scope="module")
def calibrated(scene_csv: Path, scene_dir: Path) -> tuple[int, str, str, Path, Path]:
    """One successful calibration of the synthetic scene, shared by several tests."""
    out, report = scene_dir / "out" / "camera.json", scene_dir / "out" / "report.json"
    with umask(0o022):
        code, stdout, stderr = invoke(*calibrate_args(scene_csv, out, SCENE_SIZE_TEXT, "--crs", "EPSG:2949",
                                                      report=report))
    return code, stdout, stderr, out, report


@pytest.fixture(scope="module")
def board_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Intrinsics from the 13 OpenCV sample chessboard images (640x480), via ``trafficgeo intrinsics``."""
    path = tmp_path_factory.mktemp("board") / "left.yml"
    code, stdout, stderr = invoke("intrinsics", *BOARDS, "--pattern", "9x6", "--square", "0.025", "-o", path)
    assert code == 0, stderr
    assert "Traceback" not in stderr
    assert f"wrote {path}" in stdout.replace("\n", "")
    return path


# ------------------------------------------------------------------------------------------------ 1. calibrate


def test_calibrate_synthetic_scene_writes_camera_and_report(calibrated) -> None:
    code, stdout, stderr, out, report = calibrated
    assert code == 0, stderr
    assert "Traceback" not in stderr
    assert out.is_file() and report.is_file()
    assert "wrote" in stdout

    doc = read_json(out)
    for key in CAMERA_KEYS:
        assert key in doc, key
    assert doc["format"] == "trafficgeo.camera/1"
    assert doc["image_size"] == list(SCENE_SIZE)
    assert np.asarray(doc["K"]).shape == (3, 3)
    assert np.asarray(doc["dist"]).shape == (5,)
    assert np.asarray(doc["R"]).shape == (3, 3)
    assert np.allclose(np.asarray(doc["R"]) @ np.asarray(doc["R"]).T, np.eye(3), atol=1e-9)
    assert np.asarray(doc["position"]).shape == (3,)
    assert "2949" in str(doc["crs"])
    assert set(doc["orientation"]) >= {"heading_deg", "tilt_deg", "roll_deg"}
    assert np.asarray(doc["rvec"]).size == 3 and np.asarray(doc["tvec"]).size == 3
    assert isinstance(doc["gcps"], list) and len(doc["gcps"]) == 16
    for rec in doc["gcps"]:
        assert isinstance(rec, dict)
        for key in GCP_KEYS:
            assert key in rec, (rec.get("id"), key)
        assert rec["role"] in ("control", "check")
        assert isinstance(rec["inlier"], bool)
    for key in STATS_KEYS:
        assert key in doc["stats"], key
    assert doc["stats"]["n_control"] == 12
    assert 0 < doc["stats"]["mean_px"] <= doc["stats"]["rmse_px"] <= doc["stats"]["loo_rmse_px"]

    rep = read_json(report)
    for key in ("gcps", "warnings", "recommendations"):
        assert key in rep, key
    assert isinstance(rep["warnings"], list) and isinstance(rep["recommendations"], list)
    assert [g["id"] for g in rep["gcps"]] == [g["id"] for g in doc["gcps"]]


def test_saved_camera_reproduces_u_proj_and_error(calibrated) -> None:
    _code, _stdout, _stderr, out, _report = calibrated
    doc = read_json(out)
    cam = read_camera_json(out)
    world = np.array([[g["x"], g["y"], g["z"]] for g in doc["gcps"]])
    observed = np.array([[g["u"], g["v"]] for g in doc["gcps"]])
    stored = np.array([[g["u_proj"], g["v_proj"]] for g in doc["gcps"]])
    projected = cam.project(world)
    np.testing.assert_allclose(projected, stored, rtol=0, atol=1e-6)
    error = np.hypot(*(stored - observed).T)
    np.testing.assert_allclose([g["error_px"] for g in doc["gcps"]], error, rtol=0, atol=1e-6)


def test_planted_outlier_is_not_an_inlier(calibrated, scene) -> None:
    _code, _stdout, _stderr, out, _report = calibrated
    doc = read_json(out)
    planted = {scene.gcps.ids[i] for i in np.flatnonzero(scene.outlier)}
    assert len(planted) == 1
    by_id = {g["id"]: g for g in doc["gcps"]}
    for gcp_id in planted:
        assert by_id[gcp_id]["inlier"] is False
    rejected = {g["id"] for g in doc["gcps"] if g["role"] == "control" and not g["inlier"]}
    assert rejected == planted
    assert doc["stats"]["n_inliers"] == doc["stats"]["n_control"] - 1


def test_calibrate_quiet_prints_only_the_summary(scene_csv: Path, tmp_path: Path) -> None:
    out = tmp_path / "camera.json"
    code, stdout, stderr = invoke(*calibrate_args(scene_csv, out, SCENE_SIZE_TEXT, "--crs", "EPSG:2949", "-q"))
    assert code == 0, stderr
    assert out.is_file()
    assert "GCP residuals" not in stdout  # the full table is not printed
    assert "Expect about" in stdout


# ------------------------------------------------------------------------------------------------ 2. bad input


def _bad_cases() -> dict[str, Callable[[Path, Path], list[object]]]:
    """name -> builder(tmp_path, scene_csv) of the argument list (without -o / --report)."""

    def scene(size: str = SCENE_SIZE_TEXT, *extra: object) -> Callable[[Path, Path], list[object]]:
        return lambda tmp, csv_path: ["calibrate", csv_path, "--image-size", size, "--crs", "EPSG:2949", *extra]

    def missing_file(tmp: Path, csv_path: Path) -> list[object]:
        return ["calibrate", tmp / "no-such-file.csv", "--image-size", SCENE_SIZE_TEXT]

    def missing_column(tmp: Path, csv_path: Path) -> list[object]:
        def drop_v(rows: list[list[str]]) -> list[list[str]]:
            k = rows[0].index("v")
            return [r[:k] + r[k + 1:] for r in rows]

        return ["calibrate", edit_csv(csv_path, tmp / "no_v.csv", drop_v), "--image-size", SCENE_SIZE_TEXT]

    def non_numeric(tmp: Path, csv_path: Path) -> list[object]:
        def spoil(rows: list[list[str]]) -> list[list[str]]:
            rows[3][rows[0].index("u")] = "abc"
            return rows

        return ["calibrate", edit_csv(csv_path, tmp / "abc.csv", spoil), "--image-size", SCENE_SIZE_TEXT]

    def duplicate_id(tmp: Path, csv_path: Path) -> list[object]:
        def dup(rows: list[list[str]]) -> list[list[str]]:
            rows[5][rows[0].index("id")] = rows[1][rows[0].index("id")]
            return rows

        return ["calibrate", edit_csv(csv_path, tmp / "dup.csv", dup), "--image-size", SCENE_SIZE_TEXT]

    def focal_with_intrinsics(tmp: Path, csv_path: Path) -> list[object]:
        yml = tmp / "match.yml"
        write_intrinsics_yaml(yml, Intrinsics(K=[[1800.0, 0, 959.5], [0, 1800.0, 539.5], [0, 0, 1]], dist=np.zeros(5),
                                              image_size=SCENE_SIZE))
        return scene(SCENE_SIZE_TEXT, "--focal-px", "1800", "--intrinsics", yml)(tmp, csv_path)

    def intrinsics_other_size(tmp: Path, csv_path: Path) -> list[object]:
        yml = tmp / "hd720.yml"
        write_intrinsics_yaml(yml, Intrinsics(K=[[1000.0, 0, 639.5], [0, 1000.0, 359.5], [0, 0, 1]], dist=np.zeros(5),
                                              image_size=(1280, 720)))
        return scene(SCENE_SIZE_TEXT, "--intrinsics", yml)(tmp, csv_path)

    def i24_degenerate(tmp: Path, csv_path: Path) -> list[object]:
        return ["calibrate", i24_camera_csv(tmp, "P3C4"), "--image-size", I24_SIZE, "--gcp-crs", "EPSG:4326"]

    def lonlat_without_gcp_crs(tmp: Path, csv_path: Path) -> list[object]:
        return ["calibrate", i24_camera_csv(tmp, "P1C1"), "--image-size", I24_SIZE, "--crs", "EPSG:2949"]

    return {
        "missing GCP file": missing_file,
        "missing column": missing_column,
        "non-numeric value": non_numeric,
        "duplicate id": duplicate_id,
        "pixel outside the image": scene("640x480"),
        "image size abc": scene("abc"),
        "image size 0x10": scene("0x10"),
        "unknown loss": scene(SCENE_SIZE_TEXT, "--loss", "bogus"),
        "unknown distortion term": scene(SCENE_SIZE_TEXT, "--distortion", "k1,k9"),
        "negative focal": scene(SCENE_SIZE_TEXT, "--focal-px", "-5"),
        "focal and intrinsics": focal_with_intrinsics,
        "intrinsics for another size": intrinsics_other_size,
        "degenerate I-24 P3C4": i24_degenerate,
        "lon/lat with a projected --crs": lonlat_without_gcp_crs,
    }


BAD_CASES = _bad_cases()
BAD_MESSAGES = {  # a word of the message each case must give, so the right check fired
    "missing GCP file": "does not exist",
    "missing column": "'v'",
    "non-numeric value": "not a number",
    "duplicate id": "unique id",
    "pixel outside the image": "outside the 640x480 image",
    "image size abc": "--image-size",
    "image size 0x10": "--image-size",
    "unknown loss": "loss",
    "unknown distortion term": "k9",
    "negative focal": "-5",
    "focal and intrinsics": "not both",
    "intrinsics for another size": "1280x720",
    "degenerate I-24 P3C4": "degenerate",
    "lon/lat with a projected --crs": "--gcp-crs EPSG:4326",
}


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_bad_input_exits_2_with_one_line_and_writes_nothing(case: str, scene_csv: Path, tmp_path: Path) -> None:
    args = BAD_CASES[case](tmp_path, scene_csv)
    out, report = tmp_path / "out" / "camera.json", tmp_path / "out" / "report.json"
    before = files_under(tmp_path)
    code, stdout, stderr = invoke(*args, "-o", out, "--report", report)
    assert code == 2, (stdout, stderr)
    assert "Traceback" not in stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("trafficgeo: error:"), stderr
    assert BAD_MESSAGES[case] in lines[0], stderr
    assert stdout == ""
    assert not out.exists() and not report.exists()
    assert files_under(tmp_path) == before  # no temporary files left behind either


def test_unknown_option_is_a_usage_error(scene_csv: Path, tmp_path: Path) -> None:
    out = tmp_path / "camera.json"
    code, _stdout, stderr = invoke(*calibrate_args(scene_csv, out, SCENE_SIZE_TEXT, "--no-such-option"))
    assert code == 2
    assert "Traceback" not in stderr
    assert "--no-such-option" in stderr
    assert not out.exists()


def test_missing_required_option_is_a_usage_error(scene_csv: Path, tmp_path: Path) -> None:
    code, _stdout, stderr = invoke("calibrate", scene_csv, "-o", tmp_path / "camera.json")
    assert code == 2
    assert "--image-size" in stderr
    assert "Traceback" not in stderr
    assert files_under(tmp_path) == set()


@pytest.mark.parametrize(("args", "word"), [
    (["--pattern", "1x6"], "--pattern"),
    (["--pattern", "nine"], "--pattern"),
    (["--square", "0"], "--square"),
])
def test_intrinsics_bad_options_exit_2(args: list[str], word: str, tmp_path: Path) -> None:
    out = tmp_path / "board.yml"
    code, _stdout, stderr = invoke("intrinsics", *BOARDS[:2], "-o", out, *args)
    assert code == 2
    assert stderr.startswith("trafficgeo: error:") and len(stderr.splitlines()) == 1, stderr
    assert word in stderr
    assert not out.exists()


# ------------------------------------------------------------------------------------------------ 3. paper


@pytest.mark.slow
def test_paper_table2_runs_and_warns(tmp_path: Path) -> None:
    out, report = tmp_path / "camera.json", tmp_path / "report.json"
    code, _stdout, stderr = invoke(*calibrate_args(PAPER, out, PAPER_SIZE, "--crs", "EPSG:2949", report=report))
    assert code == 0, stderr
    assert "Traceback" not in stderr
    rep = read_json(report)
    text = "\n".join(rep["warnings"])
    assert re.search(r"residuals .* the expected noise", text), text
    assert "focal length poorly determined" in text, text
    assert len(read_json(out)["gcps"]) == 7


def test_paper_table2_with_known_focal(tmp_path: Path) -> None:
    out, report = tmp_path / "camera.json", tmp_path / "report.json"
    code, _stdout, stderr = invoke(*calibrate_args(PAPER, out, PAPER_SIZE, "--crs", "EPSG:2949", "--focal-px", "848",
                                                   report=report))
    assert code == 0, stderr
    cam = read_camera_json(out)
    assert cam.K[0, 0] == pytest.approx(848.0) and cam.K[1, 1] == pytest.approx(848.0)
    assert "focal length poorly determined" not in "\n".join(read_json(report)["warnings"])


# ------------------------------------------------------------------------------------------------ 4. I-24


def test_i24_good_camera_lonlat(tmp_path: Path) -> None:
    """P1C1: 4 lon/lat GCPs, projected to the UTM zone (16N); exactly one redundant observation."""
    gcps = i24_camera_csv(tmp_path, "P1C1")
    out, report = tmp_path / "camera.json", tmp_path / "report.json"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # see test_i24_four_points_no_numpy_warnings
        code, _stdout, stderr = invoke(*calibrate_args(gcps, out, I24_SIZE, "--gcp-crs", "EPSG:4326",
                                                       report=report))
    assert code == 0, stderr
    assert "Traceback" not in stderr
    doc = read_json(out)
    assert "32616" in str(doc["crs"])  # UTM 16N, the zone of Nashville
    assert doc["stats"]["n_control"] == 4 and doc["stats"]["n_inliers"] == 4
    assert doc["stats"]["rmse_px"] < 20  # a few px on a 4K frame
    assert doc["stats"]["loo_rmse_px"] is None  # leave-one-out needs more than 4 points: null, not NaN
    cam = read_camera_json(out)
    assert 15 < cam.position[2] < 60  # a pole-mounted camera above z = 0
    assert 0 < cam.orientation.tilt_deg < 45 and abs(cam.orientation.roll_deg) < 10
    text = "\n".join(read_json(report)["warnings"])
    assert "only 4 control points" in text and "little redundancy" in text


def test_i24_four_points_no_numpy_warnings(tmp_path: Path) -> None:
    gcps = i24_camera_csv(tmp_path, "P1C1")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, stdout, stderr = invoke(*calibrate_args(gcps, tmp_path / "camera.json", I24_SIZE, "--gcp-crs",
                                                      "EPSG:4326", "-q"))
    assert code == 0, stderr
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]
    assert "nan" not in stdout.lower()


@pytest.mark.slow
def test_i24_inconsistent_camera_exits_1(tmp_path: Path) -> None:
    """P1C2's 4 points fit no pinhole camera with a central principal point (best PnP ~ 300 px RMSE): exit 1."""
    gcps = i24_camera_csv(tmp_path, "P1C2")
    out, report = tmp_path / "camera.json", tmp_path / "report.json"
    code, stdout, stderr = invoke(*calibrate_args(gcps, out, I24_SIZE, "--gcp-crs", "EPSG:4326", report=report))
    assert code == 1, (stdout, stderr)
    assert "Traceback" not in stderr
    assert stderr.startswith("trafficgeo: calibration failed:") and len(stderr.splitlines()) == 1, stderr
    assert not out.exists() and not report.exists()


# ------------------------------------------------------------------------------------------------ 5. intrinsics


def test_intrinsics_from_chessboards(board_yaml: Path) -> None:
    assert len(BOARDS) == 13
    intr = read_intrinsics_yaml(board_yaml)
    assert intr.image_size == (640, 480)
    assert intr.fx == pytest.approx(536.0, rel=0.01)
    assert intr.fy == pytest.approx(536.0, rel=0.01)
    assert intr.rms_px is not None and intr.rms_px < 0.5


def test_calibrate_with_chessboard_intrinsics(board_yaml: Path, tmp_path: Path) -> None:
    """A synthetic 640x480 scene seen through the chessboard camera, calibrated with its intrinsics held."""
    intr = read_intrinsics_yaml(board_yaml)
    sc = make_gcp_scene(5, image_size=(640, 480), n_control=12, n_check=3, focal_px=intr.fx, dist=intr.dist)
    gcps = tmp_path / "gcps.csv"
    sc.gcps.to_csv(gcps)
    out = tmp_path / "camera.json"
    code, _stdout, stderr = invoke(*calibrate_args(gcps, out, "640x480", "--crs", "EPSG:2949", "--intrinsics",
                                                   board_yaml))
    assert code == 0, stderr
    doc = read_json(out)
    np.testing.assert_array_equal(np.asarray(doc["K"]), intr.K)  # held, not refined
    np.testing.assert_array_equal(np.asarray(doc["dist"]), intr.dist)
    assert doc["stats"]["rmse_px"] < 3
    assert np.linalg.norm(read_camera_json(out).position - sc.camera.position) < 1.0


# ------------------------------------------------------------------------------------------------ 6. demo


@pytest.mark.slow
def test_demo_writes_its_files(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    code, stdout, stderr = invoke("demo", "--out", out, "--quick", "--duration", "2")
    assert code == 0, stderr
    assert "Traceback" not in stderr
    for name in ("world/gcps.csv", "world/camera_truth.json", "world/video.mp4", "camera.json", "report.json",
                 "dem.tif", "accuracy.tif", "site.gpkg", "gcps_z.csv", "vehicles_world_dem.gpkg", "tracks.csv",
                 "traffic/vehicles.csv", "traffic/counts.csv", "traffic/trajectories.gpkg",
                 "traffic/compare_counts.csv", "camera_refined.json", "refine.json", "refine_frame.jpg"):
        assert (out / name).is_file(), name
    assert read_json(out / "camera.json")["format"] == "trafficgeo.camera/1"
    assert "gcps" in read_json(out / "report.json")
    words = " ".join(stdout.split())
    assert "estimate vs truth" in words and "traffic: measured vs truth" in words and "GEH" in words
    # the orthophoto refined (or, with a reason, kept) the GCP camera
    assert "$ trafficgeo refine" in words and ("refined: " in words or "refused: " in words)
    assert read_json(out / "camera_refined.json")["refinement"]["report"] == "refine.json"
    # the loop closed on the video's counts, its scenario left for sumo-gui
    assert "The loop closed" in words and "against the truth" in words
    assert (out / "sumo" / "scenario.sumocfg").is_file() and (out / "video" / "compare_counts.csv").is_file()
    # A second run reuses the cached world.
    code, stdout, stderr = invoke("demo", "--out", out, "--quick", "--duration", "2")
    assert code == 0, stderr
    assert "reusing the demo world" in stdout


# ------------------------------------------------------------------------------------------------ 7. permissions


def test_written_files_are_readable_by_others(calibrated) -> None:
    code, _stdout, _stderr, out, report = calibrated
    assert code == 0
    for path in (out, report):
        mode = path.stat().st_mode
        assert mode & 0o044, oct(mode)
        assert mode & 0o777 == 0o644, oct(mode)  # written under umask 022, like a plain open()


def test_written_files_respect_a_strict_umask(scene_csv: Path, tmp_path: Path) -> None:
    out, report = tmp_path / "camera.json", tmp_path / "report.json"
    with umask(0o077):
        code, _stdout, stderr = invoke(*calibrate_args(scene_csv, out, SCENE_SIZE_TEXT, "--crs", "EPSG:2949", "-q",
                                                       report=report))
    assert code == 0, stderr
    for path in (out, report):
        assert path.stat().st_mode & 0o777 == 0o600, oct(path.stat().st_mode)


def test_intrinsics_yaml_is_readable_by_others(board_yaml: Path) -> None:
    # board_yaml is written by a fixture under the test process's umask; check it against that umask
    current = os.umask(0)
    os.umask(current)
    assert board_yaml.stat().st_mode & 0o777 == 0o666 & ~current


# ------------------------------------------------------------------------------------------------ console script


@pytest.mark.slow
def test_console_script_help_and_bad_input(tmp_path: Path) -> None:
    exe = Path(sys.executable).with_name("trafficgeo")
    assert exe.exists(), exe
    env = {**os.environ, "COLUMNS": "120", "NO_COLOR": "1"}
    done = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 0, done.stderr
    for command in ("calibrate", "intrinsics", "demo"):
        assert command in done.stdout

    out = tmp_path / "camera.json"
    done = subprocess.run([str(exe), "calibrate", str(tmp_path / "missing.csv"), "--image-size", "1920x1080",
                           "-o", str(out)], capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert done.stderr.startswith("trafficgeo: error:") and len(done.stderr.splitlines()) == 1, done.stderr
    assert not out.exists()


def test_parse_image_size() -> None:
    assert cli.parse_image_size("1920x1080") == (1920, 1080)
    assert cli.parse_image_size("3840X2160") == (3840, 2160)
    assert cli.parse_image_size("848*464") == (848, 464)
