"""Lanes, counting lines, crossings and counts on hand-made geometry with known answers."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from trafficgeo.errors import InputError
from trafficgeo.site.lanes import Lanes, lanes_from_boundaries, lanes_from_polygons
from trafficgeo.site.lines import CountLine
from trafficgeo.traffic.counts import aggregate_counts, find_crossings, interval_edges
from trafficgeo.traffic.lane_changes import lane_visits, main_lane

E0, N0 = 500000.0, 5000000.0  # large projected coordinates: nothing may lose precision


def _boundaries(reverse_some: bool = False) -> list[shapely.LineString]:
    """A road along +y with boundaries at x = 0, 3.5, 7 (left to right looking north), in shuffled order."""
    lines = []
    for k, x in enumerate((3.5, 7.0, 0.0)):
        a, b = (E0 + x, N0), (E0 + x, N0 + 100)
        lines.append(shapely.LineString([b, a] if reverse_some and k == 1 else [a, b]))
    return lines


def test_lanes_from_boundaries_ordered_left_to_right() -> None:
    lanes = lanes_from_boundaries(_boundaries(reverse_some=True))
    assert lanes.names == ("1", "2")
    got = lanes.assign([E0 + 1.0, E0 + 5.0, E0 + 8.0, np.nan], [N0 + 50] * 4)
    assert list(got) == ["1", "2", "", ""]


def test_lanes_from_boundaries_needs_two_distinct_lines() -> None:
    with pytest.raises(InputError, match="at least 2"):
        lanes_from_boundaries(_boundaries()[:1])
    line = _boundaries()[0]
    with pytest.raises(InputError, match="on top of each other"):
        lanes_from_boundaries([line, line])


def test_polygon_lanes_first_wins_and_names_unique() -> None:
    a = shapely.box(E0, N0, E0 + 4, N0 + 10)
    b = shapely.box(E0 + 3, N0, E0 + 7, N0 + 10)
    lanes = lanes_from_polygons([a, b], ["a", "b"])
    assert list(lanes.assign([E0 + 3.5, E0 + 6], [N0 + 1, N0 + 1])) == ["a", "b"]
    with pytest.raises(InputError, match="unique"):
        Lanes(("x", "x"), (a, b))
    with pytest.raises(InputError, match="no area"):
        lanes_from_polygons([shapely.LineString([(0, 0), (1, 1)]).buffer(0)], ["z"])


def _two_way_lanes() -> Lanes:
    """Four 3.5 m lanes along +y: x in [0, 7) southbound (bearing 180), x in [7, 14) northbound (bearing 0)."""
    boxes = [shapely.box(E0 + x, N0, E0 + x + 3.5, N0 + 100) for x in (0.0, 3.5, 7.0, 10.5)]
    return lanes_from_polygons(boxes, ["s_2", "s_1", "n_1", "n_2"], [180.0, 180.0, 0.0, 360.0])


def test_travel_direction_corrects_a_lane_across_the_centre_line() -> None:
    lanes = _two_way_lanes()
    x = [E0 + 6.0, E0 + 6.0, E0 + 2.0, E0 + 6.0, E0 + 8.0]
    heading = [2.0, 181.0, 350.0, np.nan, 175.0]
    got = lanes.assign(x, [N0 + 50.0] * 5, heading)
    # northbound 1 m left of the centre line -> its nearest northbound lane; southbound there stays; a northbound
    # point 5 m into the other carriageway (more than a lane width) keeps its lane (a wrong-way driver); no heading
    # -> no change; southbound 1 m right of the centre line -> the nearest southbound lane
    assert list(got) == ["n_1", "s_1", "s_2", "s_1", "s_1"]
    assert list(lanes.assign(x, [N0 + 50.0] * 5)) == ["s_1", "s_1", "s_2", "s_1", "n_1"]  # without headings
    # a crossing takes the direction of the track's step across the line
    pts = pd.DataFrame({"track_id": ["a", "a"], "time": [0.0, 1.0], "x": [E0 + 6.0] * 2, "y": [N0 + 40.0, N0 + 60.0],
                        "speed_kmh": [72.0, 72.0]})
    line = CountLine("L", shapely.LineString([(E0 - 1.0, N0 + 50.0), (E0 + 15.0, N0 + 50.0)]))
    assert list(find_crossings(pts, [line], lanes)["lane"]) == ["n_1"]


def test_lane_bearing_column_read_and_checked(tmp_path) -> None:
    import geopandas as gpd

    from trafficgeo.site.lanes import read_lanes

    lanes = _two_way_lanes()
    gdf = gpd.GeoDataFrame({"lane": list(lanes.names), "bearing": ["180", "180", "", "0"]},
                           geometry=list(lanes.polygons), crs="EPSG:32633")
    gdf.to_file(tmp_path / "lanes.gpkg")
    got = read_lanes(tmp_path / "lanes.gpkg", crs=None)
    assert got.bearings[:2] == (180.0, 180.0) and np.isnan(got.bearings[2]) and got.bearings[3] == 0.0
    gdf["bearing"] = ["180", "south", "0", "0"]
    gdf.to_file(tmp_path / "bad.gpkg")
    with pytest.raises(InputError, match="bearing 'south' of feature 2 is not a number"):
        read_lanes(tmp_path / "bad.gpkg", crs=None)


def test_lane_visits_ignore_jitter_and_count_changes() -> None:
    t = np.arange(0, 10, 0.1)
    lane = np.where(t < 5, "1", "2").astype(object)
    lane[20] = "2"  # one-frame jitter across the lane line
    lane[60:63] = ""  # outside every lane for a moment
    visits = lane_visits(t, lane, min_dwell_s=1.0)
    assert [v.lane for v in visits] == ["1", "2"]
    assert visits[0].start == 0.0 and visits[1].end == pytest.approx(9.9)
    assert main_lane(visits) == "1" or main_lane(visits) == "2"
    assert lane_visits(t, np.full(t.size, "", dtype=object)) == []
    # a track shorter than the dwell time still gets its lane
    assert [v.lane for v in lane_visits(t[:3], ["2", "2", "2"])] == ["2"]


def _straight_points(track: str, x: float, speed_ms: float, t0: float, n: int = 40, dt: float = 0.1,
                     northbound: bool = True, cls: str = "car") -> pd.DataFrame:
    t = t0 + dt * np.arange(n)
    y = N0 + (speed_ms * (t - t0) if northbound else 60.0 - speed_ms * (t - t0))
    return pd.DataFrame({"track_id": track, "time": t, "x": E0 + x, "y": y, "speed_kmh": 3.6 * speed_ms,
                         "class": cls, "length_m": 4.5})


def test_crossings_time_direction_lane_and_once_per_line() -> None:
    lanes = lanes_from_boundaries(_boundaries())
    line = CountLine("L1", shapely.LineString([(E0 - 1, N0 + 20), (E0 + 8, N0 + 20)]))  # drawn west -> east
    pts = pd.concat([
        _straight_points("a", 1.75, 10.0, 0.0),  # northbound in lane 1: reaches y=20 at t=2.0
        _straight_points("b", 5.25, 8.0, 1.0, n=80, northbound=False),  # southbound in lane 2: 60-8(t-1)=20 at t=6
        _straight_points("c", 1.75, 10.0, 10.0, n=10),  # stops short of the line
    ], ignore_index=True)
    # "a" wobbles back and forth across the line: still counted once, at the first crossing
    wob = _straight_points("w", 1.75, 10.0, 20.0, n=5)
    wob["y"] = N0 + 20 + np.array([-0.5, 0.5, -0.5, 0.5, 1.5])
    cr = find_crossings(pd.concat([pts, wob], ignore_index=True), [line], lanes)
    assert list(cr["track_id"]) == ["a", "b", "w"]
    a, b = cr.iloc[0], cr.iloc[1]
    assert a["time"] == pytest.approx(2.0) and b["time"] == pytest.approx(6.0)
    # looking along the line (west -> east), north is on its left: northbound crosses right -> left (-1)
    assert a["direction"] == -1 and b["direction"] == +1
    assert a["lane"] == "1" and b["lane"] == "2"
    assert a["speed_kmh"] == pytest.approx(36.0) and a["x"] == pytest.approx(E0 + 1.75)


def test_crossing_exactly_at_a_track_point_is_found_once() -> None:
    line = CountLine("L", shapely.LineString([(E0 - 5, N0 + 2.0), (E0 + 5, N0 + 2.0)]))
    pts = _straight_points("a", 0.0, 10.0, 0.0, n=10)  # y = 0, 1, 2 (exactly on the line), 3, ...
    cr = find_crossings(pts, [line])
    assert len(cr) == 1 and cr["time"].iloc[0] == pytest.approx(0.2)


def test_line_limited_to_lanes_and_polyline_lines() -> None:
    lanes = lanes_from_boundaries(_boundaries())
    bent = shapely.LineString([(E0 - 1, N0 + 20), (E0 + 3.5, N0 + 25), (E0 + 8, N0 + 20)])
    pts = pd.concat([_straight_points("a", 1.75, 10.0, 0.0), _straight_points("b", 5.25, 10.0, 0.0)])
    only2 = find_crossings(pts, [CountLine("L", bent, ("2",))], lanes)
    assert list(only2["track_id"]) == ["b"]
    both = find_crossings(pts, [CountLine("L", bent)], lanes)
    # above x = 1.75 the bent line is at y = 20 + 5 * 2.75 / 4.5
    assert both.set_index("track_id").loc["a", "time"] == pytest.approx((20 + 5 * 2.75 / 4.5) / 10.0)


def test_two_tracks_of_one_vehicle_are_counted_once() -> None:
    from trafficgeo.traffic.counts import same_vehicle

    table = pd.DataFrame({
        "time": [10.00, 10.05, 10.06, 10.07, 11.0, 20.00, 20.01],
        "speed_kmh": [50.0, 50.0, 50.0, 50.0, 50.0, np.nan, 40.0],
        "x": [E0, E0 + 0.5, E0 + 3.5, E0 + 0.4, E0, E0, E0 + 0.2],
        "y": [N0] * 7,
        "direction": [1, 1, 1, -1, 1, 1, 1],
    })
    # 0.05 s at 50 km/h = 0.7 m of travel, 0.5 m to the side: one vehicle; 3.5 m to the side: a neighbour; the
    # other direction, or a second later: other vehicles; of a pair the crossing with a speed is kept
    assert list(same_vehicle(table)) == [False, True, False, False, False, True, False]
    feet = table.assign(x=E0 + (table["x"] - E0) / 0.3048)
    assert list(same_vehicle(feet, metres_per_unit=0.3048)) == list(same_vehicle(table))


def test_no_crossings_gives_empty_table_with_columns() -> None:
    line = CountLine("L", shapely.LineString([(E0 + 100, N0), (E0 + 101, N0)]))
    cr = find_crossings(_straight_points("a", 0.0, 10.0, 0.0), [line])
    assert cr.empty and {"line", "track_id", "time", "direction"} <= set(cr.columns)
    counts = aggregate_counts(cr, 60.0, 0.0, 120.0)
    assert counts.empty


def test_interval_edges_clip_to_period() -> None:
    np.testing.assert_allclose(interval_edges(10.0, 130.0, 60.0), [10.0, 60.0, 120.0, 130.0])
    np.testing.assert_allclose(interval_edges(0.0, 120.0, 60.0), [0.0, 60.0, 120.0])
    with pytest.raises(InputError, match="interval"):
        interval_edges(0.0, 1.0, 0.0)


def test_aggregate_counts_flow_speeds_headways() -> None:
    cr = pd.DataFrame({
        "line": "L", "track_id": ["a", "b", "c", "d"], "class": ["car", "car", "truck", "car"],
        "lane": ["1", "1", "1", "2"], "direction": [1, 1, 1, 1], "time": [5.0, 8.0, 70.0, 10.0],
        "speed_kmh": [36.0, 72.0, 54.0, 50.0], "x": 0.0, "y": 0.0, "length_m": [4.5, 4.5, 12.0, 4.5]})
    counts = aggregate_counts(cr, 60.0, 0.0, 90.0)
    lane1 = counts[counts["lane"] == "1"].reset_index(drop=True)
    assert list(lane1["count"]) == [2, 1] and list(lane1["count_car"]) == [2, 0]
    assert list(lane1["count_truck"]) == [0, 1]
    assert lane1["flow_veh_h"].tolist() == pytest.approx([120.0, 120.0])  # 1 vehicle in the 30 s second interval
    assert lane1["time_mean_speed_kmh"][0] == pytest.approx(54.0)
    assert lane1["space_mean_speed_kmh"][0] == pytest.approx(2 / (1 / 36 + 1 / 72))  # 48 km/h
    assert lane1["mean_headway_s"][0] == pytest.approx(3.0)
    assert lane1["mean_gap_s"][0] == pytest.approx(3.0 - 4.5 / 10.0)  # leader 4.5 m at 10 m/s
    assert lane1["mean_headway_s"][1] == pytest.approx(62.0)
    lane2 = counts[counts["lane"] == "2"]
    assert list(lane2["count"]) == [1, 0] and np.isnan(lane2["mean_headway_s"].iloc[0])


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(st.floats(-80.0, 80.0), st.floats(0.0, 359.0), st.floats(2.0, 40.0))
def test_every_straight_track_through_the_line_is_counted_once(offset: float, heading: float, speed: float) -> None:
    """A straight track through a long line is counted exactly once, at the right time, whatever its heading."""
    h = np.radians(heading)
    direction = np.array([np.sin(h), np.cos(h)])
    line = CountLine("L", shapely.LineString([(E0 - 1000 * direction[1], N0 + 1000 * direction[0]),
                                              (E0 + 1000 * direction[1], N0 - 1000 * direction[0])]))
    t = np.arange(0.0, 10.0, 0.04)
    along = speed * (t - 5.0)  # crosses the line (through E0, N0) at t = 5
    centre = np.array([E0, N0]) + offset * np.array([direction[1], -direction[0]])
    xy = centre + along[:, None] * direction
    pts = pd.DataFrame({"track_id": "a", "time": t, "x": xy[:, 0], "y": xy[:, 1], "speed_kmh": 3.6 * speed})
    cr = find_crossings(pts, [line])
    assert len(cr) == 1
    assert cr["time"].iloc[0] == pytest.approx(5.0, abs=1e-6)
    # the line is drawn towards the vehicle's right, so its left side is ahead of the vehicle: the vehicle
    # crosses from the line's right side to its left side
    assert cr["direction"].iloc[0] == -1


# ---------------------------------------------------------------------------------------------------- no silent misses
def _one_crossing() -> pd.DataFrame:
    return pd.DataFrame({"line": ["L1"], "track_id": ["a"], "class": ["car"], "lane": ["1"], "direction": [1],
                         "time": [10.0], "speed_kmh": [50.0], "x": [0.0], "y": [0.0]})


def test_counts_list_every_line_lane_direction_and_interval_with_zeros() -> None:
    """A line nobody crossed, a lane and a direction without vehicles are rows of zeros, not missing rows."""
    from trafficgeo.site.lanes import Lanes

    lanes = Lanes(("1", "2"), (shapely.box(0, 0, 3.5, 100), shapely.box(3.5, 0, 7, 100)))
    lines = [CountLine("L1", shapely.LineString([(0, 50), (7, 50)])),
             CountLine("L2", shapely.LineString([(0, 80), (7, 80)]), lanes=("2",)),
             CountLine("L3", shapely.LineString([(0, 90), (7, 90)]))]
    counts = aggregate_counts(_one_crossing(), 60.0, 0.0, 150.0, lines=lines, lanes=lanes)
    keys = set(zip(counts["line"], counts["lane"], counts["direction"], counts["interval_start"], strict=True))
    expected = {(line, lane, d, t0) for line, lanes_ in (("L1", "12"), ("L2", "2"), ("L3", "12"))
                for lane in lanes_ for d in (-1, 1) for t0 in (0.0, 60.0, 120.0)}
    assert keys == expected and len(counts) == len(expected) == 30
    assert counts["count"].sum() == 1
    zero = counts[counts["count"] == 0]
    assert (zero["flow_veh_h"] == 0).all() and (zero["count_car"] == 0).all()
    for col in ("time_mean_speed_kmh", "space_mean_speed_kmh", "mean_headway_s", "min_headway_s", "mean_gap_s"):
        assert zero[col].isna().all(), col
    hit = counts[counts["count"] == 1].iloc[0]
    assert (hit["line"], hit["lane"], hit["direction"], hit["interval_start"]) == ("L1", "1", 1, 0.0)
    # without lanes: the lane "" of each line, both directions
    bare = aggregate_counts(_one_crossing().assign(lane=""), 60.0, 0.0, 60.0, lines=lines)
    assert sorted(zip(bare["line"], bare["lane"], bare["direction"], strict=True)) == [
        ("L1", "", -1), ("L1", "", 1), ("L2", "", -1), ("L2", "", 1), ("L3", "", -1), ("L3", "", 1)]
    # no crossing at all: still every row, of zeros
    none = aggregate_counts(_one_crossing().iloc[:0], 60.0, 0.0, 60.0, lines=lines[2:])
    assert len(none) == 2 and (none["count"] == 0).all()


def test_lanes_with_a_bearing_list_only_the_direction_they_carry() -> None:
    """A lane's zero rows are in the direction its traffic crosses the line, not the wrong way round; a lane
    without a bearing, or one running along the line, keeps both."""
    from trafficgeo.site.lanes import Lanes
    from trafficgeo.traffic.counts import lane_directions

    east = CountLine("E", shapely.LineString([(0, 50), (7, 50)]))  # drawn towards the east: its left is north
    assert lane_directions(east, 0.0) == (-1,)  # northbound: from its right (south) to its left
    assert lane_directions(east, 180.0) == (1,) and lane_directions(east, 170.0) == (1,)
    assert lane_directions(east, float("nan")) == (-1, 1) and lane_directions(east, 80.0) == (-1, 1)
    west = CountLine("W", shapely.LineString([(7, 50), (0, 50)]))
    assert lane_directions(west, 0.0) == (1,)
    lanes = Lanes(("up", "down", "any"), (shapely.box(0, 0, 3.5, 100), shapely.box(3.5, 0, 7, 100),
                                          shapely.box(7, 0, 10, 100)), bearings=(0.0, 180.0, float("nan")))
    crossing = _one_crossing().assign(line="E", lane="up", direction=-1)
    counts = aggregate_counts(crossing, 60.0, 0.0, 60.0, lines=[east], lanes=lanes)
    assert sorted(zip(counts["lane"], counts["direction"], counts["count"], strict=True)) == [
        ("any", -1, 0), ("any", 1, 0), ("down", 1, 0), ("up", -1, 1)]
    # a vehicle the wrong way round still has its row
    wrong = aggregate_counts(crossing.assign(direction=1), 60.0, 0.0, 60.0, lines=[east], lanes=lanes)
    assert wrong.set_index(["lane", "direction"]).loc[("up", 1), "count"] == 1


def test_counted_groups_keeps_the_groups_with_vehicles() -> None:
    from trafficgeo.traffic.counts import counted_groups

    lines = [CountLine("L1", shapely.LineString([(0, 50), (7, 50)])),
             CountLine("L3", shapely.LineString([(0, 90), (7, 90)]))]
    counts = aggregate_counts(_one_crossing().assign(lane=""), 60.0, 0.0, 150.0, lines=lines)
    kept = counted_groups(counts)
    assert len(counts) == 2 * 2 * 3  # the zero groups are listed ...
    assert set(zip(kept["line"], kept["direction"], strict=True)) == {("L1", 1)} and len(kept) == 3  # ... and left


def test_flow_is_left_out_where_less_than_half_an_interval_was_observed() -> None:
    """3 vehicles in the last 6.8 s of a run would read 1588 veh/h: no flow there, and observed_s says why."""
    from trafficgeo.traffic.counts import MIN_FLOW_SHARE, flow_rule

    cr = pd.DataFrame({"line": "L", "track_id": ["a", "b", "c", "d"], "class": "car", "lane": "", "direction": 1,
                       "time": [10.0, 61.0, 63.0, 65.0], "speed_kmh": 50.0, "x": 0.0, "y": 0.0})
    counts = aggregate_counts(cr, 60.0, 0.0, 66.8)
    assert counts["observed_s"].tolist() == pytest.approx([60.0, 6.8])
    assert counts["count"].tolist() == [1, 3]
    assert counts["flow_veh_h"].iloc[0] == pytest.approx(60.0)
    assert np.isnan(counts["flow_veh_h"].iloc[1])  # 3 * 3600 / 6.8 = 1588 veh/h would be an extrapolation
    assert counts["time_mean_speed_kmh"].iloc[1] == pytest.approx(50.0)  # speeds are measured, kept
    # the rule: at least half the interval observed
    assert MIN_FLOW_SHARE == 0.5
    assert flow_rule([29.9, 30.0, 60.0], 60.0).tolist() == [False, True, True]
    half = aggregate_counts(cr, 60.0, 0.0, 90.0)
    assert half["flow_veh_h"].iloc[1] == pytest.approx(3 * 120.0)  # 30 s of 60: enough


def test_a_line_nobody_crossed_is_warned_about_by_name() -> None:
    from trafficgeo.traffic.analyze import uncrossed_warnings

    lines = [CountLine("L1", shapely.LineString([(0, 50), (7, 50)])),
             CountLine("L3", shapely.LineString([(0, 90), (7, 90)]))]
    warned = uncrossed_warnings(lines, _one_crossing(), (0.0, 66.8))
    assert len(warned) == 1 and warned[0].startswith("counting line L3: no vehicle crossed it in the 66.8 s observed")
    assert len(uncrossed_warnings(lines, _one_crossing().iloc[:0], (0.0, 1.0))) == 2
