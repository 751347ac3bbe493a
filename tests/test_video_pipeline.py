"""The video pipeline end to end: process on a small demo world, resuming after an interruption, chunks, and a
smoke test on the real Intel clip."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cli_support import invoke
from trafficgeo.video.checkpoint import CHECKPOINT_DIR
from trafficgeo.video.pipeline import ProcessOptions, detect_and_track

pytestmark = pytest.mark.slow  # processes an 8 s world video several times with the learned detector (minutes)

INTEL = Path(__file__).parent / "data" / "intel-sample-video" / "car-detection.mp4"


@pytest.fixture(scope="module")
def world(small_world: Path) -> Path:
    """conftest's small world (8 s, 640x360, a counting line at 20 m): read only."""
    return small_world


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
    assert tracks["track_id"].nunique() >= 3
    # rows in frame order, each at its frame's time in the 25 fps video
    assert (tracks["frame"].diff().dropna() >= 0).all()
    np.testing.assert_allclose(tracks["time"], tracks["frame"] / 25.0, atol=1e-3)
    # the tracks follow the world's vehicles: most track boxes cover a true vehicle's box in the same frame
    on_vehicle = _share_on_true_vehicles(tracks, pd.read_csv(world / "truth_tracks.csv"))
    assert on_vehicle >= 0.95, on_vehicle  # measured 1.000 (the built-in learned detector)
    assert "vehicles" in stdout
    assert re.search(r"tracks in [0-9.]+ s \([0-9.]+x real time\)", " ".join(stdout.split())), stdout


def _share_on_true_vehicles(tracks: pd.DataFrame, truth: pd.DataFrame, min_iou: float = 0.3) -> float:
    """Share of track rows whose box overlaps the box of a visible true vehicle in the same frame by at least
    ``min_iou`` (intersection over union)."""
    seen = truth[truth["visible_fraction"] > 0]
    pairs = tracks.reset_index().merge(seen, on="frame", suffixes=("", "_true"))
    lo = np.maximum(pairs[["x1", "y1"]].to_numpy(), pairs[["x1_true", "y1_true"]].to_numpy())
    hi = np.minimum(pairs[["x2", "y2"]].to_numpy(), pairs[["x2_true", "y2_true"]].to_numpy())
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=1)
    area = np.prod(pairs[["x2", "y2"]].to_numpy() - pairs[["x1", "y1"]].to_numpy(), axis=1)
    area_true = np.prod(pairs[["x2_true", "y2_true"]].to_numpy() - pairs[["x1_true", "y1_true"]].to_numpy(), axis=1)
    pairs["iou"] = inter / (area + area_true - inter)
    best = pairs.groupby("index")["iou"].max().reindex(range(len(tracks)), fill_value=0.0)
    return float((best >= min_iou).mean())


def test_an_interrupted_run_resumes_to_the_same_tracks(world: Path, tmp_path: Path) -> None:
    """Stop after the first checkpoint (as Ctrl-C would), run again: the result equals an uninterrupted run."""
    from trafficgeo.camera.calibrated import read_camera_json

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
    pd.testing.assert_frame_equal(tracks.to_table(), full_tracks.to_table())
    np.testing.assert_array_equal(dets.frame_index, full_dets.frame_index)
    np.testing.assert_array_equal(dets.boxes, full_dets.boxes)


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
    dets, found = detect_and_track(INTEL, None, None, tmp_path / "intel", ProcessOptions(detector="background"))
    assert dets.scores.size > 50
    tracks = found.to_table()
    lengths = tracks.groupby("track_id").size()
    assert (lengths >= 25).sum() >= 3  # at least three vehicles followed for 2 s or more
    assert np.all(np.isfinite(tracks[["x1", "y1", "x2", "y2"]].to_numpy()))
