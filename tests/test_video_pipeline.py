"""The video pipeline end to end: process on a small demo world, resuming after an interruption, chunks, and a
smoke test on the real Intel clip."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cli_support import invoke
from trafficgeo.video.pipeline import CHECKPOINT_DIR, ProcessOptions, detect_and_track

INTEL = Path(__file__).parent / "data" / "intel-sample-video" / "car-detection.mp4"


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from trafficgeo.synth.world import WorldOptions, build_world

    folder = tmp_path_factory.mktemp("video_world")
    build_world(folder, WorldOptions(seed=3, duration_s=8.0, image_size=(640, 360), count_stations=(20.0,),
                                     veh_per_hour_per_lane=900.0))
    return folder


def test_process_writes_every_output_and_no_checkpoint(world: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    code, stdout, stderr = invoke("process", world / "video.mp4", "--camera", world / "camera_truth.json",
                                  "--surface", world / "cloud.laz", "--lanes", world / "lanes.gpkg",
                                  "--lines", world / "count_lines.gpkg", "--out", out,
                                  "--annotate", tmp_path / "annotated.mp4")
    assert code == 0, stderr
    from trafficgeo.video.reader import video_info

    annotated = video_info(tmp_path / "annotated.mp4")
    assert (annotated.width, annotated.height) == (640, 360) and annotated.frame_count > 100
    for name in ("detections.csv", "tracks.csv", "vehicles.csv", "counts.csv", "crossings.csv",
                 "trajectories.gpkg", "summary.json", "process.json"):
        assert (out / name).is_file(), name
    assert not (out / CHECKPOINT_DIR).exists()
    tracks = pd.read_csv(out / "tracks.csv")
    # the background is learnt before detecting: vehicles on screen at the start are found from the first frames
    assert pd.read_csv(out / "detections.csv")["time"].min() < 0.2
    assert tracks["track_id"].nunique() >= 3 and (tracks["time"].diff().dropna() > -10).all()
    assert "vehicles" in stdout
    assert re.search(r"tracks in [0-9.]+ s \([0-9.]+x real time\)", " ".join(stdout.split())), stdout


def test_an_interrupted_run_resumes_to_the_same_tracks(world: Path, tmp_path: Path) -> None:
    """Stop after the first checkpoint (as Ctrl-C would), run again: the result equals an uninterrupted run."""
    from trafficgeo.camera.io import read_camera_json

    cam = read_camera_json(world / "camera_truth.json")
    opts = ProcessOptions(checkpoint_s=3.0)
    full_dets, full_tracks = detect_and_track(world / "video.mp4", cam, None, tmp_path / "full", opts)

    class Stop(Exception):
        pass

    def stop_late(done: int, total: int, t: float) -> None:
        if t > 4.5:
            raise Stop

    with pytest.raises(Stop):
        detect_and_track(world / "video.mp4", cam, None, tmp_path / "cut", opts, progress=stop_late)
    assert (tmp_path / "cut" / CHECKPOINT_DIR / "state.json").is_file()
    assert not (tmp_path / "cut" / "tracks.csv").exists()  # nothing final was written
    seen = []
    dets, tracks = detect_and_track(world / "video.mp4", cam, None, tmp_path / "cut", opts,
                                    progress=lambda d, n, t: seen.append(t))
    assert min(seen) >= 2.9  # it went on from the checkpoint at ~3 s, not from the start
    pd.testing.assert_frame_equal(tracks.reset_index(drop=True), full_tracks.reset_index(drop=True),
                                  check_dtype=False)
    assert len(dets) == len(full_dets)


def test_chunks_stitched_count_like_one_run(world: Path, tmp_path: Path) -> None:
    common = ["--camera", world / "camera_truth.json", "--surface", world / "cloud.laz", "--lines",
              world / "count_lines.gpkg"]
    whole = tmp_path / "whole"
    assert invoke("process", world / "video.mp4", *common, "--out", whole)[0] == 0
    a, b = tmp_path / "a", tmp_path / "b"
    code, _, stderr = invoke("process", world / "video.mp4", *common, "--end", 5.0, "--out", a)
    assert code == 0, stderr
    code, _, stderr = invoke("process", world / "video.mp4", *common, "--start", 3.0, "--out", b)
    assert code == 0, stderr
    code, _, stderr = invoke("stitch", a, b, *common, "--out", tmp_path / "stitched")
    assert code == 0, stderr
    n_whole = len(pd.read_csv(whole / "crossings.csv"))
    n_stitched = len(pd.read_csv(tmp_path / "stitched" / "crossings.csv"))
    assert abs(n_stitched - n_whole) <= 1, (n_stitched, n_whole)


def test_process_bad_input(world: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    code, _, stderr = invoke("process", tmp_path / "missing.mp4", "--camera", world / "camera_truth.json",
                             "--surface", "90", "--out", out)
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr
    code, _, stderr = invoke("process", world / "video.mp4", "--camera", world / "camera_truth.json",
                             "--surface", "90", "--out", out, "--start", 100)
    assert code == 2 and "past the end" in stderr
    code, _, stderr = invoke("process", world / "video.mp4", "--camera", world / "camera_truth.json",
                             "--surface", "90", "--out", out, "--detector", tmp_path / "yolo.onnx")
    assert code == 2 and "yolo.onnx" in stderr and "download" in stderr
    assert not (out / "tracks.csv").exists()


def test_intel_clip_smoke(tmp_path: Path) -> None:
    """The real 768x432 clip (cars driving through a parking lot lane, most of them cut by the frame edge): background
    subtraction and tracking run and find vehicles that persist over many frames (the learned detector on this
    clip's labelled frames: tests/test_detector_real_frames.py)."""
    dets, tracks = detect_and_track(INTEL, None, None, tmp_path / "intel", ProcessOptions(detector="background"))
    assert len(dets) > 50
    lengths = tracks.groupby("track_id").size()
    assert (lengths >= 25).sum() >= 3  # at least three vehicles followed for 2 s or more
    assert np.all(np.isfinite(tracks[["x1", "y1", "x2", "y2"]].to_numpy()))
