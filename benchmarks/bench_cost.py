"""How good is the cost `process` states before it starts? Its estimate against the run's real wall-clock time.

Every run of `process` records both in its process.json: ``detector.estimate.seconds`` (what it said before it
started: :mod:`trafficgeo.video.cost`) and ``seconds`` (what the run took). This script reads them from the run
folders of the benchmarks (``bench_video.py``, ``bench_junction.py``; default: every process.json under ``out/``),
and with ``--run WORLD ...`` first runs `process` on generated worlds (``trafficgeo synth`` folders: a road world
with lanes.gpkg and count_lines.gpkg, or a junction world with gates.gpkg) into ``out/bench-cost/``.

Printed: per run the estimate, the real time and their ratio (real / estimate), with the estimate's time per pass
and the probe's; then the ratios' spread, next to the range the estimate states (``trafficgeo.video.cost.SPREAD``).

    python benchmarks/bench_cost.py                         # the runs already in out/
    python benchmarks/bench_cost.py --run out/bench-junction-world-seed41-pole12-60s   # and a new run first
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

from trafficgeo.video.cost import SPREAD

ROOT = Path(__file__).resolve().parents[1]


def run_process(world: Path, out: Path) -> None:
    """`process` on a generated world, as its benchmark runs it (the default detector and options)."""
    cmd = [str(Path(sys.executable).parent / "trafficgeo"), "process", str(world / "video.mp4"), "--camera",
           str(world / "camera_truth.json"), "--surface",
           str(world / "dem.tif") if (world / "dem.tif").is_file() else str(world / "cloud.laz"), "--out", str(out),
           "--restart"]
    if (world / "gates.gpkg").is_file():
        cmd += ["--gates", str(world / "gates.gpkg")]
    else:
        cmd += ["--lanes", str(world / "lanes.gpkg"), "--lines", str(world / "count_lines.gpkg")]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def rows(folders: list[Path]) -> list[dict]:
    out = []
    for folder in folders:
        for f in sorted(folder.rglob("process.json")):
            try:
                doc = json.loads(f.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
            est = (doc.get("detector") or {}).get("estimate")
            if not est or not doc.get("seconds"):
                continue
            out.append({"run": str(f.parent.relative_to(ROOT) if f.is_relative_to(ROOT) else f.parent),
                        "estimate_s": float(est["seconds"]), "real_s": float(doc["seconds"]),
                        "ms_per_pass": float(est["ms_per_pass"]),
                        "probe_ms_per_pass": est.get("probe_ms_per_pass")})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="*", type=Path, default=[ROOT / "out"])
    ap.add_argument("--run", nargs="*", type=Path, default=[], help="generated worlds to run `process` on first")
    args = ap.parse_args()
    for world in args.run:
        target = ROOT / "out" / "bench-cost" / world.name
        print(f"process {world} -> {target}", flush=True)
        run_process(world, target)
    extra = [ROOT / "out" / "bench-cost"] if args.run else []
    folders = list(dict.fromkeys(f.resolve() for f in args.folders + extra))
    table = rows(folders)
    print("| run | estimate s | real s | real / estimate | ms per pass used (probe) |")
    print("|---|---|---|---|---|")
    for r in table:
        probe = f" ({r['probe_ms_per_pass']:.0f})" if r["probe_ms_per_pass"] else " (probe: not recorded)"
        print(f"| {r['run']} | {r['estimate_s']:.0f} | {r['real_s']:.0f} | {r['real_s'] / r['estimate_s']:.2f} | "
              f"{r['ms_per_pass']:.0f}{probe} |")
    ratios = sorted(r["real_s"] / r["estimate_s"] for r in table)
    if ratios:
        inside = sum(SPREAD[0] <= x <= SPREAD[1] for x in ratios)
        print(f"\n{len(ratios)} runs: real / estimate from {ratios[0]:.2f} to {ratios[-1]:.2f}, median "
              f"{statistics.median(ratios):.2f}; {inside} within the stated range {SPREAD[0]:g}-{SPREAD[1]:g}x")


if __name__ == "__main__":
    main()
