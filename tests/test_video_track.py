"""Tracking (ByteTrack via the trackers library) and stitching time chunks, on boxes with known identities."""

from __future__ import annotations

import pickle
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from trafficgeo.errors import InputError
from trafficgeo.video.detections import Detections
from trafficgeo.video.pipeline import JUNCTION_TRACKER, LEARNED_TRACKER, ProcessOptions, settled_options
from trafficgeo.video.stitch import stitch_tracks
from trafficgeo.video.track import TrackerOptions, VehicleTracker


def _frame(k: int, hidden: bool = False) -> Detections:
    """Two vehicles: one driving right along y = 100, one driving left along y = 300 (hidden when asked)."""
    boxes = [[20 + 8 * k, 100, 100 + 8 * k, 150]]
    classes = ["car"]
    if not hidden:
        boxes.append([900 - 6 * k, 300, 1020 - 6 * k, 380])
        classes.append("truck")
    n = len(boxes)
    return Detections(boxes=np.asarray(boxes, dtype=float), scores=np.full(n, 0.9),
                      classes=np.asarray(classes, dtype=object))


def test_identities_survive_a_short_occlusion_and_classes_are_kept() -> None:
    tracker = VehicleTracker(25.0, TrackerOptions(lost_track_s=1.0))
    ids: dict[str, set[int]] = {"car": set(), "truck": set()}
    for k in range(60):
        out = tracker.update(_frame(k, hidden=20 <= k < 35))  # the truck is hidden for 0.6 s
        for i, c in zip(out.track_ids, out.classes, strict=True):
            ids[str(c)].add(int(i))
    assert len(ids["car"]) == 1 and len(ids["truck"]) == 1
    assert ids["car"] != ids["truck"]


def test_a_long_occlusion_gives_a_new_identity_and_state_pickles() -> None:
    tracker = VehicleTracker(25.0, TrackerOptions(lost_track_s=0.4))
    seen = set()
    for k in range(50):
        out = tracker.update(_frame(k, hidden=10 <= k < 30))  # hidden 0.8 s > 0.4 s
        seen |= {int(i) for i, c in zip(out.track_ids, out.classes, strict=True) if c == "truck"}
        if k == 25:
            tracker = pickle.loads(pickle.dumps(tracker))  # a checkpoint mid-run changes nothing
    assert len(seen) == 2
    with pytest.raises(InputError):
        TrackerOptions(min_iou=1.5)


def _queue_ids(options: TrackerOptions) -> tuple[set[int], set[int]]:
    """A car (A) stands in a queue, seen for 2 s at 12.5 detections a second, then is hidden; at once a second car
    (B) shows up beside it, its box overlapping A's by a quarter (IoU 0.25), and stands there 2 s. The ids of each."""
    tracker = VehicleTracker(12.5, options)
    a_box, b_box = [500.0, 300.0, 600.0, 360.0], [560.0, 300.0, 660.0, 360.0]
    ids: tuple[set[int], set[int]] = (set(), set())
    for k in range(50):
        box = a_box if k < 25 else b_box
        out = tracker.update(Detections(boxes=np.asarray([box]), scores=np.array([0.8]),
                                        classes=np.asarray(["car"], dtype=object)))
        ids[0 if k < 25 else 1].update(int(i) for i in out.track_ids)
    return ids


def test_at_a_junction_a_hidden_cars_identity_does_not_pass_to_the_car_beside_it() -> None:
    a, b = _queue_ids(JUNCTION_TRACKER)
    assert len(a) == 1 and len(b) == 1
    assert a.isdisjoint(b)  # B is a new vehicle, not A moved
    a, b = _queue_ids(LEARNED_TRACKER)  # the road's looser gate lets A's track take B's box
    assert a == b
    assert JUNCTION_TRACKER == replace(LEARNED_TRACKER, min_iou=0.3)  # nothing else differs


def test_a_site_with_gates_settles_on_the_junction_tracker() -> None:
    road = settled_options(ProcessOptions(), 25.0)
    junction = settled_options(ProcessOptions(), 25.0, junction=True)
    assert road.tracker == LEARNED_TRACKER and junction.tracker == JUNCTION_TRACKER
    assert road.every == junction.every == 2  # the learned detector about 10 times a second
    background = settled_options(ProcessOptions(detector="mog2"), 25.0, junction=True)
    assert background.tracker == TrackerOptions() and background.every == 1
    mine = TrackerOptions(min_iou=0.5)
    assert settled_options(ProcessOptions(tracker=mine), 25.0, junction=True).tracker == mine  # asked for: kept


def test_a_car_driving_through_a_junction_keeps_its_identity_at_the_learned_detectors_rate() -> None:
    """A car 100 px long crossing the frame 25 px per detection frame (12.5 a second): one identity."""
    tracker = VehicleTracker(12.5, JUNCTION_TRACKER)
    ids = set()
    for k in range(60):
        box = np.array([[20.0 + 25 * k, 400.0 + 2 * k, 120.0 + 25 * k, 460.0 + 2 * k]])
        out = tracker.update(Detections(boxes=box, scores=np.array([0.6]), classes=np.asarray(["car"], dtype=object)))
        ids.update(int(i) for i in out.track_ids)
    assert len(ids) == 1


def _chunk(rows: list[tuple]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["frame", "time", "track_id", "x1", "y1", "x2", "y2", "score", "class"])


def test_stitch_joins_vehicles_seen_in_both_chunks_once() -> None:
    # vehicle A moves right through frames 0..59 (chunk 0 covers 0..39, chunk 1 covers 30..59: overlap 30..39);
    # vehicle B only in chunk 1
    a = [(f, f / 10, 7, 10 + 5 * f, 50, 60 + 5 * f, 90, 0.9, "car") for f in range(0, 40)]
    a2 = [(f, f / 10, 1, 10 + 5 * f, 50, 60 + 5 * f, 90, 0.9, "car") for f in range(30, 60)]
    b2 = [(f, f / 10, 2, 500, 200 + f, 560, 260 + f, 0.9, "van") for f in range(30, 60)]
    joined = stitch_tracks([_chunk(a), _chunk(a2 + b2)])
    assert set(joined["track_id"]) == {"c0:7", "c1:2"}
    car = joined[joined["track_id"] == "c0:7"]
    assert sorted(car["frame"]) == list(range(60))  # every frame once, no duplicates in the overlap
    assert not joined.duplicated(["track_id", "frame"]).any()
    with pytest.raises(InputError):
        stitch_tracks([])
