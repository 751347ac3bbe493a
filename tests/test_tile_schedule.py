"""The tile schedule (trafficgeo.video.detectors.schedule): periods from the road a tile serves, still tiles skipped,
new tracks forcing their tile, and a vehicle seen only by a rarely run tile still tracked across a line."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trafficgeo.errors import InputError
from trafficgeo.video.detections import Detections
from trafficgeo.video.detectors.schedule import (
    ScheduleOptions,
    TileSchedule,
    _extent_along_m,
    tile_periods,
)
from trafficgeo.video.detectors.tile_plan import TilePlan
from trafficgeo.video.detectors.tiled import TiledDetector
from trafficgeo.video.pipeline import LEARNED_TRACKER
from trafficgeo.video.track import VehicleTracker

SHAPE = (120, 480)  # frame (H, W) px


def two_tile_plan() -> TilePlan:
    return TilePlan(frame_shape=SHAPE, input_size=416, min_size_px=24.0, max_upscale=2.0,
                    tiles=np.array([[0, 0, 240, 120], [240, 0, 480, 120]]))


def frame(cars: list[tuple[int, int]]) -> np.ndarray:
    """A dark frame with a bright 20 x 10 px car at each (x, y) top-left corner."""
    img = np.full((*SHAPE, 3), 30, dtype=np.uint8)
    for x, y in cars:
        img[y:y + 10, x:x + 20] = 220
    return img


class BrightBlobs:
    """A detector of bright blobs that, like a learned detector on far vehicles, finds nothing in the full frame
    (too small there) and finds them in the tiles; it counts its calls."""

    def __init__(self) -> None:
        self.calls = 0

    def detect(self, image: np.ndarray, time_s: float = 0.0) -> Detections:
        if image.shape[:2] == SHAPE:
            return Detections.empty()
        self.calls += 1
        grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY)
        n, _, stats, _ = cv2.connectedComponentsWithStats((grey > 128).astype(np.uint8))
        rows = [s for s in stats[1:n] if s[4] >= 20]
        boxes = np.array([[x - 0.5, y - 0.5, x + w - 0.5, y + h - 0.5] for x, y, w, h, _ in rows]).reshape(-1, 4)
        return Detections(boxes, np.full(len(boxes), 0.9), np.array(["car"] * len(boxes), dtype=object))


def test_periods_follow_the_road_a_tile_serves() -> None:
    # 100 km/h = 27.8 m/s; 4 looks at 0.1 s -> 11.1 m of road per run; at most 0.5 s (5 frames) between runs
    p = tile_periods(np.array([5.0, 11.2, 40.0, 400.0, np.inf]), 0.1)
    assert p.tolist() == [1, 1, 3, 5, 5]
    assert tile_periods(np.array([40.0]), 0.1, ScheduleOptions(design_speed_kmh=50.0)).tolist() == [5]
    assert tile_periods(np.array([40.0]), 0.2, ScheduleOptions(max_gap_s=1.0)).tolist() == [1]
    with pytest.raises(InputError, match="must be positive"):
        tile_periods(np.array([40.0]), 0.0)


@settings(max_examples=50, deadline=None)
@given(heading=st.floats(0.0, 179.9), length=st.floats(2.0, 300.0), offset=st.floats(-5e6, 5e6))
def test_extent_along_the_travel_direction(heading: float, length: float, offset: float) -> None:
    """Points along a lane of any direction (deg from north) and place: the extent is the lane's length, with the
    heading given or taken from the points' main axis."""
    s = np.linspace(0.0, length, 41)
    direction = np.array([np.sin(np.radians(heading)), np.cos(np.radians(heading))])
    xy = offset + s[:, None] * direction[None, :]
    assert _extent_along_m(xy - offset, np.full(41, heading)) == pytest.approx(length, rel=1e-9)
    assert _extent_along_m(xy - offset, np.full(41, np.nan)) == pytest.approx(length, rel=1e-9)


def test_a_tile_with_no_motion_is_skipped_and_its_vehicles_stand() -> None:
    plan = two_tile_plan()
    base = BrightBlobs()
    det = TiledDetector(base, plan)
    det.schedule = TileSchedule(plan, np.array([1, 1]))
    parked = frame([(50, 50), (300, 50)])
    first = det.detect(parked)
    assert base.calls == 2 and len(first) == 2
    again = det.detect(parked)  # nothing moved: no tile runs, both parked cars are given again
    assert base.calls == 2
    np.testing.assert_allclose(np.sort(again.boxes, axis=0), np.sort(first.boxes, axis=0))
    moved = det.detect(frame([(50, 50), (310, 50)]))  # the right tile changed: it alone runs
    assert base.calls == 3
    assert det.schedule.runs.tolist() == [1, 2] and det.schedule.reused.tolist() == [2, 1]
    assert sorted(moved.boxes[:, 0].tolist()) == [49.5, 309.5]


def test_a_new_track_forces_its_tile_on_the_next_frame() -> None:
    plan = two_tile_plan()
    schedule = TileSchedule(plan, np.array([5, 5]))
    img = frame([])
    schedule.choose(img)  # frame 0: every tile runs
    run, _ = schedule.choose(frame([(300, 50)]))
    assert not run.any()  # not due yet
    schedule.observe_tracks(np.array([[299.5, 49.5, 319.5, 59.5]]), np.array([True]))
    run, _ = schedule.choose(frame([(306, 50)]))
    assert run.tolist() == [False, True]
    schedule.observe_tracks(np.array([[299.5, 49.5, 319.5, 59.5]]), np.array([False]))  # confirmed: no force
    run, _ = schedule.choose(frame([(312, 50)]))
    assert not run.any()


def track_a_car_across(observe: bool, period: int) -> tuple[dict[int, list[float]], int]:
    """A car driving right at 6 px per detection frame through the right tile (run every ``period``-th frame),
    seen by no other pass; returns each confirmed track's box-centre x per frame, and the detector's tile calls."""
    plan = two_tile_plan()
    base = BrightBlobs()
    det = TiledDetector(base, plan)
    det.schedule = TileSchedule(plan, np.array([period, period]))
    tracker = VehicleTracker(10.0, LEARNED_TRACKER)
    tracks: dict[int, list[float]] = {}
    for k in range(37):
        dets = det.detect(frame([(250 + 6 * k, 50)]), 0.1 * k)
        out = tracker.update(dets)
        if observe:
            det.schedule.observe_tracks(*tracker.live_boxes())
        for i, b in zip(out.track_ids, out.boxes, strict=True):
            tracks.setdefault(int(i), []).append(0.5 * (b[0] + b[2]))
    return tracks, base.calls


def test_a_vehicle_crossing_a_line_in_a_rarely_run_tile_is_still_tracked_across_it() -> None:
    line_x = 360.0
    tracks, calls = track_a_car_across(observe=True, period=4)
    assert calls <= 2 + 37 // 4 + 2  # the first frame, one run in 4, and the frame that confirms the new track
    assert len(tracks) == 1  # one vehicle, one track, no switch
    xs = next(iter(tracks.values()))
    assert min(xs) < line_x < max(xs)  # on both sides of the line: its crossing is counted
    # without the forced run, the new track never gets a second detection in a row and never starts
    lost, _ = track_a_car_across(observe=False, period=4)
    assert lost == {}


def test_the_schedule_says_how_often_each_tile_runs() -> None:
    plan = two_tile_plan()
    assert TileSchedule(plan, np.array([2, 2])).summary(0.1).startswith(
        "tile schedule: each tile runs every 2 detection frames (0.20 s; each vehicle seen >= 4 times per tile at "
        "100 km/h)")
    line = TileSchedule(plan, np.array([1, 4])).summary(0.1)
    assert "every 1-4 detection frames (0.10-0.40 s;" in line
    assert "about 2.2 passes per detection frame instead of 3" in line  # 1 + 1/1 + 1/4
