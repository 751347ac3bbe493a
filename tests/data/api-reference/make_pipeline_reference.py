"""Write the reference outputs of ``process``, ``stitch`` and ``compare-sumo`` on the small generated world.

Run from a trafficgeo checkout:  python tests/data/api-reference/make_pipeline_reference.py WORLD [OUT]
(OUT defaults to the ``pipeline`` folder beside this script). WORLD is the folder of the tests' small world
(``tests/conftest.py`` ``SMALL_WORLD``, built by ``trafficgeo.synth.world.build_world``): its video, camera, point
cloud, lanes, counting lines and SUMO run are the inputs. The commands are those of the command line at commit
be710d4 (the last commit before the Python API), run in this process through ``trafficgeo.cli.main``:

* ``process`` of the whole video with the background-subtraction detector (no model weights: the shipped model has
  been rebuilt since), lanes and lines;
* ``process`` of 0-5 s and of 3 s to the end, then ``stitch`` of the two;
* ``compare-sumo`` of the whole run against the world's SUMO run.

The video used is copied to ``OUT/video.mp4``: to write the outputs again for the same video (a deliberate change of
the outputs), put the reference's ``pipeline/video.mp4`` into WORLD first.

Kept per run: the tables and summary.json (process.json and run.json hold timings and paths, left out), with what
the input files mean in ``inputs.json`` (:func:`input_meaning`) so a test can tell a changed world from changed code.
Their bytes would not do: the LAZ header holds the day it was written, and a camera JSON's angles, derived from its
rotation matrix, differ in the last bits on another CPU.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent

#: the input files (relative to the world folder) whose bytes the reference depends on
INPUTS = ("video.mp4", "camera_truth.json", "cloud.laz", "sumo/fcd.xml", "sumo/road.net.xml")

#: output files kept per run (those a run writes; compare-sumo's own tables in ``compare``)
KEEP = {
    "process": ("detections.csv", "tracks.csv", "vehicles.csv", "crossings.csv", "counts.csv", "trajectories.csv",
                "summary.json"),
    "stitch": ("vehicles.csv", "crossings.csv", "counts.csv", "trajectories.csv", "summary.json"),
    "compare": ("compare_counts.csv", "compare_speeds.csv", "simulated_crossings.csv", "compare_summary.json"),
}


def commands(world: Path, work: Path) -> list[list[str]]:
    """The command lines, in order, writing under ``work``."""
    common = ["--camera", str(world / "camera_truth.json"), "--surface", str(world / "cloud.laz"),
              "--lanes", str(world / "lanes.gpkg"), "--lines", str(world / "count_lines.gpkg")]
    video = str(world / "video.mp4")
    return [
        ["process", video, *common, "--detector", "background", "--out", str(work / "process")],
        ["process", video, *common, "--detector", "background", "--end", "5", "--out", str(work / "part_a")],
        ["process", video, *common, "--detector", "background", "--start", "3", "--out", str(work / "part_b")],
        ["stitch", str(work / "part_a"), str(work / "part_b"), *common, "--out", str(work / "stitch")],
        ["compare-sumo", str(work / "process"), str(world / "sumo" / "fcd.xml"), "--net",
         str(world / "sumo" / "road.net.xml"), "--out", str(work / "compare")],
    ]


def input_meaning(world: Path) -> dict:
    """What the input files of :func:`commands` hold, independent of their bytes: the camera JSON as parsed; the
    point cloud's count and integer coordinate sums (LAS stores scaled integers: exact) and classes; the SUMO run's
    rows, vehicles and coordinate / speed sums; the network's lanes and their lengths; the video's frame count, size,
    times and the SHA-1 of its decoded pixels (H.264 decoding is bit-exact on any CPU)."""
    import laspy
    import numpy as np
    import sumolib

    from trafficgeo.io.fcd_read import read_fcd
    from trafficgeo.video.reader import iter_frames

    las = laspy.read(world / "cloud.laz")
    cls, n_cls = np.unique(np.asarray(las.classification), return_counts=True)
    fcd = read_fcd(world / "sumo" / "fcd.xml")
    net = sumolib.net.readNet(str(world / "sumo" / "road.net.xml"))
    lanes = sorted((lane.getID(), lane.getLength()) for edge in net.getEdges() for lane in edge.getLanes())
    pixels, times, size = hashlib.sha1(), [], None
    for frame in iter_frames(world / "video.mp4"):
        pixels.update(np.ascontiguousarray(frame.image).tobytes())
        times.append(frame.time_s)
        size = [int(frame.image.shape[1]), int(frame.image.shape[0])]
    return {
        "camera_truth.json": json.loads((world / "camera_truth.json").read_text(encoding="utf-8")),
        "cloud.laz": {"points": int(las.header.point_count), "scales": [float(v) for v in las.header.scales],
                      "offsets": [float(v) for v in las.header.offsets],
                      "integer_sums": [int(np.asarray(las.points.array[k], dtype=np.int64).sum()) for k in "XYZ"],
                      "classes": {str(int(c)): int(n) for c, n in zip(cls, n_cls, strict=True)}},
        "sumo/fcd.xml": {"rows": len(fcd), "vehicles": sorted(set(fcd["track_id"].astype(str))),
                         "sums": {k: float(fcd[k].sum()) for k in ("time", "x", "y", "speed_kmh")}},
        "sumo/road.net.xml": {"lanes": [name for name, _ in lanes], "lengths_m": [float(v) for _, v in lanes]},
        "video.mp4": {"frames": len(times), "size": size, "times_s": [float(t) for t in times],
                      "decoded_pixels_sha1": pixels.hexdigest()},
    }


def inputs_differ(new: dict, old: dict, *, video: bool = True) -> list[str]:
    """The input files whose meaning differs (empty: the same world): floats within 1e-9 relative (the camera
    JSON's angles differ in their last bits on another CPU), all else equal. ``video=False`` leaves the video out
    (a renderer on another CPU may move a few pixels by a grey level: the test runs on the reference's own video)."""

    def close(a: object, b: object) -> bool:
        if isinstance(b, dict):
            return isinstance(a, dict) and set(a) == set(b) and all(close(a[k], b[k]) for k in b)
        if isinstance(b, list):
            return isinstance(a, list) and len(a) == len(b) and all(close(x, y) for x, y in zip(a, b, strict=True))
        if isinstance(b, float) and isinstance(a, int | float):
            return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9)
        return a == b

    return [name for name, want in old.items() if (video or name != "video.mp4") and not close(new.get(name), want)]


def run_all(world: Path, work: Path) -> None:
    """Run :func:`commands` through the CLI entry point; raise if one fails."""
    from trafficgeo.cli import main as cli_main

    for argv in commands(world, work):
        try:
            cli_main(argv)
        except SystemExit as exc:
            if exc.code not in (0, None):
                raise RuntimeError(f"{' '.join(argv)} exited {exc.code}") from None


def main(world: Path, out: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        run_all(world, work)
        out.mkdir(parents=True, exist_ok=True)
        for run, names in KEEP.items():
            (out / run).mkdir(exist_ok=True)
            for name in names:
                shutil.copy2(work / run / name, out / run / name)
    shutil.copy2(world / "video.mp4", out / "video.mp4")
    (out / "inputs.json").write_text(json.dumps(input_meaning(world)) + "\n", encoding="utf-8")
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]) if len(sys.argv) > 2 else HERE / "pipeline")
