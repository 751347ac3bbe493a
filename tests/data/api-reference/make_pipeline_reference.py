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

Kept per run: the tables and summary.json (process.json and run.json hold timings and paths, left out), with the
SHA-1 of the input files in ``inputs.json`` so a test can tell a changed world from changed code.
"""

from __future__ import annotations

import hashlib
import json
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


def input_digests(world: Path) -> dict[str, str]:
    return {name: hashlib.sha1((world / name).read_bytes()).hexdigest() for name in INPUTS}


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
    (out / "inputs.json").write_text(json.dumps(input_digests(world), indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]) if len(sys.argv) > 2 else HERE / "pipeline")
