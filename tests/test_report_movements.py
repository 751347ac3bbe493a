"""The turning movements in the report of a run with a junction's gates (`analyze --gates` on the junction world's
true image points): the movement diagram on the orthophoto, the tables read back from the HTML against
movements.csv and turning_movements.csv, and the diagram's arrows against the world's own gates.gpkg. A run without
gates has none of it."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import shapely

from cli_support import invoke
from test_report_content import Page
from trafficgeo.io.gis import read_gis
from trafficgeo.report.figures import MapAxes
from trafficgeo.report.html import build_page
from trafficgeo.report.movement_figures import (
    MAX_WIDTH_PT,
    MIN_WIDTH_PT,
    movement_arrows,
    movement_diagram,
    movement_flows,
)
from trafficgeo.report.movement_section import DIAGRAM_CAPTION
from trafficgeo.run.folder import RunFolder
from trafficgeo.site.gates import MOVEMENTS
from trafficgeo.synth.junction_sumo import JunctionOptions
from trafficgeo.synth.junction_world import build_junction_world

pytest.importorskip("sumolib")
pytestmark = pytest.mark.slow  # builds the junction world, analyzes it and renders a report page

HEAVY = ("truck", "bus")


@pytest.fixture(scope="module")
def junction_run(tmp_path_factory):
    world = tmp_path_factory.mktemp("junction")
    build_junction_world(world, JunctionOptions(seed=31, duration_s=100.0, ortho_resolution=0.2), video=False)
    truth = pd.read_csv(world / "truth_tracks.csv")
    seen = truth[(truth["u"] >= 0) & (truth["u"] < 1920) & (truth["v"] >= 0) & (truth["v"] < 1080)]
    seen.rename(columns={"vehicle": "track_id"})[["frame", "time", "track_id", "u", "v", "class"]].to_csv(
        world / "tracks.csv", index=False)
    run = world / "run"
    code, _, err = invoke("analyze", world / "camera_truth.json", world / "tracks.csv", "--surface", world / "dem.tif",
                          "--gates", world / "gates.gpkg", "--movement-interval", 30, "-o", run)
    assert code == 0, err
    page = build_page(run, camera=world / "camera_truth.json", ortho=world / "ortho.tif")
    return world, run, page


def _section(page) -> dict:
    return Page(page.html).sections["traffic-1"]


def _table(section: dict, first: list[str]) -> list[list[str]]:
    """The table whose header row begins with ``first``, as rows of cell texts (header first)."""
    found = [t for t in section["table"] if t and t[0][:len(first)] == first]
    assert len(found) == 1, [t[0] for t in section["table"]]
    return found[0]


def test_the_report_shows_the_movement_diagram_on_the_orthophoto(junction_run) -> None:
    _, _, page = junction_run
    s = _section(page)
    assert "Turning movements" in s["h3"]
    assert sum(alt.startswith(DIAGRAM_CAPTION) for alt in s["img"]) == 1
    left_out = " ".join(f"{what} {why}" for what, why in page.left_out)
    assert "movement diagram" not in left_out and "orthophoto" not in left_out


def test_the_turning_movement_tables_are_those_of_movements_csv(junction_run) -> None:
    _, run, page = junction_run
    s = _section(page)
    mv = pd.read_csv(run / "movements.csv", keep_default_na=False)
    done = mv[mv["complete"].astype(str) == "True"]
    assert len(done) >= 25
    t = _table(s, ["approach", "from arm"])
    assert t[0] == ["approach", "from arm", "left", "through", "right", "U", "total", "heavy %"]
    bounds = {"N": "SB", "E": "WB", "S": "NB", "W": "EB"}  # the world's arms: bearings 20, 110, 200, 290
    rows = {r[1]: r for r in t[1:]}
    assert [r[1] for r in t[1:]] == ["N", "E", "S", "W", ""]
    for arm, bound in bounds.items():
        sel = done[done["origin"] == arm]
        want = [bound, arm, *(str(int((sel["movement"] == m).sum())) for m in MOVEMENTS), str(len(sel)),
                f"{100.0 * sel['class'].isin(HEAVY).mean():.1f}" if len(sel) else "-"]
        assert rows[arm] == want
    assert rows[""][2:7] == [*(str(int((done["movement"] == m).sum())) for m in MOVEMENTS), str(len(done))]
    # the per-interval table is turning_movements.csv
    tm = pd.read_csv(run / "turning_movements.csv")
    assert len(tm) >= 3
    per = _table(s, ["from s", "to s"])
    assert len(per) == len(tm) + 1
    for row, (_, want) in zip(per[1:], tm.iterrows(), strict=True):
        assert [int(v) for v in row[2:-1]] == [int(want[c]) for c in tm.columns[2:-1]]
        assert float(row[0]) == pytest.approx(want["interval_start"], abs=0.5)
    # complete / judged from the path / incomplete, and the missing peak hour
    by_path = int(((done["origin_by"] == "path") | (done["destination_by"] == "path")).sum())
    text = " ".join(s["p"])
    assert (f"{len(mv)} vehicles through the junction: {len(done)} complete movements ({by_path} with an end judged "
            "from the path") in text
    assert f"{len(mv) - len(done)} incomplete" in text
    assert "No peak hour: less than an hour of whole 30 s intervals was observed" in text
    # travel and stopped time per movement
    tt = _table(s, ["from arm", "to arm", "movement"])
    got = {(r[0], r[1]): r for r in tt[1:]}
    assert len(got) == done.groupby(["origin", "destination"]).ngroups
    for (o, d), g in done.groupby(["origin", "destination"]):
        r = got[(o, d)]
        assert r[2] == g["movement"].iloc[0] and int(r[3]) == len(g)
        travel = pd.to_numeric(g["travel_time_s"], errors="coerce").dropna()
        assert int(r[5]) == len(travel)
        assert r[4] == (f"{travel.median():.1f}" if len(travel) else "-")
        assert float(r[6]) == pytest.approx(g["stopped_s"].astype(float).median(), abs=0.051)


def test_the_arrows_run_from_the_origin_gate_through_the_centre_to_the_destination_gate(junction_run) -> None:
    world, run, _ = junction_run
    folder = RunFolder(run)
    junction = folder.junction(None)
    gates = read_gis(world / "gates.gpkg")  # the world's own gates, not the run's layer
    mids = {str(a): np.array(shapely.line_interpolate_point(g, 0.5, normalized=True).coords[0][:2])
            for a, g in zip(gates["arm"], gates.geometry, strict=True)}
    half = {str(a): g.length / 2 for a, g in zip(gates["arm"], gates.geometry, strict=True)}
    geoms = dict(zip(gates["arm"].astype(str), gates.geometry, strict=True))
    flows = movement_flows(folder.movements())
    arrows = movement_arrows(junction, flows)
    done = folder.movements().query("complete")
    assert sum(a.count for a in arrows) == len(done) and len(arrows) == len(flows) >= 8
    centre = np.array(folder.summary().junction["centre"])
    for a in arrows:
        for point, arm in ((a.start, a.origin), (a.end, a.destination)):
            assert geoms[arm].distance(shapely.Point(point)) < 0.01  # on the gate
            assert np.hypot(*(point - mids[arm])) < half[arm]  # within half a gate of its middle
            assert min(mids, key=lambda k, p=point: np.hypot(*(p - mids[k]))) == arm  # nearer it than any other
        assert np.allclose(a.control, centre, atol=1e-6)
        # the curve passes near the centre: its middle is halfway between the ends' midpoint and the centre
        assert np.hypot(*(a.at(0.5) - centre)) <= 0.5 * np.hypot(*(0.5 * (a.start + a.end) - centre)) + 1e-6
        n = ((done["origin"] == a.origin) & (done["destination"] == a.destination)).sum()
        assert a.count == n and a.movement == done[(done["origin"] == a.origin)
                                                   & (done["destination"] == a.destination)]["movement"].iloc[0]
    # widths: proportional to the count (none under the minimum), the busiest at the maximum
    by_count = sorted(arrows, key=lambda a: a.count)
    widths = [a.width_pt for a in by_count]
    assert widths == sorted(widths) and widths[-1] == pytest.approx(MAX_WIDTH_PT)
    for a in arrows:
        assert a.width_pt == pytest.approx(max(MAX_WIDTH_PT * a.count / by_count[-1].count, MIN_WIDTH_PT))
    assert len({a.width_pt for a in arrows}) == len({a.count for a in arrows})
    # drawn: one arrow per movement, one line per gate, also without an orthophoto
    fig = movement_diagram(junction, flows, MapAxes(origin=(244900.0, 5182500.0)))
    gids = {artist.get_gid() for artist in fig.axes[0].get_children()}
    assert {f"movement-{a.origin}-{a.destination}" for a in arrows} <= gids
    assert {f"gate-{arm}" for arm in mids} <= gids


def test_a_run_without_gates_has_no_turning_movements(junction_run, tmp_path) -> None:
    world, _, _ = junction_run
    tracks = pd.read_csv(world / "tracks.csv")
    tracks[tracks["time"] < 30.0].to_csv(tmp_path / "tracks.csv", index=False)
    run = tmp_path / "run"
    code, _, err = invoke("analyze", world / "camera_truth.json", tmp_path / "tracks.csv", "--surface",
                          world / "dem.tif", "-o", run)
    assert code == 0, err
    page = build_page(run, camera=world / "camera_truth.json")
    s = _section(page)
    assert "Turning movements" not in s["h3"]
    assert not any(alt.startswith(DIAGRAM_CAPTION) for alt in s["img"])
    assert not any(t[0][:2] == ["approach", "from arm"] for t in s["table"])
    assert not any("movement diagram" in what for what, _ in page.left_out)
