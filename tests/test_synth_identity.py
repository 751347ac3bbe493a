"""Identity metrics (trafficgeo.synth.identity) on hand-made boxes with answers worked out by hand."""

from __future__ import annotations

import pandas as pd
import pytest

from trafficgeo.synth.identity import identity_scores, vehicle_ids

COLUMNS = ["frame", "id", "x1", "y1", "x2", "y2"]


def _truth() -> pd.DataFrame:
    """Two vehicles over 20 frames: A drives right, B stands."""
    rows = []
    for f in range(20):
        rows += [(f, "A", 10 + f, 10, 50 + f, 40), (f, "B", 200, 10, 240, 40)]
    return pd.DataFrame(rows, columns=COLUMNS)


def test_perfect_tracks_score_one() -> None:
    s = identity_scores(_truth(), _truth())
    assert (s.idf1, s.id_switches, s.fragmentations, s.hota) == (1.0, 0, 0, pytest.approx(1.0))
    assert (s.truth_ids, s.hypothesis_ids) == (2, 2)


def test_a_vehicle_given_a_new_id_halfway_is_one_switch() -> None:
    """A's id changes at frame 10: one switch; IDF1 = (20 + 10) right boxes of 40 = 0.75; joined again (the
    journeys stage's job), 1.0."""
    hyp = _truth()
    hyp.loc[(hyp["id"] == "A") & (hyp["frame"] >= 10), "id"] = "C"
    s = identity_scores(_truth(), hyp)
    assert s.id_switches == 1 and s.idf1 == pytest.approx(0.75) and s.hota < 1.0 and s.hypothesis_ids == 3
    # the same, with A unseen on frames 10 and 11: a fragmentation too
    gap = hyp[~((hyp["id"] == "C") & (hyp["frame"] < 12))]
    s2 = identity_scores(_truth(), gap)
    assert s2.fragmentations == 1 and s2.id_switches == 1


def test_boxes_take_the_vehicle_they_became() -> None:
    """tracks.csv rows take the vehicle id of trajectories.csv (by tracker id and frame); a box analyze did not use
    takes its tracker id's nearest used box's vehicle; a tracker id never used keeps its own id, marked."""
    tracks = pd.DataFrame({"frame": [0, 1, 2, 3, 4, 5, 0], "track_id": [4, 4, 9, 9, 9, 9, 7], "x1": 0.0,
                           "y1": 0.0, "x2": 1.0, "y2": 1.0})
    points = pd.DataFrame({"track_id": ["4", "4", "4", "9.2"], "source_track": ["4", "4", "9", "9"],
                           "frame": [0, 1, 2, 5]})
    assert list(vehicle_ids(tracks, points)["id"]) == ["4", "4", "4", "4", "9.2", "9.2", "t7"]
