"""The pipeline's public stages: ``detect`` gives the detections over time of a video window on a site,
``track`` over them gives the tracks the resumable detect-and-track pass wrote (the same ids, the same boxes),
``analyze`` gives what ``analyze_tracks`` gives, and stored detections are read back only from a finished run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from trafficgeo.errors import InputError
from trafficgeo.pipeline.stages import analyze, detect, detect_and_track, track
from trafficgeo.run.tracks import TRACK_COLUMNS, ImageTracks
from trafficgeo.site import Site
from trafficgeo.traffic.analyze import AnalysisOptions
from trafficgeo.video.checkpoint import read_detections
from trafficgeo.video.pipeline import ProcessOptions, settled_options
from trafficgeo.video.reader import video_info

pytestmark = pytest.mark.slow  # decodes and detects the small world's video


@pytest.fixture(scope="module")
def detected(small_world: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    w = small_world
    site = Site.load(w / "camera_truth.json", 90.0, w / "lanes.gpkg", w / "count_lines.gpkg")
    fps = video_info(w / "video.mp4").fps
    opts = settled_options(ProcessOptions(detector="background", end_s=5.0, checkpoint_s=2.0), fps)
    work = tmp_path_factory.mktemp("stages")
    frames = detect(w / "video.mp4", site, work, opts)
    return {"site": site, "fps": fps, "opts": opts, "work": work, "frames": frames, "video": w / "video.mp4"}


def test_detect_gives_the_window_frame_by_frame(detected: dict) -> None:
    frames, opts = detected["frames"], detected["opts"]
    assert len(frames) > 0 and np.all(np.diff(frames.frame_index) == opts.every)  # every n-th frame, none missing
    assert frames.time_s[0] == pytest.approx(0.0, abs=1e-9) and frames.time_s[-1] < 5.0
    assert np.all(np.diff(frames.time_s) > 0)
    assert frames.boxes.shape == (frames.row.size, 4) and frames.scores.size == frames.classes.size == frames.row.size
    assert np.all(np.diff(frames.row) >= 0) and frames.row.max() < len(frames)
    written = pd.read_csv(detected["work"] / "detections.csv")  # what the pass wrote, 3 decimals
    assert len(written) == frames.row.size
    np.testing.assert_allclose(written[["x1", "y1", "x2", "y2"]].to_numpy(), frames.boxes, atol=5e-4)
    np.testing.assert_array_equal(written["frame"].to_numpy(), frames.frame_index[frames.row])


def test_track_on_stored_detections_gives_the_pass_tracks(detected: dict) -> None:
    frames, opts = detected["frames"], detected["opts"]
    again = read_detections(detected["work"])  # the same detections read back from the work folder
    np.testing.assert_array_equal(again.boxes, frames.boxes)
    found = track(again, detected["fps"] / opts.every, opts.tracker)
    assert isinstance(found, ImageTracks) and len(found) > 0
    assert set(found.frame) <= set(frames.frame_index)  # the video's frame numbers, not positions
    tracks = found.to_table()
    assert tuple(tracks.columns) == TRACK_COLUMNS
    written = pd.read_csv(detected["work"] / "tracks.csv")
    assert len(written) == len(tracks)
    np.testing.assert_array_equal(written["frame"].to_numpy(), tracks["frame"].to_numpy())
    np.testing.assert_array_equal(written["track_id"].astype(str).to_numpy(), tracks["track_id"].to_numpy())
    np.testing.assert_allclose(written[["x1", "y1", "x2", "y2"]].to_numpy(),
                               tracks[["x1", "y1", "x2", "y2"]].to_numpy(dtype=float), atol=5e-4)
    np.testing.assert_allclose(written["time"].to_numpy(), tracks["time"].to_numpy(dtype=float), atol=5e-7)


def test_analyze_on_the_site_counts_the_tracks(detected: dict) -> None:
    import trafficgeo as tg
    from trafficgeo.traffic.speed import ScaleKnowledge

    site = detected["site"]
    result = analyze(detected["work"] / "tracks.csv", site, analysis=AnalysisOptions(interval_s=5.0))
    direct = tg.analyze_tracks(site.camera.camera, site.surface, tg.load_tracks(detected["work"] / "tracks.csv"),
                               lanes=site.lanes, lines=site.count_lines, interval_s=5.0,
                               knowledge=ScaleKnowledge.from_camera(site.camera))
    assert len(result.vehicles) == len(direct.vehicles) > 0
    pd.testing.assert_frame_equal(result.counts, direct.counts)
    np.testing.assert_allclose(result.vehicles["speed_kmh"].to_numpy(dtype=float),
                               direct.vehicles["speed_kmh"].to_numpy(dtype=float), rtol=1e-9, equal_nan=True)


def test_track_of_no_detections_is_an_empty_table() -> None:
    from trafficgeo.video.detections import DetectionFrames

    none = DetectionFrames(frame_index=np.arange(3), time_s=np.arange(3) / 10.0, row=np.zeros(0, np.int64),
                           boxes=np.zeros((0, 4)), scores=np.zeros(0), classes=np.zeros(0, dtype=object))
    out = track(none, 10.0)
    assert len(out) == 0 and tuple(out.to_table().columns) == TRACK_COLUMNS


def test_the_pass_tracks_are_what_its_tracks_csv_reads_back(detected: dict) -> None:
    """What ``process`` analyses in memory is, to the last bit, what ``analyze`` reads from its tracks.csv; the
    detections it returns are the stored ones at full precision."""
    import trafficgeo as tg

    said: list[str] = []
    frames, tracks = detect_and_track(detected["video"], detected["site"], detected["work"], detected["opts"],
                                      notice=said.append)
    assert any("had finished" in line for line in said)  # from the finished checkpoint, not detected again
    np.testing.assert_array_equal(frames.boxes, detected["frames"].boxes)
    back = tg.load_tracks(detected["work"] / "tracks.csv")
    assert len(back) == len(tracks) > 0
    for name in ("track_id", "frame", "time", "u", "v", "box", "vclass", "score"):
        np.testing.assert_array_equal(getattr(tracks, name), getattr(back, name), err_msg=name)


def test_read_detections_refuses_an_unfinished_or_missing_run(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no finished detection run"):
        read_detections(tmp_path)
    ck = tmp_path / ".checkpoint"
    ck.mkdir()
    (ck / "state.json").write_text('{"complete": false, "parts": []}', encoding="utf-8")
    with pytest.raises(InputError, match="no finished detection run"):
        read_detections(tmp_path)
