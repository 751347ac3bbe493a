"""The junction world (trafficgeo.synth.junction_world): its truth is checked against the SUMO simulation's own
files (network, vehicle routes, FCD), not against the code that wrote it."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections import Counter

import numpy as np
import pandas as pd
import pytest
from tests.cli_support import invoke

from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.errors import InputError
from trafficgeo.io.gis import read_gis
from trafficgeo.synth.junction_sumo import JunctionOptions, arm_bearings, compass_name, run_junction_sumo
from trafficgeo.synth.junction_world import build_junction_world

sumolib = pytest.importorskip("sumolib")

FAST = {"duration_s": 20.0, "ortho_resolution": 0.2, "seed": 3}
SUMO_DIRECTION = {"s": "through", "l": "left", "r": "right", "t": "U", "L": "left", "R": "right"}


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    out = tmp_path_factory.mktemp("junction")
    opts = JunctionOptions(**FAST)
    summary = build_junction_world(out, opts, video=False)
    return out, opts, summary


def _routes(folder) -> dict[str, list[str]]:
    root = ET.parse(folder / "sumo" / "vehroutes.xml").getroot()
    return {v.get("id"): v.find("route").get("edges").split() for v in root.iter("vehicle")}


def test_summary_and_files(world) -> None:
    out, _, summary = world
    assert summary["kind"] == "junction" and summary["vehicles"] > 5 and summary["frames"] == 500
    assert json.loads((out / "world.json").read_text())["kind"] == "junction"
    for name in ("ortho.tif", "dem.tif", "cloud.laz", "camera_truth.json", "gcps.csv", "truth_tracks.csv",
                 "truth_tracks.gpkg", "gates.gpkg", "truth_movements.csv", "sumo/junction.net.xml"):
        assert (out / name).is_file(), name
    assert not (out / "video.mp4").exists()
    gcps = pd.read_csv(out / "gcps.csv")
    assert len(gcps) >= 10 and set(gcps["role"]) == {"control", "check"}


def test_network_has_a_traffic_light_and_every_movement(world) -> None:
    out, opts, _ = world
    net = sumolib.net.readNet(str(out / "sumo" / "junction.net.xml"))
    assert net.getNode("C").getType() == "traffic_light"
    bearings = arm_bearings(opts)
    assert sorted(bearings) == ["E", "N", "S", "W"]
    for o in bearings:
        lanes = net.getEdge(f"{o}_in").getLanes()
        assert len(lanes) == 2
        reach = {(c.getTo().getID(), c.getDirection()) for lane in lanes for c in lane.getOutgoing()}
        assert {to for to, _ in reach} == {f"{d}_out" for d in bearings if d != o}  # no U-turns, all others
        right, left = ({SUMO_DIRECTION[c.getDirection()] for c in lane.getOutgoing()} for lane in lanes)
        assert right == {"through", "right"} and left == {"left", "through"}


def test_gates_cross_every_arm(world) -> None:
    from shapely.geometry import LineString

    out, opts, _ = world
    gates = read_gis(out / "gates.gpkg")
    assert sorted(gates["arm"]) == ["E", "N", "S", "W"]
    net = sumolib.net.readNet(str(out / "sumo" / "junction.net.xml"))
    ox, oy, _ = opts.origin
    for row in gates.itertuples():
        assert compass_name(row.bearing_deg) == row.arm
        assert row.bearing_deg == pytest.approx(arm_bearings(opts)[row.arm], abs=1e-6)
        for edge in (f"{row.arm}_in", f"{row.arm}_out"):
            for lane in net.getEdge(edge).getLanes():
                shape = LineString([(x + ox, y + oy) for x, y in lane.getShape()])
                assert row.geometry.intersects(shape), (row.arm, lane.getID())
        mid = np.array(row.geometry.interpolate(0.5, normalized=True).coords[0][:2])
        assert np.hypot(*(mid - (ox, oy))) == pytest.approx(opts.gate_distance_m, abs=1e-6)


def test_movements_agree_with_the_simulation(world) -> None:
    out, opts, _ = world
    mov = pd.read_csv(out / "truth_movements.csv", keep_default_na=False)
    routes = _routes(out)
    net = sumolib.net.readNet(str(out / "sumo" / "junction.net.xml"))
    fcd_ids = {v.id for v in sumolib.xml.parse_fast(str(out / "sumo" / "fcd.xml"), "vehicle", ["id"])}
    assert set(mov["vehicle"]) == fcd_ids
    both = 0
    for r in mov.itertuples():
        edges = routes[r.vehicle]
        assert (edges[0], edges[-1]) == (f"{r.origin}_in", f"{r.destination}_out")
        conns = net.getEdge(edges[0]).getOutgoing()[net.getEdge(edges[-1])]
        assert {SUMO_DIRECTION[c.getDirection()] for c in conns} == {r.movement}
        if r.entry_time != "" and r.exit_time != "":
            both += 1
            assert 0 <= float(r.entry_time) < float(r.exit_time) < opts.duration_s
    assert both >= 3
    # Right-hand traffic: from the south, north is through, west is left, east is right.
    expect = {("S", "N"): "through", ("S", "W"): "left", ("S", "E"): "right", ("N", "E"): "left"}
    for (o, d), m in expect.items():
        assert set(mov.loc[(mov["origin"] == o) & (mov["destination"] == d), "movement"]) <= {m}


def test_camera_sees_the_centre_and_every_gate(world) -> None:
    out, opts, _ = world
    cam = read_camera_json(out / "camera_truth.json")
    assert cam.in_image(cam.project(np.array([opts.origin])))[0]
    assert cam.position[2] == pytest.approx(opts.origin[2] + opts.camera_height)
    gates = read_gis(out / "gates.gpkg")
    for row in gates.itertuples():
        pts = np.array([row.geometry.interpolate(f, normalized=True).coords[0][:2] for f in np.linspace(0, 1, 21)])
        uv = cam.project(np.column_stack([pts, np.full(len(pts), opts.origin[2])]))
        assert cam.in_image(uv).any(), row.arm


def test_same_seed_same_truth(world, tmp_path) -> None:
    out, opts, _ = world
    build_junction_world(tmp_path, opts, video=False)
    for name in ("truth_movements.csv", "truth_tracks.csv", "gcps.csv", "camera_truth.json", "sumo/fcd.xml",
                 "sumo/junction.net.xml", "sumo/vehroutes.xml"):
        assert (tmp_path / name).read_bytes() == (out / name).read_bytes(), name


def test_bad_options_are_refused(tmp_path) -> None:
    with pytest.raises(InputError, match="camera_height must be > 0"):
        JunctionOptions(camera_height=-1.0)
    with pytest.raises(InputError, match="turning shares must sum to 1"):
        JunctionOptions(turning={"left": 0.5, "through": 0.6})
    with pytest.raises(InputError, match="camera_corner"):
        JunctionOptions(camera_corner="N")
    code, _, err = invoke("synth", "--junction", "--out", tmp_path / "j", "--curve-radius", "80")
    assert code == 2 and "--curve-radius applies to the road world only" in err
    code, _, err = invoke("synth", "--junction", "--out", tmp_path / "j", "--camera-height", "0")
    assert code == 2 and "--camera-height must be > 0" in err
    code, _, err = invoke("synth", "--out", tmp_path / "j", "--turning", "left=1")
    assert code == 2 and "--turning applies to the junction world only" in err
    assert not (tmp_path / "j").exists()


@pytest.mark.slow
def test_small_video_has_truth_boxes(tmp_path) -> None:
    import av

    opts = JunctionOptions(duration_s=2.0, image_size=(640, 360), ortho_resolution=0.1, seed=1)
    summary = build_junction_world(tmp_path, opts, video=True)
    with av.open(str(tmp_path / "video.mp4")) as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(frames) == summary["frames"] == 50 and frames[0].shape == (360, 640, 3)
    tracks = pd.read_csv(tmp_path / "truth_tracks.csv")
    boxed = tracks.dropna(subset=["x1"])
    assert len(boxed) > 0 and (boxed["visible_fraction"] > 0).any()


@pytest.mark.slow
def test_turning_shares_follow_the_options(tmp_path) -> None:
    turning = {"left": 0.3, "through": 0.5, "right": 0.2}
    opts = JunctionOptions(duration_s=900.0, fps=10.0, turning=turning, veh_per_hour_per_arm=400.0, seed=5)
    run_junction_sumo(tmp_path / "sumo", opts)
    bearings = arm_bearings(opts)
    net = sumolib.net.readNet(str(tmp_path / "sumo" / "junction.net.xml"))
    counts: Counter[str] = Counter()
    for edges in _routes(tmp_path).values():
        conns = net.getEdge(edges[0]).getOutgoing()[net.getEdge(edges[-1])]
        counts[SUMO_DIRECTION[conns[0].getDirection()]] += 1
    n = sum(counts.values())
    assert n > 300 and len(bearings) == 4
    for m, share in turning.items():
        assert counts[m] / n == pytest.approx(share, abs=0.06), (m, counts)


def test_sloped_ground_and_30_fps(tmp_path) -> None:
    """Vehicles, camera and DEM stand on the same (sloped) ground; 30 fps is simulated at 10 ms and resampled."""
    import rasterio

    opts = JunctionOptions(duration_s=2.0, fps=30.0, ground_slope=0.02, ground_slope_bearing_deg=60.0,
                           ortho_resolution=0.5, seed=2)
    summary = build_junction_world(tmp_path, opts, video=False)
    assert summary["frames"] == 60
    tracks = pd.read_csv(tmp_path / "truth_tracks.csv")
    assert np.allclose(np.diff(np.unique(tracks["time"])), 1 / 30, atol=1e-3)
    assert tracks["frame"].between(0, 59).all()
    cam = read_camera_json(tmp_path / "camera_truth.json")
    with rasterio.open(tmp_path / "dem.tif") as dem:
        z = np.array([v[0] for v in dem.sample(zip(tracks["x"], tracks["y"], strict=True))])
        zc = next(dem.sample([tuple(cam.position[:2])]))[0]
    half = opts.view_half_size - 1.0
    inside = (np.abs(tracks["x"] - opts.origin[0]) < half) & (np.abs(tracks["y"] - opts.origin[1]) < half)
    assert inside.all()  # the rasters cover the arms
    assert np.abs(z - tracks["z"]).max() < 0.01
    assert cam.position[2] - zc == pytest.approx(opts.camera_height, abs=0.01)
    assert tracks["z"].std() > 0.1  # the ground does slope
