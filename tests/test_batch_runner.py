"""The batch runner on Dask distributed (a local cluster of 2 worker processes, 1 thread each) and serially, with
fake tasks from :mod:`batch_support` that record their runs in files (start/end, attempts, markers)."""

from __future__ import annotations

import csv
import os
import sys
from pathlib import Path

import pytest

from batch_support import FakeTask, ReportThreads, attempts, make_plan, marker, spans
from trafficgeo.batch.model import parse_utc, task_folder
from trafficgeo.batch.runner import (
    STATUS_COLUMNS,
    BatchProgress,
    RunOptions,
    run_batch,
    start_local_cluster,
    thread_settings,
)
from trafficgeo.errors import InputError

pytestmark = pytest.mark.slow

TESTS = str(Path(__file__).resolve().parent)


@pytest.fixture(scope="module")
def cluster():
    """One local cluster for the module: 2 workers, 1 thread each, 2 retries (allowed worker deaths)."""
    c = start_local_cluster(RunOptions(workers=2, threads_per_worker=1, retries=2))
    yield c
    c.close()


def on(cluster, **kw) -> RunOptions:
    return RunOptions(scheduler=cluster.scheduler_address, security=cluster.security, retries=2, **kw)


STRANGER = """
import os, sys
import distributed
address = sys.argv[1]
for name, addr in (("tls without credentials", address),
                   ("plain tcp", "tcp://" + address.removeprefix("tls://"))):
    try:
        with distributed.Client(addr, timeout="3s", set_as_default=False) as client:
            print(name, "ran", client.submit(sum, [1, 2]).result(timeout=10), flush=True)
    except Exception as exc:
        print(name, "refused", type(exc).__name__, flush=True)
os._exit(0)  # no interpreter shutdown: the refused clients' loops are not waited for
"""


def test_the_local_cluster_takes_no_stranger(cluster) -> None:
    """Issue 43: the local cluster listened on loopback only, but any local process could connect and run code in
    its workers (a shared host is the normal case on a city's servers). It speaks TLS with credentials made for it:
    another process without them is refused (over TLS and over plain TCP), a client with them runs code.

    The stranger is a separate process, as on a shared host, with a hard time limit: a stranger that is never
    answered runs no code either, and a hung connection attempt cannot hang the suite."""
    import subprocess

    import distributed

    assert cluster.scheduler_address.startswith("tls://127.0.0.1:")
    try:
        done = subprocess.run([sys.executable, "-c", STRANGER, cluster.scheduler_address], capture_output=True,
                              text=True, timeout=60)
        out = done.stdout
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
    assert " ran " not in out, out
    for line in out.splitlines():
        assert " refused " in line, out
    with distributed.Client(cluster.scheduler_address, security=cluster.security, timeout="10s",
                            set_as_default=False) as client:
        assert client.submit(sum, [1, 2]).result(timeout=30) == 3


def status_rows(dataset: Path) -> list[dict[str, str]]:
    with open(dataset / "status.csv", newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_workers_have_the_thread_limits_and_see_the_tests_folder(cluster) -> None:
    from distributed import Client

    with Client(cluster, set_as_default=False) as client:
        seen = client.run(thread_settings)
        paths = client.run(lambda: list(sys.path))
    assert len(seen) == 2
    for s in seen.values():
        assert s["cv2"] == 1 and s["numba"] == 1  # defaults on this machine: one per core
        assert all(s[v] == "1" for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                         "NUMBA_NUM_THREADS", "TRAFFICGEO_THREADS"))
    assert all(TESTS in p for p in paths.values())


def test_own_cluster_runs_every_task_with_its_thread_limits(tmp_path) -> None:
    plan = make_plan(cameras=1, files=2)
    env_before = {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "TRAFFICGEO_THREADS")}
    calls: list[BatchProgress] = []
    report = run_batch(plan, tmp_path, RunOptions(workers=1, threads_per_worker=3), execute=ReportThreads(),
                       progress=calls.append)
    assert [o.status for o in report.outcomes] == ["done"] * 3
    for o in report.outcomes:  # each task saw 3 threads everywhere (the defaults would be 1 or 2 on this machine)
        assert o.reason == "OMP=3 MKL=3 OPENBLAS=3 NUMBA=3 TRAFFICGEO=3 cv2=3 numba=3 ort=3"
    assert not report.interrupted and report.seconds > 0
    # the cluster extra installs bokeh, so the local cluster serves its dashboard and the report links it
    assert report.dashboard is not None and report.dashboard.startswith("http://127.0.0.1:")
    assert {k: os.environ.get(k) for k in env_before} == env_before  # this process's environment is untouched
    assert calls[0].done == 0 and calls[0].total == 3 and calls[-1].done == 3 and calls[-1].running == 0
    assert calls[0].dashboard == report.dashboard  # known from the start, for the progress display


def test_all_done_progress_and_status(cluster, tmp_path) -> None:
    plan = make_plan(cameras=2, files=3, minutes=30.0)
    calls: list[BatchProgress] = []
    seen: list[dict[str, int]] = []

    def progress(state: BatchProgress) -> None:  # status.csv is already rewritten when progress is called
        calls.append(state)
        rows = status_rows(tmp_path)
        seen.append({s: sum(r["status"] == s for r in rows) for s in ("done", "running", "pending")})

    report = run_batch(plan, tmp_path, on(cluster), execute=FakeTask(sleep_s=0.05), progress=progress)
    assert [o.task_id for o in report.outcomes] == [t.task_id for t in plan.tasks]
    assert report.count("done") == 8 and not report.interrupted
    assert report.video_hours == pytest.approx(3.0)  # 6 detect tasks of 30 min; track tasks add no video
    assert len(calls) == 9 and [c.done for c in calls] == list(range(9))
    assert calls[-1].video_hours == pytest.approx(3.0) and calls[-1].speed > 0
    assert max(c.running for c in calls) <= 4
    assert [(v["done"], v["running"]) for v in seen] == [(c.done, c.running) for c in calls]
    assert seen[0]["pending"] == 8 and max(v["running"] for v in seen) >= 1
    rows = status_rows(tmp_path)
    assert list(rows[0]) == list(STATUS_COLUMNS)
    assert [r["task_id"] for r in rows] == [t.task_id for t in plan.tasks]
    assert {r["status"] for r in rows} == {"done"}
    assert [r["stage"] for r in rows] == ["detect"] * 6 + ["track"] * 2
    assert rows[0]["camera_id"] == "cam0" and rows[-1]["camera_id"] == "cam1"
    assert all(float(r["seconds"]) >= 0.05 for r in rows)
    assert all(parse_utc(r["finished_utc"]) for r in rows)
    # track tasks started after each of their detect tasks ended
    runs = {name: (a, b) for name, a, b in spans(tmp_path)}
    for t in plan.tasks[6:]:
        assert runs[task_folder(t.task_id)][0] >= max(runs[task_folder(d)][1] for d in t.depends)


def max_in_flight(dataset: Path) -> int:
    events = sorted([(a, 1) for _, a, _ in spans(dataset)] + [(b, -1) for _, _, b in spans(dataset)],
                    key=lambda e: (e[0], e[1]))
    level = top = 0
    for _, step in events:
        level += step
        top = max(top, level)
    return top


def test_window_bounds_the_tasks_in_flight(cluster, tmp_path) -> None:
    plan = make_plan(cameras=1, files=4)
    report = run_batch(plan, tmp_path / "w1", on(cluster, window=1), execute=FakeTask(sleep_s=0.15))
    assert report.count("done") == 5
    assert max_in_flight(tmp_path / "w1") == 1
    in_order = [name for name, _, _ in sorted(spans(tmp_path / "w1"), key=lambda s: s[1])]
    assert in_order == [task_folder(t.task_id) for t in plan.tasks]  # one at a time: plan order
    # the check can fail: with a window of 2 the two workers run two tasks at once
    run_batch(plan, tmp_path / "w2", on(cluster, window=2), execute=FakeTask(sleep_s=0.15))
    assert max_in_flight(tmp_path / "w2") == 2


def test_failed_dependency_and_bad_input_not_retried(cluster, tmp_path) -> None:
    plan = make_plan(cameras=2, files=2)
    report = run_batch(plan, tmp_path, on(cluster), execute=FakeTask(bad=frozenset({"detect/cam0/01"})))
    by_id = {o.task_id: o for o in report.outcomes}
    assert by_id["detect/cam0/01"].status == "failed"
    assert by_id["detect/cam0/01"].reason == "bad input of detect/cam0/01"
    assert attempts(tmp_path, "detect/cam0/01") == 1
    assert by_id["track/cam0/2026-05-04"].status == "failed"
    assert by_id["track/cam0/2026-05-04"].reason == "depends on failed task detect/cam0/01"
    assert attempts(tmp_path, "track/cam0/2026-05-04") == 0  # never ran
    assert by_id["track/cam1/2026-05-04"].status == "done"
    assert report.count("done") == 4 and report.count("failed") == 2


def test_exception_retried_then_failed_with_one_line(cluster, tmp_path) -> None:
    plan = make_plan(cameras=1, files=2)
    report = run_batch(plan, tmp_path, on(cluster), execute=FakeTask(raise_ids=frozenset({"detect/cam0/00"})))
    by_id = {o.task_id: o for o in report.outcomes}
    assert attempts(tmp_path, "detect/cam0/00") == 3  # 1 + 2 retries
    assert by_id["detect/cam0/00"].reason == "RuntimeError: boom in detect/cam0/00 second line"
    assert by_id["detect/cam0/01"].status == "done"
    assert by_id["track/cam0/2026-05-04"].reason == "depends on failed task detect/cam0/00"


def test_killed_worker_is_retried(cluster, tmp_path) -> None:
    plan = make_plan(cameras=1, files=3)
    report = run_batch(plan, tmp_path, on(cluster), execute=FakeTask(kill_ids=frozenset({"detect/cam0/01"})))
    assert {o.status for o in report.outcomes} <= {"done", "skipped"}, [o.reason for o in report.outcomes]
    assert len(report.outcomes) == 4 and report.outcomes[1].status == "done"
    assert marker(tmp_path, "detect/cam0/01", "killed").exists()
    assert attempts(tmp_path, "detect/cam0/01") == 2
    pids = set(marker(tmp_path, "detect/cam0/01", "attempts").read_text().split())
    assert len(pids) == 2  # the second attempt ran in another process


def stop_after(n: int):
    def progress(state: BatchProgress) -> None:
        if state.done >= n:
            raise KeyboardInterrupt
    return progress


@pytest.mark.parametrize("where", ["dask", "serial"])
def test_interrupt_then_rerun_completes(cluster, tmp_path, where) -> None:
    plan = make_plan(cameras=2, files=3)
    options = on(cluster) if where == "dask" else RunOptions(workers=0)
    first = run_batch(plan, tmp_path, options, execute=FakeTask(sleep_s=0.1), progress=stop_after(2))
    assert first.interrupted and first.count("done") == 2
    rows = status_rows(tmp_path)
    assert sum(r["status"] == "done" for r in rows) == 2
    assert {r["status"] for r in rows} == {"done", "pending"}  # in-flight tasks went back to pending
    second = run_batch(plan, tmp_path, options, execute=FakeTask(sleep_s=0.1))
    assert not second.interrupted
    assert {o.status for o in second.outcomes} <= {"done", "skipped"} and len(second.outcomes) == 8
    assert second.count("skipped") >= 2
    assert {r["status"] for r in status_rows(tmp_path)} <= {"done", "skipped"}


def test_serial_gives_the_outcomes_of_dask(cluster, tmp_path) -> None:
    plan = make_plan(cameras=2, files=2)
    fake = FakeTask(bad=frozenset({"detect/cam1/00"}), raise_ids=frozenset({"detect/cam0/01"}))
    a = run_batch(plan, tmp_path / "dask", on(cluster), execute=fake)
    b = run_batch(plan, tmp_path / "serial", RunOptions(workers=0, retries=2), execute=fake)
    assert b.dashboard is None
    assert [(o.task_id, o.status, o.reason) for o in a.outcomes] == [(o.task_id, o.status, o.reason)
                                                                      for o in b.outcomes]
    assert a.count("failed") == 4 and a.video_hours == pytest.approx(b.video_hours) == pytest.approx(1.0)
    for t in plan.tasks:
        assert attempts(tmp_path / "dask", t.task_id) == attempts(tmp_path / "serial", t.task_id)
    # serial runs in plan order, one at a time
    order = sorted(spans(tmp_path / "serial"), key=lambda s: s[1])
    assert [s[0] for s in order if s[0].startswith("detect")] == sorted(s[0] for s in order
                                                                        if s[0].startswith("detect"))


def test_missing_dask_and_bad_options_are_input_errors(tmp_path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(InputError, match=r"install the cluster extra: pip install 'trafficgeo\[cluster\]'"):
        run_batch(make_plan(1, 1), tmp_path, RunOptions(workers=2), execute=FakeTask())
    with pytest.raises(InputError, match="workers -1"):
        RunOptions(workers=-1)
    with pytest.raises(InputError, match="window 0"):
        RunOptions(window=0)
    # serial needs no Dask
    assert run_batch(make_plan(1, 1), tmp_path, RunOptions(workers=0), execute=FakeTask()).count("done") == 2


@pytest.mark.skipif(os.name != "posix", reason="process groups and SIGINT are POSIX")
def test_ctrl_c_in_a_terminal_stops_cleanly(tmp_path) -> None:
    """SIGINT to the whole process group (what Ctrl-C in a terminal does) while tasks run: the workers ignore it,
    the runner cancels, closes the cluster and reports; no traceback on the terminal."""
    import signal
    import subprocess
    import time

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(TESTS).parent / "src"), TESTS]))
    proc = subprocess.Popen([sys.executable, str(Path(TESTS) / "batch_support.py"), str(tmp_path)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        lines.append(proc.stdout.readline())
        if lines[-1].strip() == "done=2":
            break
    os.killpg(proc.pid, signal.SIGINT)
    out, _ = proc.communicate(timeout=60)
    text = "".join(lines) + out
    assert proc.returncode == 130, text
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text
    assert "interrupted=True" in text
    rows = status_rows(tmp_path)
    assert 2 <= sum(r["status"] == "done" for r in rows) < 14 and any(r["status"] == "pending" for r in rows)


def test_task_killing_its_worker_every_time_fails_after_the_allowed_deaths(cluster, tmp_path) -> None:
    plan = make_plan(cameras=1, files=2)
    report = run_batch(plan, tmp_path, on(cluster), execute=FakeTask(always_kill_ids=frozenset({"detect/cam0/00"})))
    by_id = {o.task_id: o for o in report.outcomes}
    assert by_id["detect/cam0/00"].status == "failed"
    assert by_id["detect/cam0/00"].reason.startswith("the worker process died 3 times running it (out of memory?")
    assert attempts(tmp_path, "detect/cam0/00") == 3
    # done, or skipped when it had finished on a worker that the other task killed before it reported back
    assert by_id["detect/cam0/01"].status in ("done", "skipped")
    assert marker(tmp_path, "detect/cam0/01", "done").exists()
    assert by_id["track/cam0/2026-05-04"].reason == "depends on failed task detect/cam0/00"


def test_an_execute_that_cannot_be_pickled_is_refused_before_anything_runs(cluster, tmp_path) -> None:
    import threading

    class Holding(FakeTask):  # stands for an execute holding an ONNX session
        lock = threading.Lock()

        def __reduce__(self):
            return (Holding, (), {"lock": self.lock})

    with pytest.raises(InputError, match=r"cannot be sent to the Dask workers \(.*lock.*\); keep models, ONNX"):
        run_batch(make_plan(1, 1), tmp_path, on(cluster), execute=Holding())
    assert attempts(tmp_path, "detect/cam0/00") == 0


def test_a_ctrl_c_while_futures_are_built_waits_until_the_block_ends() -> None:
    """SIGINT inside ``held`` (where the runner builds Dask futures: an interrupt half-way through a Future's
    ``__init__`` leaves one whose ``__del__`` prints a traceback) raises only when the block ends; outside, at once."""
    import signal

    from trafficgeo.batch.interrupts import DeferredInterrupt

    interrupt = DeferredInterrupt()
    steps = []
    with interrupt.installed():
        with pytest.raises(KeyboardInterrupt):
            with interrupt.held():
                os.kill(os.getpid(), signal.SIGINT)
                steps.append("after the signal, inside")
        steps.append("raised at the end of the block")
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # the handler runs at the next bytecode boundary
                steps.append("not reached")
        with interrupt.held():
            steps.append("no signal: nothing raised")
    assert steps == ["after the signal, inside", "raised at the end of the block", "no signal: nothing raised"]
    assert signal.getsignal(signal.SIGINT) is not interrupt
