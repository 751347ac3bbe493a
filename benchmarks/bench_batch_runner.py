"""Benchmark: the cost of running a batch on Dask distributed against running it serially in this process.

Fake tasks from ``tests/batch_support.py`` (no video work), so only the runner and Dask are measured:

* start-up: :func:`~trafficgeo.batch.runner.start_local_cluster` of 2 workers (1 thread each) until every worker
  runs, and its close;
* overhead per task: ``--noop`` no-op tasks through :func:`~trafficgeo.batch.runner.run_batch` on a running cluster
  (by its address; start-up excluded) and serially; the serial time is the runner's own bookkeeping (status.csv is
  rewritten after each task, so it grows with the batch);
* speed-up: ``--sleep`` tasks of ``--sleep-s`` seconds each (they wait, using no CPU) serially and on 2 workers
  (the 2-worker time includes starting and closing the cluster, as ``trafficgeo batch run`` does).

Run ``python benchmarks/bench_batch_runner.py [--noop 200] [--sleep 16] [--sleep-s 0.25]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from batch_support import FakeTask, make_plan, noop
from trafficgeo.batch.runner import RunOptions, run_batch, start_local_cluster


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noop", type=int, default=200, help="no-op tasks for the overhead (default 200)")
    ap.add_argument("--sleep", type=int, default=16, help="sleeping tasks for the speed-up (default 16)")
    ap.add_argument("--sleep-s", type=float, default=0.25, help="seconds each sleeping task waits (default 0.25)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        cluster = start_local_cluster(RunOptions(workers=2))
        started = time.perf_counter() - t0
        try:
            noop_plan = make_plan(cameras=1, files=args.noop)
            run_batch(make_plan(1, 4), root / "warm", RunOptions(scheduler=cluster.scheduler_address), execute=noop)
            t0 = time.perf_counter()
            dask_noop = run_batch(noop_plan, root / "noop-dask", RunOptions(scheduler=cluster.scheduler_address),
                                  execute=noop)
            dask_noop_s = time.perf_counter() - t0
        finally:
            t0 = time.perf_counter()
            cluster.close()
            closed = time.perf_counter() - t0
        t0 = time.perf_counter()
        serial_noop = run_batch(noop_plan, root / "noop-serial", RunOptions(workers=0), execute=noop)
        serial_noop_s = time.perf_counter() - t0
        n = len(noop_plan.tasks)
        assert dask_noop.count("done") == serial_noop.count("done") == n

        sleep_plan = make_plan(cameras=1, files=args.sleep - 1)  # + 1 track task
        fake = FakeTask(sleep_s=args.sleep_s)
        t0 = time.perf_counter()
        serial = run_batch(sleep_plan, root / "sleep-serial", RunOptions(workers=0), execute=fake)
        serial_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        two = run_batch(sleep_plan, root / "sleep-dask", RunOptions(workers=2), execute=fake)
        two_s = time.perf_counter() - t0
        assert serial.count("done") == two.count("done") == len(sleep_plan.tasks)

    ideal = (-(-(len(sleep_plan.tasks) - 1) // 2) + 1) * args.sleep_s  # detect tasks 2 at a time, then the track task
    print(f"local cluster of 2 workers: start {started:.2f} s, close {closed:.2f} s")
    print(f"{n} no-op tasks: dask {dask_noop_s:.2f} s ({1000 * dask_noop_s / n:.1f} ms/task), "
          f"serial {serial_noop_s:.2f} s ({1000 * serial_noop_s / n:.1f} ms/task)")
    print(f"{len(sleep_plan.tasks)} tasks of {args.sleep_s} s: serial {serial_s:.2f} s, 2 workers {two_s:.2f} s "
          f"(incl. cluster start/close; ideal {ideal:.2f} s + start)")


if __name__ == "__main__":
    main()
