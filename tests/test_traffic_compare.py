"""Tests of observed-vs-simulated comparisons (trafficgeo.traffic.compare) with hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

from trafficgeo.errors import InputError
from trafficgeo.traffic.compare import (
    COUNT_KEYS,
    compare_counts,
    compare_speeds,
    compare_speeds_by,
    compare_travel_times,
    count_summary,
    geh,
    travel_times,
)

flows = st.floats(min_value=0.0, max_value=1e5, allow_nan=False, allow_infinity=False)


# ---------------------------------------------------------------------------------------------------- GEH
def test_geh_hand_values() -> None:
    assert geh(100, 80) == pytest.approx(math.sqrt(2 * 20**2 / 180))  # 2.1082...
    assert geh(100, 80) == pytest.approx(2.1082, abs=1e-4)
    assert geh(0, 0) == 0.0 and isinstance(geh(0, 0), float)
    assert geh(600, 420) == pytest.approx(7.97, abs=0.005) and geh(600, 420) > 5
    assert geh(0, 50) == pytest.approx(10.0)  # sqrt(2 * 2500 / 50)
    np.testing.assert_allclose(geh([100, 0, 600], [80, 0, 420]), [2.10819, 0.0, 7.97053], atol=1e-5)
    assert np.isnan(geh(np.nan, 10))
    with pytest.raises(InputError, match="negative"):
        geh([10, -1], [10, 10])


@given(flows, flows)
def test_geh_symmetric_and_zero_iff_equal(m: float, c: float) -> None:
    g = geh(m, c)
    assert g == geh(c, m)
    assert g >= 0
    assert (g == 0) == (m == c)


@given(st.floats(min_value=1.0, max_value=1e5), st.floats(0, 1), st.floats(0, 1))
def test_geh_increases_with_difference_at_fixed_total(total: float, a: float, b: float) -> None:
    d1, d2 = sorted((a * total, b * total))  # two |M - C| for the same M + C
    g1 = geh((total + d1) / 2, (total - d1) / 2)
    g2 = geh((total + d2) / 2, (total - d2) / 2)
    assert g1 <= g2 + 1e-12
    if d2 - d1 > 1e-6 * total:
        assert g1 < g2


# ---------------------------------------------------------------------------------------------------- counts
def _counts(rows: list[tuple]) -> pd.DataFrame:
    t = pd.DataFrame(rows, columns=[*COUNT_KEYS, "count"])
    t["flow_veh_h"] = t["count"] * 3600 / (t["interval_end"] - t["interval_start"])
    t["time_mean_speed_kmh"] = 50.0  # further columns are ignored
    return t


OBS = _counts([("A", "1", 1, 0, 900, 150), ("A", "1", 1, 900, 1800, 25), ("A", "2", 1, 0, 900, 20),
               ("B", "", -1, 0, 900, 0)])
SIM = _counts([("A", "1", 1, 0, 900, 105), ("A", "1", 1, 1800, 2700, 10), ("A", "2", 1, 0, 900, 20),
               ("B", "", -1, 0, 900, 0)])


def test_compare_counts_outer_join() -> None:
    t = compare_counts(OBS, SIM)
    assert list(t.columns) == [*COUNT_KEYS, "observed", "simulated", "observed_flow_veh_h", "simulated_flow_veh_h",
                               "geh", "geh_ok"]
    assert len(t) == 5
    a1 = t[(t["line"] == "A") & (t["lane"] == "1")].set_index("interval_start")
    assert a1.loc[0, ["observed", "simulated"]].tolist() == [150, 105]
    assert a1.loc[0, "observed_flow_veh_h"] == 600 and a1.loc[0, "simulated_flow_veh_h"] == 420
    assert a1.loc[0, "geh"] == pytest.approx(7.97, abs=0.005) and not a1.loc[0, "geh_ok"]
    assert a1.loc[900, ["observed", "simulated"]].tolist() == [25, 0]  # missing in the simulation: 0 vehicles
    assert a1.loc[900, "geh"] == pytest.approx(math.sqrt(2 * 100**2 / 100))  # 100 vs 0 veh/h: 14.14
    assert a1.loc[1800, ["observed", "simulated"]].tolist() == [0, 10]  # missing in the observation
    b = t[t["line"] == "B"].iloc[0]
    assert b["geh"] == 0 and b["geh_ok"] and b["direction"] == -1
    assert t.loc[(t["line"] == "A") & (t["lane"] == "2"), "geh"].item() == 0


def test_count_summary() -> None:
    s = count_summary(compare_counts(OBS, SIM))
    assert s["rows"] == 5 and s["total_observed"] == 195 and s["total_simulated"] == 135
    assert s["share_geh_below_5"] == pytest.approx(2 / 5)
    gehs = [geh(600, 420), geh(100, 0), geh(0, 40), 0.0, 0.0]
    assert s["mean_geh"] == pytest.approx(np.mean(gehs))
    # totals over the three distinct 15-min intervals (0.75 h): 260 vs 180 veh/h
    assert s["geh_total"] == pytest.approx(geh(195 / 0.75, 135 / 0.75))
    groups = {(g["line"], g["lane"]): g for g in s["groups"]}
    assert set(groups) == {("A", "1"), ("A", "2"), ("B", "")}
    a1 = groups[("A", "1")]
    assert (a1["observed"], a1["simulated"]) == (175, 115)
    assert a1["geh"] == pytest.approx(geh(175 / 0.75, 115 / 0.75))
    assert groups[("A", "2")]["observed_flow_veh_h"] == pytest.approx(80.0) and groups[("A", "2")]["geh"] == 0
    by_dir = count_summary(compare_counts(OBS, SIM), by=("line", "direction"))
    assert {(g["line"], g["direction"]) for g in by_dir["groups"]} == {("A", 1), ("B", -1)}
    empty = count_summary(compare_counts(OBS.iloc[:0], SIM.iloc[:0]))
    assert empty["rows"] == 0 and np.isnan(empty["mean_geh"]) and empty["groups"] == []


def test_compare_counts_errors() -> None:
    with pytest.raises(InputError, match="lacks column"):
        compare_counts(OBS.drop(columns=["count"]), SIM)
    with pytest.raises(InputError, match="two rows"):
        compare_counts(pd.concat([OBS, OBS.iloc[:1]]), SIM)
    bad = OBS.copy()
    bad.loc[0, "interval_end"] = 0
    with pytest.raises(InputError, match="intervals must end after"):
        compare_counts(bad, SIM)
    bad = OBS.copy()
    bad["count"] = bad["count"].astype(object)
    bad.loc[1, "count"] = "many"
    with pytest.raises(InputError, match="row 1"):
        compare_counts(bad, SIM)


# ---------------------------------------------------------------------------------------------------- speeds
def test_compare_speeds_identical_and_different() -> None:
    rng = np.random.default_rng(0)
    v = rng.normal(50, 8, 400)
    same = compare_speeds(v, v.copy())
    assert same["ks_statistic"] == 0 and same["ks_pvalue"] == pytest.approx(1.0) and same["mean_difference_kmh"] == 0
    assert same["observed_n"] == 400 and same["observed_mean_kmh"] == pytest.approx(v.mean())
    assert same["observed_std_kmh"] == pytest.approx(v.std(ddof=1))
    assert same["observed_p85_kmh"] == pytest.approx(np.percentile(v, 85))
    fast = compare_speeds(v, v + 10)
    assert fast["mean_difference_kmh"] == pytest.approx(10) and fast["ks_statistic"] > 0.4 and fast["ks_pvalue"] < 1e-6


def test_compare_speeds_hand_values() -> None:
    r = compare_speeds([40, 50, 60, np.nan], [45, 55])
    assert r["observed_n"] == 3 and r["simulated_n"] == 2  # NaN dropped
    assert r["observed_mean_kmh"] == 50 and r["simulated_mean_kmh"] == 50 and r["mean_difference_kmh"] == 0
    assert r["observed_std_kmh"] == 10 and r["observed_p50_kmh"] == 50 and r["observed_p15_kmh"] == pytest.approx(43)
    assert r["ks_statistic"] == pytest.approx(1 / 3)  # ECDFs: at 40 -> 1/3 vs 0, ..., max gap 1/3
    empty = compare_speeds([], [50])
    assert empty["observed_n"] == 0 and np.isnan(empty["observed_mean_kmh"]) and np.isnan(empty["ks_statistic"])


def _crossings(rows: list[tuple]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["line", "track_id", "class", "lane", "direction", "time", "speed_kmh"]).assign(
        x=0.0, y=0.0)


def test_compare_speeds_by_line_and_lane() -> None:
    obs = _crossings([("A", "1", "car", "1", 1, 1.0, 40.0), ("A", "2", "car", "1", 1, 2.0, 60.0),
                      ("A", "3", "car", "2", 1, 3.0, 80.0), ("B", "1", "car", None, 1, 9.0, 45.0)])
    sim = _crossings([("A", "s1", "car", "1", 1, 1.0, 50.0), ("A", "s2", "car", "1", 1, 2.0, 50.0),
                      ("C", "s3", "car", "1", 1, 5.0, 70.0)])
    t = compare_speeds_by(obs, sim)
    assert list(t[["line", "lane"]].itertuples(index=False, name=None)) == [("A", "1"), ("A", "2"), ("B", ""),
                                                                            ("C", "1")]
    a1 = t.iloc[0]
    assert a1["observed_n"] == 2 and a1["simulated_n"] == 2 and a1["observed_mean_kmh"] == 50
    assert a1["ks_statistic"] == pytest.approx(0.5)
    assert t.iloc[1]["simulated_n"] == 0 and np.isnan(t.iloc[1]["ks_statistic"])
    by_line = compare_speeds_by(obs, sim, by=("line",))
    assert list(by_line["line"]) == ["A", "B", "C"] and by_line.iloc[0]["observed_n"] == 3
    with pytest.raises(InputError, match="speed_kmh"):
        compare_speeds_by(obs.drop(columns=["speed_kmh"]), sim)


# ---------------------------------------------------------------------------------------------------- travel times
def test_travel_times() -> None:
    c = _crossings([
        ("up", "a", "car", "1", 1, 10.0, 50.0), ("down", "a", "car", "1", 1, 25.0, 50.0),  # 15 s
        ("up", "b", "truck", "2", 1, 12.0, 40.0),  # crosses only one line
        ("down", "c", "car", "1", -1, 5.0, 50.0), ("up", "c", "car", "1", -1, 20.0, 50.0),  # the other way
        ("down", "d", "bus", "2", 1, 40.0, 30.0), ("up", "d", "bus", "2", 1, 11.0, 30.0),  # 29 s, rows unordered
        ("other", "a", "car", "1", 1, 18.0, 50.0),
    ])
    t = travel_times(c, "up", "down")
    assert list(t.columns) == ["track_id", "class", "t_from", "t_to", "travel_time_s"]
    assert t.values.tolist() == [["a", "car", 10.0, 25.0, 15.0], ["d", "bus", 11.0, 40.0, 29.0]]
    back = travel_times(c, "down", "up")
    assert back.values.tolist() == [["c", "car", 5.0, 20.0, 15.0]]
    assert travel_times(c, "up", "nowhere").empty


def test_compare_travel_times() -> None:
    obs = pd.DataFrame({"track_id": list("abcd"), "class": "car", "t_from": 0.0, "t_to": 0.0,
                        "travel_time_s": [10.0, 12.0, 14.0, 40.0]})
    r = compare_travel_times(obs, [11.0, 13.0, 15.0])
    assert r["observed_n"] == 4 and r["simulated_n"] == 3
    assert r["observed_mean_s"] == 19 and r["observed_median_s"] == 13 and r["simulated_median_s"] == 13
    assert r["observed_p85_s"] == pytest.approx(np.percentile([10, 12, 14, 40], 85))
    assert r["mean_difference_s"] == pytest.approx(13 - 19)
    assert r["ks_statistic"] == pytest.approx(0.25)  # ECDFs differ most at 10 s (1/4 vs 0) and 15 s (3/4 vs 1)
    same = compare_travel_times(obs, obs)
    assert same["ks_statistic"] == 0 and same["mean_difference_s"] == 0
    with pytest.raises(InputError, match="travel_time_s"):
        compare_travel_times(obs.drop(columns=["travel_time_s"]), obs)
