"""Checks on the hand-labelled real frames (the truth itself: files, box geometry, conventions, licences) and on
the scorer of tests/labelled_frames.py (hand-made cases with known counts)."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from labelled_frames import (
    INTEL_LABELS,
    NGSIM_LABELS,
    Score,
    ignored_truth,
    load_labels,
    match_pairs,
    read_boxes,
    score_frame,
    score_labels,
)
from trafficgeo.video.detections import box_iou

CLASSES = {"car", "van", "pickup", "truck", "bus", "motorcycle"}
INTEL_VIDEO = Path(__file__).parent / "data" / "intel-sample-video" / "car-detection.mp4"
# folder -> (frames at least, boxes per frame at least, image size W x H, licence, attribution)
SETS = {
    NGSIM_LABELS: (20, 15, (640, 480), "CC BY-SA 4.0", "FHWA NGSIM"),
    INTEL_LABELS: (10, 1, (768, 432), "CC BY 4.0", "Intel IoT DevKit sample-videos"),
}
IDS = [p.name for p in SETS]


@pytest.fixture(scope="module", params=list(SETS), ids=IDS)
def label_set(request: pytest.FixtureRequest) -> tuple[Path, pd.DataFrame]:
    return request.param, read_boxes(request.param)


def test_every_frame_is_listed_and_labelled(label_set: tuple[Path, pd.DataFrame]) -> None:
    folder, table = label_set
    n_frames, n_boxes, (w, h), _, _ = SETS[folder]
    files = sorted(p.name for p in folder.iterdir() if p.suffix in (".jpg", ".png"))
    assert files == sorted(table["image"].unique()), "every frame file has boxes and every box has its frame"
    assert len(files) >= n_frames
    counts = table.groupby("image").size()
    assert counts.min() >= n_boxes, counts.idxmin()
    for name in files:
        image = cv2.imread(str(folder / name), cv2.IMREAD_COLOR)
        assert image is not None and image.shape == (h, w, 3), name


def test_boxes_are_well_formed(label_set: tuple[Path, pd.DataFrame]) -> None:
    folder, table = label_set
    _, _, (w, h), _, _ = SETS[folder]
    b = table[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
    assert np.all(b[:, 0] < b[:, 2]) and np.all(b[:, 1] < b[:, 3])
    # Inside the image in the pixel-centre convention: edges from -0.5 to W - 0.5 / H - 0.5.
    assert np.all(b[:, :2] >= -0.5) and np.all(b[:, 2] <= w - 0.5) and np.all(b[:, 3] <= h - 0.5)
    # Edges lie between pixels: integer + 0.5.
    assert np.allclose(np.mod(b, 1.0), 0.5)
    assert set(table["class"]) <= CLASSES
    assert set(table["truncated"]) <= {0, 1} and set(table["occluded"]) <= {0, 1}
    # A box that reaches the frame edge is flagged truncated.
    at_edge = (b[:, 0] <= -0.5) | (b[:, 1] <= -0.5) | (b[:, 2] >= w - 0.5) | (b[:, 3] >= h - 0.5)
    assert np.all(table["truncated"].to_numpy()[at_edge] == 1)


def test_no_vehicle_is_labelled_twice(label_set: tuple[Path, pd.DataFrame]) -> None:
    _, table = label_set
    for name, rows in table.groupby("image"):
        b = rows[["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
        iou = box_iou(b[:, None], b[None])
        np.fill_diagonal(iou, 0.0)
        assert iou.max(initial=0.0) < 0.3, name


def test_source_states_licence_attribution_and_convention(label_set: tuple[Path, pd.DataFrame]) -> None:
    folder, _ = label_set
    _, _, _, licence, attribution = SETS[folder]
    text = (folder / "SOURCE.txt").read_text(encoding="utf-8")
    assert re.search(r"^License: " + re.escape(licence), text, flags=re.M)
    assert attribution in text
    assert "x1 = i - 0.5" in text and "pixel-centre" in text


def test_ngsim_frames_are_the_unchanged_originals() -> None:
    """Each JPEG's SHA-256 is the one SOURCE.txt lists (copied byte for byte from the NGSIM frame set)."""
    listed = dict(re.findall(r"^\s*(seq\d_frame_\d{4}\.jpg)\s+seq\d/frame_\d{4}\.jpg\s+([0-9a-f]{64})\s*$",
                             (NGSIM_LABELS / "SOURCE.txt").read_text(encoding="utf-8"), flags=re.M))
    files = sorted(p.name for p in NGSIM_LABELS.glob("*.jpg"))
    assert sorted(listed) == files
    for name in files:
        assert hashlib.sha256((NGSIM_LABELS / name).read_bytes()).hexdigest() == listed[name], name
    views = {name.split("_")[0] for name in files}
    assert views == {"seq2", "seq4"}


@pytest.mark.slow
def test_intel_frames_are_the_decoded_video_frames() -> None:
    """Each PNG is the frame of car-detection.mp4 at the index frames.csv gives (12.5 fps: time = index x 0.08 s)."""
    frames = pd.read_csv(INTEL_LABELS / "frames.csv")
    assert sorted(frames["image"]) == sorted(p.name for p in INTEL_LABELS.glob("*.png"))
    assert np.allclose(frames["time_s"], frames["frame_index"] * 0.08)
    want = dict(zip(frames["frame_index"], frames["image"], strict=True))
    decoded: dict[int, np.ndarray] = {}
    cap = cv2.VideoCapture(str(INTEL_VIDEO))
    try:
        for index in range(max(want) + 2):
            ok, frame = cap.read()
            assert ok, f"video ended before frame {index}"
            if index in want or index - 1 in want or index + 1 in want:
                decoded[index] = frame.astype(np.int16)
    finally:
        cap.release()
    for index, name in want.items():
        png = cv2.imread(str(INTEL_LABELS / name), cv2.IMREAD_COLOR).astype(np.int16)
        # Equal up to the decoder's colour conversion (identical with OpenCV's FFmpeg here); the neighbouring
        # frames differ by 2.6 grey levels or more on average, so the index is pinned down.
        own = float(np.abs(png - decoded[index]).mean())
        assert own < 1.0, (name, own)
        assert own < min(float(np.abs(png - decoded[i]).mean()) for i in (index - 1, index + 1)), name


def test_load_labels_returns_images_boxes_classes_flags() -> None:
    labels = load_labels(INTEL_LABELS)
    table = read_boxes(INTEL_LABELS)
    assert sorted(labels) == sorted(table["image"].unique())
    image, boxes, classes, flags = labels["frame_0210.png"]
    assert image.shape == (432, 768, 3) and image.dtype == np.uint8
    assert boxes.shape == (2, 4) and classes.shape == (2,) and flags.shape == (2, 2) and flags.dtype == bool
    assert sum(len(f.boxes) for f in labels.values()) == len(table)


# ---- scorer on hand-made cases -------------------------------------------------------------------------------

TRUTH = np.array([[0, 0, 10, 10], [20, 0, 30, 10], [40, 0, 50, 10]], dtype=np.float64)


def test_perfect_detections_score_one() -> None:
    s = score_frame(TRUTH, TRUTH)
    assert (s.tp, s.fp, s.fn) == (3, 0, 0) and s.precision == s.recall == s.f1 == 1.0


def test_shifted_duplicate_and_missed_boxes() -> None:
    det = np.array([
        [1, 0, 11, 10],     # IoU 9/11 = 0.82 with truth 0: found
        [0, 0, 10, 10],     # duplicate of truth 0: false positive
        [25, 0, 35, 10],    # IoU 5/15 = 0.33 with truth 1: too far, false positive; truth 1 missed
        [100, 0, 110, 10],  # nothing there: false positive
    ], dtype=np.float64)
    s = score_frame(det, TRUTH)
    assert (s.tp, s.fp, s.fn) == (1, 3, 2)
    assert s.precision == pytest.approx(1 / 4) and s.recall == pytest.approx(1 / 3)
    assert s.f1 == pytest.approx(2 * (1 / 4) * (1 / 3) / (1 / 4 + 1 / 3))
    assert score_frame(det, TRUTH, iou_min=0.3).tp == 2  # the 0.33 overlap counts at a looser threshold


def test_no_detections_and_no_truth() -> None:
    assert score_frame(np.zeros((0, 4)), TRUTH) == Score(fn=3)
    assert score_frame(TRUTH, np.zeros((0, 4))) == Score(fp=3)
    assert score_frame(np.zeros((0, 4)), np.zeros((0, 4))).f1 == 0.0


def test_ignored_truth_is_neither_missed_nor_a_false_positive() -> None:
    truth = np.vstack([TRUTH, [[60, 0, 64, 10]]])  # a sliver 4 px wide
    ign = ignored_truth(truth, min_side_px=6)
    assert ign.tolist() == [False, False, False, True]
    missed = score_frame(TRUTH, truth, ign)
    assert (missed.tp, missed.fp, missed.fn, missed.ignored_truth, missed.ignored_detections) == (3, 0, 0, 1, 0)
    found = score_frame(truth, truth, ign)
    assert (found.tp, found.fp, found.fn, found.ignored_detections) == (3, 0, 0, 1)
    # Without the ignore option the sliver is a vehicle to find.
    assert score_frame(TRUTH, truth).fn == 1


def test_ignore_by_flags() -> None:
    flags = np.array([[True, False], [False, True], [False, False]])
    assert ignored_truth(TRUTH, flags).tolist() == [False, False, False]
    assert ignored_truth(TRUTH, flags, ignore_truncated=True).tolist() == [True, False, False]
    assert ignored_truth(TRUTH, flags, ignore_occluded=True).tolist() == [False, True, False]


def test_greedy_and_hungarian_matching() -> None:
    # Detection 0 overlaps truth 0 best, but taking that pair leaves detection 1 without a partner.
    iou = np.array([[0.8, 0.6], [0.7, 0.0]])
    assert sorted(match_pairs(iou, 0.5, "greedy")) == [(0, 0)]
    assert sorted(match_pairs(iou, 0.5, "hungarian")) == [(0, 1), (1, 0)]
    # Among equally many matches Hungarian keeps the larger overlaps.
    assert sorted(match_pairs(np.array([[0.9, 0.6], [0.6, 0.9]]), 0.5, "hungarian")) == [(0, 0), (1, 1)]
    assert match_pairs(np.zeros((0, 3))) == []
    with pytest.raises(ValueError, match="unknown matching method"):
        match_pairs(iou, 0.5, "best")


def test_score_labels_on_the_truth_itself() -> None:
    labels = load_labels(INTEL_LABELS)
    by_id = {id(f.image): f.boxes for f in labels.values()}
    total, per = score_labels(labels, lambda image: by_id[id(image)])
    assert (total.tp, total.fp, total.fn) == (sum(len(f.boxes) for f in labels.values()), 0, 0)
    assert set(per) == set(labels)
    shifted, _ = score_labels(labels, lambda image: by_id[id(image)] + 40.0, iou_min=0.5)
    assert shifted.recall < 1.0
