"""Run a batch's tasks on Dask distributed (a local cluster by default) or serially in this process.

:func:`run_batch` takes a plan (an object with ``tasks``, ``cameras`` and ``crs``, e.g.
:class:`trafficgeo.batch.manifest.BatchPlan`) and a dataset folder and runs each task once:

- **Where**: ``RunOptions.workers`` worker processes of a :class:`distributed.LocalCluster` on the loopback
  interface (``threads_per_worker`` task threads each, ``memory_limit`` each; TLS with credentials made for it, so
  that no other local process can connect and run code in its workers), or the running cluster at
  ``RunOptions.scheduler`` (``tcp://host:8786``), or, with ``workers=0`` and no scheduler, **serially in this
  process** without Dask (same order rules, same report; for debugging and to measure Dask's overhead).
- **Threads**: every worker process gets ``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
  ``NUMBA_NUM_THREADS`` and ``TRAFFICGEO_THREADS`` = ``threads_per_worker`` in its environment before it starts,
  and a worker plugin calls ``cv2.setNumThreads`` before any task runs. onnxruntime reads no environment variable:
  code that builds an ONNX session in a task passes :func:`worker_threads` as its intra-op thread count. Sessions
  are built inside the task on the worker; the runner sends only the task, the dataset path and the execute
  callable (plain data, checked to pickle before anything runs), never a session. On a running cluster
  (``scheduler``) the plugin sets the variables and OpenCV when the run registers it; BLAS pools already started
  in those workers keep their size (start the workers with the variables set), and the workers must see the
  dataset folder at the same path and have the same trafficgeo installed.
- **Order**: tasks are submitted in plan order (the detect tasks first), at most ``window`` submitted and not
  finished at a time; a task with ``depends`` only once all of them ended done or skipped. When one of them failed,
  the task is recorded failed ("depends on failed task <id>") without running.
- **Errors**: a task returning a failed outcome (bad input, an InputError) is not retried; a task raising any other
  exception (a bug) or whose worker process died is retried ``retries`` times, then recorded failed with a
  one-line reason (worker deaths count against the scheduler's ``allowed-failures``, which a local cluster sets to
  ``retries``; a running cluster keeps its own).
- **Status**: ``DATASET/status.csv`` (task_id, stage, camera_id, status, seconds, reason, finished_utc) is
  rewritten atomically at the start and after each finished task; ``progress`` gets a :class:`BatchProgress`.
- **Ctrl-C**: outstanding work is cancelled, the cluster closed, status.csv written, and the report says
  ``interrupted``; a rerun skips the tasks already done (their idempotence). Local workers ignore SIGINT (the
  terminal sends it to them too), so they print nothing; a Ctrl-C during the local cluster's start (1-2 s) is
  ignored, one while a task is being submitted takes effect right after
  (:class:`~trafficgeo.batch.interrupts.DeferredInterrupt`). Call :func:`run_batch` under ``if __name__ == "__main__":``
  in a script (worker processes are spawned).

The execute callable is ``execute(task, dataset) -> TaskOutcome`` (``dataset`` a :class:`~pathlib.Path`); on Dask it
must pickle (cloudpickle; best a module-level function or a small object of an importable module). The default runs
:func:`trafficgeo.batch.tasks.run_task` with a :class:`~trafficgeo.batch.tasks.BatchContext` of the plan.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import logging
import os
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from trafficgeo.batch.interrupts import DeferredInterrupt, sigint_ignored
from trafficgeo.batch.model import Task, TaskOutcome, utc_text
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import atomic_open
from trafficgeo.io.environment import environment

#: the environment variables that bound a worker process's library threads (set to ``threads_per_worker``)
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS",
                    "TRAFFICGEO_THREADS")
STATUS_COLUMNS = ("task_id", "stage", "camera_id", "status", "seconds", "reason", "finished_utc")
CLUSTER_HINT = "install the cluster extra: pip install 'trafficgeo[cluster]'"
_DASH_PORT = 8787


@dataclass(frozen=True)
class RunOptions:
    """How to run a batch.

    ``workers``: worker processes of the local cluster (0: run serially in this process, without Dask);
    ``threads_per_worker``: tasks a worker runs at once, and the thread count of OpenCV, BLAS, numba and onnxruntime
    in each worker; ``memory_limit``: per worker (Dask's text, ``"4GiB"``); ``scheduler``: address of a running Dask
    scheduler (``tcp://host:8786``) to use instead of a local cluster, with its ``security`` (a
    :class:`distributed.Security`) when it takes TLS clients only, as :func:`start_local_cluster`'s does;
    ``window``: tasks submitted and not finished at most (default 2 x the cluster's task threads, i.e. 2 x
    ``workers`` at one thread each); ``retries``: extra attempts of a task that raised or whose worker died."""

    workers: int = 2
    threads_per_worker: int = 1
    memory_limit: str = "4GiB"
    scheduler: str | None = None
    window: int | None = None
    retries: int = 2
    security: Any = None

    def __post_init__(self) -> None:
        for name in ("workers", "threads_per_worker", "retries"):
            value = getattr(self, name)
            low = 1 if name == "threads_per_worker" else 0
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise InputError(f"{name} {value!r} must be a whole number >= {low}", parameters=(name,))
        if self.window is not None and (isinstance(self.window, bool) or not isinstance(self.window, int)
                                        or self.window < 1):
            raise InputError(f"window {self.window!r} must be a whole number >= 1 (tasks in flight)",
                             parameters=("window",))

    @property
    def serial(self) -> bool:
        """Whether the tasks run in this process without Dask (``workers=0`` and no scheduler)."""
        return self.workers == 0 and not self.scheduler


@dataclass(frozen=True)
class BatchReport:
    """What a run gave: the outcomes of the tasks that finished (plan order; tasks not finished when interrupted
    are absent), wall ``seconds``, ``video_hours`` of video the detect tasks processed (done, not skipped),
    the Dask ``dashboard`` link (None when serial or without bokeh) and whether Ctrl-C ``interrupted`` it."""

    outcomes: tuple[TaskOutcome, ...]
    seconds: float
    video_hours: float
    dashboard: str | None
    interrupted: bool

    def count(self, status: str) -> int:
        """Number of outcomes with ``status`` (done, skipped, failed)."""
        return sum(o.status == status for o in self.outcomes)


@dataclass(frozen=True)
class BatchProgress:
    """The state of a run for a progress display: task counts, ``video_hours`` processed so far (detect tasks
    done), ``elapsed_s`` of wall time, ``speed`` = hours of video per hour of wall time (0 at the start) and the
    Dask ``dashboard`` link (None when serial or not served)."""

    total: int
    done: int
    skipped: int
    failed: int
    running: int
    video_hours: float
    elapsed_s: float
    speed: float
    dashboard: str | None = None


def worker_threads() -> int:
    """Threads a task may use for one library (onnxruntime intra-op, OpenCV): ``TRAFFICGEO_THREADS`` as set in
    batch workers, else 1."""
    try:
        return max(1, int(os.environ.get("TRAFFICGEO_THREADS", "1")))
    except ValueError:
        return 1


def thread_environment(threads: int) -> dict[str, str]:
    """The environment variables that bound a worker's library threads to ``threads``."""
    return {name: str(int(threads)) for name in THREAD_VARIABLES}


def apply_thread_limits(threads: int) -> dict[str, Any]:
    """Set this process's thread limits to ``threads`` (environment, OpenCV); returns the settings it sees
    (the variables, ``cv2`` threads, numba's thread count when numba is loaded)."""
    import sys

    import cv2

    os.environ.update(thread_environment(threads))
    cv2.setNumThreads(int(threads))
    seen: dict[str, Any] = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    seen["cv2"] = cv2.getNumThreads()
    if "numba" in sys.modules:
        seen["numba"] = sys.modules["numba"].config.NUMBA_NUM_THREADS
    return seen


def thread_settings() -> dict[str, Any]:
    """The thread settings of this process (to check a worker with ``client.run``): the variables, OpenCV's
    thread count, numba's configured thread count."""
    import cv2
    import numba

    seen: dict[str, Any] = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    seen["cv2"] = cv2.getNumThreads()
    seen["numba"] = numba.config.NUMBA_NUM_THREADS
    return seen


def _thread_limits_plugin() -> type:
    """The Dask worker plugin class that sets the library thread limits when a worker starts (before any task).

    Built on first use so that importing this module does not import Dask; it lives in the module's namespace as
    ``_ThreadLimits`` (see :func:`__getattr__`) so workers unpickle it by reference."""
    from distributed import WorkerPlugin

    class _ThreadLimits(WorkerPlugin):
        idempotent = True  # registered again with the same settings (several runs on one cluster): nothing to do

        def __init__(self, threads: int, ignore_sigint: bool = False) -> None:
            self.threads = int(threads)
            self.ignore_sigint = ignore_sigint
            self.name = f"trafficgeo-threads-{self.threads}" + ("-local" if ignore_sigint else "")

        def setup(self, worker: Any) -> None:
            apply_thread_limits(self.threads)
            if self.ignore_sigint:  # a local worker restarted after a crash: Ctrl-C is the client's business
                import signal
                import threading

                if os.name == "posix" and threading.current_thread() is threading.main_thread():
                    signal.signal(signal.SIGINT, signal.SIG_IGN)

    _ThreadLimits.__module__ = __name__
    _ThreadLimits.__qualname__ = "_ThreadLimits"
    return _ThreadLimits


def __getattr__(name: str) -> Any:
    if name == "_ThreadLimits":
        cls = _thread_limits_plugin()
        globals()[name] = cls
        return cls
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _plugin(threads: int, ignore_sigint: bool = False) -> Any:
    import sys

    return sys.modules[__name__]._ThreadLimits(threads, ignore_sigint)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    text = f"{type(exc).__name__}: {text}" if text else type(exc).__name__
    return text if len(text) <= 240 else text[:237] + "..."


def attempt(execute: Callable[[Task, Path], TaskOutcome], task: Task, dataset: Path) -> TaskOutcome:
    """Run ``execute(task, dataset)`` once (on a worker or here): an :class:`InputError` becomes a failed outcome
    (not retried); any other exception propagates (retried). Fills ``seconds`` when the task left it 0."""
    t0 = time.perf_counter()
    try:
        outcome = execute(task, dataset)
    except InputError as exc:
        return TaskOutcome(task.task_id, "failed", reason=" ".join(str(exc).split()),
                           seconds=time.perf_counter() - t0)
    if not isinstance(outcome, TaskOutcome) or outcome.task_id != task.task_id:
        raise TypeError(f"task {task.task_id}: execute returned {outcome!r:.120}, not the task's TaskOutcome")
    if outcome.seconds == 0.0:
        outcome = dataclasses.replace(outcome, seconds=time.perf_counter() - t0)
    return outcome


class _RunTask:
    """The default execute: :func:`trafficgeo.batch.tasks.run_task` with the plan's context (plain data)."""

    def __init__(self, ctx: Any) -> None:
        self.ctx = ctx

    def __call__(self, task: Task, dataset: Path) -> TaskOutcome:
        from trafficgeo.batch.tasks import run_task

        return run_task(task, self.ctx)


class _Book:
    """The runner's bookkeeping: states of the tasks, ready order, status.csv and progress."""

    def __init__(self, tasks: tuple[Task, ...], dataset: Path, progress: Callable[[BatchProgress], Any] | None):
        self.tasks = tasks
        self.by_id = {t.task_id: t for t in tasks}
        self.dataset = dataset
        self.progress = progress
        self.state = {t.task_id: "pending" for t in tasks}
        self.outcomes: dict[str, TaskOutcome] = {}
        self.finished_utc: dict[str, str] = {}
        self.waiting = [t for t in tasks]  # plan order
        self.t0 = time.perf_counter()
        self.dashboard: str | None = None

    def video_hours(self) -> float:
        total_s = 0.0
        for tid, o in self.outcomes.items():
            task = self.by_id[tid]
            if o.status == "done" and task.stage == "detect":
                total_s += o.video_s if o.video_s > 0 else task.hours_of_video * 3600.0
        return total_s / 3600.0

    def next_ready(self) -> Task | None:
        """The first waiting task (plan order) whose dependencies all ended done/skipped; tasks with a failed
        dependency are recorded failed on the way."""
        while True:
            blocked = False
            for i, task in enumerate(self.waiting):
                failed = [d for d in task.depends if self.state.get(d) == "failed" or d not in self.by_id]
                if failed:
                    del self.waiting[i]
                    why = (f"depends on failed task {failed[0]}" if failed[0] in self.by_id
                           else f"depends on task {failed[0]} which is not in the plan")
                    self.finish(TaskOutcome(task.task_id, "failed", reason=why))
                    blocked = True
                    break
                if all(self.state[d] in ("done", "skipped") for d in task.depends):
                    del self.waiting[i]
                    self.state[task.task_id] = "running"
                    return task
            if not blocked:
                return None

    def finish(self, outcome: TaskOutcome) -> None:
        self.outcomes[outcome.task_id] = outcome
        self.state[outcome.task_id] = outcome.status
        self.finished_utc[outcome.task_id] = utc_text(datetime.now(UTC).replace(microsecond=0))
        self.write_status()
        self.report_progress()

    def snapshot(self) -> BatchProgress:
        counts = {s: 0 for s in ("done", "skipped", "failed", "running")}
        for s in self.state.values():
            if s in counts:
                counts[s] += 1
        elapsed = time.perf_counter() - self.t0
        hours = self.video_hours()
        return BatchProgress(len(self.tasks), counts["done"], counts["skipped"], counts["failed"], counts["running"],
                             hours, elapsed, hours / (elapsed / 3600.0) if elapsed > 0 and hours > 0 else 0.0,
                             self.dashboard)

    def report_progress(self) -> None:
        if self.progress is not None:
            self.progress(self.snapshot())

    def write_status(self) -> None:
        self.dataset.mkdir(parents=True, exist_ok=True)
        with atomic_open(self.dataset / "status.csv", "w", newline="") as fh:
            out = csv.writer(fh, lineterminator="\n")
            out.writerow(STATUS_COLUMNS)
            for t in self.tasks:
                o = self.outcomes.get(t.task_id)
                out.writerow([t.task_id, t.stage, t.camera_id, self.state[t.task_id],
                              f"{o.seconds:.3f}" if o else "", o.reason if o else "",
                              self.finished_utc.get(t.task_id, "")])

    def report(self, dashboard: str | None, interrupted: bool) -> BatchReport:
        outcomes = tuple(self.outcomes[t.task_id] for t in self.tasks if t.task_id in self.outcomes)
        return BatchReport(outcomes, time.perf_counter() - self.t0, self.video_hours(), dashboard, interrupted)


def run_batch(plan: Any, dataset: str | os.PathLike[str], options: RunOptions = RunOptions(), *,
              execute: Callable[[Task, Path], TaskOutcome] | None = None,
              progress: Callable[[BatchProgress], Any] | None = None) -> BatchReport:
    """Run the tasks of ``plan`` into the dataset folder ``dataset`` as ``options`` say (see the module doc).

    ``execute(task, dataset) -> TaskOutcome`` runs one task (default: ``trafficgeo.batch.tasks.run_task`` with
    ``BatchContext.from_plan(plan, dataset)``); ``progress(BatchProgress)`` is called at the start and as each task
    finishes. Returns a :class:`BatchReport` (``interrupted`` after Ctrl-C). Raises :class:`InputError` when Dask
    is not installed or the scheduler cannot be reached."""
    folder = Path(dataset)
    tasks = tuple(plan.tasks)
    ids = [t.task_id for t in tasks]
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise InputError(f"task id {dup} appears twice in the plan; each task needs its own id")
    if execute is None:
        from trafficgeo.batch.tasks import BatchContext

        execute = _RunTask(BatchContext.from_plan(plan, folder))
    from trafficgeo.io.folder_lock import hold_folder

    with hold_folder(folder):  # one batch at a time in a dataset: a second is refused at once, naming the first
        book = _Book(tasks, folder, progress)  # status.csv is first written once the run can start: a bad
        if options.serial:                      # scheduler address leaves no dataset folder behind
            return _run_serial(book, execute, options)
        return _run_dask(book, execute, options)


def _run_serial(book: _Book, execute: Callable[[Task, Path], TaskOutcome], options: RunOptions) -> BatchReport:
    interrupted = False
    book.write_status()
    try:
        book.report_progress()
        while (task := book.next_ready()) is not None:
            for left in range(options.retries, -1, -1):
                try:
                    outcome = attempt(execute, task, book.dataset)
                    break
                except Exception as exc:
                    if left == 0:
                        outcome = TaskOutcome(task.task_id, "failed", reason=_one_line(exc))
            book.finish(outcome)
    except KeyboardInterrupt:
        interrupted = True
        for tid, state in book.state.items():
            if state == "running":
                book.state[tid] = "pending"
        book.write_status()
    return book.report(None, interrupted)


def _import_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise InputError(f"Dask distributed is not installed; {CLUSTER_HINT}") from None
    return distributed


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Keep Dask's own logging and warnings off the terminal (worker restarts, closing streams)."""
    names = ("distributed", "tornado", "asyncio", "bokeh")
    levels = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL + 1)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        for n, level in levels.items():
            logging.getLogger(n).setLevel(level)




def start_local_cluster(options: RunOptions = RunOptions()) -> Any:
    """A :class:`distributed.LocalCluster` of ``options.workers`` processes on 127.0.0.1 with the thread limits
    of ``options.threads_per_worker`` (environment before spawn, cv2 plugin) and ``allowed-failures`` =
    ``options.retries``. :func:`run_batch` starts one itself; start one here to run several batches on it (pass
    its ``scheduler_address`` as ``RunOptions.scheduler`` and its ``security`` as ``RunOptions.security``: it takes
    TLS clients with its own temporary credentials only); close it when done."""
    distributed = _import_distributed()
    import dask

    env = thread_environment(options.threads_per_worker)
    config = {"distributed.scheduler.allowed-failures": options.retries,
              "distributed.nanny.pre-spawn-environ": dict(env), "distributed.nanny.environ": dict(env),
              "distributed.worker.daemon": True}
    cluster = None
    try:
        with _quiet(), environment(env), dask.config.set(config):
            with sigint_ignored():  # the workers ignore Ctrl-C: this process handles it
                # TLS with credentials made for this cluster (security=True): on a shared host another local
                # process could otherwise connect to the loopback scheduler and run code in the workers
                cluster = distributed.LocalCluster(n_workers=max(1, options.workers),
                                                   threads_per_worker=options.threads_per_worker,
                                                   memory_limit=options.memory_limit, processes=True,
                                                   host="127.0.0.1", dashboard_address=f"127.0.0.1:{_DASH_PORT}",
                                                   silence_logs=logging.CRITICAL, env=env, security=True)
            with distributed.Client(cluster, set_as_default=False) as client:
                client.register_plugin(_plugin(options.threads_per_worker, ignore_sigint=True))
    except BaseException:  # Ctrl-C while starting: no cluster left behind
        if cluster is not None:
            with _quiet():
                cluster.close()
        raise
    return cluster


def _run_dask(book: _Book, execute: Callable[[Task, Path], TaskOutcome], options: RunOptions) -> BatchReport:
    distributed = _import_distributed()
    _check_sendable(execute)
    cluster = None
    client = None
    interrupted = False
    dashboard = None
    in_flight: dict[Any, str] = {}
    saved_env = {k: os.environ.get(k) for k in THREAD_VARIABLES + ("MALLOC_TRIM_THRESHOLD_",)}
    interrupt = DeferredInterrupt()
    with _quiet(), interrupt.installed():
        try:
            interrupt.holding = True  # a Ctrl-C while the cluster starts takes effect once it is up
            if options.scheduler:
                try:
                    client = distributed.Client(options.scheduler, timeout="10s", set_as_default=False,
                                                security=options.security)
                except (OSError, TimeoutError) as exc:
                    raise InputError(f"could not reach the Dask scheduler at {options.scheduler} ({_one_line(exc)});"
                                     " start it or check the address", parameters=("scheduler",)) from None
                try:
                    client.register_plugin(_plugin(options.threads_per_worker))
                except Exception as exc:
                    raise InputError(f"the Dask workers of {options.scheduler} could not set up trafficgeo "
                                     f"({_one_line(exc)}); install the same trafficgeo on every worker",
                                     parameters=("scheduler",)) from None
            else:
                cluster = start_local_cluster(options)
                client = distributed.Client(cluster, set_as_default=False)
            dashboard = client.dashboard_link if _has_dashboard(client, local=cluster is not None) else None
            book.dashboard = dashboard
            window = options.window or 2 * max(1, sum(client.nthreads().values()))
            allowed_deaths = _allowed_failures(client)
            book.write_status()
            book.report_progress()
            done_set = distributed.as_completed(loop=client.loop)

            def fill() -> None:
                while len(in_flight) < window and (task := book.next_ready()) is not None:
                    key = f"{task.task_id}-{uuid.uuid4().hex[:12]}"
                    fut = client.submit(attempt, execute, task, book.dataset, key=key, pure=False,
                                        retries=options.retries)
                    in_flight[fut] = task.task_id
                    done_set.add(fut)

            with interrupt.held():
                fill()
                book.write_status()
            for fut in done_set:  # Ctrl-C raises only while this waits
                with interrupt.held():
                    tid = in_flight.pop(fut)
                    book.finish(_result(fut, tid, allowed_deaths))
                    fut.release()
                    fill()
        except KeyboardInterrupt:
            interrupted = True
            interrupt.holding = True  # a second Ctrl-C does not break the clean-up
            if client is not None and in_flight:
                with contextlib.suppress(Exception):
                    client.cancel(list(in_flight), force=True)
            for tid, state in book.state.items():
                if state == "running":
                    book.state[tid] = "pending"
            book.write_status()
        finally:
            interrupt.holding = True  # closing: a Ctrl-C now (after the last task, too) must not break it
            if client is not None:
                with contextlib.suppress(Exception):
                    client.close(timeout=10)
            if cluster is not None:
                with contextlib.suppress(Exception):
                    cluster.close(timeout=20)
            for k, v in saved_env.items():  # the nanny sets its pre-spawn variables in this process too
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    return book.report(dashboard, interrupted)


def _check_sendable(execute: Callable[[Task, Path], TaskOutcome]) -> None:
    """The execute callable goes to the workers with every task: it must pickle (and should be small)."""
    from distributed.protocol.pickle import dumps

    try:
        dumps(execute)
    except Exception as exc:
        raise InputError(f"execute {execute!r} cannot be sent to the Dask workers ({_one_line(exc)}); keep models, "
                         "ONNX sessions and open files out of it and build them inside the task") from None


def _allowed_failures(client: Any) -> int:
    """How many worker deaths the scheduler allows a task before it gives up (``allowed-failures``)."""
    import dask

    with contextlib.suppress(Exception):
        return int(client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.allowed_failures))
    return int(dask.config.get("distributed.scheduler.allowed-failures"))


def _has_dashboard(client: Any, local: bool) -> bool:
    """Whether the scheduler serves the dashboard (a local one needs bokeh here; its HTTP server runs anyway)."""
    if local:
        import importlib.util

        if importlib.util.find_spec("bokeh") is None:
            return False
    with contextlib.suppress(Exception):
        return "dashboard" in client.scheduler_info().get("services", {})
    return False


def _result(fut: Any, task_id: str, allowed_deaths: int) -> TaskOutcome:
    """The outcome of a finished future: its TaskOutcome, or failed with the exception's one line."""
    if fut.status == "finished":
        return fut.result()
    try:
        exc = fut.exception()
    except Exception as err:  # cancelled futures raise on exception()
        exc = err
    if exc is None:
        return TaskOutcome(task_id, "failed", reason=f"task {fut.status}")
    if type(exc).__name__ == "KilledWorker":  # Dask's own words name keys and addresses, not the cause
        return TaskOutcome(task_id, "failed", reason=f"the worker process died {allowed_deaths + 1} times running "
                           "it (out of memory? raise memory_limit or give it fewer threads; see the worker logs)")
    return TaskOutcome(task_id, "failed", reason=_one_line(exc))
