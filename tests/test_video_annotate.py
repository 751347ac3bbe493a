"""The annotated video (issue 29, part 4): every input frame is written, each track's box is drawn on every frame
from its first to its last tracked frame (interpolated between the detector's frames, nothing after its end), and
labels read "#0 ... 47 km/h"."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from trafficgeo.video.annotate import annotate_video, box_label, frame_boxes
from trafficgeo.video.reader import iter_frames, video_info
from video_support import write_two_car_video

FPS, SECONDS = 10, 2.1  # 21 frames: not a multiple of the detection stride below


def _tracks(frames: np.ndarray, x0: float) -> pd.DataFrame:
    """One track "7" seen by the detector on ``frames`` only: a 40 x 30 px box moving 6 px a frame from ``x0``."""
    x = x0 + 6.0 * frames
    return pd.DataFrame({"frame": frames, "time": frames / FPS, "track_id": 7, "x1": x, "y1": 70.0,
                         "x2": x + 40, "y2": 100.0, "score": 0.9, "class": "car"})


def _points(frames: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"source_track": 7, "frame": frames, "lane": "L1", "speed_kmh": 47.2})


def test_labels_mark_the_id_so_it_does_not_read_as_part_of_the_speed() -> None:
    assert box_label("0", "L1", 47.2) == "#0 L1 47 km/h"
    assert box_label("0", None, 47.2) == "#0 47 km/h"
    assert box_label("12", "", float("nan")) == "#12"


def test_boxes_are_interpolated_between_detection_frames_and_end_at_the_last() -> None:
    frames = np.array([3, 6, 9, 12])
    boxes = frame_boxes(_tracks(frames, 20.0), _points(frames[1:]))
    assert boxes["frame"].tolist() == list(range(3, 13))  # every frame from the first to the last, none after
    np.testing.assert_allclose(boxes["x1"], 20.0 + 6.0 * np.arange(3, 13), atol=1e-9)  # px, linear
    np.testing.assert_allclose(boxes["y2"], 100.0, atol=1e-9)
    # frames before the first analysed point take its label; later ones the last analysed point's
    assert set(boxes["label"]) == {"#7 L1 47 km/h"}


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_two_car_video(tmp_path_factory.mktemp("annotate") / "clip.mp4", FPS, SECONDS, rows=(10, 150),
                               seed=3)


def _outline_change(before: np.ndarray, after: np.ndarray, x1: float) -> float:
    """Mean absolute change (grey levels) of the drawn frame on the box's left edge (column x1, rows 70-100)."""
    c = round(x1)
    return float(np.abs(after[72:99, c - 1:c + 2].astype(float) - before[72:99, c - 1:c + 2].astype(float)).mean())


def test_every_frame_is_written_and_boxes_drawn_between_detections(clip: Path, tmp_path: Path) -> None:
    frames = np.array([3, 6, 9, 12])  # the detector ran every third frame
    out = tmp_path / "annotated.mp4"
    annotate_video(clip, out, _tracks(frames, 20.0), _points(frames))
    source = [f.image for f in iter_frames(clip)]
    drawn = [f.image for f in iter_frames(out)]
    assert len(source) == round(FPS * SECONDS) == 21
    assert len(drawn) == len(source) and video_info(out).frame_count == 21
    for k, (before, after) in enumerate(zip(source, drawn, strict=True)):
        change = _outline_change(before, after, 20.0 + 6.0 * k)
        if 3 <= k <= 12:
            assert change > 40, f"frame {k}: no box drawn ({change:.1f} grey levels)"
        else:
            assert change < 15, f"frame {k}: a box drawn outside the track's frames ({change:.1f} grey levels)"
