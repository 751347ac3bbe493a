"""Benchmark: closing the loop with SUMO on generated worlds whose truth is a SUMO simulation.

For each world, the observed run is written from the world's true trajectories
(:func:`trafficgeo.synth.observed_run.truth_run_folder`: counting lines across the road, lanes ``d<dir>_<k>``), then
:func:`trafficgeo.close_sumo_loop` builds the demand on the world's own network (randomTrips.py candidates,
``routeSampler.py --optimize full``), runs SUMO and compares, for each counting interval asked for.

Worlds:

* ``short``: 300 s, 600 veh/h per lane, 2 x 2 lanes, lines at stations -100 and +100 m;
* ``long``: 900 s (15 min) with varying demand - 400, 900 then 600 veh/h per lane in three 5-minute periods
  (Poisson arrivals per class, the demo world's mix) - lines at -150, 0 and +150 m.

Figures per world and interval: rows of the count comparison (line x lane x direction x interval), share with
GEH < 5 (targets: >= 85 % usual, >= 95 % asked for), also split into the first line along each SUMO edge (the
counts the demand is fitted to) and the lines downstream of it (what the simulation makes of it), mean GEH, the
largest |mean speed difference| over lines and lanes (target <= 2 km/h) and the mean KS distance of the spot
speeds, the travel-time difference between the first and last line (simulated - observed mean), wall time to build
the scenario (mapping, randomTrips, routeSampler, files) and to run SUMO and compare. ``--details`` also prints the
per-lane speed table of each run.

Run ``python benchmarks/bench_sumo_loop.py [--worlds short,long] [--intervals 60,300,900] [--seed 0] [--keep DIR]
[--details]``.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import pandas as pd

from trafficgeo.simulation.loop import close_sumo_loop, lane_speed_table
from trafficgeo.simulation.tools import run_sumo_program
from trafficgeo.synth.observed_run import truth_run_folder
from trafficgeo.synth.sumo_scene import VEHICLE_CLASSES, Demand, RoadSpec
from trafficgeo.synth.sumo_world import WARMUP_S, Trajectories, read_fcd, run_sumo_world

ROAD = RoadSpec()
MIX = Demand().mix
PERIODS = ((0.0, 300.0, 400.0), (300.0, 600.0, 900.0), (600.0, 900.0, 600.0))  # s, s, veh/h per lane
STEP_S = 0.5


def _varying_routes(road: RoadSpec, warmup_s: float) -> str:
    """Flows of :data:`PERIODS` (times after the warm-up; the first period's demand also fills the warm-up)."""
    rows = ["<routes>\n"]
    for name in MIX:
        vc = VEHICLE_CLASSES[name]
        rows.append(f'    <vType id="{name}" vClass="{vc.sumo_vclass}" length="{vc.length}" width="{vc.width}" '
                    f'height="{vc.height}" minGap="{vc.min_gap}" maxSpeed="{vc.max_speed}" accel="{vc.accel}" '
                    f'decel="{vc.decel}" speedFactor="{vc.speed_factor_spec}"/>\n')
    for d in road.directions:
        rows.append(f'    <route id="r{d}" edges="d{d}"/>\n')
    flows = []
    for k, (b, e, per_lane) in enumerate(PERIODS):
        begin = 0.0 if k == 0 else b + warmup_s
        for d in road.directions:
            for name, share in MIX.items():
                rate = per_lane * road.lanes * share / 3600.0
                flows.append((begin, f'    <flow id="p{k}_d{d}_{name}" type="{name}" route="r{d}" begin="{begin}" '
                                     f'end="{e + warmup_s}" period="exp({rate})" departLane="random" '
                                     'departSpeed="desired"/>\n'))
    rows += [text for _, text in sorted(flows, key=lambda f: f[0])]
    rows.append("</routes>\n")
    return "".join(rows)


def long_world(folder: Path, seed: int) -> tuple[Path, Trajectories]:
    """The ``long`` world: the network of :func:`run_sumo_world`, SUMO on varying flows."""
    base = run_sumo_world(folder, ROAD, Demand(100.0), duration_s=10.0, step_s=STEP_S, seed=seed)
    routes = folder / "varying.rou.xml"
    routes.write_text(_varying_routes(ROAD, WARMUP_S))
    end = WARMUP_S + PERIODS[-1][1]
    fcd = folder / "varying.fcd.xml"
    run_sumo_program("sumo", ["--net-file", str(base.net), "--route-files", str(routes), "--begin", "0", "--end",
                              repr(end), "--step-length", repr(STEP_S), "--seed", str(seed), "--no-step-log",
                              "--time-to-teleport", "-1", "--lanechange.duration", "3", "--fcd-output", str(fcd),
                              "--fcd-output.attributes", "x,y,angle,type,speed,pos,lane,signals",
                              "--device.fcd.begin", repr(WARMUP_S)], 600.0)
    return base.net, read_fcd(fcd, ROAD, base.net, t0=WARMUP_S)


def _split_shares(loop) -> tuple[float, float]:
    """Share of GEH < 5 at the first line along each SUMO edge (where the demand is fitted) and at the others."""
    mapping = pd.read_csv(loop.scenario.folder / "mapping.csv", dtype={"line": str, "lane": str},
                          keep_default_na=False)
    first = mapping.sort_values(["pos_m", "line"], kind="stable").groupby("sumo_edge")["line"].first()
    fitted = set(mapping.loc[mapping["line"] == mapping["sumo_edge"].map(first), "line"]
                 + "/" + mapping.loc[mapping["line"] == mapping["sumo_edge"].map(first), "direction"].astype(str))
    t = loop.validation.comparison.counts
    key = t["line"].astype(str) + "/" + t["direction"].astype(int).astype(str)
    ok = t["geh"] < 5
    return float(ok[key.isin(fitted)].mean()), float(ok[~key.isin(fitted)].mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worlds", default="short,long")
    ap.add_argument("--intervals", default="60,300,900", help="counting intervals (s); longer than a world: skipped")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=Path, help="keep the worlds, runs and scenarios in this folder")
    ap.add_argument("--details", action="store_true", help="print the per-lane speeds of every run")
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench_sumo_loop_"))
    root.mkdir(parents=True, exist_ok=True)
    intervals = [float(v) for v in args.intervals.split(",")]
    rows = []
    try:
        for world in args.worlds.split(","):
            t = time.perf_counter()
            if world == "short":
                run = run_sumo_world(root / "short" / "world", ROAD, Demand(600.0), duration_s=300.0, step_s=STEP_S,
                                     seed=args.seed + 1)
                net, traj, stations, duration = run.net, run.trajectories, (-100.0, 100.0), 300.0
            elif world == "long":
                net, traj = long_world(root / "long" / "world", args.seed + 2)
                stations, duration = (-150.0, 0.0, 150.0), PERIODS[-1][1]
            else:
                raise SystemExit(f"unknown world {world!r}; use short and/or long")
            run_dir = root / world / "run"
            truth_run_folder(run_dir, traj, ROAD, stations_m=stations, interval_s=60.0)
            print(f"world {world}: {len(set(traj.vehicle))} vehicles in {duration:g} s, lines at {stations} m "
                  f"(built in {time.perf_counter() - t:.1f} s)")
            for interval in intervals:
                if interval > duration:
                    continue
                loop = close_sumo_loop(run_dir, net, root / world / f"scenario_{interval:g}", interval_s=interval,
                                       seed=args.seed)
                v = loop.validation
                speeds = v.comparison.speeds
                fitted, downstream = _split_shares(loop)
                rows.append((world, interval, v.counts, v.share_geh_below_5, fitted, downstream, v.mean_geh,
                             v.max_abs_speed_difference_kmh, float(speeds["ks_statistic"].mean()),
                             v.travel_time_difference_s, loop.scenario.vehicles, loop.build_s, loop.run_and_compare_s))
                if args.details:
                    print(f"\n{world}, interval {interval:g} s: speeds per line and lane")
                    print(lane_speed_table(v).round(2).to_string(index=False))
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    head = ("world", "interval s", "counts", "GEH<5", "fitted lines", "downstream", "mean GEH", "max|dv| km/h",
            "mean KS", "dTT s", "vehicles", "build s", "run+cmp s")
    print("\n" + " | ".join(head))
    print(" | ".join("---" for _ in head))
    for r in rows:
        print(f"{r[0]} | {r[1]:g} | {r[2]} | {r[3]:.1%} | {r[4]:.1%} | {r[5]:.1%} | {r[6]:.2f} | {r[7]:.2f} | "
              f"{r[8]:.3f} | {r[9]:+.2f} | {r[10]} | {r[11]:.1f} | {r[12]:.1f}")


if __name__ == "__main__":
    main()
