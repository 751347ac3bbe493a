"""``trafficgeo batch plan | run | summarize`` end to end on the two-camera city: a local Dask cluster of 2 workers
gives the same dataset as running the tasks serially, a second run does nothing, a changed option re-runs only what
it touches, a corrupt video fails only its own tasks, and the city-wide GeoPackage holds the dataset's counts."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import geopandas as gpd
import pandas as pd
import pytest
from tests.cli_support import invoke

from trafficgeo.batch.dataset import read_table
from trafficgeo.batch.model import task_folder

pytestmark = pytest.mark.slow

TABLES = ("vehicles", "crossings", "counts", "trajectories")


def _status(dataset: Path) -> dict[str, str]:
    with open(dataset / "status.csv", newline="", encoding="utf-8") as f:
        return {row["task_id"]: row["status"] for row in csv.DictReader(f)}


def _edit_options(cameras_csv: Path, edit) -> None:
    """Rewrite the options of every camera of ``cameras_csv`` with ``edit(camera_id, options) -> options``."""
    with open(cameras_csv, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        row["options"] = json.dumps(edit(row["camera_id"], json.loads(row["options"] or "{}")))
    with open(cameras_csv, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _sorted(df: pd.DataFrame) -> pd.DataFrame:
    df = pd.DataFrame(df.drop(columns="geometry", errors="ignore"))
    return df.sort_values(list(df.columns)).reset_index(drop=True)


@pytest.fixture(scope="module")
def city(small_city: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the city (the tests edit its cameras.csv and damage a video) with its task manifest."""
    folder = tmp_path_factory.mktemp("batch_city") / "city"
    shutil.copytree(small_city, folder)
    # checkpoints every 2 s of video, so that a task killed in the middle has something to resume from
    _edit_options(folder / "cameras.csv", lambda camera_id, options: {**options, "checkpoint_s": 2})
    code, out, err = invoke("batch", "plan", folder / "cameras.csv", "--videos", str(folder / "videos" / "*.mp4"),
                            "-o", folder / "tasks.csv")
    assert code == 0, err
    text = " ".join(out.split())
    assert "2 camera(s), 4 video file(s)" in text and "6 tasks (4 detect, 2 track)" in text
    return folder


@pytest.fixture(scope="module")
def dataset(city: Path) -> Path:
    out = city.parent / "dataset"
    code, stdout, err = invoke("batch", "run", city / "tasks.csv", "--out", out, "--workers", 2)
    assert code == 0, err
    text = " ".join(stdout.split())
    assert "6 done, 0 skipped (already done), 0 failed" in text
    assert text.count("dashboard: http://127.0.0.1:") == 1
    return out


def test_two_workers_give_what_a_serial_run_gives(city: Path, dataset: Path) -> None:
    # the manifest is editable: keep camera cam1's tasks only, and run them in this process without Dask
    rows = list(csv.DictReader(open(city / "tasks.csv", newline="", encoding="utf-8")))
    cam1 = city / "tasks_cam1.csv"
    with open(cam1, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(r for r in rows if r["camera_id"] == "cam1")
    serial = city.parent / "serial"
    code, _, err = invoke("batch", "run", cam1, "--out", serial, "--workers", 0)
    assert code == 0, err
    for table in TABLES:
        on_dask = read_table(dataset, table, camera="cam1")
        alone = read_table(serial, table, camera="cam1")
        assert len(on_dask) > 0, table
        pd.testing.assert_frame_equal(_sorted(on_dask), _sorted(alone), obj=table)
    # the dataset is readable by geopandas with its hive partitions, in the dataset's CRS, with lon/lat
    vehicles = gpd.read_parquet(dataset / "vehicles")
    assert set(vehicles["camera"].astype(str)) == {"cam1", "cam2"} and vehicles.crs.to_epsg() == 2949
    assert vehicles["lat"].between(46, 47).all() and vehicles["lon"].between(-72, -70).all()
    assert json.loads((dataset / "dataset.json").read_text())["crs"] == "EPSG:2949"


def _kill_a_worker_mid_task(run: subprocess.Popen, out: Path, videos: dict[str, Path]) -> str | None:
    """Wait until a detect task of the ``run`` (a ``batch run`` process) has written a checkpoint part, then kill
    (SIGKILL) the worker process that is decoding that task's video; returns the task's folder name."""
    import psutil

    deadline = time.monotonic() + 300
    while run.poll() is None and time.monotonic() < deadline:
        for part in sorted((out / "_work").glob("*/.checkpoint/part*.npz")):
            name = part.parents[1].name
            for child in psutil.Process(run.pid).children(recursive=True):
                try:
                    files = {Path(f.path).resolve() for f in child.open_files()}
                except psutil.Error:
                    continue
                if videos[name] in files:
                    child.kill()
                    return name
        time.sleep(0.02)
    return None


def test_a_worker_killed_mid_task_still_ends_with_the_complete_dataset(city: Path, dataset: Path) -> None:
    """(Before the tests that change the dataset.) A ``batch run`` of the same tasks in its own process; one of its
    workers is killed (SIGKILL) while it decodes a video, after the task's first checkpoint: the dataset ends
    complete and equal to the undisturbed one."""
    tasks = list(csv.DictReader(open(city / "tasks.csv", newline="", encoding="utf-8")))
    videos = {task_folder(t["task_id"]): Path(city, t["video"]).resolve() for t in tasks if t["stage"] == "detect"}
    out = city.parent / "killed_dataset"
    run = subprocess.Popen([sys.executable, "-c", "import sys; from trafficgeo import cli; cli.main(sys.argv[1:])",
                            "batch", "run", str(city / "tasks.csv"), "--out", str(out), "--workers", "2"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        killed = _kill_a_worker_mid_task(run, out, videos)
        stdout, stderr = run.communicate(timeout=600)
    finally:
        run.kill()
    assert killed is not None, "no worker was caught in the middle of a detect task"
    assert run.returncode == 0, stderr
    assert "6 done, 0 skipped (already done), 0 failed" in " ".join(stdout.split())
    assert set(_status(out).values()) == {"done"} and not (out / "_work").exists()
    for table in TABLES:
        for camera in ("cam1", "cam2"):
            pd.testing.assert_frame_equal(_sorted(read_table(out, table, camera=camera)),
                                          _sorted(read_table(dataset, table, camera=camera)), obj=table)


def test_a_second_run_skips_everything_and_a_changed_option_reruns_only_its_tasks(city: Path,
                                                                                   dataset: Path) -> None:
    code, stdout, err = invoke("batch", "run", city / "tasks.csv", "--out", dataset, "--workers", 2)
    assert code == 0, err
    assert "0 done, 6 skipped (already done), 0 failed" in " ".join(stdout.split())
    assert set(_status(dataset).values()) == {"skipped"}
    before = read_table(dataset, "counts", camera="cam1")
    # camera cam2 counts per 5 s instead of 10 s: only its track task runs again (detection does not depend on it)
    cameras = (city / "cameras.csv").read_text(encoding="utf-8")
    _edit_options(city / "cameras.csv", lambda camera_id, options: {**options, "interval_s": 5}
                  if camera_id == "cam2" else options)
    try:
        code, stdout, err = invoke("batch", "run", city / "tasks.csv", "--out", dataset, "--workers", 2)
        assert code == 0, err
        status = _status(dataset)
        assert status.pop("track/cam2/2026-05-04") == "done"
        assert set(status.values()) == {"skipped"}
        counts = read_table(dataset, "counts", camera="cam2")
        spans = (pd.to_datetime(counts["end_utc"]) - pd.to_datetime(counts["start_utc"])).dt.total_seconds()
        assert spans.max() == pytest.approx(5.0)
        pd.testing.assert_frame_equal(_sorted(read_table(dataset, "counts", camera="cam1")), _sorted(before))
    finally:
        (city / "cameras.csv").write_text(cameras, encoding="utf-8")


def test_a_second_batch_on_the_same_dataset_is_refused_at_once(city: Path, dataset: Path) -> None:
    """Issue 43: two concurrent runs on one dataset both exited 1 with a confusing message. The dataset is locked
    for a run: a second one exits 2 at once, naming the first one's pid, and changes nothing."""
    import os

    src = Path(__file__).resolve().parents[1] / "src"
    hold = ("import sys\nfrom trafficgeo.io.folder_lock import hold_folder\nwith hold_folder(sys.argv[1]):\n"
            "    print('held', flush=True)\n    sys.stdin.read()\n")
    before = (dataset / "status.csv").read_bytes()
    holder = subprocess.Popen([sys.executable, "-c", hold, str(dataset)], env={**os.environ, "PYTHONPATH": str(src)},
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        code, _stdout, err = invoke("batch", "run", city / "tasks.csv", "--out", dataset, "--workers", 2)
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert f"another trafficgeo run (pid {holder.pid}) is writing to this folder" in err
    finally:
        holder.kill()
        holder.wait(timeout=30)
    assert (dataset / "status.csv").read_bytes() == before


def test_a_full_disk_under_batch_plan_and_run(city: Path, tmp_path: Path) -> None:
    """Issue 43: a full disk under batch plan or batch run stops with one line and exit code 1, with no task
    manifest written and no temporary file left."""
    from cli_support import invoke_on_a_full_disk

    cut = invoke_on_a_full_disk(200, "batch", "plan", city / "cameras.csv", "--videos",
                                str(city / "videos" / "*.mp4"), "-o", tmp_path / "tasks.csv")
    lines = [ln for ln in cut.stderr.splitlines() if ln.startswith("trafficgeo")]
    assert cut.returncode == 1 and len(lines) == 1 and "could not write" in lines[0], cut.stderr
    assert list(tmp_path.iterdir()) == []
    out = tmp_path / "dataset"
    cut = invoke_on_a_full_disk(200, "batch", "run", city / "tasks.csv", "--out", out, "--workers", 0)
    lines = [ln for ln in cut.stderr.splitlines() if ln.startswith("trafficgeo")]
    assert cut.returncode == 1 and len(lines) == 1 and "Traceback" not in cut.stderr, cut.stderr
    assert not any(".tmp" in p.name for p in out.rglob("*")) if out.exists() else True


def test_a_corrupt_video_fails_only_its_own_tasks(city: Path, dataset: Path) -> None:
    broken = city.parent / "broken"
    shutil.copytree(city, broken)
    video = broken / "videos" / "cam1_2026-05-04_07-30-10.mp4"
    video.write_bytes(video.read_bytes()[:2000])  # cut: no frame can be decoded
    out = broken.parent / "broken_dataset"
    code, stdout, err = invoke("batch", "run", broken / "tasks.csv", "--out", out, "--workers", 2)
    text = " ".join(stdout.split())
    assert code == 1, (stdout, err)
    assert "Traceback" not in stdout + err
    status = _status(out)
    assert status["detect/cam1/20260504T053010Z"] == "failed" and status["track/cam1/2026-05-04"] == "failed"
    assert {status[k] for k in status if "cam2" in k} == {"done"}
    assert "failed: detect/cam1/20260504T053010Z: " in text and "depends on failed task" in text
    assert not (out / "vehicles" / "camera=cam1").exists()
    pd.testing.assert_frame_equal(_sorted(read_table(out, "vehicles", camera="cam2")),
                                  _sorted(read_table(dataset, "vehicles", camera="cam2")))


def test_summarize_writes_the_dataset_counts_city_wide(dataset: Path, tmp_path: Path) -> None:
    code, _, err = invoke("batch", "summarize", dataset, "-o", tmp_path / "city.gpkg")
    assert code == 0, err
    counts = gpd.read_file(tmp_path / "city.gpkg", layer="counts")
    table = read_table(dataset, "counts")
    assert counts["count"].sum() == table["count"].sum() > 0
    assert set(counts["camera"]) == {"cam1", "cam2"} and counts.crs.to_epsg() == 2949
    cameras = gpd.read_file(tmp_path / "city.gpkg", layer="cameras")
    assert sorted(cameras["camera_id"]) == ["cam1", "cam2"]
