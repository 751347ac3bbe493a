"""Tests of the piecewise FCD parser (trafficgeo.io.fcd_parse): pieces join to the whole-file result, a layout
break in any piece falls back to expat, and memory stays bounded by the piece size rather than the file size."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import trafficgeo.io.fcd_parse as fcd_parse
from trafficgeo.io.fcd_read import read_fcd
from trafficgeo.io.fcd_write import write_fcd


def _points(n_vehicles: int, n_steps: int, seed: int = 0) -> pd.DataFrame:
    """Vehicles at random positions (m) in a local metric CRS, 0.1 s steps, SUMO-like ids, types and lanes."""
    rng = np.random.default_rng(seed)
    n = n_vehicles * n_steps
    return pd.DataFrame({
        "track_id": np.tile([f"flow_{k // 10}.{k % 10}" for k in range(n_vehicles)], n_steps),
        "time": np.repeat(np.arange(n_steps) * 0.1, n_vehicles),
        "x": rng.uniform(0, 2000, n), "y": rng.uniform(0, 2000, n), "z": rng.uniform(0, 30, n),
        "speed_kmh": rng.uniform(0, 120, n), "heading_deg": rng.uniform(0, 360, n),
        "class": np.tile(["passenger", "truck", "b&us"], n)[:n], "sumo_lane": np.tile(["e1_0", "e2_1"], n)[:n]})


class _Counter:
    """Wraps a function and counts its calls."""

    def __init__(self, fn: object) -> None:
        self.fn, self.calls = fn, 0

    def __call__(self, *args: object) -> object:
        self.calls += 1
        return self.fn(*args)  # type: ignore[operator]


@pytest.fixture
def fcd(tmp_path: Path) -> Path:
    f = tmp_path / "fcd.xml"
    write_fcd(f, _points(25, 60), crs=None)
    return f


@pytest.mark.parametrize("piece_bytes", [200, 3000, 20000])
def test_pieces_join_to_the_whole_file(monkeypatch: pytest.MonkeyPatch, fcd: Path, piece_bytes: int) -> None:
    """Pieces smaller than one timestep (200 B: each holds whole timesteps anyway), a few timesteps, many."""
    whole = read_fcd(fcd)
    assert len(whole) == 25 * 60 and set(whole["class"]) == {"passenger", "truck", "b&us"}
    fast, expat = _Counter(fcd_parse._parse_fcd_fast), _Counter(fcd_parse._parse_fcd_expat)
    monkeypatch.setattr(fcd_parse, "_parse_fcd_fast", fast)
    monkeypatch.setattr(fcd_parse, "_parse_fcd_expat", expat)
    monkeypatch.setattr(fcd_parse, "_PIECE_BYTES", piece_bytes)
    pieces = read_fcd(fcd)
    assert expat.calls == 0 and fast.calls > (5 if piece_bytes == 20000 else 50)
    pd.testing.assert_frame_equal(pieces, whole)


def test_comment_in_a_late_piece_falls_back_to_expat(monkeypatch: pytest.MonkeyPatch, fcd: Path) -> None:
    whole = read_fcd(fcd)
    text = fcd.read_text(encoding="utf-8")
    cut = text.rindex("<timestep")  # the last timestep: far beyond the first pieces
    fcd.write_text(text[:cut] + "<!-- a <timestep> in a comment -->\n    " + text[cut:], encoding="utf-8")
    fast, expat = _Counter(fcd_parse._parse_fcd_fast), _Counter(fcd_parse._parse_fcd_expat)
    monkeypatch.setattr(fcd_parse, "_parse_fcd_fast", fast)
    monkeypatch.setattr(fcd_parse, "_parse_fcd_expat", expat)
    monkeypatch.setattr(fcd_parse, "_PIECE_BYTES", 2000)
    got = read_fcd(fcd)
    assert expat.calls == 1 and fast.calls > 10
    pd.testing.assert_frame_equal(got, whole)


def test_pieces_with_other_attributes_fall_back(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Without z in the first half and with z in the second, each piece is uniform but they differ: expat reads
    the file, z is NaN where it was not written."""
    pts = _points(5, 40)
    first, second = tmp_path / "a.xml", tmp_path / "b.xml"
    write_fcd(first, pts[pts["time"] < 2.0].drop(columns=["z"]), crs=None)
    write_fcd(second, pts[pts["time"] >= 2.0], crs=None)
    a, b = first.read_text(encoding="utf-8"), second.read_text(encoding="utf-8")
    body = b[b.index("    <timestep"):]
    f = tmp_path / "mixed.xml"
    f.write_text(a[:a.index("</fcd-export>")] + body, encoding="utf-8")
    monkeypatch.setattr(fcd_parse, "_PIECE_BYTES", 1000)
    expat = _Counter(fcd_parse._parse_fcd_expat)
    monkeypatch.setattr(fcd_parse, "_parse_fcd_expat", expat)
    got = read_fcd(f)
    assert expat.calls == 1 and len(got) == len(pts)
    early = got["time"] < 2.0 - 1e-9
    assert got.loc[early, "z"].isna().all() and got.loc[~early, "z"].notna().all()
    np.testing.assert_allclose(got.loc[~early, "z"], pts.loc[pts["time"] >= 2.0, "z"], atol=1e-4)


@pytest.mark.slow
def test_memory_bounded_by_pieces_not_file(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Python-traced peak memory of parsing a ~12 MB FCD: below 1.5 x the file size with 256 KiB pieces, while the
    whole file in one piece takes over 5 x (the byte-level parser's index arrays are 8 bytes per quote)."""
    f = tmp_path / "big.xml"
    write_fcd(f, _points(100, 800), crs=None, decimals=2)
    size = f.stat().st_size
    assert 8e6 < size < 16e6

    def peak(piece_bytes: int) -> float:
        monkeypatch.setattr(fcd_parse, "_PIECE_BYTES", piece_bytes)
        tracemalloc.start()
        try:
            cols = fcd_parse.fcd_columns(f)
            return tracemalloc.get_traced_memory()[1] / size
        finally:
            tracemalloc.stop()
            assert len(cols["time"]) == 80000

    small, whole = peak(1 << 18), peak(size + 1)
    assert small < 1.5 < 5.0 < whole, (small, whole)
