"""SUMO at a junction: `sumo-demand` on a run analyzed with --gates builds a demand of its turning movements on the
junction world's own network, and `sumo-validate` counts the simulated vehicles' movements at the same gates with
the same code (GEH per movement and interval); gates map to the arms' in- and out-edges, and a gate the network
does not reach is refused."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from cli_support import invoke
from trafficgeo.synth.junction_sumo import JunctionOptions
from trafficgeo.synth.junction_world import build_junction_world

pytest.importorskip("sumolib")
pytestmark = pytest.mark.slow

DURATION_S = 300.0
INTERVAL_S = 300


@pytest.fixture(scope="module")
def junction_run(tmp_path_factory):
    """The junction world (300 s) analyzed with its gates: the true image points of its vehicles, every frame."""
    out = tmp_path_factory.mktemp("junction")
    world = out / "world"
    build_junction_world(world, JunctionOptions(seed=31, duration_s=DURATION_S, ortho_resolution=0.2), video=False)
    truth = pd.read_csv(world / "truth_tracks.csv")
    seen = truth[(truth["u"] >= 0) & (truth["u"] < 1920) & (truth["v"] >= 0) & (truth["v"] < 1080)]
    seen.rename(columns={"vehicle": "track_id"})[["frame", "time", "track_id", "u", "v", "class"]].to_csv(
        world / "tracks.csv", index=False)
    run = out / "run"
    code, _, err = invoke("analyze", world / "camera_truth.json", world / "tracks.csv", "--surface",
                          world / "dem.tif", "--gates", world / "gates.gpkg", "--movement-interval", INTERVAL_S,
                          "-o", run)
    assert code == 0, err
    return world, run


def _net(world):
    return next((world / "sumo").glob("*.net.xml"))


def test_each_gate_maps_to_its_arms_in_and_out_edge(junction_run) -> None:
    from trafficgeo.simulation.junction import map_gates, read_run_junction
    from trafficgeo.traffic.validation import read_observed_run

    world, run = junction_run
    observed = read_observed_run(run)
    junction = read_run_junction(run, observed.crs)
    gates = map_gates(junction, _net(world), observed.crs)
    assert sorted(gates.table["arm"]) == ["E", "N", "S", "W"]
    for r in gates.table.itertuples():
        assert (r.in_edge, r.out_edge) == (f"{r.arm}_in", f"{r.arm}_out")
        assert r.in_pos_m > 0 and r.out_pos_m > 0
    assert gates.warnings == ()


def test_sumo_demand_and_validate_reproduce_every_movement_per_interval(junction_run, tmp_path) -> None:
    world, run = junction_run
    scenario = tmp_path / "scenario"
    code, out, err = invoke("sumo-demand", run, "--net", _net(world), "-o", scenario, "--interval", INTERVAL_S)
    assert code == 0, err
    doc = json.loads((scenario / "scenario.json").read_text())
    assert doc["junction"]["arms"]["N"] == {"in_edge": "N_in", "out_edge": "N_out"}
    observed = pd.read_csv(scenario / "observed_movement_counts.csv")
    assert doc["vehicles"] == doc["observed_movements"] == int(observed["count"].sum()) > 50
    routes = (scenario / "demand.rou.xml").read_text()
    assert 'edges="S_in N_out"' in routes and 'edges="W_in S_out"' in routes

    code, out, err = invoke("sumo-validate", scenario, run)
    assert code == 0, err
    assert "turning movements: observed vs simulated" in out and "movement counts" in out
    table = pd.read_csv(scenario / "compare_movements.csv")
    assert len(table) >= 10  # the 12 movements of the world (no U-turns), those with a vehicle
    assert (table["geh"] < 5).all(), table[table["geh"] >= 5].to_string()  # the done-when target
    assert table["observed"].sum() == observed["count"].sum()
    assert abs(int(table["simulated"].sum()) - int(table["observed"].sum())) <= 2
    summary = json.loads((scenario / "compare_summary.json").read_text())
    assert summary["movements"]["share_geh_below_5"] == 1.0 and summary["counts"]["rows"] == 0  # no counting lines
    record = json.loads((scenario / "compare_simulation.json").read_text())
    assert record["movements"] == len(table) and record["movement_share_geh_below_5"] == 1.0
    assert record["target_met"] is True
    simulated = pd.read_csv(scenario / "simulated_movements.csv")
    assert simulated["complete"].all()


def test_a_gate_that_crosses_no_edge_of_the_network_is_refused(junction_run, tmp_path) -> None:
    from trafficgeo.simulation.tools import run_sumo_program

    world, run = junction_run
    net = tmp_path / "no_west.net.xml"  # the junction's network without its west arm
    run_sumo_program("netconvert", ["-s", str(_net(world)), "--remove-edges.explicit", "W_in,W_out", "-o", str(net)],
                     120.0)
    scenario = tmp_path / "scenario"
    code, out, err = invoke("sumo-demand", run, "--net", net, "-o", scenario, "--interval", INTERVAL_S)
    assert code == 2
    text = " ".join((out + err).split())
    assert "gate of arm 'W' crosses no edge of the network" in text
    assert not scenario.exists()
    assert not any(p.name.startswith(".sumo-demand-") for p in tmp_path.iterdir())
