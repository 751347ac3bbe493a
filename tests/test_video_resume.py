"""Resuming ``process``: a run killed (SIGKILL) at any point and run again gives exactly the outputs of an
uninterrupted run; checkpoints are plain data, checked before use and tied to every input; one run at a time per
output folder; temporary files of killed writers are cleared."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cli_support import invoke
from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.io.atomic import atomic_path, is_temporary_name, remove_stale_temporaries
from trafficgeo.io.folder_lock import hold_folder
from trafficgeo.video.checkpoint import (
    CHECKPOINT_DIR,
    STATE_FILE,
    load_checkpoint,
    read_part,
    run_key,
)
from trafficgeo.video.detections import Detections
from trafficgeo.video.pipeline import ProcessOptions, detect_and_track
from trafficgeo.video.track import VehicleTracker

pytestmark = pytest.mark.slow  # builds a world and kills and resumes runs in subprocesses

SRC = Path(__file__).resolve().parents[1] / "src"
CHECKPOINT_S = 1.5  # segments start at 0, 1.5, 3 and 4.5 s
PRIME_S = 3.0  # background learning before a segment, shortened for speed: the last two segments start after it, so
# an uninterrupted run learns their models on frames it decodes anyway, a resumed run decodes them again


@pytest.fixture(autouse=True)
def _short_priming(monkeypatch: pytest.MonkeyPatch) -> None:
    import trafficgeo.video.pipeline

    monkeypatch.setattr(trafficgeo.video.pipeline, "PRIME_S", PRIME_S)


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from trafficgeo.synth.world import WorldOptions, build_world

    folder = tmp_path_factory.mktemp("resume_world")
    build_world(folder, WorldOptions(seed=3, duration_s=6.0, image_size=(480, 270), count_stations=(-20.0,),
                                     veh_per_hour_per_lane=900.0, ortho_resolution=0.2, view_half_size=60.0))
    return folder


def _python(code: str, *args: object, input_text: str = "") -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code), *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=300, input=input_text)


# ``trafficgeo ARGV[2:]`` in its own process, SIGKILLed at the first frame at or after ARGV[1] s of video, or (ARGV[1]
# = "analysis") in the analysis, after detection and tracking.
KILLED = """
    import os, signal, sys
    import trafficgeo.traffic.analyze as analyze
    import trafficgeo.video.pipeline
    from trafficgeo import cli
    from trafficgeo.video.checkpoint import PartBuffer
    where, trafficgeo.video.pipeline.PRIME_S, args = sys.argv[1], float(sys.argv[2]), sys.argv[3:]
    add = PartBuffer.add

    def add_or_die(self, index, time_s, *rest):
        if where != "analysis" and time_s >= float(where):
            os.kill(os.getpid(), signal.SIGKILL)
        add(self, index, time_s, *rest)

    def die_analysing(*a, **k):
        os.kill(os.getpid(), signal.SIGKILL)

    PartBuffer.add = add_or_die
    analyze.analyze = die_analysing if where == "analysis" else analyze.analyze
    cli.main(args)
"""


def _same_files(a: Path, b: Path, names: tuple[str, ...]) -> None:
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_killed_anywhere_and_resumed_gives_the_uninterrupted_result(world: Path, tmp_path: Path) -> None:
    """SIGKILL in the 2nd segment, then (resumed) in the last one, which starts after the background priming time,
    then (resumed) in the analysis: each rerun goes on where the last checkpoint was, and the outputs equal
    an uninterrupted run's, row for row."""
    common = [world / "video.mp4", "--camera", world / "camera_truth.json", "--surface", "90", "--lanes",
              world / "lanes.gpkg", "--lines", world / "count_lines.gpkg", "--checkpoint", CHECKPOINT_S,
              "--detector", "background"]  # the one whose state is rebuilt at each checkpoint
    full = tmp_path / "full"
    code, _, stderr = invoke("process", *common, "--out", full)
    assert code == 0, stderr
    cut = tmp_path / "cut"
    args = ["process", *common, "--out", cut]
    assert _python(KILLED, 2.0, PRIME_S, *args).returncode == -signal.SIGKILL
    assert not (cut / "tracks.csv").exists()
    run = _python(KILLED, 5.0, PRIME_S, *args)
    assert run.returncode == -signal.SIGKILL and "resuming from 1.5 s" in run.stdout, run.stderr
    run = _python(KILLED, "analysis", PRIME_S, *args)
    assert run.returncode == -signal.SIGKILL and "resuming from 4.5 s" in run.stdout, run.stderr
    code, stdout, stderr = invoke(*args)  # detection had finished: no decoding, the analysis again
    assert code == 0, stderr
    assert "resuming from 6.0 s" in stdout and "had finished" in stdout
    _same_files(full, cut, ("detections.csv", "tracks.csv", "vehicles.csv", "crossings.csv"))
    tracks = pd.read_csv(full / "tracks.csv")
    assert tracks["track_id"].nunique() >= 5 and tracks["time"].max() > 5.0  # vehicles all along
    assert len(pd.read_csv(full / "crossings.csv")) >= 2 and not (cut / CHECKPOINT_DIR).exists()


@pytest.mark.slow
def test_the_learned_detector_on_the_sparse_schedule_resumes_to_the_uninterrupted_result(world: Path,
                                                                                        tmp_path: Path) -> None:
    """Issue 43: with NanoDet and the sparse tile schedule a kill and a rerun gave other detections, vehicles and
    speeds than the uninterrupted run: the schedule's memory (its frame counter, each tile's last run and thumbnail,
    the tiles' last detections it gives again) was not in the checkpoint. It is now (schedule.npz), and a rerun
    keeps the schedule the interrupted run chose."""
    common = [world / "video.mp4", "--camera", world / "camera_truth.json", "--surface", "90", "--lanes",
              world / "lanes.gpkg", "--lines", world / "count_lines.gpkg", "--checkpoint", CHECKPOINT_S,
              "--tile-schedule", "sparse"]
    full = tmp_path / "full"
    code, stdout, stderr = invoke("process", *common, "--out", full)
    assert code == 0, stderr
    assert "tile schedule: each tile runs every" in stdout  # the schedule is what is tested
    cut = tmp_path / "cut"
    args = ["process", *common, "--out", cut]
    assert _python(KILLED, 2.0, PRIME_S, *args).returncode == -signal.SIGKILL
    state = json.loads((cut / CHECKPOINT_DIR / STATE_FILE).read_text())
    assert state["schedule"]["used"] == "sparse" and state["schedule"]["name"] == "schedule.npz"
    run = _python(KILLED, 4.0, PRIME_S, *args)
    assert run.returncode == -signal.SIGKILL and "resuming from 1.5 s" in run.stdout, run.stderr
    code, stdout, stderr = invoke(*args)
    assert code == 0 and "resuming from 3.0 s" in stdout, stderr
    _same_files(full, cut, ("detections.csv", "tracks.csv", "vehicles.csv", "crossings.csv", "counts.csv"))
    a, b = (json.loads((d / "process.json").read_text())["detector"]["schedule"] for d in (full, cut))
    assert a == b  # its counters carried over too


@pytest.mark.slow
def test_a_run_whose_runtime_changed_starts_again(world: Path, tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 43: the run key held backend "auto", not the runtime the probe chose, so a changed probe cache resumed
    an INT8 run with the float model. The chosen runtime is in the key now: a rerun where the probe chooses another
    starts again (one model's detections throughout)."""
    from dataclasses import replace

    import trafficgeo.video.detectors.learned as learned
    from trafficgeo.camera.calibrated import read_camera_json
    from trafficgeo.site.lanes import read_lanes
    from trafficgeo.video.checkpoint import PartBuffer

    cam = read_camera_json(world / "camera_truth.json")
    surface = ConstantSurface(90.0)
    lanes = read_lanes(world / "lanes.gpkg", crs=cam.crs)
    opts = ProcessOptions(checkpoint_s=CHECKPOINT_S, end_s=3.5, tile_schedule="sparse")
    out = tmp_path / "out"
    real = learned.detector_backend
    add = PartBuffer.add

    def stop_at_2(self, index, time_s, *rest):
        if time_s >= 2.0:
            raise KeyboardInterrupt
        add(self, index, time_s, *rest)

    def another_runtime(detector):  # what the probe would not choose on this machine (it chooses by speed)
        chosen = real(detector)
        return replace(chosen, backend="onnxruntime" if chosen.backend == "onnxruntime-int8" else "onnxruntime-int8")

    with monkeypatch.context() as m:  # the first attempt: the probe chose another runtime, then Ctrl-C
        m.setattr(learned, "detector_backend", another_runtime)
        m.setattr(PartBuffer, "add", stop_at_2)
        with pytest.raises(KeyboardInterrupt):
            detect_and_track(world / "video.mp4", cam, surface, out, opts, lanes=lanes)
    said: list[str] = []
    detect_and_track(world / "video.mp4", cam, surface, out, opts, lanes=lanes, notice=said.append)
    assert any("ignoring the checkpoint" in s and "other inputs or options" in s for s in said), said
    assert not any(s.startswith("resuming") for s in said)


def test_a_changed_roi_or_surface_is_another_run(world: Path, tmp_path: Path) -> None:
    from trafficgeo.camera.calibrated import read_camera_json

    cam = read_camera_json(world / "camera_truth.json")
    surface = ConstantSurface(90.0)
    opts = ProcessOptions(detector="background", checkpoint_s=CHECKPOINT_S, end_s=3.5)

    class Stop(Exception):
        pass

    def stop(done: int, total: int, t: float) -> None:
        if t > 2.0:
            raise Stop

    out = tmp_path / "run"
    with pytest.raises(Stop):
        detect_and_track(world / "video.mp4", cam, surface, out, opts, progress=stop)
    roi = np.full((270, 480), 255, dtype=np.uint8)
    roi[:, :40] = 0
    said: list[str] = []
    seen: list[float] = []
    detect_and_track(world / "video.mp4", cam, surface, out, opts, roi=roi, notice=said.append,
                     progress=lambda d, n, t: seen.append(t))
    assert min(seen) < 0.1  # from the start, not from the checkpoint at 1.5 s
    assert said == [f"ignoring the checkpoint in {out / CHECKPOINT_DIR}: it belongs to a run with other inputs or "
                    "options; starting again"]

    def key(**changes: object) -> str:
        doc = {"camera": cam, "surface": surface, "roi": None, "options": {"checkpoint_s": 1.5},
               "detector_file": None, **changes}
        return run_key(world / "video.mp4", **doc)

    base = key()
    assert base == key()
    others = [key(surface=ConstantSurface(90.5)), key(roi=roi), key(camera=cam.replace(position=cam.position + 0.1)),
              key(options={"checkpoint_s": 2.0}), key(detector_file=world / "camera_truth.json")]
    assert len({base, *others}) == 6


def _planted_pickle(folder: Path, flag: Path) -> None:
    import pickle

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {flag}",))

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "state.pkl").write_bytes(pickle.dumps(Payload()))
    np.savez(folder / "part00000.npz", frame_index=np.array([Payload()], dtype=object))


def test_checkpoints_are_data_checked_and_never_unpickled(world: Path, tmp_path: Path) -> None:
    """A planted pickle (old state.pkl, or an object array inside a part) is never loaded; a damaged or foreign
    checkpoint is ignored with one line saying why, and the run starts again with the right result."""
    from trafficgeo.camera.calibrated import read_camera_json

    cam = read_camera_json(world / "camera_truth.json")
    opts = ProcessOptions(detector="background", checkpoint_s=1.0, end_s=2.5)
    good = tmp_path / "good"
    ref = detect_and_track(world / "video.mp4", cam, None, good, opts)[1].to_table()
    flag = tmp_path / "executed"
    out = tmp_path / "out"
    _planted_pickle(out / CHECKPOINT_DIR, flag)
    said: list[str] = []
    tracks = detect_and_track(world / "video.mp4", cam, None, out, opts, notice=said.append)[1].to_table()
    assert not flag.exists()
    assert len(said) == 1 and "state.json" in said[0] and "starting again" in said[0]
    pd.testing.assert_frame_equal(tracks, ref)

    # a valid checkpoint, damaged in several ways: each is refused with the reason
    def cut_run() -> Path:
        folder = tmp_path / f"cut{len(list(tmp_path.iterdir()))}"

        def stop(done: int, total: int, t: float) -> None:
            if t > 1.5:
                raise KeyboardInterrupt

        with pytest.raises(KeyboardInterrupt):
            detect_and_track(world / "video.mp4", cam, None, folder, opts, progress=stop)
        return folder / CHECKPOINT_DIR

    ck = cut_run()
    key = json.loads((ck / STATE_FILE).read_text())["key"]
    state = load_checkpoint(ck, key)
    assert [e["name"] for e in state.parts] == ["part00000.npz"] and state.next_time_s == 1.0
    part = read_part(ck, state.parts[0])
    assert part.arrays["frame_time"].dtype == np.float64 and part.n_frames == 25
    doc = json.loads((ck / STATE_FILE).read_text())
    with pytest.raises(ValueError, match="other inputs"):
        load_checkpoint(ck, "0" * 32)
    for broken, reason in ((dict(doc, next_time_s="1"), "next_time_s"), (dict(doc, parts={}), "parts"),
                           (dict(doc, parts=[dict(doc["parts"][0], name="../x.npz")]), r"parts\[0\]"),
                           (dict(doc, version=1), "not a checkpoint"), ([1], "not a checkpoint")):
        (ck / STATE_FILE).write_text(json.dumps(broken))
        with pytest.raises(ValueError, match=reason):
            load_checkpoint(ck, key)
    (ck / STATE_FILE).write_text("{not json")
    with pytest.raises(ValueError, match="cannot be read"):
        load_checkpoint(ck, key)
    (ck / STATE_FILE).write_text(json.dumps(doc))
    (ck / "part00000.npz").write_bytes((ck / "part00000.npz").read_bytes()[:-10])
    with pytest.raises(ValueError, match="changed since"):
        read_part(ck, state.parts[0])
    np.savez(ck / "part00000.npz", frame_index=np.array([1], dtype=object))
    with pytest.raises(ValueError):  # an object array would need unpickling: refused (and its hash differs)
        read_part(ck, dict(state.parts[0], sha256=_sha(ck / "part00000.npz")))
    said.clear()
    tracks = detect_and_track(world / "video.mp4", cam, None, ck.parent, opts, notice=said.append)[1].to_table()
    assert len(said) == 1 and "part00000.npz has changed" in said[0]
    pd.testing.assert_frame_equal(tracks, ref)

    ck = cut_run()
    (ck / "part00000.npz").unlink()
    said.clear()
    detect_and_track(world / "video.mp4", cam, None, ck.parent, opts, notice=said.append)
    assert said == [f"ignoring the checkpoint in {ck}: part00000.npz is missing; starting again"]


def _sha(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_no_pickle_in_the_product() -> None:
    """Nothing in the package unpickles (checkpoints and outputs are npz/CSV/Parquet/JSON read without pickle).
    The batch runner hands its task function to Dask, which serializes it between its own processes; that is
    the only serializing allowed, and it only writes (``distributed.protocol.pickle.dumps`` to check it can)."""
    import re

    unpickling = re.compile(r"\b(pickle|cloudpickle|dill|joblib|marshal)\.loads?\(|read_pickle\(|"
                            r"allow_pickle\s*=\s*True|^\s*(import|from) (pickle|cloudpickle|dill|joblib)\b",
                            re.MULTILINE)
    hits = [(p.name, m.group(0)) for p in SRC.rglob("*.py") for m in unpickling.finditer(p.read_text("utf-8"))]
    assert not hits
    assert unpickling.search("x = pickle.loads(blob)") and unpickling.search("np.load(f, allow_pickle=True)")
    assert unpickling.search("import pickle\n")
    assert not unpickling.search("from distributed.protocol.pickle import dumps")
    serializing = [p.name for p in SRC.rglob("*.py") if "pickle" in p.read_text(encoding="utf-8")]
    assert serializing == ["runner.py"], serializing


def test_the_tracker_restores_by_replaying_its_detections() -> None:
    """Two trackers fed interleaved give the ids of one fed alone (no shared counters): replaying the detections
    into a fresh tracker restores it."""
    rng = np.random.default_rng(1)

    def frame(k: int) -> Detections:
        boxes = np.array([[10 + 7 * k + 40 * i, 20 * i, 60 + 7 * k + 40 * i, 20 * i + 30] for i in range(3)], float)
        return Detections(boxes + rng.normal(0, 0.3, boxes.shape), np.full(3, 0.9), np.array(["car"] * 3, object))

    frames = [frame(k) for k in range(30)]
    solo = VehicleTracker(25.0)
    alone = [solo.update(f).track_ids.tolist() for f in frames]
    a, b = VehicleTracker(25.0), VehicleTracker(25.0)
    for k, f in enumerate(frames):
        b.update(frames[-1 - k])
        assert a.update(f).track_ids.tolist() == alone[k]
    resumed = VehicleTracker(25.0)
    for f in frames[:15]:
        resumed.update(f)
    assert [resumed.update(f).track_ids.tolist() for f in frames[15:]] == alone[15:]


LOCK = """
    import sys
    from trafficgeo.errors import InputError
    from trafficgeo.io.folder_lock import hold_folder
    try:
        with hold_folder(sys.argv[1]):
            print("held", flush=True)
            sys.stdin.read()
    except InputError as exc:
        print(exc)
"""


def test_a_second_run_on_the_same_folder_is_refused(world: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(LOCK), str(out)], env=env,
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        code, _, stderr = invoke("process", world / "video.mp4", "--camera", world / "camera_truth.json",
                                 "--surface", "90", "--out", out, "--end", 1.0)
        assert code == 2 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr
        assert f"another trafficgeo run (pid {holder.pid}) is writing to this folder" in stderr
        assert sorted(p.name for p in out.iterdir()) == [".lock"]  # nothing was written
    finally:
        holder.kill()  # as SIGKILL: the lock goes with the process
        holder.wait(timeout=30)
    with hold_folder(out), hold_folder(out):  # free again; re-entrant within one process
        run = _python(LOCK, out)
    assert f"another trafficgeo run (pid {os.getpid()})" in run.stdout
    assert _python(LOCK, out, input_text="").stdout.strip() == "held"
    new = tmp_path / "new"
    code, _, stderr = invoke("process", world / "video.mp4", "--camera", world / "camera_truth.json", "--surface",
                             "90", "--out", new, "--detector", tmp_path / "missing.onnx")
    assert code == 2 and not new.exists()  # a refused run leaves no folder behind


def test_stale_temporaries_of_a_killed_run_are_removed(world: Path, tmp_path: Path) -> None:
    from trafficgeo.camera.calibrated import read_camera_json

    out = tmp_path / "out"
    ck = out / CHECKPOINT_DIR
    stale, writers = [], []
    for target in (out / "tracks.csv", out / "trajectories.gpkg", ck / "part00003.npz", ck / STATE_FILE):
        writers.append(atomic_path(target))  # entered and never left (kept alive): a writer killed mid-write
        tmp = writers[-1].__enter__()
        tmp.write_text("half")
        stale.append(tmp)
    assert all(p.exists() and is_temporary_name(p.name) for p in stale)
    keep = [out / ".notes.tmp", out / "my.tmp.csv", out / ".a.csv.ABCDEFGH.tmp.csv", out / ".a.csv.abcdefgh.tmp.txt"]
    for p in keep:
        p.write_text("mine")
    assert not any(is_temporary_name(p.name) for p in keep)
    detect_and_track(world / "video.mp4", read_camera_json(world / "camera_truth.json"), None, out,
                     ProcessOptions(detector="background", end_s=0.5))
    assert not any(p.exists() for p in stale)
    assert all(p.exists() for p in keep)
    assert remove_stale_temporaries(tmp_path / "missing") == []
