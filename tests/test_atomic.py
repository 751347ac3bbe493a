"""Atomic output (trafficgeo.io.atomic): a reader sees the old file or the whole new one, never a part."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from trafficgeo.io.atomic import atomic_path, write_csv_atomic, write_json_atomic


def test_atomic_path_replaces_the_target_only_on_success(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "out.txt"
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent and tmp != target
        tmp.write_text("new")
        assert not target.exists()
    assert target.read_text() == "new"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash while writing")
    assert target.read_text() == "new"
    assert [p.name for p in target.parent.iterdir()] == ["out.txt"]  # no temporary file left behind


def test_write_csv_atomic_writes_missing_values_as_empty_fields(tmp_path: Path) -> None:
    table = pd.DataFrame({"id": [1, 2], "speed_kmh": [50.123456, np.nan], "lane": ["d1_1", None]})
    path = tmp_path / "t.csv"
    write_csv_atomic(path, table, float_format="%.2f")
    assert path.read_text().splitlines() == ["id,speed_kmh,lane", "1,50.12,d1_1", "2,,"]


def test_write_csv_atomic_leaves_the_old_file_when_writing_fails(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    path.write_text("old\n")
    with pytest.raises((TypeError, ValueError)):
        write_csv_atomic(path, pd.DataFrame({"a": [1.0]}), float_format=3)  # not a format string
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["t.csv"]


def test_write_json_atomic_writes_standard_json(tmp_path: Path) -> None:
    path = tmp_path / "d.json"
    write_json_atomic(path, {"rmse": np.float64("nan"), "n": np.int64(3), "uv": np.array([1.5, np.inf])})
    assert json.loads(path.read_text()) == {"rmse": None, "n": 3, "uv": [1.5, None]}
