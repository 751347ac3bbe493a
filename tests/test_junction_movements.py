"""Turning movements end to end on the junction world: `trafficgeo analyze --gates` on the image points of the true
vehicles (the footprint centres seen through the true camera, every frame), scored against the simulation's own
truth (truth_movements.csv from SUMO's routes and gate crossings)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from cli_support import invoke
from trafficgeo.run.folder import RunFolder
from trafficgeo.synth.junction_sumo import JunctionOptions
from trafficgeo.synth.junction_world import build_junction_world
from trafficgeo.traffic.trajectories import JUNCTION_PIXEL_SIGMA, TrajectoryOptions

pytest.importorskip("sumolib")
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    out = tmp_path_factory.mktemp("junction")
    build_junction_world(out, JunctionOptions(seed=31, duration_s=100.0, ortho_resolution=0.2), video=False)
    truth = pd.read_csv(out / "truth_tracks.csv")
    w, h = 1920, 1080
    seen = truth[(truth["u"] >= 0) & (truth["u"] < w) & (truth["v"] >= 0) & (truth["v"] < h)]
    tracks = seen.rename(columns={"vehicle": "track_id"})[["frame", "time", "track_id", "u", "v", "class"]]
    tracks.to_csv(out / "tracks.csv", index=False)
    return out


def test_analyze_with_gates_counts_every_movement_of_the_vehicles_that_crossed_two_gates(world, tmp_path) -> None:
    run = tmp_path / "run"
    code, out, err = invoke("analyze", world / "camera_truth.json", world / "tracks.csv", "--surface",
                            world / "dem.tif", "--gates", world / "gates.gpkg", "--movement-interval", 60, "-o", run)
    assert code == 0, err
    assert "turning movements" in out and "complete movements" in out
    folder = RunFolder(run)
    moves = folder.movements()
    truth = pd.read_csv(world / "truth_movements.csv", keep_default_na=False)
    both = truth[(truth["entry_time"] != "") & (truth["exit_time"] != "")]
    assert len(both) >= 25
    # per-movement counts over the vehicles that entered and left in the video
    done = moves[moves["complete"]]
    key = ["origin", "destination"]
    true_n = both.groupby(key).size()
    got_n = done[done["track_id"].isin(set(both["vehicle"]))].groupby(key).size()
    pairs = true_n.index.union(got_n.index)
    err_sum = (true_n.reindex(pairs, fill_value=0) - got_n.reindex(pairs, fill_value=0)).abs().sum()
    assert 1 - err_sum / true_n.sum() >= 0.95
    # vehicle by vehicle: the same arms, movement type and gate times (to the 40 ms frame)
    m = both.merge(moves, left_on="vehicle", right_on="track_id", suffixes=("_true", ""))
    assert len(m) >= 0.95 * len(both)
    assert (m["origin_true"] == m["origin"]).mean() >= 0.95
    assert (m["destination_true"] == m["destination"]).mean() >= 0.95
    agree = m[(m["origin_true"] == m["origin"]) & (m["destination_true"] == m["destination"])]
    assert (agree["movement_true"] == agree["movement"]).all()
    timed = agree[agree["origin_by"] == "gate"]
    assert np.abs(timed["entry_time_true"].astype(float) - timed["entry_time"]).max() < 0.2
    # the interval table adds up to the complete movements, and the summary says how many were incomplete
    counts = folder.movement_counts()
    assert counts["count"].sum() == len(done)
    table = folder.turning_movements()
    arms = ("N", "E", "S", "W")
    assert table[[f"{a}_{mv}" for a in arms for mv in ("left", "through", "right", "U")]].to_numpy().sum() == len(done)
    assert (table["total"] == table[[c for c in table.columns if c[:2] in {f"{a}_" for a in arms}]].sum(axis=1)).all()
    junction = json.loads((run / "summary.json").read_text())["junction"]
    assert junction["complete"] == len(done) and junction["incomplete"] == int((~moves["complete"]).sum())
    assert junction["arms"]["S"]["approach"] == "NB" or junction["arms"]["S"]["approach"] in ("NEB", "NWB")
    assert junction["peak_hour"] is None  # 100 s: no hour to find a peak in
    # with gates, the tracks were smoothed with the junction's pixel noise
    options = json.loads((run / "summary.json").read_text())["options"]
    assert options["pixel_sigma"] == JUNCTION_PIXEL_SIGMA and options["accel_sigma"] == TrajectoryOptions().accel_sigma
    assert options["journeys"]["join_glimpses"] is False  # and the journeys joined with the junction's defaults


def test_junction_smoothing_defaults_give_way_to_what_is_asked() -> None:
    at = TrajectoryOptions.at_junction(pixel_sigma=5.0, accel_sigma=3.0)
    assert (at.pixel_sigma, at.accel_sigma) == (5.0, 3.0)
    assert TrajectoryOptions.at_junction().pixel_sigma == JUNCTION_PIXEL_SIGMA != TrajectoryOptions().pixel_sigma


def test_a_gates_file_without_arms_or_with_one_gate_is_refused(world, tmp_path) -> None:
    import geopandas as gpd

    gates = gpd.read_file(world / "gates.gpkg")
    one = tmp_path / "one.gpkg"
    gates.iloc[:1].to_file(one)
    code, _, err = invoke("analyze", world / "camera_truth.json", world / "tracks.csv", "--surface", world / "dem.tif",
                          "--gates", one, "-o", tmp_path / "run")
    assert code == 2 and "at least two arms" in err and "--gates" in err
    assert not (tmp_path / "run" / "movements.csv").exists()
    code, _, err = invoke("analyze", world / "camera_truth.json", world / "tracks.csv", "--surface", world / "dem.tif",
                          "--gates", world / "gates.gpkg", "--movement-interval", 0, "-o", tmp_path / "run")
    assert code == 2 and "--movement-interval" in err
