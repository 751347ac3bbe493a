"""The report's Simulation section: a run folder whose comparison ``sumo-validate`` wrote (the loop closed on a
SUMO world's true trajectories) gets its own section; a plain ``compare-sumo`` comparison stays in the traffic
section."""

from __future__ import annotations

import base64
import json
import re
import shutil
from html import unescape
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from scipy import stats

import trafficgeo as tg
from trafficgeo.report import simulation_figures as SF
from trafficgeo.report.html import build_page
from trafficgeo.run.records import SIMULATION_RECORD

STATIONS = (-100.0, 100.0)  # two counting lines 200 m apart
LANES = ("d1_1", "d1_2", "d2_1", "d2_2")  # 2 lanes per direction (RoadSpec's default)


def _bars(fig, gid: str) -> list:
    return [p for ax in fig.axes for p in ax.patches if p.get_gid() == gid]


def test_speed_histograms_side_by_side_on_known_speeds() -> None:
    rng = np.random.default_rng(4)
    obs_a, sim_a = rng.normal(50, 4, 40), rng.normal(53, 4, 35)
    observed = pd.DataFrame({"line": ["L"] * 40 + ["L"] * 5 + ["M"] * 3, "lane": ["a"] * 40 + ["b"] * 5 + ["a"] * 3,
                             "speed_kmh": np.concatenate([obs_a, [30.0] * 5, [np.nan, 70.0, 71.0]])})
    simulated = pd.DataFrame({"line": ["L"] * 35 + ["M"] * 2 + ["N"] * 4, "lane": ["a"] * 35 + ["a"] * 2 + ["a"] * 4,
                              "speed_kmh": np.concatenate([sim_a, [69.0, 99.0], [10.0] * 4])})
    # L/a and M/a have vehicles on both sides; L/b only observed, N/a only simulated; the NaN speed is dropped
    assert [(line, lane, o.size, s.size) for line, lane, o, s in SF.speed_panels(observed, simulated)] == [
        ("L", "a", 40, 35), ("M", "a", 2, 2)]
    fig = SF.observed_vs_simulated_speeds(observed, simulated)
    assert len(fig.axes) == 2
    bins = SF.speed_bins(SF.speed_panels(observed, simulated))
    assert bins[0] == np.floor(min(obs_a.min(), sim_a.min())) and bins[-1] == 99.0 and len(bins) == 21
    for line, n_obs, n_sim in (("L", 40, 35), ("M", 2, 2)):
        o, s = _bars(fig, f"sim-speed-observed-{line}-a"), _bars(fig, f"sim-speed-simulated-{line}-a")
        assert sum(p.get_height() for p in o) == n_obs and sum(p.get_height() for p in s) == n_sim
        np.testing.assert_allclose([p.get_x() for p in o], bins[:-1])  # the same bins in every panel
        np.testing.assert_allclose([p.get_x() for p in s], bins[:-1] + np.diff(bins) / 2)
    title = fig.axes[0].get_title(loc="left")
    assert f"KS {stats.ks_2samp(obs_a, sim_a).statistic:.2f}" in title and "n 40 obs / 35 sim" in title
    assert SF.observed_vs_simulated_speeds(observed[observed["line"] == "L"], simulated[simulated["line"] == "N"]) \
        is None


@pytest.fixture(scope="module")
def loop(tmp_path_factory: pytest.TempPathFactory) -> dict:
    from trafficgeo.synth.observed_run import truth_run_folder
    from trafficgeo.synth.sumo_scene import Demand, RoadSpec
    from trafficgeo.synth.sumo_world import run_sumo_world

    base = tmp_path_factory.mktemp("report_simulation")
    road = RoadSpec()
    sumo = run_sumo_world(base / "world", road, Demand(500.0), duration_s=300.0, step_s=0.5, seed=1)
    truth_run_folder(base / "observed", sumo.trajectories, road, stations_m=STATIONS, interval_s=60.0)
    run = base / "run"
    shutil.copytree(base / "observed", run)
    result = tg.close_sumo_loop(run, sumo.net, base / "scenario", interval_s=150.0, seed=0, comparison_dir=run)
    # the same folder, then a plain compare-sumo of the scenario's simulation written over the comparison
    plain = base / "plain"
    shutil.copytree(run, plain)
    sc = result.scenario
    tg.compare_with_sumo(plain, sc.folder / "fcd.xml", net=sumo.net, time_offset_s=sc.time_offset_s, out_dir=plain)
    return {"run": run, "plain": plain, "result": result, "page": build_page(run, dpi=40),
            "plain_page": build_page(plain, dpi=40)}


def _section(html: str, anchor: str) -> str:
    m = re.search(rf'<section id="{anchor}">(.*?)</section>', html, re.S)
    assert m is not None, anchor
    return m.group(1)


def _figures(section_html: str) -> dict[str, np.ndarray]:
    """alt text -> decoded image of each figure in a piece of the page."""
    out = {}
    for data, alt in re.findall(r'<img src="data:image/png;base64,([^"]+)" alt="([^"]*)"', section_html):
        img = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.shape[0] > 50 and img.shape[1] > 50
        out[unescape(alt)] = img
    return out


@pytest.mark.slow  # SUMO world, sumo-demand and SUMO (about 15 s with the pages)
def test_sumo_validate_comparison_gets_a_simulation_section(loop: dict) -> None:
    run, val = loop["run"], loop["result"].validation
    manifest = json.loads((run / "compare_run.json").read_text())
    assert manifest["command"] == "sumo-validate" and SIMULATION_RECORD in manifest["files"]
    page = loop["page"]
    assert "Simulation" in page.sections and '<a href="#simulation-1">Simulation</a>' in page.html
    sim = unescape(_section(page.html, "simulation-1"))
    # the headline: the validation's share of counts with GEH < 5 against the 85 % target, and its mean GEH
    assert val.counts == 2 * 4 * 2  # 2 lines x 4 lanes x 2 intervals of 150 s
    verdict = "met" if val.target_met else "NOT met"
    assert (f"{100 * val.share_geh_below_5:.1f} % of the {val.counts} counts (line, lane, direction, interval) have "
            f"GEH < 5, against the target of 85 %: {verdict}. Mean GEH {val.mean_geh:.2f}") in sim
    table = val.comparison.counts
    assert f"observed {int(table['observed'].sum())} vehicles, simulated {int(table['simulated'].sum())}" in sim
    sc = loop["result"].scenario
    assert str(sc.folder.resolve()) in sim and str(sc.net) in sim
    assert f"<td>seed</td><td class=\"n\">{sc.seed}</td>" in sim
    assert f"<td>vehicles in the demand</td><td class=\"n\">{sc.vehicles}</td>" in sim
    figures = _figures(sim)
    assert len(figures) == 2
    assert any(a.startswith("Observed against simulated hourly flows") for a in figures)
    assert any(a.startswith("Spot speeds at the counting lines") for a in figures)
    # travel times from the first to the last line, as the comparison has them
    tt = val.comparison.travel_times
    assert f"Travel times from line {tt['from_line']} to line {tt['to_line']}" in sim
    assert f"Simulated minus observed mean: {tt['mean_difference_s']:.1f} s" in sim
    assert sim.count('class="outlier"') == int((table["geh"] >= 5).sum())
    # the traffic section no longer holds the compare-sumo part
    traffic = unescape(_section(page.html, "traffic-1"))
    assert "Observed vs simulated (compare-sumo)" not in traffic and "is in the Simulation section" in traffic


@pytest.mark.slow
def test_speed_panels_are_the_lines_and_lanes_with_vehicles_on_both_sides(loop: dict) -> None:
    run, val = loop["run"], loop["result"].validation
    rec = json.loads((run / SIMULATION_RECORD).read_text())
    cr = pd.read_csv(run / "crossings.csv", dtype={"line": str, "lane": str})
    cr = cr[(cr["time"] >= rec["begin_s"]) & (cr["time"] < rec["end_s"])]
    sim = pd.read_csv(run / "simulated_crossings.csv", dtype={"line": str, "lane": str})
    fig = SF.observed_vs_simulated_speeds(cr, sim)
    speeds = val.comparison.speeds
    both = speeds[(speeds["observed_n"] > 0) & (speeds["simulated_n"] > 0)]
    assert len(fig.axes) == len(both) == len(STATIONS) * len(LANES)
    titles = [ax.get_title(loc="left") for ax in fig.axes]
    for title, row in zip(titles, both.sort_values(["line", "lane"]).to_dict("records"), strict=True):
        line, lane = row["line"], row["lane"]
        assert title.startswith(f"line {line}, lane {lane}: KS {row['ks_statistic']:.2f}")
        assert sum(p.get_height() for p in _bars(fig, f"sim-speed-observed-{line}-{lane}")) == row["observed_n"]
        assert sum(p.get_height() for p in _bars(fig, f"sim-speed-simulated-{line}-{lane}")) == row["simulated_n"]


@pytest.mark.slow
def test_plain_compare_sumo_stays_in_the_traffic_section(loop: dict) -> None:
    plain = loop["plain"]
    manifest = json.loads((plain / "compare_run.json").read_text())
    assert manifest["command"] == "compare-sumo" and SIMULATION_RECORD not in manifest["files"]
    assert (plain / SIMULATION_RECORD).is_file()  # left from sumo-validate, but no longer part of the comparison
    page = loop["plain_page"]
    assert not any(s.startswith("Simulation") for s in page.sections)
    assert 'id="simulation-1"' not in page.html
    traffic = unescape(_section(page.html, "traffic-1"))
    assert "Observed vs simulated (compare-sumo)" in traffic
    assert any(a.startswith("Observed against simulated hourly flows") for a in _figures(traffic))


@pytest.mark.slow
def test_a_record_not_from_sumo_validate_is_one_line_error(loop: dict, tmp_path: Path) -> None:
    from trafficgeo.errors import InputError
    from trafficgeo.io.run_manifest import COMPARE_MANIFEST, publish_outputs

    run = tmp_path / "run"
    shutil.copytree(loop["run"], run)
    (run / SIMULATION_RECORD).write_text(json.dumps({"format": "something else"}))
    files = json.loads((run / COMPARE_MANIFEST).read_text())["files"]
    publish_outputs(run, list(files), command="sumo-validate", name=COMPARE_MANIFEST)
    with pytest.raises(InputError, match=r"compare_simulation.json: not a compare_simulation.json written by "
                       r"trafficgeo \('format' is not trafficgeo-sumo-validation/1\); run 'trafficgeo sumo-validate' "
                       r"again to write it$") as info:
        build_page(run, dpi=40)
    assert "\n" not in str(info.value)
