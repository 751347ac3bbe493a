"""Fake batch tasks for the runner tests, importable by Dask worker processes (they unpickle them by reference).

A :class:`FakeTask` writes a marker ``_fake/<task>.done`` when it completes and skips a task whose marker exists
(the idempotence of the real tasks); every attempt appends a line to ``_fake/<task>.attempts``, and each run
records its start and end (``time.time()``) in ``_fake/<task>.<pid>.<start ns>.span``. Behaviour per task id:
``bad`` ids return a failed outcome (bad input), ``raise_ids`` raise RuntimeError on every attempt, ``kill_ids``
SIGKILL their own worker process on the first attempt (a marker ``_fake/<task>.killed`` says it happened),
``always_kill_ids`` on every attempt.
A task with ``depends`` fails (reason "dependency missing") if a dependency's marker is absent when it starts.
"""

from __future__ import annotations

import os
import signal
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

from trafficgeo.batch.model import Task, TaskOutcome, task_folder

T0 = datetime(2026, 5, 4, 6, 0, tzinfo=UTC)


@dataclass(frozen=True)
class FakePlan:
    """The parts of a BatchPlan the runner reads."""

    tasks: tuple[Task, ...]
    cameras: dict = field(default_factory=dict)
    crs: str = "EPSG:32633"


def make_plan(cameras: int = 2, files: int = 3, minutes: float = 30.0) -> FakePlan:
    """``files`` detect tasks of ``minutes`` each per camera (plan order: all detect tasks, camera by camera), then
    one track task per camera depending on its detect tasks."""
    detect, track = [], []
    for c in range(cameras):
        cam = f"cam{c}"
        ids = []
        for f in range(files):
            start = T0 + timedelta(minutes=minutes * f)
            tid = f"detect/{cam}/{f:02d}"
            ids.append(tid)
            detect.append(Task(tid, "detect", cam, "2026-05-04", start, start + timedelta(minutes=minutes),
                               video=Path(f"/videos/{cam}_{f}.mp4"), video_end_s=minutes * 60.0))
        track.append(Task(f"track/{cam}/2026-05-04", "track", cam, "2026-05-04", T0,
                          T0 + timedelta(minutes=minutes * files), depends=tuple(ids)))
    return FakePlan(tuple(detect + track))


def marker(dataset: Path, task_id: str, what: str) -> Path:
    return Path(dataset) / "_fake" / f"{task_folder(task_id)}.{what}"


@dataclass(frozen=True)
class FakeTask:
    """A fake ``execute(task, dataset)`` (see the module doc); ``sleep_s`` per run."""

    sleep_s: float = 0.0
    bad: frozenset[str] = frozenset()
    raise_ids: frozenset[str] = frozenset()
    kill_ids: frozenset[str] = frozenset()
    always_kill_ids: frozenset[str] = frozenset()

    def __call__(self, task: Task, dataset: Path) -> TaskOutcome:
        folder = Path(dataset) / "_fake"
        folder.mkdir(parents=True, exist_ok=True)
        with open(marker(dataset, task.task_id, "attempts"), "a") as fh:
            fh.write(f"{os.getpid()}\n")
        done = marker(dataset, task.task_id, "done")
        if done.exists():
            return TaskOutcome(task.task_id, "skipped", key="k")
        start = time.time()
        try:
            if task.task_id in self.kill_ids:
                killed = marker(dataset, task.task_id, "killed")
                if not killed.exists():
                    killed.write_text("1")
                    os.kill(os.getpid(), signal.SIGKILL)
            if task.task_id in self.always_kill_ids:
                os.kill(os.getpid(), signal.SIGKILL)
            if task.task_id in self.raise_ids:
                raise RuntimeError(f"boom in {task.task_id}\nsecond line")
            if task.task_id in self.bad:
                return TaskOutcome(task.task_id, "failed", reason=f"bad input of {task.task_id}")
            missing = [d for d in task.depends if not marker(dataset, d, "done").exists()]
            if missing:
                return TaskOutcome(task.task_id, "failed", reason=f"dependency missing: {missing[0]}")
            time.sleep(self.sleep_s)
            done.write_text("1")
            return TaskOutcome(task.task_id, "done", key="k", video_s=task.hours_of_video * 3600.0)
        finally:
            name = f"{task_folder(task.task_id)}.{os.getpid()}.{time.time_ns()}.span"
            (folder / name).write_text(f"{start!r} {time.time()!r}\n")


def spans(dataset: Path) -> list[tuple[str, float, float]]:
    """(task folder, start, end) of every recorded run."""
    out = []
    for p in sorted((Path(dataset) / "_fake").glob("*.span")):
        a, b = p.read_text().split()
        out.append((p.name.split(".")[0], float(a), float(b)))
    return out


def attempts(dataset: Path, task_id: str) -> int:
    p = marker(dataset, task_id, "attempts")
    return len(p.read_text().splitlines()) if p.exists() else 0


def noop(task: Task, dataset: Path) -> TaskOutcome:
    """A task doing nothing (to measure the runner's overhead per task)."""
    return TaskOutcome(task.task_id, "done")


@dataclass(frozen=True)
class ReportThreads:
    """A task that reports the thread settings it sees in its outcome's ``reason`` (and ends done)."""

    def __call__(self, task: Task, dataset: Path) -> TaskOutcome:
        from trafficgeo.batch.runner import thread_settings, worker_threads

        s = thread_settings()
        text = (f"OMP={s['OMP_NUM_THREADS']} MKL={s['MKL_NUM_THREADS']} OPENBLAS={s['OPENBLAS_NUM_THREADS']} "
                f"NUMBA={s['NUMBA_NUM_THREADS']} TRAFFICGEO={s['TRAFFICGEO_THREADS']} cv2={s['cv2']} "
                f"numba={s['numba']} ort={worker_threads()}")
        return TaskOutcome(task.task_id, "done", reason=text)


def main(argv: list[str]) -> int:
    """``python batch_support.py DATASET``: run a plan of 2 cameras x 6 files of 0.4 s tasks on a local cluster of 2
    workers, printing ``done=N`` lines; exit 130 when interrupted (as the CLI will)."""
    from trafficgeo.batch.runner import RunOptions, run_batch

    report = run_batch(make_plan(2, 6), Path(argv[0]), RunOptions(workers=2), execute=FakeTask(sleep_s=0.4),
                       progress=lambda s: print(f"done={s.done}", flush=True))
    print(f"interrupted={report.interrupted} done={report.count('done')}", flush=True)
    return 130 if report.interrupted else 0


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))
