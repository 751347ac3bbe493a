"""Vehicles carried on through an occlusion (trafficgeo.traffic.occlusion), on hand-made tracks with known answers.

A road runs north (+y) from (E0, N0); lanes "1" (x 0..3.5) and "2" (x 3.5..7); a counting line crosses both lanes
at y = N0 + 30. Car A drives north in lane 1 at 10 m/s and vanishes at t = 2 s, 20 m up the road; in the image
another vehicle's box then covers its box from below (nearer the camera).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import shapely

from trafficgeo.errors import InputError
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.site.lanes import lanes_from_boundaries
from trafficgeo.site.lines import CountLine
from trafficgeo.traffic.occlusion import HIDDEN_MATCH_S, hidden_crossings, hidden_ends
from trafficgeo.traffic.trajectories import TrajectoryOptions

E0, N0 = 500000.0, 5000000.0
FPS = 10.0
LANES = lanes_from_boundaries([shapely.LineString([(E0 + x, N0 - 50), (E0 + x, N0 + 150)]) for x in (0.0, 3.5, 7.0)])
LINE = CountLine("L", shapely.LineString([(E0 - 1.0, N0 + 30.0), (E0 + 8.0, N0 + 30.0)]))
CROSSING_COLUMNS = ["line", "track_id", "class", "lane", "direction", "time", "speed_kmh", "x", "y"]


def _points(track: str, t: np.ndarray, y: np.ndarray, x: float = 1.75, source: str | None = None) -> pd.DataFrame:
    speed = np.gradient(y, t) * 3.6
    return pd.DataFrame({"track_id": track, "source_track": source or track, "frame": np.rint(t * FPS).astype(int),
                         "time": t, "x": E0 + x, "y": N0 + y, "speed_kmh": np.abs(speed),
                         "heading_deg": np.where(speed >= 0, 0.0, 180.0), "class": "car",
                         "lane": LANES.assign(np.full(t.size, E0 + x), N0 + y)})


def _image(boxes: dict[str, tuple[np.ndarray, np.ndarray]]) -> ImageTracks:
    """Image tracks from {track: (times, (N, 4) boxes)}."""
    tid = np.concatenate([np.full(len(t), k, dtype=object) for k, (t, _) in boxes.items()])
    t = np.concatenate([t for t, _ in boxes.values()])
    box = np.vstack([b for _, b in boxes.values()])
    return ImageTracks(track_id=tid, frame=np.rint(t * FPS).astype(int), time=t, u=(box[:, 0] + box[:, 2]) / 2,
                       v=box[:, 3], box=box, vclass=np.full(t.size, "car", dtype=object), score=np.ones(t.size))


def _scene(occluder_y2: float = 700.0, a_box_x: float = 900.0, occluder_x1: float | None = None):
    """Car A's world points and image boxes, and an occluder whose box (bottom at ``occluder_y2``, left edge at
    ``occluder_x1``) covers A's last one (bottom at 650) when ``occluder_y2`` > 650."""
    t = np.arange(0.0, 2.0 + 1e-9, 1 / FPS)
    a = _points("A", t, 10.0 * t)
    a_boxes = np.column_stack([np.full(t.size, a_box_x), 600 - 10 * t, np.full(t.size, a_box_x + 60), 650 - 10 * t])
    a_boxes[-1] = [a_box_x, 600, a_box_x + 60, 650]
    x1 = a_box_x - 20 if occluder_x1 is None else occluder_x1
    late = t >= 1.5  # the occluder comes into the picture late
    occluder = np.tile([x1, occluder_y2 - 120, x1 + 100, occluder_y2], (late.sum(), 1)).astype(float)
    return a, _image({"A": (t, a_boxes), "O": (t[late], occluder)})


def _empty_crossings() -> pd.DataFrame:
    return pd.DataFrame({c: pd.Series(dtype=object if c in ("line", "track_id", "class", "lane") else float)
                         for c in CROSSING_COLUMNS})


def test_a_vehicle_that_vanishes_behind_a_nearer_one_is_counted_where_it_would_cross() -> None:
    points, tracks = _scene()
    ends = hidden_ends(points, tracks, (1920, 1080))
    assert list(ends["end"]) == ["last"]  # its first end is in the open
    assert ends["vx"].iloc[0] == pytest.approx(0.0, abs=1e-9) and ends["vy"].iloc[0] == pytest.approx(10.0)
    got = hidden_crossings(points, tracks, (1920, 1080), [LINE], LANES, _empty_crossings(), coast_s=3.0,
                           period=(0.0, 10.0))
    assert len(got) == 1
    row = got.iloc[0]
    assert row["track_id"] == "A" and row["lane"] == "1" and row["line"] == "L"
    assert row["time"] == pytest.approx(3.0, abs=1e-6)  # 10 m more at 10 m/s
    assert row["y"] == pytest.approx(N0 + 30.0, abs=1e-6) and row["x"] == pytest.approx(E0 + 1.75, abs=1e-6)
    assert np.isnan(row["speed_kmh"])  # not seen at the line
    # not far enough to reach the line, or the line beyond the period: nothing
    assert hidden_crossings(points, tracks, (1920, 1080), [LINE], LANES, _empty_crossings(), coast_s=0.9,
                            period=(0.0, 10.0)).empty
    assert hidden_crossings(points, tracks, (1920, 1080), [LINE], LANES, _empty_crossings(), coast_s=3.0,
                            period=(0.0, 2.5)).empty


def test_ends_in_the_open_farther_behind_or_at_the_frame_edge_are_not_hidden() -> None:
    points, tracks = _scene(occluder_y2=620.0)  # the other box ends higher in the image: it is farther away
    assert hidden_ends(points, tracks, (1920, 1080)).empty
    points, tracks = _scene(a_box_x=1.0)  # A's box touches the frame's left edge: it may have left the picture
    assert hidden_ends(points, tracks, (1920, 1080)).empty
    points, tracks = _scene(occluder_x1=948.0)  # covers 12 of A's 60 px: a fifth of its box
    assert hidden_ends(points, tracks, (1920, 1080)).empty
    assert len(hidden_ends(points, tracks, (1920, 1080), cover=0.15)) == 1
    points, tracks = _scene()
    # a track shorter than the velocity window has no hidden end
    short = points[points["time"] >= 1.5]
    assert hidden_ends(short, tracks, (1920, 1080)).empty


def test_the_vehicle_found_again_is_not_counted_twice() -> None:
    points, tracks = _scene()
    seen = _empty_crossings()
    seen.loc[0] = ["L", "B", "car", "1", 1, 3.0 + 0.8 * HIDDEN_MATCH_S, 36.0, E0 + 1.75, N0 + 30.0]
    assert hidden_crossings(points, tracks, (1920, 1080), [LINE], LANES, seen, coast_s=3.0,
                            period=(0.0, 10.0)).empty
    seen.loc[0, "lane"] = "2"  # a vehicle in the other lane at the same time does not count
    assert len(hidden_crossings(points, tracks, (1920, 1080), [LINE], LANES, seen, coast_s=3.0,
                                period=(0.0, 10.0))) == 1


def test_a_first_end_is_carried_back_and_two_ends_of_one_vehicle_count_once() -> None:
    points, tracks = _scene()  # A vanishes at y = 20 (t = 2) ...
    t = np.arange(3.5, 6.0 + 1e-9, 1 / FPS)
    c = _points("C", t, 40.0 + 10.0 * (t - 4.0))  # ... and is found again as C at y = 35 (t = 3.5)
    c_boxes = np.column_stack([np.full(t.size, 900.0), 500 - 10 * (t - 3.5), np.full(t.size, 960.0),
                               540 - 10 * (t - 3.5)])
    early = t <= 4.0  # a nearer vehicle hides C until it is found again
    occluder = np.tile([880.0, 480.0, 980.0, 600.0], (early.sum(), 1))
    both = pd.concat([points, c], ignore_index=True)
    image = _image({"A": (tracks.time[tracks.track_id == "A"], tracks.box[tracks.track_id == "A"]),
                    "O": (tracks.time[tracks.track_id == "O"], tracks.box[tracks.track_id == "O"]),
                    "C": (t, c_boxes), "O2": (t[early], occluder)})
    ends = hidden_ends(both, image, (1920, 1080))
    assert sorted(zip(ends["track_id"], ends["end"], strict=True)) == [("A", "last"), ("C", "first")]
    got = hidden_crossings(both, image, (1920, 1080), [LINE], LANES, _empty_crossings(), coast_s=3.0,
                           period=(0.0, 10.0))
    assert len(got) == 1 and got["time"].iloc[0] == pytest.approx(3.0, abs=1e-6)  # both ends put it at 3 s


def test_coasting_is_an_option_that_can_be_turned_off() -> None:
    assert TrajectoryOptions().coast_hidden_s == 3.0
    points, tracks = _scene()
    assert hidden_crossings(points, tracks, (1920, 1080), [LINE], LANES, _empty_crossings(), coast_s=0.0,
                            period=(0.0, 10.0)).empty
    with pytest.raises(InputError, match="coast_hidden_s"):
        TrajectoryOptions(coast_hidden_s=-1.0)
