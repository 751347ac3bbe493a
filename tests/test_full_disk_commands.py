"""A full disk under every command that writes (issue 43): each stops with one line and exit code 1 (the README's
code for an output the disk would not take), writes nothing at its output's name and leaves no temporary file. The
full disk is a file-size limit (RLIMIT_FSIZE with SIGXFSZ ignored, so that a write past it fails with EFBIG as one
to a full disk fails with ENOSPC) in the command's own process; each command first runs without it, to show that
its inputs are good. (GeoTIFF writers: tests/test_full_disk_geotiff.py; analyze's tables and GeoPackage:
tests/test_run_outputs.py.)"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from cli_support import invoke, invoke_on_a_full_disk

pytestmark = pytest.mark.slow  # a background-subtraction run and a command per case in their own processes

LIMIT = 200  # bytes: below every output written here


@pytest.fixture(scope="module")
def inputs(small_world: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The small world and a finished process run of it (background subtraction)."""
    root = tmp_path_factory.mktemp("full_disk")
    run = root / "run"
    code, _stdout, stderr = invoke("process", small_world / "video.mp4", "--camera", small_world / "camera_truth.json",
                                   "--surface", small_world / "cloud.laz", "--lines", small_world / "count_lines.gpkg",
                                   "--lanes", small_world / "lanes.gpkg", "--detector", "background", "--out", run)
    assert code == 0, stderr
    for name, span in (("chunk_a", ["--end", 5]), ("chunk_b", ["--start", 3])):
        code, _stdout, stderr = invoke("process", small_world / "video.mp4", "--camera",
                                       small_world / "camera_truth.json", "--surface", 90, "--detector", "background",
                                       *span, "--out", root / name)
        assert code == 0, stderr
    from trafficgeo.camera.calibrated import read_camera_json
    from trafficgeo.camera.pose_file import write_pose_file

    write_pose_file(root / "pose.yml", read_camera_json(small_world / "camera_truth.json"))
    (root / "pixels.csv").write_text("u,v\n320,300\n100,250\n500,280\n")
    (root / "points.csv").write_text("x,y,z\n244985.0,5182580.0,90.0\n244990.0,5182600.0,90.0\n")
    return {"world": small_world, "run": run, "root": root}


W = Callable[[dict[str, Path], Path], list[object]]
COMMANDS: dict[str, tuple[W, str]] = {  # argv (inputs, output path), what the output is: "file" or "folder"
    "calibrate": (lambda i, o: ["calibrate", i["world"] / "gcps.csv", "--image-size", "640x360", "-o", o], "file"),
    "georef": (lambda i, o: ["georef", i["world"] / "camera_truth.json", i["root"] / "pixels.csv", "--surface",
                             "90", "-o", o], "file"),
    "project": (lambda i, o: ["project", i["world"] / "camera_truth.json", i["root"] / "points.csv", "-o", o],
                "file"),
    "gcp-z": (lambda i, o: ["gcp-z", i["world"] / "gcps.csv", "--cloud", i["world"] / "cloud.laz", "-o", o], "file"),
    "frame": (lambda i, o: ["frame", i["world"] / "video.mp4", "--at", 1, "-o", o], "file"),
    "export-fcd": (lambda i, o: ["export-fcd", i["run"], "-o", o], "file"),
    "report": (lambda i, o: ["report", i["run"], "-o", o], "file"),
    "sumo-net": (lambda i, o: ["sumo-net", i["world"] / "lanes.gpkg", "--out", o], "file"),
    "process": (lambda i, o: ["process", i["world"] / "video.mp4", "--camera", i["world"] / "camera_truth.json",
                              "--surface", "90", "--detector", "background", "--out", o], "folder"),
    "compare-sumo": (lambda i, o: ["compare-sumo", i["run"], i["world"] / "sumo" / "fcd.xml", "--out", o], "folder"),
    "stitch": (lambda i, o: ["stitch", i["root"] / "chunk_a", i["root"] / "chunk_b", "--camera",
                             i["world"] / "camera_truth.json", "--surface", "90", "--out", o], "folder"),
    "import-camera": (lambda i, o: ["import-camera", i["root"] / "pose.yml", "-o", o], "file"),
    "synth": (lambda i, o: ["synth", "--out", o, "--duration", 2, "--image-size", "320x180", "--seed", 1], "folder"),
    "refine": (lambda i, o: ["refine", i["world"] / "camera_truth.json", "--ortho", i["world"] / "ortho.tif",
                             "--surface", i["world"] / "cloud.laz", "--video", i["world"] / "video.mp4", "--gcps",
                             i["world"] / "gcps.csv", "-o", o], "file"),
    "intrinsics": (lambda i, o: ["intrinsics", *sorted(CHESSBOARD.glob("left0[1-6].jpg")), "--pattern", "9x6", "-o",
                                 o], "file"),
}
CHESSBOARD = Path(__file__).parent / "data" / "opencv-chessboard"
SUFFIX = {"calibrate": ".json", "import-camera": ".json", "refine": ".json", "intrinsics": ".yml", "georef": ".csv",
          "project": ".csv", "gcp-z": ".csv", "frame": ".png", "export-fcd": ".xml", "report": ".html",
          "sumo-net": ".net.xml"}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_full_disk_under_a_command_is_one_line_exit_1_and_nothing_half_written(command: str,
                                                                                  inputs: dict[str, Path],
                                                                                  tmp_path: Path) -> None:
    argv, kind = COMMANDS[command]
    name = "out" + SUFFIX.get(command, "")
    room = tmp_path / "room"
    room.mkdir()
    code, _stdout, stderr = invoke(*argv(inputs, room / name))
    assert code == 0, stderr
    written = room / name
    assert written.exists() and (kind == "folder" or written.stat().st_size > LIMIT)
    full = tmp_path / "full"
    full.mkdir()
    cut = invoke_on_a_full_disk(LIMIT, *argv(inputs, full / name))
    lines = [ln for ln in cut.stderr.splitlines() if ln.startswith("trafficgeo")]
    assert cut.returncode == 1 and len(lines) == 1 and "could not write" in lines[0], (cut.stdout, cut.stderr)
    assert "Traceback" not in cut.stderr
    left = sorted(p.relative_to(full).as_posix() for p in full.rglob("*") if p.is_file())
    if kind == "file":
        assert left == [], left  # neither the output nor a temporary file
    else:  # a run folder: no output listed as written (no manifest), no temporary file
        assert "run.json" not in left and not any(Path(p).name.startswith(".") and ".tmp" in p for p in left), left


def test_a_full_disk_under_the_demo_is_one_line_exit_1(tmp_path: Path) -> None:
    """The demo under a full disk (its whole run is too long for a test: only the refused one runs)."""
    cut = invoke_on_a_full_disk(LIMIT, "demo", "--quick", "--out", tmp_path / "demo")
    lines = [ln for ln in cut.stderr.splitlines() if ln.startswith("trafficgeo")]
    assert cut.returncode == 1 and len(lines) == 1 and "could not write" in lines[0], (cut.stdout, cut.stderr)
    assert "Traceback" not in cut.stderr
    assert not any(".tmp" in p.name for p in (tmp_path / "demo").rglob("*"))
