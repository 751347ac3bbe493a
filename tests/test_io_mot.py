"""The one MOT Challenge text reader (trafficgeo.io.mot), as read_tracks uses it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trafficgeo.errors import InputError
from trafficgeo.io.mot import MOT_COLUMNS, read_mot
from trafficgeo.traffic.tracks import read_tracks

HINT = "give a MOT file"


def _write(tmp_path: Path, text: str, name: str = "gt.txt") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_gt_lines_to_corner_boxes(tmp_path: Path) -> None:
    p = _write(tmp_path, "1, 3, 100, 50, 40, 30, 1, -1, -1, -1\n2,3,104.5,52,40,30,0.7,-1,-1,-1\n"
                         "1,car7,10,10,5,5,-1,1,0.5\n")
    t = read_mot(p, HINT)
    assert list(t.columns) == MOT_COLUMNS
    assert t["frame"].tolist() == [1, 2, 1] and t["frame"].dtype == np.int64
    assert t["track_id"].tolist() == ["3", "3", "car7"]
    np.testing.assert_array_equal(t[["x1", "y1", "x2", "y2"]].to_numpy(),
                                  [[100, 50, 140, 80], [104.5, 52, 144.5, 82], [10, 10, 15, 15]])
    assert t["score"].tolist() == [1.0, 0.7, -1.0]


def test_six_columns_and_empty_file(tmp_path: Path) -> None:
    t = read_mot(_write(tmp_path, "4,1,0,0,2,3\n"), HINT)
    assert t["frame"].tolist() == [4] and np.isnan(t["score"]).all() and t["y2"].tolist() == [3.0]
    empty = read_mot(_write(tmp_path, "", "e.txt"), HINT)
    assert empty.empty and list(empty.columns) == MOT_COLUMNS


@pytest.mark.parametrize(("text", "match"), [
    ("1,2,3\n", "at least frame,id,left,top,width,height; found 3"),
    ("1,1,0,0,2,2,1\n2,1,0,zero,2,2,1\n", r"line 2: bb_top = 'zero' is not a finite number; give a MOT file"),
    ("1,1,0,0,2,2,1\n0,1,0,0,2,2,1\n", r"line 2: frame = '0' is not a whole number >= 1"),
    ("1.5,1,0,0,2,2,1\n", r"line 1: frame = '1.5' is not a whole number >= 1"),
    ("1,1,0,0,2,,1\n", r"line 1: bb_height = '' is not a finite number"),
    ("1,1,0,0,2,2,inf\n", r"line 1: conf = 'inf' is not a finite number"),
])
def test_errors_name_the_line(tmp_path: Path, text: str, match: str) -> None:
    with pytest.raises(InputError, match=match) as err:
        read_mot(_write(tmp_path, text), HINT)
    assert "\n" not in str(err.value)


def test_read_tracks_reads_mot_through_it(tmp_path: Path) -> None:
    p = _write(tmp_path, "1,3,100,50,40,40,1\n3,3,104,52,40,40,0.5\n")
    t = read_tracks(p, fps=10)
    np.testing.assert_allclose(t.time, [0.0, 0.2])
    np.testing.assert_allclose(t.box[1], [104, 52, 144, 92])
    with pytest.raises(InputError, match=r"line 1: bb_left = 'x'.*MOT Challenge"):
        read_tracks(_write(tmp_path, "1,3,x,50,40,40,1\n", "bad.txt"), fps=10)
