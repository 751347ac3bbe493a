"""A sweep of damaged inputs over the commands: each input file of each command, and each file of a run folder,
replaced in turn by a damaged copy (missing, a folder, empty, random bytes, cut in half, a word or a huge number or
NaN in a number's place, UTF-16, JSON nested 100,000 deep). Whatever the damage, a command ends with a one-line
message and exit 2 and writes nothing (or, where the damage leaves a valid file - half of a CSV is still a CSV -
runs, or ends with exit 1 and its reason); never a traceback. A fault-injection pass of about 400 such cases over the
commands found the tracebacks this sweep now keeps out; the next such case is meant to be found here.
"""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import laspy
import numpy as np
import pandas as pd
import pyproj
import pytest
import rasterio
from rasterio.transform import from_origin

from cli_support import invoke
from test_cli_traffic import CRS, E0, FPS, N0, Z0, scene  # noqa: F401  (scene is a fixture)
from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.camera.pose_file import write_pose_file
from trafficgeo.io.run_manifest import MANIFEST, publish_outputs

DATA = Path(__file__).parent / "data"
pytestmark = pytest.mark.slow


# ------------------------------------------------------------------------------------------------ damages
def _numbers_replaced(text: str, by: str) -> str:
    """The first number of every data line (after the header) replaced by ``by``."""
    lines = text.splitlines()
    out = lines[:1] + [re.sub(r"-?\d+\.?\d*(e[-+]?\d+)?", by, line, count=1) for line in lines[1:]]
    return "\n".join(out) + "\n"


def _json_value_replaced(text: str, by: str) -> str:
    """The first number of a JSON document replaced by ``by`` (a word, a huge number, NaN)."""
    return re.sub(r"(?<=[:\[,]\s)-?\d+\.?\d*(e[-+]?\d+)?", by, text, count=1)


TEXT_DAMAGES: dict[str, Callable[[bytes], bytes]] = {
    "empty": lambda b: b"",
    "binary": lambda b: np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8).tobytes(),
    "half": lambda b: b[: len(b) // 2],
    "word": lambda b: _numbers_replaced(b.decode(), "abc").encode(),
    "huge": lambda b: _numbers_replaced(b.decode(), "1e308").encode(),
    "nan": lambda b: _numbers_replaced(b.decode(), "nan").encode(),
    "utf16": lambda b: b.decode().encode("utf-16"),
}
JSON_DAMAGES: dict[str, Callable[[bytes], bytes]] = {
    "empty": lambda b: b"",
    "binary": TEXT_DAMAGES["binary"],
    "half": TEXT_DAMAGES["half"],
    "word": lambda b: _json_value_replaced(b.decode(), '"abc"').encode(),
    "huge": lambda b: _json_value_replaced(b.decode(), "1e999").encode(),
    "nan": lambda b: _json_value_replaced(b.decode(), "NaN").encode(),
    "nested": lambda b: b"[" * 100_000 + b"]" * 100_000,
    "list": lambda b: b"[1, 2, 3]",
}
BINARY_DAMAGES: dict[str, Callable[[bytes], bytes]] = {
    "empty": TEXT_DAMAGES["empty"],
    "binary": TEXT_DAMAGES["binary"],
    "half": TEXT_DAMAGES["half"],
    "text": lambda b: b"id,x,y\n1,2,3\n",
}


def _damages(name: str) -> dict[str, Callable[[bytes], bytes]]:
    suffix = Path(name).suffix.lower()
    if suffix == ".json":
        return JSON_DAMAGES
    if suffix in (".csv", ".yml", ".pgw", ".geojson", ".txt", ".xml"):
        return TEXT_DAMAGES
    return BINARY_DAMAGES


# ------------------------------------------------------------------------------------------------ inputs
@pytest.fixture(scope="module")
def inputs(scene: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:  # noqa: F811
    """One valid file of every kind the commands read, a run folder of `analyze` (for compare-sumo's input sweep) and
    one of `process` (every file a run folder can hold, for the readers' sweep)."""
    root = tmp_path_factory.mktemp("damage_inputs")
    files = dict(scene)
    camera = read_camera_json(scene["camera"])
    world = np.array([[E0 + dx, N0 + dy, Z0] for dx in (-6.0, -2.0, 3.0) for dy in (15.0, 30.0, 55.0, 90.0)])
    px = camera.project(world)
    pd.DataFrame({"id": [f"P{i}" for i in range(len(world))], "x": world[:, 0], "y": world[:, 1], "z": world[:, 2],
                  "u": px[:, 0], "v": px[:, 1]}).to_csv(root / "gcps.csv", index=False)
    pd.DataFrame({"u": [960.0, 700.0], "v": [700.0, 900.0]}).to_csv(root / "pixels.csv", index=False)
    pd.DataFrame({"x": world[:3, 0], "y": world[:3, 1], "z": world[:3, 2]}).to_csv(root / "world.csv", index=False)
    with rasterio.open(root / "dem.tif", "w", driver="GTiff", width=80, height=160, count=1, dtype="float32",
                       crs=CRS, transform=from_origin(E0 - 40.0, N0 + 300.0, 1.0, 2.0)) as dst:
        dst.write(np.full((1, 160, 80), Z0, dtype=np.float32))
    write_pose_file(root / "pose.yml", camera)
    cv2.imwrite(str(root / "map.png"), np.random.default_rng(0).integers(0, 255, (60, 80, 3), dtype=np.uint8))
    (root / "map.pgw").write_text(f"0.5\n0\n0\n-0.5\n{E0}\n{N0}\n")
    (root / "corners.csv").write_text(f"u,v,x,y\n0,0,{E0},{N0}\n79,0,{E0 + 40},{N0}\n79,59,{E0 + 40},{N0 - 30}\n"
                                      f"0,59,{E0},{N0 - 30}\n")
    rng = np.random.default_rng(2)  # a small ground cloud (LAZ) under the camera
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets, header.scales = [E0, N0, 0.0], [0.01, 0.01, 0.01]
    header.add_crs(pyproj.CRS(CRS))
    cloud = laspy.LasData(header)
    cloud.x, cloud.y = E0 + rng.uniform(-20, 20, 4000), N0 + rng.uniform(0, 60, 4000)
    cloud.z = np.full(4000, Z0) + rng.normal(0, 0.02, 4000)
    cloud.classification = np.full(4000, 2, dtype=np.uint8)
    cloud.write(root / "cloud.laz")
    shutil.copy(DATA / "sumo-fcd-sample" / "fcd_geo_utm.sumo.xml", root / "fcd.xml")
    shutil.copy(DATA / "intel-sample-video" / "car-detection.mp4", root / "video.mp4")
    code, _, err = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0, "--lanes",
                          scene["lanes"], "--lines", scene["lines"], "--out", root / "run")
    assert code == 0, err
    # a run of `process` (its detections and tracks too) on the real clip, with a nominal camera 8.5 m above it
    clip_camera = Camera.from_orientation((768, 432), 600.0, [E0, N0, Z0 + 8.5], 0.0, 75.0, crs=CRS)
    write_camera_json(root / "clip_camera.json", clip_camera)
    (root / "clip_line.csv").write_text("line,u,v\nmid,0,215.5\nmid,767,215.5\n")
    code, _, err = invoke("process", root / "video.mp4", "--camera", root / "clip_camera.json", "--surface", Z0,
                          "--lines", root / "clip_line.csv", "--detector", "background", "--end", "12", "--out",
                          root / "process_run")
    assert code == 0, err
    files.update({k: root / n for k, n in [
        ("gcps", "gcps.csv"), ("pixels", "pixels.csv"), ("world", "world.csv"), ("dem", "dem.tif"),
        ("pose", "pose.yml"), ("map", "map.png"), ("pgw", "map.pgw"), ("corners", "corners.csv"),
        ("cloud", "cloud.laz"), ("fcd", "fcd.xml"), ("video", "video.mp4"), ("run", "run"),
        ("process_run", "process_run"), ("clip_camera", "clip_camera.json"), ("clip_line", "clip_line.csv")]})
    return files


# Each command with the input it reads in the place of "{IN}" (a key of `inputs`), and what it would write under
# OUT. Other inputs are valid.
COMMANDS: dict[str, tuple[str, list[str]]] = {
    "calibrate gcps": ("gcps", ["calibrate", "{IN}", "--image-size", "1920x1080", "--crs", CRS, "-o",
                                "OUT/camera.json", "--report", "OUT/report.json"]),
    "calibrate intrinsics": ("pose", ["calibrate", "{gcps}", "--image-size", "1920x1080", "--crs", CRS,
                                      "--intrinsics", "{IN}", "-o", "OUT/camera.json"]),
    "import-camera": ("pose", ["import-camera", "{IN}", "--crs", CRS, "-o", "OUT/camera.json"]),
    "georef camera": ("camera", ["georef", "{IN}", "{pixels}", "--surface", str(Z0), "-o", "OUT/world.csv"]),
    "georef pixels": ("pixels", ["georef", "{camera}", "{IN}", "--surface", str(Z0), "-o", "OUT/world.csv"]),
    "georef surface": ("dem", ["georef", "{camera}", "{pixels}", "--surface", "{IN}", "-o", "OUT/world.csv"]),
    "project world": ("world", ["project", "{camera}", "{IN}", "-o", "OUT/pixels.csv"]),
    "dem cloud": ("cloud", ["dem", "{IN}", "-o", "OUT/dem.tif"]),
    "gcp-z gcps": ("gcps", ["gcp-z", "{IN}", "--dem", "{dem}", "-o", "OUT/gcps_z.csv"]),
    "gcp-z dem": ("dem", ["gcp-z", "{gcps}", "--dem", "{IN}", "-o", "OUT/gcps_z.csv"]),
    "accuracy camera": ("camera", ["accuracy", "{IN}", "--surface", str(Z0), "-o", "OUT/accuracy.tif"]),
    "ortho-from-image image": ("map", ["ortho-from-image", "{IN}", "--crs", CRS, "--world-file", "{pgw}", "-o",
                                       "OUT/ortho.tif"]),
    "ortho-from-image world file": ("pgw", ["ortho-from-image", "{map}", "--crs", CRS, "--world-file", "{IN}",
                                            "-o", "OUT/ortho.tif"]),
    "ortho-from-image corners": ("corners", ["ortho-from-image", "{map}", "--crs", CRS, "--corners", "{IN}", "-o",
                                             "OUT/ortho.tif"]),
    "analyze tracks": ("tracks", ["analyze", "{camera}", "{IN}", "--fps", str(FPS), "--surface", str(Z0), "--out",
                                  "OUT/run"]),
    "analyze lanes": ("lanes", ["analyze", "{camera}", "{tracks}", "--fps", str(FPS), "--surface", str(Z0),
                                "--lanes", "{IN}", "--out", "OUT/run"]),
    "analyze lines": ("lines", ["analyze", "{camera}", "{tracks}", "--fps", str(FPS), "--surface", str(Z0),
                                "--lines", "{IN}", "--out", "OUT/run"]),
    "compare-sumo fcd": ("fcd", ["compare-sumo", "{run}", "{IN}", "--out", "OUT/compare"]),
    "frame video": ("video", ["frame", "{IN}", "--at", "1", "-o", "OUT/frame.png"]),
}
def _suffix(key: str) -> str:
    return {"gcps": ".csv", "pose": ".yml", "camera": ".json", "pixels": ".csv", "dem": ".tif", "world": ".csv",
            "cloud": ".laz", "map": ".png", "pgw": ".pgw", "corners": ".csv", "tracks": ".csv", "lanes": ".geojson",
            "lines": ".csv", "fcd": ".xml", "video": ".mp4"}[key]


CASES = [(name, damage) for name, (key, _) in COMMANDS.items()
         for damage in ["missing", "folder", *_damages(f"x{_suffix(key)}")]]


def _damaged(src: Path, damage: str, folder: Path) -> Path:
    path = folder / f"damaged{src.suffix}"
    if damage == "missing":
        return path
    if damage == "folder":
        path.mkdir()
        return path
    path.write_bytes(_damages(src.name)[damage](src.read_bytes()))
    return path


def _check(code: int, stderr: str, out: Path, case: str) -> None:
    assert "Traceback" not in stderr, f"{case}: a traceback\n{stderr[-1500:]}"
    assert code in (0, 1, 2), f"{case}: exit {code}\n{stderr[-800:]}"
    if code:
        lines = [line for line in stderr.strip().splitlines() if line.startswith("trafficgeo")]
        assert lines and lines[-1].startswith("trafficgeo: "), f"{case}: no one-line reason\n{stderr[-800:]}"
    if code == 2:
        assert len(stderr.strip().splitlines()) == 1, f"{case}: more than one line\n{stderr[-800:]}"
        written = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file()) if out.exists() else []
        assert not written, f"{case}: bad input, yet wrote {written}"


@pytest.mark.parametrize(("command", "damage"), CASES)
def test_a_damaged_input_is_one_line_and_nothing_written(command: str, damage: str, inputs: dict[str, Path],
                                                         tmp_path: Path) -> None:
    key, args = COMMANDS[command]
    bad = _damaged(inputs[key], damage, tmp_path)
    out = tmp_path / "out"
    argv = [a.replace("{IN}", str(bad)).replace("OUT", str(out)) for a in args]
    argv = [str(inputs[a[1:-1]]) if re.fullmatch(r"\{\w+\}", a) else a for a in argv]
    code, _, err = invoke(*argv)
    _check(code, err, out, f"{command} / {damage}")


# ------------------------------------------------------------------------------------------------ run folders
RUN_FILES = ["counts.csv", "vehicles.csv", "crossings.csv", "summary.json", "trajectories.gpkg",
             "trajectories.csv", "tracks.csv", "detections.csv", "process.json", MANIFEST]
READERS: dict[str, list[str]] = {
    "report": ["report", "RUN", "-o", "OUT/report.html"],
    "export-fcd": ["export-fcd", "RUN", "-o", "OUT/observed.fcd.xml"],
    "compare-sumo": ["compare-sumo", "RUN", "{fcd}", "--out", "OUT/compare"],
    "stitch": ["stitch", "RUN", "--camera", "{clip_camera}", "--surface", str(Z0), "--lines", "{clip_line}",
               "--out", "OUT/stitched"],
}
# A stale manifest is refused before any file is parsed: one damage per file shows it. Sealed into a new manifest,
# each file meets its parser: the damages that reach different code (bytes, a cut, a wrong value, a wrong shape).
SEALED_DAMAGES = {"binary", "half", "word", "nan", "nested", "list"}
RUN_CASES = [(reader, name, damage, sealed) for reader in READERS for name in RUN_FILES
             for damage in _damages(name) for sealed in (False, True)
             if (not sealed and damage == "binary") or (sealed and name != MANIFEST and damage in SEALED_DAMAGES)]


@pytest.mark.parametrize(("reader", "name", "damage", "sealed"), RUN_CASES)
def test_a_damaged_run_folder_is_one_line_and_nothing_written(reader: str, name: str, damage: str, sealed: bool,
                                                              inputs: dict[str, Path], tmp_path: Path) -> None:
    """A file of a run folder damaged after the run (its manifest then refuses the folder), or damaged and sealed
    into a new manifest (as a tool that rewrote the folder would leave it): each reader ends in one line."""
    run = tmp_path / "run"
    shutil.copytree(inputs["process_run"], run)
    target = run / name
    target.write_bytes(_damages(name)[damage](target.read_bytes()))
    if sealed:
        files = json.loads((run / MANIFEST).read_text())["files"]
        publish_outputs(run, list(files), command="analyze")
    out = tmp_path / "out"
    argv = [a.replace("RUN", str(run)).replace("OUT", str(out)) for a in READERS[reader]]
    argv = [str(inputs[a[1:-1]]) if re.fullmatch(r"\{\w+\}", a) else a for a in argv]
    code, _, err = invoke(*argv)
    _check(code, err, out, f"{reader} / {name} / {damage} / {'sealed' if sealed else 'stale manifest'}")


@pytest.mark.parametrize("command", [*COMMANDS, *READERS])
def test_the_sweep_starts_from_inputs_that_work(command: str, inputs: dict[str, Path], tmp_path: Path) -> None:
    """Undamaged, every command of the sweep runs (exit 0): each refusal above is the damage's doing."""
    out = tmp_path / "out"
    args = COMMANDS[command][1] if command in COMMANDS else READERS[command]
    key = COMMANDS[command][0] if command in COMMANDS else "run"
    argv = [a.replace("{IN}", str(inputs[key])).replace("RUN", str(inputs["process_run"])).replace("OUT", str(out))
            for a in args]
    argv = [str(inputs[a[1:-1]]) if re.fullmatch(r"\{\w+\}", a) else a for a in argv]
    code, _, err = invoke(*argv)
    assert code == 0, f"{command}: exit {code}\n{err[-1500:]}"
