"""The portable comparisons of tests/reference_values.py: they let the last bits of another CPU through and catch
any difference a user or a change of the code would make."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from reference_values import (
    FIT,
    LAST_BITS,
    TRAFFIC,
    Tol,
    assert_covariance_close,
    assert_csv_close,
    assert_json_close,
    assert_text_close,
)


def test_json_floats_agree_to_their_tolerance_and_everything_else_exactly() -> None:
    old = {"a": 0.5, "b": [1.0, 2.0], "n": 3, "s": "x", "flag": True, "none": None}
    assert_json_close({**old, "a": 0.5 + 4e-16, "b": [1.0, 2.0 - 1e-12]}, old)  # last bits
    for bad in ({**old, "a": 0.5 + 1e-6}, {**old, "n": 4}, {**old, "s": "y"}, {**old, "flag": False},
                {**old, "none": 0.0}, {**old, "b": [1.0]}, {k: v for k, v in old.items() if k != "s"}):
        with pytest.raises(AssertionError):
            assert_json_close(bad, old)
    with pytest.raises(AssertionError, match=r"^\.a: 0\.5001"):
        assert_json_close({**old, "a": 0.5001}, old, tol=FIT)
    assert_json_close({**old, "a": 0.50004}, old, tol=FIT)
    # an override by the value's path
    assert_json_close({"g": [{"du": 1.1}]}, {"g": [{"du": 1.0}]}, overrides={"*.du": Tol(0.0, 0.2)})
    with pytest.raises(AssertionError):
        assert_json_close({"g": [{"dv": 1.1}]}, {"g": [{"dv": 1.0}]}, overrides={"*.du": Tol(0.0, 0.2)})
    # NaN only where the reference has NaN
    assert LAST_BITS.close(math.nan, math.nan) and not LAST_BITS.close(0.0, math.nan)


def test_covariances_are_compared_scaled_by_their_standard_deviations() -> None:
    old = np.array([[1e8, 5e3], [5e3, 1e-2]])  # a km-scale std beside a 0.1 m one
    assert_covariance_close(old + np.array([[5.0, 0.05], [0.05, 5e-10]]), old, "C")  # <= 1e-4 scaled
    with pytest.raises(AssertionError, match="sqrt"):
        assert_covariance_close(old + np.array([[0.0, 0.0], [0.0, 5e-6]]), old, "C")  # the small variance moved
    assert_json_close({"covariance": {"matrix": (old * (1 + 1e-6)).tolist()}},
                      {"covariance": {"matrix": old.tolist()}}, covariances=(".covariance.matrix",))


def test_printed_numbers_may_differ_by_one_unit_of_their_last_digit() -> None:
    old = "check points: 5, RMSE 0.094 m (max 1.5e-03 m)\nk1 estimated"
    assert_text_close(old, old)
    assert_text_close("check points: 5, RMSE 0.095 m (max 1.6e-03 m)\nk1 estimated", old)
    for bad in ("check points: 5, RMSE 0.096 m (max 1.5e-03 m)\nk1 estimated",  # two units
                "check points: 6, RMSE 0.094 m (max 1.5e-03 m)\nk1 estimated",  # a count
                "check points: 5, RMSE 0.0940 m (max 1.5e-03 m)\nk1 estimated",  # another format
                "check points: 5, RMSE 0.094 m (max 1.5e-03 m)\nk1 not estimated",  # the words
                "check points: 5, RMSE 0.094 m (max 1.5e-03 m)"):  # a line less
        with pytest.raises(AssertionError):
            assert_text_close(bad, old)


def test_csv_cells_agree_to_the_tolerance_or_the_last_printed_digit(tmp_path: Path) -> None:
    old, new = tmp_path / "old.csv", tmp_path / "new.csv"
    old.write_text("line,lane,count,flow_veh_h,x\n1,d1_1,3,454.5455,100.123456789012\n")
    new.write_text("line,lane,count,flow_veh_h,x\n1,d1_1,3,454.5454,100.123456789013\n")
    assert_csv_close(new, old, "counts", LAST_BITS)
    for row in ("1,d1_1,4,454.5455,100.123456789012", "1,d1_2,3,454.5455,100.123456789012",
                "1,d1_1,3,454.5453,100.123456789012", "1,d1_1,3,454.5455,100.12346"):
        new.write_text(f"line,lane,count,flow_veh_h,x\n{row}\n")
        with pytest.raises(AssertionError):
            assert_csv_close(new, old, "counts", LAST_BITS)



def test_traffic_positions_are_held_to_micrometres_at_utm_northings(tmp_path: Path) -> None:
    """A northing of 5e6 m: the last bits pass, a millimetre does not (a relative 1e-6 would let 5 m through)."""
    old, new = tmp_path / "old.csv", tmp_path / "new.csv"
    old.write_text("time,y\n1.5,5182593.123456789\n")
    new.write_text("time,y\n1.5,5182593.123456790\n")
    assert_csv_close(new, old, "trajectories", TRAFFIC)
    new.write_text("time,y\n1.5,5182593.124456789\n")
    with pytest.raises(AssertionError):
        assert_csv_close(new, old, "trajectories", TRAFFIC)
