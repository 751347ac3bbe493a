"""``trafficgeo batch plan|run|summarize``: many cameras and files on Dask (thin over :mod:`trafficgeo.batch`)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console

batch_app = typer.Typer(no_args_is_help=True, help="Many cameras and video files: plan the tasks, run them on Dask "
                        "(a local cluster or a running one), summarize the dataset.")
app.add_typer(batch_app, name="batch")


@batch_app.command("plan")
def plan(
    cameras: Annotated[Path, typer.Argument(help="cameras.csv: camera_id,camera,surface,timezone,lanes,lines,"
                                            "detector,options (paths relative to it)")],
    videos: Annotated[list[str], typer.Option("--videos", help="glob(s) of the video files; may contain {camera}")],
    output: Annotated[Path, typer.Option("--output", "-o", help="the task manifest to write (tasks.csv)")],
    name_pattern: Annotated[str, typer.Option(help="file names: camera id and local start time (strftime)")]
    = "{camera}_%Y-%m-%d_%H-%M-%S",
    crs: Annotated[str | None, typer.Option(help="CRS of the dataset (default: the first camera's)")] = None,
    max_window: Annotated[float, typer.Option(help="longest piece of a file one detect task takes (s)")] = 3600.0,
) -> None:
    """Find the cameras' video files, read their start times and write the editable task manifest."""
    from trafficgeo.batch.manifest import plan_batch, plan_summary, write_tasks

    result = plan_batch(cameras, videos, name_pattern=name_pattern, crs=crs, max_window_s=max_window)
    for line in plan_summary(result):
        console.print(line, markup=False, highlight=False)
    write_tasks(output, result)
    console.print(f"wrote {len(result.tasks)} tasks to {output}")


@batch_app.command("run")
def run(
    tasks: Annotated[Path, typer.Argument(help="tasks.csv from 'trafficgeo batch plan'")],
    out: Annotated[Path, typer.Option("--out", "-o", help="the dataset folder (GeoParquet, partitioned)")],
    workers: Annotated[int, typer.Option(help="worker processes of the local cluster (0: run in this process)")] = 2,
    threads: Annotated[int, typer.Option(help="threads per worker (OpenCV, ONNX Runtime, numba)")] = 1,
    memory_limit: Annotated[str, typer.Option(help="memory limit per worker, e.g. 4GiB")] = "4GiB",
    scheduler: Annotated[str | None, typer.Option(help="address of a running Dask scheduler (tcp://host:8786) "
                                                  "instead of a local cluster")] = None,
    retries: Annotated[int, typer.Option(help="retries of a task whose worker died")] = 2,
) -> None:
    """Run the tasks (skipping those already done with the same inputs); Ctrl-C stops, running again continues."""
    from rich.progress import BarColumn, Progress, TextColumn

    from trafficgeo.batch.manifest import read_tasks
    from trafficgeo.batch.runner import RunOptions, run_batch

    manifest = read_tasks(tasks)
    options = RunOptions(workers=workers, threads_per_worker=threads, memory_limit=memory_limit,
                         scheduler=scheduler, retries=retries)
    columns = (TextColumn("[progress.description]{task.description}"), BarColumn(),
               TextColumn("{task.completed}/{task.total} tasks, {task.fields[line]}"))
    with Progress(*columns, console=console, transient=True) as bar:
        shown = bar.add_task("batch", total=len(manifest.tasks), line="starting")
        shown_link: list[str] = []  # the dashboard link, printed once as soon as the cluster serves it

        def tick(state) -> None:
            if state.dashboard and not shown_link:
                shown_link.append(state.dashboard)
                console.print(f"dashboard: {state.dashboard}")
            bar.update(shown, completed=state.done + state.skipped + state.failed,
                       line=f"{state.failed} failed, {state.running} running, "
                            f"{state.speed:.2f} h of video per hour")

        report = run_batch(manifest, out, options, progress=tick)
    if report.dashboard and not shown_link:
        console.print(f"dashboard: {report.dashboard}")
    for outcome in report.outcomes:
        if outcome.status == "failed":
            console.print(f"failed: {outcome.task_id}: {outcome.reason}", markup=False, highlight=False)
    counts = {s: sum(o.status == s for o in report.outcomes) for s in ("done", "skipped", "failed")}
    console.print(f"{counts['done']} done, {counts['skipped']} skipped (already done), {counts['failed']} failed in "
                  f"{report.seconds:.1f} s ({report.video_hours:.2f} h of video); status in {out / 'status.csv'}")
    if report.interrupted:
        console.print("interrupted; run the same command again to continue")
        sys.exit(130)
    if counts["failed"]:
        sys.exit(1)


@batch_app.command("summarize")
def summarize(
    dataset: Annotated[Path, typer.Argument(help="the dataset folder of 'trafficgeo batch run'")],
    output: Annotated[Path, typer.Option("--output", "-o", help="the city-wide GeoPackage to write (.gpkg)")],
) -> None:
    """Counts per camera, line, lane, direction and interval of the whole dataset as one GeoPackage."""
    from trafficgeo.batch.dataset import summarize_dataset

    written = summarize_dataset(dataset, output)
    console.print(f"wrote {written}")
