"""Reading image-space tracks: CSV with points or boxes, MOT Challenge text, times from fps or a column, errors."""

from __future__ import annotations

import numpy as np
import pytest

from trafficgeo.errors import InputError
from trafficgeo.traffic.tracks import read_tracks


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_csv_with_ground_points_and_fps(tmp_path):
    p = write(tmp_path, "t.csv", "frame,track_id,u,v,class,score,extra\n2,a,10,20,car,0.9,x\n0,a,8,18,car,0.8,y\n"
                                 "1,b,100,200,,,z\n")
    t = read_tracks(p, fps=25)
    assert t.track_id.tolist() == ["a", "a", "b"] and t.frame.tolist() == [0, 2, 1]
    np.testing.assert_allclose(t.time, [0.0, 0.08, 0.04])
    np.testing.assert_allclose(t.u, [8, 10, 100])
    assert t.vclass.tolist() == ["car", "car", ""] and np.isnan(t.score[2])
    assert np.isnan(t.box).all()


def test_csv_boxes_give_the_bottom_centre_and_a_time_column_wins(tmp_path):
    p = write(tmp_path, "t.csv", "frame,track_id,x1,y1,x2,y2,time\n5,7,100,50,140,90,1.25\n")
    t = read_tracks(p)
    assert (t.u[0], t.v[0]) == (120.0, 90.0) and t.time[0] == 1.25 and t.track_id[0] == "7"


def test_mot_challenge_text(tmp_path):
    p = write(tmp_path, "gt.txt",
              "1,3,100,50,40,40,1,-1,-1,-1\n2,3,104,52,40,40,0.7,-1,-1,-1\n1,4,10,10,5,5,1,-1,-1,-1\n")
    t = read_tracks(p, fps=10)
    assert t.track_id.tolist() == ["3", "3", "4"]
    np.testing.assert_allclose(t.time, [0.0, 0.1, 0.0])  # MOT frames are 1-based
    np.testing.assert_allclose(t.box[1], [104, 52, 144, 92])
    np.testing.assert_allclose([t.u[1], t.v[1]], [124, 92])
    np.testing.assert_allclose(t.score, [1.0, 0.7, 1.0])


@pytest.mark.parametrize("text, word", [
    ("frame,u,v\n1,2,3\n", "track_id"),
    ("frame,track_id\n1,a\n", "ground point"),
    ("frame,track_id,u,v\n1,a,2,3\n", "`fps`"),
    ("frame,track_id,u,v,time\n1,a,x,3,0\n", "'x'"),
    ("frame,track_id,u,v,time\n1.5,a,2,3,0\n", "whole numbers"),
    ("frame,track_id,u,v,time\n1,a,2,3,0\n1,a,4,5,0\n", "twice"),
    ("frame,track_id,x1,y1,x2,y2,time\n1,a,10,10,5,20,0\n", "x2 < x1"),
])
def test_bad_tracks_get_one_line_errors(tmp_path, text, word):
    p = write(tmp_path, "bad.csv", text)
    with pytest.raises(InputError, match=None) as err:
        read_tracks(p)
    message = str(err.value)
    assert word in message and "\n" not in message and str(p) in message


def test_missing_file_and_bad_fps(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_tracks(tmp_path / "none.csv", fps=25)
    p = write(tmp_path, "t.csv", "frame,track_id,u,v\n1,a,2,3\n")
    with pytest.raises(InputError, match="is not a video frame rate"):
        read_tracks(p, fps=0)
    with pytest.raises(InputError, match="at least frame,id"):
        read_tracks(write(tmp_path, "short.txt", "1,2,3\n"), fps=10)


def test_track_ids_may_contain_hash(tmp_path) -> None:
    """A '#' is an ordinary character in a track id, not the start of a comment."""
    p = tmp_path / "t.csv"
    p.write_text("frame,track_id,u,v\n0,car#1,10,20\n1,car#1,11,21\n")
    t = read_tracks(p, fps=10)
    assert list(t.track_id) == ["car#1", "car#1"] and np.isfinite(t.v).all()
