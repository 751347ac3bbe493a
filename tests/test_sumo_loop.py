"""Closing the loop with SUMO (trafficgeo.simulation): observed counts -> sumo-demand -> SUMO -> sumo-validate.

The observed run is written from the true trajectories of a SUMO world (trafficgeo.synth.observed_run), so the
truth is a real SUMO simulation: the demand built from its counts must reproduce them in a new SUMO run.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import trafficgeo as tg
from cli_support import invoke
from trafficgeo.errors import InputError
from trafficgeo.simulation.mapping import MappingError, map_observations
from trafficgeo.synth.observed_run import truth_run_folder
from trafficgeo.synth.sumo_scene import Demand, RoadSpec
from trafficgeo.synth.sumo_world import run_sumo_world
from trafficgeo.traffic.validation import read_observed_run

pytestmark = pytest.mark.slow  # SUMO, randomTrips and routeSampler run (about 30 s in all)

ROAD = RoadSpec()  # EPSG:2949, 2 lanes per direction, 50 km/h
STATIONS = (-100.0, 100.0)  # two counting lines across the road, 200 m apart
DURATION_S = 600.0
INTERVAL_S = 300.0


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("sumo_loop")
    sumo = run_sumo_world(base / "world", ROAD, Demand(600.0), duration_s=DURATION_S, step_s=0.5, seed=1)
    truth_run_folder(base / "run", sumo.trajectories, ROAD, stations_m=STATIONS, interval_s=60.0)
    # the same observation in another CRS than the network's (UTM 19N on WGS 84, the net is MTM 7 on NAD83(CSRS))
    truth_run_folder(base / "run_utm", sumo.trajectories, ROAD, stations_m=STATIONS, interval_s=60.0,
                     crs="EPSG:32619")
    return {"base": base, "net": sumo.net, "run": base / "run", "run_utm": base / "run_utm"}


def _check_fit(loop: tg.SumoLoopResult, min_share: float = 1.0) -> None:
    table = loop.validation.comparison.counts
    assert len(table) == 2 * 4 * 2  # 2 lines x 4 lanes (2 per direction) x 2 intervals
    assert (table["geh"] < 5).mean() >= min_share, table
    assert loop.share_geh_below_5 >= min_share and loop.validation.target_met
    # every observed vehicle is simulated within a few percent (routeSampler meets the edge counts)
    obs, sim = int(table["observed"].sum()), int(table["simulated"].sum())
    assert obs > 700 and abs(sim - obs) <= 0.05 * obs, (obs, sim)
    # speeds per line and lane within 2.5 km/h (measured: at most 1.5), travel times within 1 s (measured 0.1)
    speeds = loop.validation.comparison.speeds
    assert len(speeds) == 8 and (speeds["mean_difference_kmh"].abs() <= 2.5).all(), speeds
    assert abs(loop.validation.travel_time_difference_s) < 1.0


def test_the_simulated_vehicles_cross_the_fitted_lines_when_the_observed_ones_did(world: dict[str, Path],
                                                                                  tmp_path: Path) -> None:
    """Each simulated vehicle takes an observed vehicle's time at the first line along its edge: the demand replays
    the arrivals, not only their number per interval (routeSampler alone spreads them at random over it)."""
    loop = tg.close_sumo_loop(world["run"], world["net"], tmp_path / "scenario", interval_s=INTERVAL_S, seed=0)
    obs = pd.read_csv(world["run"] / "crossings.csv", dtype={"line": str})
    sim = loop.validation.comparison.simulated_crossings.astype({"line": str})
    for line, direction in (("s-100", -1), ("s100", 1)):  # the first line along d1 and along d2
        t_obs = np.sort(obs.loc[(obs["line"] == line) & (obs["direction"] == direction), "time"].to_numpy(float))
        t_sim = np.sort(sim.loc[(sim["line"] == line) & (sim["direction"] == direction), "time"].to_numpy(float))
        assert len(t_obs) > 150 and len(t_sim) == len(t_obs)
        gaps = np.abs(t_sim - t_obs)
        # measured: median 0.0002 s, 95th percentile 0.0007 s; routeSampler's own departures gave a median of
        # 27.6 s and a 95th percentile of 63 s (and before the departures were put on SUMO's steps, 0.47 / 0.79 s)
        assert np.median(gaps) < 0.1 and np.quantile(gaps, 0.95) < 0.5, (np.median(gaps), np.quantile(gaps, 0.95))


def test_round_trip_reproduces_the_observed_counts(world: dict[str, Path], tmp_path: Path) -> None:
    loop = tg.close_sumo_loop(world["run"], world["net"], tmp_path / "scenario", interval_s=INTERVAL_S, seed=0)
    _check_fit(loop)
    sc = loop.scenario
    for name in ("scenario.sumocfg", "demand.rou.xml", "counts.edgedata.xml", "candidates.rou.xml", "mapping.csv",
                 "scenario.json", "fcd.xml", "simulated.edgedata.xml", "compare_counts.csv", "compare_summary.json"):
        assert (sc.folder / name).is_file(), name
    # the edge data routeSampler got: the lanes of each edge summed at the first line along it (d1 runs towards
    # increasing stations, d2 the other way), i.e. the observed vehicles in each direction, all simulated
    cr = pd.read_csv(world["run"] / "crossings.csv", dtype={"lane": str, "line": str})
    first = {"d1": ("s-100", -1), "d2": ("s100", 1)}
    edge_text = (sc.folder / "counts.edgedata.xml").read_text()
    import xml.etree.ElementTree as ET

    intervals = ET.fromstring(edge_text).findall("interval")
    got = {(float(iv.get("begin")), e.get("id")): int(e.get("entered")) for iv in intervals for e in iv}
    for edge, (line, direction) in first.items():
        t = cr.loc[(cr["line"] == line) & (cr["direction"] == direction), "time"]
        assert got[(0.0, edge)] == int((t < 300).sum()) and got[(300.0, edge)] == int((t >= 300).sum())
    # a warm-up before the observation at the rate of its first interval: 1.5 x 200 m / 13 m/s + 10 s, to 10 s
    assert (intervals[0].get("begin"), intervals[0].get("end")) == ("-40.000", "0.000")
    assert len(got) == 6 and sc.vehicles == sum(got.values())  # routeSampler --optimize full meets every count
    # vehicle types from the observed mix: shares sum to 1, classes of the world
    shares = {t["class"]: t["share"] for t in sc.vehicle_types}
    assert set(shares) <= {"car", "van", "truck", "bus"} and sum(shares.values()) == pytest.approx(1.0)
    assert shares["car"] > 0.6
    # deterministic for a seed: the same demand again
    again = tg.build_sumo_scenario(world["run"], world["net"], tmp_path / "again", interval_s=INTERVAL_S, seed=0)
    assert (again.folder / "demand.rou.xml").read_bytes() == (sc.folder / "demand.rou.xml").read_bytes()


def test_a_run_in_another_crs_than_the_network(world: dict[str, Path], tmp_path: Path) -> None:
    observed = read_observed_run(world["run_utm"])
    assert observed.crs.to_epsg() == 32619
    mapping = map_observations(observed, world["net"])
    # lane d<direction>_<k> (k = 1 innermost) is SUMO lane d<direction>_<lanes - k> (SUMO counts from the right)
    got = dict(zip(mapping.table["lane"], mapping.table["sumo_lane"], strict=True))
    assert got == {"d1_1": "d1_1", "d1_2": "d1_0", "d2_1": "d2_1", "d2_2": "d2_0"}
    # the line at station -100 m is 140 m along d1 (which starts 40 m before the 400 m road) and 340 m along d2
    pos = mapping.table.groupby(["line", "sumo_edge"])["pos_m"].first()
    assert pos[("s-100", "d1")] == pytest.approx(140.0, abs=1.5) and pos[("s-100", "d2")] == pytest.approx(340, abs=1.5)
    loop = tg.close_sumo_loop(world["run_utm"], world["net"], tmp_path / "scenario", interval_s=INTERVAL_S)
    _check_fit(loop)


def test_a_full_disk_under_sumo_demand_and_sumo_validate(world: dict[str, Path], tmp_path: Path) -> None:
    """Issue 43: a full disk under sumo-demand or sumo-validate stops with one line and exit code 1, and leaves no
    scenario or comparison looking written (no manifest) and no temporary file."""
    from cli_support import invoke_on_a_full_disk

    run = tmp_path / "run"
    shutil.copytree(world["run"], run)
    cut = invoke_on_a_full_disk(200, "sumo-demand", run, "--net", world["net"], "--out", tmp_path / "cut",
                                "--interval", 300, "--seed", 3)
    lines = [ln for ln in cut.stderr.splitlines() if ln.startswith("trafficgeo")]
    assert cut.returncode == 1 and len(lines) == 1 and "could not write" in lines[0], cut.stderr
    left = [p.name for p in (tmp_path / "cut").rglob("*")] if (tmp_path / "cut").exists() else []
    assert "scenario_run.json" not in left and not any(".tmp" in n for n in left), left
    code, _stdout, stderr = invoke("sumo-demand", run, "--net", world["net"], "--out", tmp_path / "sc", "--interval",
                                   300, "--seed", 3)
    assert code == 0, stderr
    before = sorted(p.name for p in run.iterdir())
    cut = invoke_on_a_full_disk(200, "sumo-validate", tmp_path / "sc", run, "--out", run)
    lines = [ln for ln in cut.stderr.splitlines() if ln.startswith("trafficgeo")]
    assert cut.returncode == 1 and len(lines) == 1, cut.stderr
    assert "Traceback" not in cut.stderr
    after = sorted(p.name for p in run.iterdir())
    assert "compare_run.json" not in after and not any(".tmp" in n for n in after), (before, after)


def test_sumo_validate_feeds_the_report_of_a_run_folder(world: dict[str, Path], tmp_path: Path) -> None:
    from trafficgeo.report.inputs import find_inputs

    run = tmp_path / "run"
    shutil.copytree(world["run"], run)
    code, stdout, stderr = invoke("sumo-demand", run, "--net", world["net"], "--out", tmp_path / "sc", "--interval",
                                  300, "--seed", 3)
    assert code == 0, stderr
    assert "SUMO time = observed time +" in " ".join(stdout.split())
    code, stdout, stderr = invoke("sumo-validate", tmp_path / "sc", run, "--out", run)
    assert code == 0, stderr
    assert "target >= 85% met" in " ".join(stdout.split())
    table = pd.read_csv(run / "compare_counts.csv")
    assert len(table) == 16 and set(table["interval_start"]) == {0.0, 300.0}  # the scenario's, not the run's 60 s
    inputs = find_inputs(run)
    assert inputs.traffic and inputs.traffic[0].compare  # the HTML report shows "Observed vs simulated"
    assert inputs.traffic[0].compare_summary.counts.rows == 16  # compare_summary.json read typed by the run folder


def test_a_line_off_the_network_is_one_line_error_with_a_table(world: dict[str, Path], tmp_path: Path) -> None:
    # a second world's road 2 km east: its counting lines cross no edge of the first world's network
    far = RoadSpec(origin=(ROAD.origin[0] + 2000.0, ROAD.origin[1], ROAD.origin[2]))
    sumo = run_sumo_world(tmp_path / "far", far, Demand(300.0), duration_s=30.0, step_s=0.5, seed=2)
    truth_run_folder(tmp_path / "run", sumo.trajectories, far, stations_m=(0.0,), interval_s=30.0)
    with pytest.raises(MappingError, match=r"^net .*counting line 's0' crosses no edge of the network") as info:
        map_observations(read_observed_run(tmp_path / "run"), world["net"])
    assert "\n" not in str(info.value)
    assert set(info.value.table["problem"]) == {"crosses no SUMO edge in this direction"}
    out = tmp_path / "scenario"
    code, stdout, stderr = invoke("sumo-demand", tmp_path / "run", "--net", world["net"], "--out", out)
    assert code == 2 and stderr.count("\n") == 1 and "error: --net " in stderr
    assert "counting lines on the SUMO network" in stdout and "s0" in stdout  # the table
    assert not out.exists()


def _net(folder: Path, world: dict[str, Path], nodes: dict[str, tuple[float, float]],
         edges: list[tuple[str, str, str, int]]) -> Path:
    """A network with the world's location (same netOffset and projection) from nodes (x, y relative to the road's
    origin) and edges (id, from, to, lanes), built by netconvert."""
    from trafficgeo.simulation.tools import run_sumo_program

    folder.mkdir(parents=True, exist_ok=True)
    location = next(ln for ln in (world["net"].parent / "road.nod.xml").read_text().splitlines() if "<location" in ln)
    (folder / "n.nod.xml").write_text("<nodes>\n" + location + "\n" + "".join(
        f'<node id="{n}" x="{x!r}" y="{y!r}"/>\n' for n, (x, y) in nodes.items()) + "</nodes>\n")
    (folder / "n.edg.xml").write_text("<edges>\n" + "".join(
        f'<edge id="{e}" from="{a}" to="{b}" numLanes="{k}" speed="{ROAD.speed_limit!r}" width="3.5" '
        'spreadType="right"/>\n' for e, a, b, k in edges) + "</edges>\n")
    run_sumo_program("netconvert", ["--node-files", str(folder / "n.nod.xml"), "--edge-files",
                                    str(folder / "n.edg.xml"), "--offset.disable-normalization", "--no-turnarounds",
                                    "-o", str(folder / "net.net.xml")], 60.0)
    return folder / "net.net.xml"


def _along(station: float, offset: float = 0.0) -> tuple[float, float]:
    """x, y relative to the origin of a point ``station`` m along the road axis and ``offset`` m right of it."""
    a = np.radians(ROAD.azimuth_deg)
    return (float(station * np.sin(a) + offset * np.cos(a)), float(station * np.cos(a) - offset * np.sin(a)))


def test_a_network_of_several_edges_with_a_side_road(world: dict[str, Path], tmp_path: Path) -> None:
    """The road cut in two at a junction (station 0) with a side road: routes of two edges (and some through the
    side road) are the candidates; the demand must pass both lines with one vehicle, not two."""
    net = _net(tmp_path / "net", world, {"A": _along(-240), "M": _along(0), "B": _along(240), "S": _along(0, 200)},
               [("a1", "A", "M", 2), ("b1", "M", "B", 2), ("b2", "B", "M", 2), ("a2", "M", "A", 2),
                ("sin", "S", "M", 1), ("sout", "M", "S", 1)])
    loop = tg.close_sumo_loop(world["run"], net, tmp_path / "scenario", interval_s=INTERVAL_S)
    mapping = pd.read_csv(loop.scenario.folder / "mapping.csv", dtype=str, keep_default_na=False)
    assert dict(zip(mapping["line"] + mapping["lane"], mapping["sumo_edge"], strict=True)) == {
        "s-100d1_1": "a1", "s-100d1_2": "a1", "s-100d2_1": "a2", "s-100d2_2": "a2",
        "s100d1_1": "b1", "s100d1_2": "b1", "s100d2_1": "b2", "s100d2_2": "b2"}
    routes = (loop.scenario.folder / "demand.rou.xml").read_text()
    through = routes.count('edges="a1 b1"') + routes.count('edges="b2 a2"')
    assert through >= 0.9 * loop.scenario.vehicles  # measured: 199 of 204
    # Downstream of the junction SUMO's own lane changing spreads the vehicles over the two lanes: one count in 16
    # may miss GEH 5 (measured on world seeds 1-4: 93.8-100 % of the counts below 5; before the observed times
    # were replayed, 87.5-100 %), while every count at the lines the demand is fitted to is met.
    _check_fit(loop, min_share=0.9)
    table = loop.validation.comparison.counts
    fitted = ((table["line"] == "s-100") & (table["direction"] == -1)) | ((table["line"] == "s100")
                                                                        & (table["direction"] == 1))
    assert (table.loc[fitted, "geh"] < 1.0).all(), table


def test_a_line_over_two_parallel_edges_without_lanes_is_ambiguous(world: dict[str, Path], tmp_path: Path) -> None:
    from dataclasses import replace

    # two one-way carriageways side by side in direction 1, as two edges; a run without lane polygons
    # (lane centres 2.75 and 6.25 m right of the axis, both under the lines, which span 8 m either side)
    net = _net(tmp_path / "net", world, {"A": _along(-240, 1), "B": _along(240, 1), "C": _along(-240, 4.5),
                                         "D": _along(240, 4.5)}, [("east", "A", "B", 1), ("west", "C", "D", 1)])
    observed = read_observed_run(world["run"])
    crossings = observed.crossings.assign(lane="")
    no_lanes = replace(observed, lanes=None, crossings=crossings,
                       counts=observed.counts.assign(lane="").drop_duplicates(
                           ["line", "lane", "direction", "interval_start"]))
    with pytest.raises(MappingError, match=r"^net .*: line 's-100' lane '\(none\)' direction -1: ambiguous: lanes of "
                       r"edges east, west \(4 of 4 line/lane/direction groups not mapped\)") as info:
        map_observations(no_lanes, net)
    problems = info.value.table.set_index(["line", "direction"])["problem"]
    assert problems[("s100", -1)] == "ambiguous: lanes of edges east, west"
    assert problems[("s100", 1)] == "crosses no SUMO edge in this direction"  # no edge of direction 2 here
    assert "\n" not in str(info.value)


def test_a_wrong_way_vehicle_is_left_out_with_a_warning(world: dict[str, Path]) -> None:
    from dataclasses import replace

    observed = read_observed_run(world["run"])
    cr = observed.crossings
    wrong = cr[(cr["line"] == "s-100") & (cr["lane"] == "d1_1")].head(1).assign(direction=1, track_id="ghost")
    mapping = map_observations(replace(observed, crossings=pd.concat([cr, wrong], ignore_index=True)), world["net"])
    assert mapping.warnings == ("line 's-100' lane 'd1_1' direction +1: no SUMO lane of this direction under the "
                                "observed lane; its 1 vehicle(s) left out",)
    assert len(mapping.mapped) == 8 and len(mapping.table) == 9


def _empty_run(tmp: Path, world: dict[str, Path]) -> Path:
    """A run whose lines no vehicle crossed (only its first 1 s of truth)."""
    d = tmp / "empty_run"
    shutil.copytree(world["run"], d)
    from trafficgeo.io.run_manifest import publish_outputs

    summary = tg.RunFolder(d).summary()

    cr = pd.read_csv(d / "crossings.csv")
    cr.iloc[:0].to_csv(d / "crossings.csv", index=False)
    c = pd.read_csv(d / "counts.csv")
    c.iloc[:0].to_csv(d / "counts.csv", index=False)
    publish_outputs(d, [d / n for n in ("summary.json", "counts.csv", "crossings.csv", "trajectories.gpkg")],
                    command="analyze")
    assert summary.period_s == (0.0, DURATION_S)
    return d


BAD = {
    "missing_net": (lambda t, w: [w["run"], "--net", t / "nope.net.xml"], "--net "),
    "zero_interval": (lambda t, w: [w["run"], "--net", w["net"], "--interval", 0], "--interval 0"),
    "nan_interval": (lambda t, w: [w["run"], "--net", w["net"], "--interval", "nan"], "--interval nan"),
    "begin_after_end": (lambda t, w: [w["run"], "--net", w["net"], "--begin", 200, "--end", 100], "--begin 200"),
    "not_a_run": (lambda t, w: [t, "--net", w["net"]], "no summary.json"),
    "empty_run": (lambda t, w: [_empty_run(t, w), "--net", w["net"]], "no vehicle counted"),
    "missing_routes": (lambda t, w: [w["run"], "--net", w["net"], "--routes", t / "r.rou.xml"], "--routes "),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_exits_2_with_one_line_and_nothing_written(case: str, world: dict[str, Path],
                                                              tmp_path: Path) -> None:
    make, expect = BAD[case]
    out = tmp_path / "scenario"
    code, _stdout, stderr = invoke("sumo-demand", *make(tmp_path, world), "--out", out)
    assert code == 2, stderr
    assert stderr.startswith("trafficgeo: error: ") and stderr.count("\n") == 1, stderr
    assert expect in stderr, stderr
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".sumo")]  # no work folder left behind


def test_sumo_validate_bad_input(world: dict[str, Path], tmp_path: Path) -> None:
    code, _, stderr = invoke("sumo-validate", tmp_path / "nope", world["run"])
    assert code == 2 and "SCENARIO" in stderr and "sumo-demand" in stderr
    with pytest.raises(InputError, match=r"^scenario .*nope: no scenario\.json"):
        tg.validate_sumo_scenario(tmp_path / "nope", tmp_path)


def test_departure_lanes_and_speeds_come_from_observed_vehicles(world: dict[str, Path], tmp_path: Path) -> None:
    sc = tg.build_sumo_scenario(world["run"], world["net"], tmp_path / "sc", interval_s=INTERVAL_S)
    text = (sc.folder / "demand.rou.xml").read_text()
    import xml.etree.ElementTree as ET

    veh = ET.fromstring(text).findall("vehicle")
    assert len(veh) == sc.vehicles > 360
    factors = np.array([float(v.get("speedFactor")) for v in veh])
    observed = pd.read_csv(world["run"] / "crossings.csv")
    obs_factor = observed["speed_kmh"].to_numpy() / ROAD.speed_limit_kmh
    assert abs(np.median(factors) - np.median(obs_factor)) < 0.03
    depart = np.array([float(v.get("depart")) for v in veh])
    assert np.all(np.diff(depart) >= 0) and depart.min() >= 0  # sorted, after the start of the simulation
    assert {v.get("departLane") for v in veh} <= {"0", "1"}  # every route starts on an observed edge
    # inserted 30 m before the first line along their edge (at 140 m on both edges), a little farther back when the
    # departure was moved to the SUMO step before it: by what the vehicle drives in under one 0.5 s step
    pos = np.array([float(v.get("departPos")) for v in veh])
    assert np.all((pos <= 110.0) & (pos > 110.0 - 0.5 * 2.0 * ROAD.speed_limit_kmh / 3.6)), pos
    assert np.allclose(np.round(depart / 0.5) * 0.5, depart, atol=0.006)  # written to 0.01 s


def test_user_routes_and_the_run_a_scenario_belongs_to(world: dict[str, Path], tmp_path: Path) -> None:
    sc = tg.build_sumo_scenario(world["run"], world["net"], tmp_path / "sc", interval_s=INTERVAL_S)
    # validating against other observations (here the run in UTM: other crossings) is refused before SUMO runs
    with pytest.raises(InputError, match=r"^run .*run_utm: not the observations scenario .* was built from"):
        tg.validate_sumo_scenario(sc.folder, world["run_utm"], out_dir=tmp_path / "cmp")
    assert not (tmp_path / "cmp").exists() and not (sc.folder / "fcd.xml").exists()
    # the user's candidate routes instead of randomTrips.py
    routes = tmp_path / "mine.rou.xml"
    routes.write_text('<routes>\n    <route id="r1" edges="d1"/>\n    <route id="r2" edges="d2"/>\n</routes>\n')
    code, _, stderr = invoke("sumo-demand", world["run"], "--net", world["net"], "--routes", routes, "--out",
                             tmp_path / "mine", "--interval", INTERVAL_S)
    assert code == 0, stderr
    doc = json.loads((tmp_path / "mine" / "scenario.json").read_text())
    assert doc["routes"] == str(routes.resolve()) and doc["vehicles"] == sc.vehicles
    assert not (tmp_path / "mine" / "candidates.rou.xml").exists()
    routes.write_text('<routes>\n    <route id="r1" edges="d1"/>\n</routes>\n')
    code, _, stderr = invoke("sumo-demand", world["run"], "--net", world["net"], "--routes", routes, "--out",
                             tmp_path / "one_way")
    assert code == 2 and "error: --routes " in stderr and "no route passes the counted edge(s) d2" in stderr
    assert not (tmp_path / "one_way").exists()
