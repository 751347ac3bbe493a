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
    times, the SHA-1 of its decoded pixels (H.264 decoding is bit-exact on any CPU) and an 8x8 grey thumbnail per
    frame (to tell a few changed pixels from another world)."""
    import cv2
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
    pixels, thumbs, times = hashlib.sha1(), [], []
    for frame in iter_frames(world / "video.mp4"):
        pixels.update(np.ascontiguousarray(frame.image).tobytes())
        grey = cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY).astype(np.float64)
        h, w = grey.shape
        thumbs.append(np.round(grey.reshape(8, h // 8, 8, w // 8).mean(axis=(1, 3)), 2).ravel().tolist())
        times.append(frame.time_s)
    return {
        "camera_truth.json": json.loads((world / "camera_truth.json").read_text(encoding="utf-8")),
        "cloud.laz": {"points": int(las.header.point_count), "scales": [float(v) for v in las.header.scales],
                      "offsets": [float(v) for v in las.header.offsets],
                      "integer_sums": [int(np.asarray(las.points.array[k], dtype=np.int64).sum()) for k in "XYZ"],
                      "classes": {str(int(c)): int(n) for c, n in zip(cls, n_cls, strict=True)}},
        "sumo/fcd.xml": {"rows": len(fcd), "vehicles": sorted(set(fcd["track_id"].astype(str))),
                         "sums": {k: float(fcd[k].sum()) for k in ("time", "x", "y", "speed_kmh")}},
        "sumo/road.net.xml": {"lanes": [name for name, _ in lanes], "lengths_m": [float(v) for _, v in lanes]},
        "video.mp4": {"frames": len(times), "size": [int(w), int(h)], "times_s": [float(t) for t in times],
                      "decoded_pixels_sha1": pixels.hexdigest(), "thumbnails_8x8_grey": thumbs},
    }


#: Grey levels (0-255, mean absolute over an 8x8 thumbnail cell) by which a frame of the world's video may differ
#: from the reference's and still be the same world: a renderer on another CPU moves single pixels by a level or two
#: (a cell is ~2,000 of them); a vehicle moved by even a metre changes its cells by tens of levels.
VIDEO_GREY_TOLERANCE = 1.0


def inputs_differ(new: dict, old: dict) -> list[str]:
    """The input files whose meaning differs (empty: the same world). Floats within 1e-9 relative (the camera
    JSON's angles), the video within :data:`VIDEO_GREY_TOLERANCE`."""
    import numpy as np

    def close(a: object, b: object) -> bool:
        if isinstance(b, dict):
            return isinstance(a, dict) and set(a) == set(b) and all(close(a[k], b[k]) for k in b)
        if isinstance(b, list):
            return isinstance(a, list) and len(a) == len(b) and all(close(x, y) for x, y in zip(a, b, strict=True))
        if isinstance(b, float) and isinstance(a, int | float):
            return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9)
        return a == b

    differ = []
    for name, want in old.items():
        got = new.get(name)
        if name == "video.mp4":
            same_shape = got is not None and all(got[k] == want[k] for k in ("frames", "size")) and \
                close(got["times_s"], want["times_s"])
            if not same_shape or np.abs(np.asarray(got["thumbnails_8x8_grey"]) -
                                        np.asarray(want["thumbnails_8x8_grey"])).max() > VIDEO_GREY_TOLERANCE:
                differ.append(name)
        elif not close(got, want):
            differ.append(name)
    return differ


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
    (out / "inputs.json").write_text(json.dumps(input_meaning(world)) + "\n", encoding="utf-8")
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]) if len(sys.argv) > 2 else HERE / "pipeline")
