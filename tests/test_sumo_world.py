"""Tests of the SUMO traffic world (trafficgeo.synth.sumo_world): SUMO really runs."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyproj
import pytest

from trafficgeo.errors import InputError, TrafficgeoError
from trafficgeo.simulation.tools import sumo_binary
from trafficgeo.synth.gcp_scene import RoadSurface
from trafficgeo.synth.sumo_scene import VEHICLE_CLASSES, Demand, RoadSpec
from trafficgeo.synth.sumo_world import SumoRun, Trajectories, _run_tool, read_fcd, run_sumo_world

pytestmark = pytest.mark.slow  # runs SUMO several times (one run of 120 s of busy traffic)

ROAD = RoadSpec()
DEMAND = Demand()
BUSY = Demand(1000.0)  # enough vehicles in 120 s for flow and mix statistics
FIELDS = list(Trajectories.__dataclass_fields__)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, SumoRun]:
    base = tmp_path_factory.mktemp("sumo")
    a = run_sumo_world(base / "a", ROAD, DEMAND, seed=0)
    b = run_sumo_world(base / "b", ROAD, DEMAND, seed=0)
    c = run_sumo_world(base / "c", ROAD, DEMAND, seed=1)
    long = run_sumo_world(base / "long", ROAD, BUSY, duration_s=120.0, seed=3)
    return {"a": a, "b": b, "c": c, "long": long}


def _same(t1: Trajectories, t2: Trajectories) -> bool:
    return all(np.array_equal(getattr(t1, f), getattr(t2, f)) for f in FIELDS)


# ---------------------------------------------------------------------------------------------------- the run
def test_run_writes_files_and_finds_binaries(runs: dict[str, SumoRun]) -> None:
    run = runs["a"]
    for p in (run.net, run.routes, run.fcd):
        assert p.is_file() and p.parent == run.folder
    assert sorted(p.name for p in run.folder.iterdir()) == [
        "demand.rou.xml", "fcd.xml", "road.edg.xml", "road.net.xml", "road.nod.xml"]  # no temporary files left
    exe = sumo_binary("sumo")
    assert Path(exe).is_file() and os.access(exe, os.X_OK)
    assert Path(sumo_binary("netconvert")).is_file()
    assert run.sumo_version.count(".") >= 2 and run.sumo_version[0].isdigit()
    head = run.fcd.read_text(encoding="utf-8")[:2000]
    assert "generated on" not in head and "sumoConfiguration" not in head
    assert len(run.trajectories) > 10000  # its wall time: benchmarks/bench_fcd.py --parts world


def test_same_seed_identical_different_seed_different(runs: dict[str, SumoRun]) -> None:
    a, b, c = runs["a"], runs["b"], runs["c"]
    assert a.fcd.read_bytes() == b.fcd.read_bytes()
    assert a.net.read_bytes() == b.net.read_bytes()
    assert a.routes.read_bytes() == b.routes.read_bytes()
    assert _same(a.trajectories, b.trajectories)
    assert a.fcd.read_bytes() != c.fcd.read_bytes()
    assert not _same(a.trajectories, c.trajectories)


def test_read_fcd_reproduces_run_trajectories(runs: dict[str, SumoRun]) -> None:
    run = runs["a"]
    assert _same(read_fcd(run.fcd, ROAD, run.net), run.trajectories)  # t0 = first time step = end of warm-up


# ---------------------------------------------------------------------------------------------------- geometry
def test_points_lie_on_their_lanes(runs: dict[str, SumoRun]) -> None:
    t = runs["a"].trajectories
    assert t.time.min() == 0.0 and t.time.max() == pytest.approx(60.0 - 0.04)
    np.testing.assert_allclose(t.time / 0.04, np.round(t.time / 0.04), atol=1e-6)
    assert np.all(np.diff(t.time) >= 0)
    assert set(np.unique(t.direction)) == {1, 2} and set(np.unique(t.lane)) == {1, 2}
    centre = np.array([ROAD.lane_centre_offset(int(d), int(k)) for d, k in zip(t.direction, t.lane, strict=True)])
    off = np.abs(t.offset - centre)
    assert np.mean(off <= 0.01) > 0.9  # on their lane centres except while changing lanes
    assert np.all(off <= 0.5 * ROAD.lane_width + 1e-9)  # the lane is the one under the footprint centre
    # lane changes drift across over LANE_CHANGE_DURATION_S instead of jumping: no lateral step above 0.15 m/frame
    order = np.lexsort((t.time, t.vehicle))
    same = t.vehicle[order][1:] == t.vehicle[order][:-1]
    assert np.max(np.abs(np.diff(t.offset[order]))[same]) < 0.15
    assert np.all(np.abs(t.station) <= 0.5 * ROAD.length_m)
    assert np.all((t.offset > 0) == (t.direction == 1))
    expected = np.where(t.direction == 1, ROAD.azimuth_deg, ROAD.azimuth_deg + 180.0)
    dh = np.abs((t.heading_deg - expected + 180.0) % 360.0 - 180.0)
    assert np.max(dh[off <= 0.01]) <= 2.0 and np.max(dh) <= 8.0  # a lane change turns the vehicle a little
    np.testing.assert_allclose(t.z, ROAD.origin[2])
    # vehicles do change lanes (LC2013 overtaking): some vehicle id appears in two lanes
    pairs = np.unique(np.char.add(np.char.add(t.vehicle, "/"), t.lane.astype(str)))
    assert len(pairs) > len(np.unique(t.vehicle))


def test_lane_numbering_and_polygons() -> None:
    road = RoadSpec(lanes=3, lane_width=3.0)
    assert [road.lane_centre_offset(1, k) for k in (1, 2, 3)] == [1.5, 4.5, 7.5]
    assert [road.lane_centre_offset(2, k) for k in (1, 2, 3)] == [-1.5, -4.5, -7.5]
    assert road.heading_deg(1) == 30.0 and road.heading_deg(2) == 210.0
    poly = road.lane_polygon(2, 3)
    s, o = road.surface.station_offset(poly[:, 0], poly[:, 1])
    np.testing.assert_allclose(s, [-200, 200, 200, -200], atol=1e-9)
    np.testing.assert_allclose(o, [-6.0, -6.0, -9.0, -9.0], atol=1e-9)
    with pytest.raises(InputError):
        road.lane_centre_offset(1, 4)
    with pytest.raises(InputError):
        RoadSpec(two_way=False).lane_centre_offset(2, 1)


def test_georeferencing_matches_sumolib_and_pyproj(runs: dict[str, SumoRun]) -> None:
    import sumolib

    run = runs["a"]
    net = sumolib.net.readNet(str(run.net))
    off = np.array(net.getLocationOffset())
    np.testing.assert_allclose(off, -np.array(ROAD.origin[:2]), atol=1e-9)  # world = sumo - netOffset
    crs = pyproj.CRS(ROAD.crs)
    # SUMO only projects: its lon/lat are on the CRS's own datum (NAD83(CSRS)), not WGS 84
    to_geo = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
    geod = pyproj.Geod(ellps="GRS80")
    surface = RoadSurface(np.array(ROAD.origin), ROAD.azimuth_deg)
    n_lanes = 0
    for edge in net.getEdges():
        direction = int(edge.getID()[1])
        for lane in edge.getLanes():
            shape = np.array(lane.getShape())
            world = shape - off
            lon_s, lat_s = np.array([net.convertXY2LonLat(x, y) for x, y in shape]).T
            lon_p, lat_p = to_geo.transform(world[:, 0], world[:, 1])
            _, _, dist = geod.inv(lon_s, lat_s, lon_p, lat_p)
            assert np.max(dist) < 0.01
            # lane centre lines from SUMO's own net lie where RoadSpec puts them (SUMO index 0 = outermost lane)
            ours = ROAD.lanes - lane.getIndex()
            _, o = surface.station_offset(world[:, 0], world[:, 1])
            np.testing.assert_allclose(o, ROAD.lane_centre_offset(direction, ours), atol=2e-3)
            n_lanes += 1
    assert n_lanes == 4


def test_world_points_are_footprint_centres(runs: dict[str, SumoRun]) -> None:
    import sumolib

    run = runs["a"]
    t = run.trajectories
    s, o = RoadSurface(np.array(ROAD.origin), ROAD.azimuth_deg).station_offset(t.x, t.y)
    np.testing.assert_allclose(s, t.station, atol=1e-9)
    np.testing.assert_allclose(o, t.offset, atol=1e-9)
    # raw FCD (front bumper, SUMO coordinates) of the first recorded step
    raw = {}
    for step, veh in sumolib.xml.parse_fast_nested(str(run.fcd), "timestep", ["time"], "vehicle",
                                                   ["id", "x", "y", "angle"]):
        if float(step.time) > 60.0:
            break
        raw[veh.id] = (float(veh.x), float(veh.y), float(veh.angle))
    first = np.flatnonzero(t.time == 0.0)
    assert len(first) > 5
    for i in first:
        fx, fy, ang = raw[str(t.vehicle[i])]
        half = 0.5 * t.length[i]
        front = np.array([fx, fy]) + np.array(ROAD.origin[:2])
        centre = front - half * np.array([np.sin(np.radians(ang)), np.cos(np.radians(ang))])
        np.testing.assert_allclose([t.x[i], t.y[i]], centre, atol=1e-6)


def test_one_way_road_elsewhere(tmp_path: Path) -> None:
    road = RoadSpec(origin=(300100.5, 5050000.25, 12.0), azimuth_deg=290.0, length_m=250.0, lanes=3, two_way=False,
                    lane_width=3.25, speed_limit_kmh=70.0)
    run = run_sumo_world(tmp_path, road, Demand(900.0, {"car": 0.9, "truck": 0.1}), duration_s=20.0, warmup_s=30.0,
                         step_s=0.1, seed=5)
    t = run.trajectories
    assert len(t) > 100 and np.all(t.direction == 1) and set(np.unique(t.lane)) <= {1, 2, 3}
    assert set(np.unique(t.vclass)) <= {"car", "truck"}
    centre = (t.lane - 0.5) * road.lane_width
    assert np.max(np.abs(t.offset - centre)) <= 0.01
    assert np.all(np.abs(t.station) <= 125.0)
    dh = (t.heading_deg - 290.0 + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(dh)) <= 2.0
    np.testing.assert_allclose(t.time / 0.1, np.round(t.time / 0.1), atol=1e-6)
    assert t.time.max() == pytest.approx(19.9)


# ---------------------------------------------------------------------------------------------------- traffic
def test_flow_matches_demand(runs: dict[str, SumoRun]) -> None:
    t = runs["long"].trajectories
    duration = 120.0
    for d in (1, 2):
        m = t.direction == d
        ids, inv = np.unique(t.vehicle[m], return_inverse=True)
        smin = np.full(len(ids), np.inf)
        smax = np.full(len(ids), -np.inf)
        np.minimum.at(smin, inv, t.station[m])
        np.maximum.at(smax, inv, t.station[m])
        crossed = np.count_nonzero((smin < 0.0) & (smax > 0.0))
        per_lane_hour = crossed / ROAD.lanes / duration * 3600.0
        assert 0.6 * BUSY.veh_per_hour_per_lane <= per_lane_hour <= 1.4 * BUSY.veh_per_hour_per_lane


def test_class_sizes_and_mix(runs: dict[str, SumoRun]) -> None:
    car, truck = VEHICLE_CLASSES["car"], VEHICLE_CLASSES["truck"]
    assert 4.2 <= car.length <= 4.8 and 1.7 <= car.width <= 1.9 and 1.4 <= car.height <= 1.6
    assert truck.length >= 10.0 and truck.height >= 3.5 and truck.width <= 2.6
    assert VEHICLE_CLASSES["bus"].length >= 10.0 and 5.0 <= VEHICLE_CLASSES["van"].length <= 6.5
    assert set(VEHICLE_CLASSES) == {"car", "van", "truck", "bus"}
    t = runs["long"].trajectories
    for name, vc in VEHICLE_CLASSES.items():
        m = t.vclass == name
        assert m.any()
        assert np.all(t.length[m] == vc.length) and np.all(t.width[m] == vc.width) and np.all(t.height[m] == vc.height)
    ids, first = np.unique(t.vehicle, return_index=True)
    classes = t.vclass[first]
    assert len(ids) > 120
    share = {name: np.mean(classes == name) for name in VEHICLE_CLASSES}
    assert 0.68 <= share["car"] <= 0.9
    assert 0.03 <= share["van"] <= 0.18 and 0.02 <= share["truck"] <= 0.14 and 0.0 < share["bus"] <= 0.08
    assert hash(BUSY) == hash(Demand(1000.0)) and BUSY == Demand(1000.0)


def test_speeds_near_limit_never_above_max_factor(runs: dict[str, SumoRun]) -> None:
    t = runs["a"].trajectories
    limit = ROAD.speed_limit
    top = max(vc.speed_factor[3] for vc in VEHICLE_CLASSES.values())
    assert np.all(t.speed >= 0.0)
    assert np.max(t.speed) <= limit * top + 0.002
    assert 0.85 * limit <= np.median(t.speed) <= 1.1 * limit
    assert np.mean(t.speed > 0.7 * limit) > 0.9


# ---------------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("make", [
    lambda: RoadSpec(lanes=0),
    lambda: RoadSpec(lanes=1.5),
    lambda: RoadSpec(length_m=-1.0),
    lambda: RoadSpec(lane_width=0.0),
    lambda: RoadSpec(origin=(1.0, 2.0)),
    lambda: RoadSpec(crs="EPSG:4326"),
    lambda: RoadSpec(crs="EPSG:2236"),  # US survey feet
    lambda: Demand(veh_per_hour_per_lane=-10.0),
    lambda: Demand(veh_per_hour_per_lane=float("nan")),
    lambda: Demand(mix={"car": 0.5, "truck": 0.2}),
    lambda: Demand(mix={"car": 0.9, "tram": 0.1}),
    lambda: Demand(mix={"car": 1.2, "truck": -0.2}),
    lambda: Demand(mix={}),
])
def test_bad_specs_raise_one_line_input_error(make) -> None:
    with pytest.raises(InputError) as info:
        make()
    assert "\n" not in str(info.value) and str(info.value)


@pytest.mark.parametrize("kwargs", [
    {"step_s": 1 / 30}, {"step_s": 0.0}, {"duration_s": -5.0}, {"warmup_s": -1.0}, {"seed": -1}, {"seed": 1.5},
])
def test_bad_run_options_raise_before_running(tmp_path: Path, kwargs: dict) -> None:
    with pytest.raises(InputError) as info:
        run_sumo_world(tmp_path, ROAD, DEMAND, **kwargs)
    assert "\n" not in str(info.value)
    assert not list(tmp_path.iterdir())


def test_missing_tool_and_failing_sumo() -> None:
    with pytest.raises(InputError, match="eclipse-sumo"):
        sumo_binary("no-such-sumo-tool")
    with pytest.raises(TrafficgeoError, match="exit code") as info:
        _run_tool("sumo", ["--net-file", "/nonexistent/road.net.xml", "--no-step-log"], 60.0)
    assert "\n" not in str(info.value)


def test_read_fcd_rejects_mismatched_road(runs: dict[str, SumoRun], tmp_path: Path) -> None:
    run = runs["a"]
    with pytest.raises(InputError, match="origin"):
        read_fcd(run.fcd, RoadSpec(origin=(245100.0, 5182600.0, 90.0)), run.net)
    with pytest.raises(InputError, match="lane"):
        read_fcd(run.fcd, RoadSpec(lanes=1), run.net)
    with pytest.raises(InputError, match="does not exist"):
        read_fcd(tmp_path / "missing.xml", ROAD, run.net)


def test_zero_demand_gives_empty_trajectories(tmp_path: Path) -> None:
    run = run_sumo_world(tmp_path, ROAD, Demand(0.0), duration_s=2.0, warmup_s=1.0, step_s=0.5)
    t = run.trajectories
    assert len(t) == 0 and t.vehicle.dtype.kind == "U" and t.direction.dtype == np.int64


def test_curved_road_keeps_vehicles_on_their_lanes_and_headings(tmp_path):
    road = RoadSpec(length_m=200.0, curve_radius=-150.0)
    run = run_sumo_world(tmp_path, road, Demand(900.0), duration_s=20.0, step_s=0.1, warmup_s=30.0, seed=2)
    t = run.trajectories
    assert len(t) > 100
    centred = np.ones(len(t), dtype=bool)
    for d in road.directions:
        for k in range(1, road.lanes + 1):
            m = (t.direction == d) & (t.lane == k)
            if m.any():
                # The footprint centre of a long vehicle sits inside the curve by up to L^2 / (8 R); vehicles
                # changing lanes are between the centres for a while.
                dev = np.abs(t.offset[m] - road.lane_centre_offset(d, k))
                assert np.quantile(dev, 0.9) < 0.15
                centred[m] = dev < 0.15
    expect = np.array([road.heading_deg(int(d), s) for d, s in zip(t.direction, t.station, strict=True)])
    dh = np.abs((t.heading_deg - expect + 180) % 360 - 180)
    assert np.quantile(dh[centred], 0.95) < 1.0 and dh.max() < 8.0  # lane changes turn vehicles a little
    with pytest.raises(InputError):
        RoadSpec(curve_radius=20.0)


def test_finding_sumo_leaves_the_proj_database_of_this_process_alone() -> None:
    """Importing the eclipse-sumo package sets PROJ_DATA to SUMO's older PROJ database; a process that inherits it (a
    Dask worker spawned after a world was built) then cannot transform coordinates. Finding SUMO must not leak it."""
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("PROJ_DATA", "PROJ_LIB", "SUMO_HOME")}
    code = ("import os; from trafficgeo.synth.sumo_world import sumo_binary; sumo_binary('sumo'); "
            "print([k for k in ('PROJ_DATA', 'PROJ_LIB', 'SUMO_HOME') if k in os.environ])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
