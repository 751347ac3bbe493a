"""Turning movements from trajectories and junction gates (trafficgeo.site.gates, trafficgeo.traffic.movements), on
paths whose movements are known by construction: a four-arm junction turned to any bearing, far from the CRS origin."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from trafficgeo.errors import InputError
from trafficgeo.site.gates import Gate, Junction, turn_deg
from trafficgeo.traffic.movements import (
    MOVEMENT_COLUMNS,
    gate_crossings,
    movement_counts,
    peak_hour,
    turning_movement_table,
    vehicle_movements,
)

GATE_M = 30.0  # gate distance from the centre
ARM_BEARINGS = {"N": 0.0, "E": 90.0, "S": 180.0, "W": 270.0}


def unit(bearing_deg: float) -> np.ndarray:
    b = np.radians(bearing_deg)
    return np.array([np.sin(b), np.cos(b)])


def junction(rotation_deg: float = 0.0, centre=(0.0, 0.0), gate_m: float = GATE_M) -> Junction:
    c = np.asarray(centre, dtype=float)
    gates = []
    for arm, b in ARM_BEARINGS.items():
        u = unit(b + rotation_deg)
        n = np.array([u[1], -u[0]])
        m = c + gate_m * u
        gates.append(Gate(arm, shapely.LineString([m - 8 * n, m + 8 * n])))
    return Junction.from_gates(gates)


def path(origin: str, destination: str, *, rotation_deg: float = 0.0, centre=(0.0, 0.0), start_m: float = 60.0,
         end_m: float = 60.0, t0: float = 0.0, speed_mps: float = 10.0, stop_s: float = 0.0, dt: float = 0.1,
         tid: str = "1", cls: str = "car") -> pd.DataFrame:
    """A right-hand-traffic path in from arm ``origin`` (from ``start_m`` out, 1.75 m right of the axis) to the
    centre, then out along arm ``destination`` to ``end_m`` out (negative distances: start/end inside the gates).
    ``stop_s`` seconds standing 10 m before the centre."""
    c = np.asarray(centre, dtype=float)
    ui = unit(ARM_BEARINGS[origin] + rotation_deg)
    uo = unit(ARM_BEARINGS[destination] + rotation_deg)
    right_in = np.array([-ui[1], ui[0]])  # right of travel when heading into the junction (-ui)
    right_out = np.array([uo[1], -uo[0]])
    pieces = [c + np.outer(np.linspace(start_m, 10.0, 50), ui) + 1.75 * right_in]
    if origin == destination:
        arc = [c + 10.0 * ui + 1.75 * right_in, c + 5.0 * ui + 0.0 * right_in, c + 10.0 * uo + 1.75 * right_out]
        pieces.append(np.array(arc))
    else:
        pieces.append(np.array([c + 0.0 * ui]))
    pieces.append(c + np.outer(np.linspace(10.0, end_m, 50), uo) + 1.75 * right_out)
    xy = np.vstack(pieces)
    seg = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    keep = np.concatenate([[True], seg > 1e-9])
    xy, s = xy[keep], s[keep]
    ts = np.arange(0.0, s[-1] / speed_mps, dt)
    d = ts * speed_mps
    pts = np.column_stack([np.interp(d, s, xy[:, 0]), np.interp(d, s, xy[:, 1])])
    speed = np.full(len(ts), speed_mps * 3.6)
    if stop_s > 0:  # stand at the point 10 m before the centre
        k = int(np.searchsorted(d, start_m - 10.0)) if start_m > 10 else 0
        n = round(stop_s / dt)
        pts = np.vstack([pts[:k], np.repeat(pts[k:k + 1], n, axis=0), pts[k:]])
        speed = np.concatenate([speed[:k], np.zeros(n), speed[k:]])
        ts = np.arange(len(pts)) * dt
    return pd.DataFrame({"track_id": tid, "time": t0 + ts, "x": pts[:, 0], "y": pts[:, 1], "speed_kmh": speed,
                         "class": cls})


def run(paths: list[pd.DataFrame], j: Junction) -> pd.DataFrame:
    pts = pd.concat(paths, ignore_index=True)
    veh = pts.groupby("track_id", as_index=False).agg(**{"class": ("class", "first")})
    return vehicle_movements(pts, veh, j)


def test_every_movement_of_a_four_arm_junction() -> None:
    j = junction()
    expected = {("S", "N"): "through", ("S", "W"): "left", ("S", "E"): "right", ("S", "S"): "U",
                ("E", "W"): "through", ("E", "S"): "left", ("E", "N"): "right", ("N", "E"): "left"}
    paths = [path(o, d, tid=f"{o}{d}") for o, d in expected]
    mv = run(paths, j).set_index("track_id")
    assert list(run(paths, j).columns) == MOVEMENT_COLUMNS
    for (o, d), kind in expected.items():
        row = mv.loc[f"{o}{d}"]
        assert (row.origin, row.destination, row.movement) == (o, d, kind)
        assert row.origin_by == row.destination_by == "gate" and bool(row.complete)
        assert row.entry_time < row.exit_time
        assert row.travel_time_s == pytest.approx(row.exit_time - row.entry_time)


def test_entry_and_exit_times_are_the_gate_crossings_and_stops_are_timed() -> None:
    j = junction()
    p = path("S", "N", start_m=60.0, speed_mps=10.0, stop_s=12.0)
    row = run([p], j).iloc[0]
    assert row.entry_time == pytest.approx(3.0, abs=0.11)  # 30 m to the gate at 10 m/s
    assert row.stopped_s == pytest.approx(12.0, abs=0.25)
    assert row.travel_time_s == pytest.approx(6.0 + 12.0, abs=0.3)
    crossings = gate_crossings(p, j)
    assert list(crossings["arm"]) == ["S", "N"] and list(crossings["entering"]) == [True, False]


def test_first_or_last_seen_inside_is_assigned_by_the_path_or_left_incomplete() -> None:
    j = junction()
    queued = path("E", "W", start_m=20.0, tid="queued")  # first seen inside the gate, on the east approach
    leaving = path("N", "S", end_m=20.0, tid="leaving")  # last seen inside the gate, heading out south
    middle = path("S", "N", start_m=4.0, end_m=60.0, tid="middle")  # first seen in the middle of the junction
    lost = path("W", "E", start_m=60.0, end_m=2.0, tid="lost")  # lost in the middle
    # found again a quarter of the way out to its gate (7.5 m of 30), heading in; lost as far out, heading out
    found, gone = path("S", "E", t0=100.0, tid="found"), path("E", "N", t0=200.0, tid="gone")
    found = found.iloc[int(np.argmax(np.hypot(found["x"], found["y"]) <= 7.5)):]
    near = np.flatnonzero(np.hypot(gone["x"], gone["y"]) <= 7.5)
    gone = gone.iloc[: near[-1] + 1]
    mv = run([queued, leaving, middle, lost, found, gone], j).set_index("track_id")
    assert tuple(mv.loc["found", ["origin", "origin_by", "movement"]]) == ("S", "path", "right")
    assert (mv.loc["gone", "destination"], mv.loc["gone", "destination_by"]) == ("N", "path")
    assert (mv.loc["queued", "origin"], mv.loc["queued", "origin_by"]) == ("E", "path")
    assert np.isnan(mv.loc["queued", "entry_time"]) and mv.loc["queued", "movement"] == "through"
    assert (mv.loc["leaving", "destination"], mv.loc["leaving", "destination_by"]) == ("S", "path")
    assert (mv.loc["middle", "origin"], bool(mv.loc["middle", "complete"])) == ("", False)
    assert (mv.loc["lost", "destination"], bool(mv.loc["lost", "complete"])) == ("", False)
    assert mv.loc["lost", "origin"] == "W"


def test_vehicles_only_on_an_arm_and_stationary_ones_are_not_movements() -> None:
    j = junction()
    outside = path("S", "S", start_m=200.0, end_m=200.0, tid="outside")
    outside = outside[np.hypot(outside["x"], outside["y"]) > 100.0]  # its part beyond the gates only
    parked = path("S", "N", tid="parked")
    pts = pd.concat([outside, parked], ignore_index=True)
    veh = pd.DataFrame({"track_id": ["outside", "parked"], "class": ["car", "car"], "stationary": [False, True]})
    assert len(vehicle_movements(pts, veh, j)) == 0


@settings(max_examples=40, deadline=None)
@given(rotation=st.floats(-180.0, 180.0), x0=st.floats(-5e6, 5e6), y0=st.floats(0.0, 5e6),
       pair=st.sampled_from([("S", "N", "through"), ("S", "W", "left"), ("S", "E", "right"), ("W", "S", "right"),
                             ("W", "N", "left"), ("N", "N", "U")]))
def test_movements_hold_for_any_bearing_and_far_coordinates(rotation, x0, y0, pair) -> None:
    o, d, kind = pair
    c = (x0, y0)
    j = junction(rotation, c)
    assert np.allclose(j.centre, c, atol=1e-6 * max(1.0, abs(x0), abs(y0)))
    row = run([path(o, d, rotation_deg=rotation, centre=c)], j).iloc[0]
    assert (row.origin, row.destination, row.movement) == (o, d, kind)


@given(a=st.floats(0.0, 360.0), turn=st.floats(-179.0, 179.0))
def test_turn_angle_is_the_clockwise_change_of_heading(a, turn) -> None:
    destination = (a + 180.0 + turn) % 360.0
    assert turn_deg(a, destination) == pytest.approx(turn, abs=1e-9)


def test_counts_table_peak_hour_and_phf() -> None:
    j = junction()
    # 2 h of traffic: per 15 min, S->N through 10 + k, S->W left 2, one truck E->W every interval
    paths, n = [], 0
    for k in range(8):
        for i in range(10 + k):
            paths.append(path("S", "N", t0=900.0 * k + 45.0 * i, tid=f"v{n}"))
            n += 1
        for i in range(2):
            paths.append(path("S", "W", t0=900.0 * k + 30.0 + 200.0 * i, tid=f"v{n}"))
            n += 1
        paths.append(path("E", "W", t0=900.0 * k + 400.0, tid=f"v{n}", cls="truck"))
        n += 1
    mv = run(paths, j)
    assert mv["complete"].all() and len(mv) == n
    counts = movement_counts(mv, j, 900.0, 0.0, 7200.0)
    assert counts["count"].sum() == n
    sn = counts[(counts.origin == "S") & (counts.destination == "N")].groupby("interval_start")["count"].sum()
    assert list(sn) == [10 + k for k in range(8)]
    table = turning_movement_table(counts, j)
    assert list(table["S_through"]) == [10 + k for k in range(8)]
    assert list(table["S_left"]) == [2] * 8 and list(table["E_through"]) == [1] * 8 and list(table["N_U"]) == [0] * 8
    assert list(table["heavy"]) == [1] * 8
    peak = peak_hour(table, 900.0)
    assert peak is not None and (peak.start, peak.end) == (3600.0, 7200.0)
    volumes = [13 + k for k in range(4, 8)]
    assert peak.volume == sum(volumes)
    assert peak.phf == pytest.approx(sum(volumes) / (4 * max(volumes)))
    assert peak.heavy_pct == pytest.approx(100.0 * 4 / sum(volumes))
    assert peak_hour(table.iloc[:3], 900.0) is None  # less than an hour observed


def test_bad_gates_are_refused() -> None:
    g = junction().gates
    with pytest.raises(InputError, match="at least two arms"):
        Junction.from_gates(g[:1])
    with pytest.raises(InputError, match="unique"):
        Junction.from_gates([g[0], Gate(g[0].arm, g[1].geometry)])


def test_the_two_halves_of_a_track_broken_inside_the_junction_are_one_movement() -> None:
    j = junction()
    whole = path("S", "W", tid="car")  # a left turn at 10 m/s
    inside = np.hypot(whole["x"], whole["y"]) < 8.0
    k = np.flatnonzero(inside)
    first = whole.iloc[: k[0]].assign(track_id="a")  # lost 8 m before the centre ...
    second = whole.iloc[k[-1] + 1:].assign(track_id="b")  # ... found again 8 m past it, 1.6 s later
    row = run([first, second], j)
    assert len(row) == 1 and (row.iloc[0].origin, row.iloc[0].destination, row.iloc[0].movement) == ("S", "W", "left")
    assert row.iloc[0].track_ids == "a;b" and row.iloc[0].complete
    # found again too late to have been the same vehicle (6 s: farther than it could have driven), or as a truck
    late = second.assign(time=second["time"] + 6.0)
    assert not run([first, late], j)["complete"].any()
    assert not run([first, second.assign(**{"class": "truck"})], j)["complete"].any()
    # two vehicles lost at once and found again: each joined to its own
    other = path("N", "E", tid="o", t0=0.05)
    ins = np.flatnonzero(np.hypot(other["x"], other["y"]) < 8.0)
    pieces = [first, second, other.iloc[: ins[0]].assign(track_id="c"), other.iloc[ins[-1] + 1:].assign(track_id="d")]
    rows = run(pieces, j).set_index("track_ids")
    assert rows.loc["a;b", "movement"] == "left" and rows.loc["c;d", "movement"] == "left"
    assert rows.loc["c;d", "destination"] == "E"


def test_a_u_turn_needs_a_turn_inside_the_junction() -> None:
    j = junction()
    real = run([path("S", "S", tid="u")], j).iloc[0]  # into the junction and round: a U-turn
    assert (real.origin, real.destination, real.movement) == ("S", "S", "U") and real.complete
    # a piece of track that crosses the S gate inbound and back out 5 m further on without going in (a box
    # jittering at the gate, or the front and back of a bus): not a U-turn; its motion along the arm keeps one end
    out = path("N", "S", tid="x")
    d = np.hypot(out["x"], out["y"])
    k = np.flatnonzero(d > GATE_M - 3.0)
    piece = out.iloc[k[k > len(out) // 2]].iloc[:25].copy()  # leaving by S, from 3 m inside the gate
    back = piece.iloc[:5].assign(x=piece["x"].iloc[0] + 0.1, y=-(GATE_M - 4.0))  # first a moment 4 m inside
    jitter = pd.concat([back, piece], ignore_index=True).assign(time=np.arange(30) * 0.1, track_id="j")
    jitter.loc[:4, "y"] = -(GATE_M + 1.0)  # ... but on the arm's outer side, so it "enters" then leaves
    row = run([jitter], j).iloc[0]
    assert not (row.origin == row.destination == "S"), row
    assert row.destination == "S" and row.origin == "" and not row.complete


def test_two_boxes_on_one_vehicle_seen_at_once_are_one_movement_but_neighbours_are_not() -> None:
    j = junction()
    whole = path("W", "S", tid="car")
    d = np.hypot(whole["x"], whole["y"])
    k = np.flatnonzero(d < 8.0)
    first = whole.iloc[: k[-1]].assign(track_id="a")  # to 8 m past the centre ...
    second = whole.iloc[k[0]:].assign(track_id="b")  # ... and a second id on it from 8 m before: 1.6 s at once
    row = run([first, second], j)
    assert len(row) == 1 and row.iloc[0].track_ids == "a;b"
    assert (row.iloc[0].origin, row.iloc[0].destination) == ("W", "S") and row.iloc[0].complete
    # a neighbour 3.5 m to the side (in the next lane, left of travel) over the same time is another vehicle
    heading = np.column_stack([np.gradient(second["x"].to_numpy()), np.gradient(second["y"].to_numpy())])
    heading /= np.hypot(*heading.T)[:, None]
    side = second.assign(x=second["x"] - 3.5 * heading[:, 1], y=second["y"] + 3.5 * heading[:, 0])
    apart = run([first, side], j)  # two movements (each may be complete by its own path), never one of both
    assert len(apart) == 2 and not apart["track_ids"].str.contains(";").any()
    # the front of a bus detected as a van 4 m ahead of the bus's own box, its track ending inside the junction
    # where its path points to another arm: one vehicle, whose arms are the bus's gate crossings
    bus = path("W", "S", tid="bus", cls="bus", speed_mps=6.0)
    front = bus.iloc[:-60].copy()
    front[["x", "y"]] = np.column_stack([np.interp(front["time"] + 4.0 / 6.0, bus["time"], bus["x"]),
                                         np.interp(front["time"] + 4.0 / 6.0, bus["time"], bus["y"])])
    rows = run([bus, front.assign(track_id="front", **{"class": "van"})], j)
    assert len(rows) == 1 and (rows.iloc[0].origin, rows.iloc[0].destination) == ("W", "S")
    assert rows.iloc[0]["class"] == "bus"
    # and two halves are never joined into a U-turn
    again = path("S", "S", tid="u")
    inside = np.flatnonzero(np.hypot(again["x"], again["y"]) < 8.0)
    halves = [again.iloc[: inside[0]].assign(track_id="p"), again.iloc[inside[-1] + 1:].assign(track_id="q")]
    assert not run(halves, j)["complete"].any()


def _with_trackers(pieces: list[pd.DataFrame], trackers: dict[str, str], j: Junction) -> pd.DataFrame:
    """vehicle_movements of ``pieces`` whose vehicles came from the tracker ids ``trackers`` (vehicle -> ids)."""
    pts = pd.concat(pieces, ignore_index=True)
    veh = pts.groupby("track_id", as_index=False).agg(**{"class": ("class", "first")})
    veh["tracker_ids"] = veh["track_id"].map(trackers)
    return vehicle_movements(pts, veh, j)


def test_a_track_cut_where_its_vehicle_stood_is_one_movement_not_two() -> None:
    j = junction()
    car = path("N", "S", stop_s=30.0, tid="car")  # stands 30 s 10 m before the centre, then goes straight on
    moving = car["speed_kmh"].to_numpy() > 0
    restart = float(car["time"].to_numpy()[np.flatnonzero(~moving)[-1]])
    t = car["time"].to_numpy()
    # the tracker kept one id, but its boxes jumped as the car set off: the smoother cut the track there and the
    # id's points went to two pieces that interleave for 2.5 s; each piece looks whole by its path
    both = (t > restart) & (t <= restart + 2.5)
    odd = np.cumsum(both) % 2 == 1
    first = car[(t <= restart + 2.5) & ~(both & odd)].assign(track_id="a")
    second = car[(t > restart) & ~(both & ~odd)].assign(track_id="b")
    alone = [_with_trackers([p], {p["track_id"].iloc[0]: "7"}, j).iloc[0] for p in (first, second)]
    assert [(r.origin_by, r.destination_by) for r in alone] == [("gate", "path"), ("path", "gate")]
    assert all((r.origin, r.destination) == ("N", "S") and r.complete for r in alone)
    rows = _with_trackers([first, second], {"a": "7", "b": "7"}, j)
    assert len(rows) == 1 and rows.iloc[0].track_ids == "a;b" and rows.iloc[0].complete
    r = rows.iloc[0]
    assert (r.origin, r.destination, r.origin_by, r.destination_by) == ("N", "S", "gate", "gate")
    assert r.exit_time == alone[1].exit_time and r.entry_time == alone[0].entry_time
    # a car ahead on the same movement, its track lost 10 m past the centre 1 s before this one sets off: under
    # another tracker id, another vehicle (as far as anything shows), not this one's first half
    ahead = path("N", "S", tid="ahead", t0=restart - 1.0 - 7.0)
    ahead = ahead[ahead["time"] <= restart - 1.0]
    tail = car[t > restart].assign(track_id="b")
    rows = _with_trackers([ahead, tail], {"ahead": "6", "b": "7"}, j)
    assert len(rows.query("complete")) == 2 and set(rows["track_ids"]) == {"ahead", "b"}
    assert len(_with_trackers([ahead, tail], {"ahead": "7", "b": "7"}, j)) == 1  # one id: one vehicle


def test_a_tail_that_begins_as_its_head_ends_is_joined_to_it() -> None:
    j = junction()
    whole = path("E", "W", tid="car")  # straight through at 10 m/s
    d = np.hypot(whole["x"], whole["y"])
    k = int(np.flatnonzero(d < 2.0)[0])
    ahead = np.array([-1.0, 0.0])  # its direction of travel (westbound)
    first = whole.iloc[:k + 1].assign(track_id="a")  # lost near the centre ...
    # ... and a new id on a box 3 m farther along, from 0.3 s before the first one ends: not standing together
    second = whole.iloc[k - 2:].assign(track_id="b", x=lambda p: p["x"] + 3.0 * ahead[0])
    rows = _with_trackers([first, second], {"a": "1", "b": "2"}, j)
    assert len(rows) == 1 and rows.iloc[0].track_ids == "a;b"
    assert (rows.iloc[0].origin, rows.iloc[0].destination) == ("E", "W") and rows.iloc[0].complete
    # begun 1 s before the first ends (10 m back along it), it is another vehicle
    early = whole.iloc[k - 10:].assign(track_id="b", x=lambda p: p["x"] + 3.0 * ahead[0])
    apart = _with_trackers([first, early], {"a": "1", "b": "2"}, j)
    assert len(apart) == 2 and not apart["track_ids"].str.contains(";").any()


def _straight(points: list[tuple[float, float]], speed_mps: float = 8.0, dt: float = 0.1) -> np.ndarray:
    """Positions every ``dt`` s along the polyline ``points`` at ``speed_mps``."""
    xy = np.asarray(points, dtype=float)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    d = np.arange(0.0, s[-1], speed_mps * dt)
    return np.column_stack([np.interp(d, s, xy[:, 0]), np.interp(d, s, xy[:, 1])])


def test_a_track_that_turns_back_along_its_own_way_or_only_by_a_join_is_no_u_turn() -> None:
    """Two ways a run shows a U-turn that no vehicle made, on the S arm (x > 0: the lanes into the junction,
    x < 0: out of it): a tracker's identity passed from a car queued at the stop line to a car leaving by the same
    arm just beside it comes back along its own way (0.5 m to the side): no U-turn, one end dropped (a half). A
    way in and a way out on the other side of the road that are two pieces of track joined at the turn (a
    vehicle's way in, another's way out): no piece of track turns round, so no U-turn.
    The same way in and out as one piece of track is a U-turn."""
    j = junction()
    back = _straight([(1.75, -40.0), (1.75, -7.0), (1.25, -7.5), (1.25, -40.0)])
    reversed_ = pd.DataFrame({"track_id": "r", "time": np.arange(len(back)) * 0.1, "x": back[:, 0],
                              "y": back[:, 1], "speed_kmh": 28.8, "class": "car"})
    way = _straight([(1.75, -40.0), (1.75, -6.0), (0.0, -4.0), (-1.75, -6.0), (-1.75, -40.0)])
    whole = pd.DataFrame({"track_id": "u", "time": np.arange(len(way)) * 0.1, "x": way[:, 0], "y": way[:, 1],
                          "speed_kmh": 28.8, "class": "car"})
    turn = int(np.argmin(np.hypot(*way.T)))
    joined = whole.assign(track_id="p", fragment=np.where(np.arange(len(way)) <= turn, "p.1", "p.2"),
                          time=whole["time"] + 100.0)  # one after the other: never seen together
    one = whole.assign(fragment="u.1", time=whole["time"] + 200.0)
    rows = run([reversed_, joined, one], j).set_index("track_id")
    assert sorted([rows.at["r", "origin"], rows.at["r", "destination"]]) == ["", "S"]
    assert not rows.at["r", "complete"]
    assert not (rows.at["p", "origin"] == rows.at["p", "destination"] == "S")
    assert (rows.at["u", "origin"], rows.at["u", "destination"], rows.at["u", "movement"]) == ("S", "S", "U")


def test_a_vehicle_lost_while_it_stood_is_joined_when_found_again_nearby() -> None:
    """A car standing 40 s 10 m before the centre (a red light): its track is lost 5 s into the stop and found
    again 0.6 s after it sets off, 6 m on: one vehicle, though unseen for 35 s. Found again 16 m on (farther than
    a queue creeps), or lost while it drove at 10 m/s, it is not."""
    j = junction()
    car = path("N", "S", stop_s=40.0, tid="car")
    t, v = car["time"].to_numpy(), car["speed_kmh"].to_numpy()
    stood = np.flatnonzero(v == 0)
    lost, restart = t[stood[0]] + 5.0, t[stood[-1]]
    head = car[t <= lost].assign(track_id="a")
    rows = _with_trackers([head, car[t >= restart + 0.6].assign(track_id="b")], {"a": "1", "b": "2"}, j)
    assert len(rows) == 1 and rows.iloc[0].track_ids == "a;b" and rows.iloc[0].complete
    assert (rows.iloc[0].origin, rows.iloc[0].destination, rows.iloc[0].movement) == ("N", "S", "through")
    far = _with_trackers([head, car[t >= restart + 1.6].assign(track_id="b")], {"a": "1", "b": "2"}, j)
    assert not far["complete"].any()
    moving = path("N", "S", tid="m")  # never stood: lost 8 m before the centre, found 35 s later 6 m past it
    tm = moving["time"].to_numpy()
    d = np.hypot(moving["x"], moving["y"]).to_numpy()
    k_lost = int(np.flatnonzero(d < 8.0)[0])
    first = moving.iloc[:k_lost].assign(track_id="c")
    second = moving.iloc[k_lost + 14:].assign(track_id="d", time=tm[k_lost + 14:] + 35.0)
    assert not _with_trackers([first, second], {"c": "1", "d": "2"}, j)["complete"].any()


def test_a_tail_found_as_its_vehicle_sped_up_is_joined_and_a_truck_box_may_jump_aside() -> None:
    """The distance between two halves is what the faster of their two speeds covers in the gap (a car lost as it
    set off at 1 m/s, found 0.8 s later 8 m on at 10 m/s), and within the position error of the halves' ends (4 m)
    the line between them may point anywhere (a truck's box centre 2.5 m on and 3.5 m aside)."""
    j = junction()
    car = path("E", "W", tid="car")
    d = np.hypot(car["x"], car["y"]).to_numpy()
    k = int(np.flatnonzero(d < 6.0)[0])
    head = car.iloc[:k].assign(track_id="a")
    head.loc[head.index[-5:], "speed_kmh"] = 3.6  # its smoothed speed at the end: 1 m/s
    tail = car.iloc[k + 7:].assign(track_id="b")  # 0.8 s later, 8 m farther
    rows = _with_trackers([head, tail], {"a": "1", "b": "2"}, j)
    assert len(rows) == 1 and rows.iloc[0].complete and rows.iloc[0].track_ids == "a;b"
    truck = path("W", "E", tid="truck", cls="truck", speed_mps=5.0)
    d = np.hypot(truck["x"], truck["y"]).to_numpy()
    k = int(np.flatnonzero(d < 3.0)[0])
    first = truck.iloc[:k].assign(track_id="p")
    # the next piece starts 0.1 s later, 2.5 m farther along (eastbound) and 3.5 m to the side: 4.3 m off at 54 deg
    second = truck.iloc[k + 1:].assign(track_id="q", x=lambda p: p["x"] + 2.0, y=lambda p: p["y"] - 3.5)
    rows = _with_trackers([first, second], {"p": "1", "q": "2"}, j)
    assert len(rows) == 1 and rows.iloc[0].complete and (rows.iloc[0].origin, rows.iloc[0].destination) == ("W", "E")


@pytest.mark.parametrize(("cut", "joined_class"), [(0.55, "truck"), (0.7, "van")])
def test_a_vehicle_whose_pieces_are_partly_heavy_is_heavy_from_35_percent_of_its_points(cut, joined_class) -> None:
    """A truck seen as a van by one id and as a truck by another over the same time (two boxes on one vehicle): the
    detector takes a truck for a van far more often than the reverse, so the movement is a truck's when its truck
    piece holds 35 % of the points (40 % here), though the van piece holds more; at 27 % it stays a van."""
    j = junction()
    whole = path("W", "S", tid="x")
    k = int(cut * len(whole))
    van = whole.iloc[: k + 15].assign(track_id="a", **{"class": "van"})
    truck = whole.iloc[k:].assign(track_id="b", **{"class": "truck"})
    rows = run([van, truck], j)
    assert len(rows) == 1 and rows.iloc[0].track_ids == "a;b" and rows.iloc[0].complete
    assert rows.iloc[0]["class"] == joined_class
