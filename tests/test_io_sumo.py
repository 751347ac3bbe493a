"""Tests of SUMO exchange (trafficgeo.io.sumo): FCD read/write in every coordinate mode, mean data, real SUMO runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pyproj
import pytest

import trafficgeo.io.fcd_parse as fcd_parse
from trafficgeo.crs import projected_to_lonlat
from trafficgeo.errors import InputError
from trafficgeo.io.fcd_read import FCD_COLUMNS, read_fcd
from trafficgeo.io.fcd_write import write_fcd
from trafficgeo.io.sumo import MEANDATA_COLUMNS, read_meandata
from trafficgeo.io.sumo_net import read_net_location
from trafficgeo.synth.sumo_scene import VEHICLE_CLASSES, Demand, RoadSpec
from trafficgeo.synth.sumo_world import SumoRun, _run_tool, run_sumo_world

DATA = Path(__file__).parent / "data" / "sumo-fcd-sample"
SAMPLE = DATA / "fcd_geo_utm.sumo.xml"
FEET = 1200.0 / 3937.0  # metres per US survey foot (EPSG:2240)
UTM16 = "+proj=utm +zone=16 +datum=WGS84 +units=m +no_defs"


def _net(path: Path, offset: str = "-740000.00,-3730000.00", proj: str = UTM16) -> Path:
    """A network file with only a <location> (all that read_fcd/write_fcd use of it)."""
    path.write_text(f'<?xml version="1.0" encoding="UTF-8"?>\n<net version="1.20">\n'
                    f'    <location netOffset="{offset}" convBoundary="0,0,1,1" origBoundary="0,0,1,1" '
                    f'projParameter="{proj}"/>\n</net>\n', encoding="utf-8")
    return path


def _tracks(n_tracks: int = 6, n_steps: int = 40, *, origin: tuple[float, float] = (2230000.0, 1375000.0),
            unit: float = FEET, seed: int = 0) -> pd.DataFrame:
    """Curving synthetic tracks near (Atlanta, EPSG:2240 feet by default) with z, class, lane and speeds."""
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(n_tracks):
        h0, v = rng.uniform(0, 360), rng.uniform(5, 20)  # deg, m/s
        t = np.round(np.arange(n_steps) * 0.04 + k * 0.2, 3)
        h = np.mod(h0 + 2.0 * t, 360.0)  # turning 2 deg/s
        step = v * 0.04 / unit
        x = origin[0] + rng.uniform(-300, 300) + np.cumsum(step * np.sin(np.radians(h)))
        y = origin[1] + rng.uniform(-300, 300) + np.cumsum(step * np.cos(np.radians(h)))
        rows.append(pd.DataFrame({"track_id": f"veh&{k}" if k == 1 else f"v{k}", "time": t, "x": x, "y": y,
                                  "z": 300.0 + 0.01 * np.arange(n_steps), "speed_kmh": v * 3.6, "heading_deg": h,
                                  "class": ["car", "truck", ""][k % 3], "sumo_lane": f"e{k}_0"}))
    return pd.concat(rows, ignore_index=True)


def _assert_same_points(got: pd.DataFrame, want: pd.DataFrame, unit: float) -> None:
    """Equal tracks: positions to 1 mm (``unit`` metres per CRS unit), heading, speed, z, text columns."""
    key = ["track_id", "time"]
    g = got.sort_values(key).reset_index(drop=True)
    w = want.sort_values(key).reset_index(drop=True)
    assert list(g["track_id"]) == list(w["track_id"])
    np.testing.assert_allclose(g["time"], w["time"], atol=1e-9)
    for c in ("x", "y", "z"):
        np.testing.assert_allclose(g[c].to_numpy() * unit, w[c].to_numpy() * unit, atol=1e-3, rtol=0)
    dh = np.mod(g["heading_deg"].to_numpy() - w["heading_deg"].to_numpy() + 180.0, 360.0) - 180.0
    assert np.abs(dh).max() < 1e-3
    np.testing.assert_allclose(g["speed_kmh"], w["speed_kmh"], atol=1e-3)
    assert list(g["class"]) == list(w["class"].fillna(""))
    assert list(g["sumo_lane"]) == list(w["sumo_lane"])
    assert g["front_bumper"].all()


# ---------------------------------------------------------------------------------------------------- real sample
def test_sample_reads_as_utm32_and_matches_sumo_geometry() -> None:
    df = read_fcd(SAMPLE, crs="EPSG:32632")
    assert list(df.columns) == FCD_COLUMNS
    assert len(df) == 15 and df["track_id"].nunique() == 2 and df["time"].nunique() == 10
    np.testing.assert_array_equal(np.unique(df["time"]), np.arange(10.0))
    assert df.groupby("track_id")["time"].min().to_dict() == {"0": 0.0, "1": 5.0}
    assert set(df["class"]) == {"t1", "t2"} and set(df["sumo_lane"]) == {"4/1to3/1_0"}
    assert df.attrs["notes"] == [] and pyproj.CRS(df.attrs["crs"]).to_epsg() == 32632
    # exact speeds: 10 and 9 m/s, heading west, and the positions move by that much per second
    speeds = df.groupby("track_id")["speed_kmh"].unique()
    assert list(speeds["0"]) == [36.0] and list(speeds["1"]) == pytest.approx([32.4])
    assert (df["heading_deg"] == 270.0).all() and np.isnan(df["z"]).all() and df["front_bumper"].all()
    for vid, v in (("0", 10.0), ("1", 9.0)):
        g = df[df["track_id"] == vid]
        np.testing.assert_allclose(np.diff(g["x"]) / np.diff(g["time"]), -v, atol=1e-6)
        np.testing.assert_allclose(g["y"], 5411358.23)
    # SUMO's test network: lane 4/1to3/1_0 from network x 1595.25 westwards at y 401.65, netOffset -651925.45,...
    first = df.iloc[0]
    assert first["x"] == pytest.approx(651925.45 + 1595.25 - 100.0, abs=1e-6)  # pos = 100 m at t = 0
    # SUMO's own --fcd-output.geo run of the same scenario puts this point at 11.090774 E, 48.836229 N (Bavaria)
    lon, lat = projected_to_lonlat(df["x"], df["y"], pyproj.CRS.from_epsg(32632))
    assert lon[0] == pytest.approx(11.090774, abs=1e-6) and lat[0] == pytest.approx(48.836229, abs=1e-6)
    assert np.all((lon > 11.0) & (lon < 11.2) & (lat > 48.8) & (lat < 48.9))


def test_sample_other_crs_and_no_crs(tmp_path: Path) -> None:
    plain = read_fcd(SAMPLE)  # no CRS: the numbers as they are
    assert plain.attrs["crs"] is None
    assert plain["x"].iloc[0] == pytest.approx(653420.70) and plain["y"].iloc[0] == pytest.approx(5411358.23)
    as_etrs = read_fcd(SAMPLE, crs="EPSG:25832")  # plain coordinates are taken to be in crs: not moved
    assert as_etrs["x"].equals(plain["x"]) and as_etrs.attrs["notes"] == []
    # in the network coordinates of SUMO's test net: lane 4/1to3/1_0 runs from x = 1595.25 at y = 401.65
    net = _net(tmp_path / "sumo-test.net.xml", "-651925.45,-5410956.58",
               "+proj=utm +zone=32 +ellps=WGS84 +datum=WGS84 +units=m +no_defs")
    f = tmp_path / "net.xml"
    write_fcd(f, plain, crs="EPSG:32632", net=net)
    pos = np.array([float(v.split('"')[0]) for v in SAMPLE.read_text(encoding="utf-8").split(' pos="')[1:]])
    raw = read_fcd(f)
    np.testing.assert_allclose(raw["x"], 1595.25 - pos, atol=1e-6)
    np.testing.assert_allclose(raw["y"], 401.65, atol=1e-6)
    etrs = read_fcd(f, net=net, crs="EPSG:25832")  # ETRS89 / UTM 32N: within a metre of WGS 84 / UTM 32N
    assert any("reprojected" in n for n in etrs.attrs["notes"])
    assert np.abs(etrs["x"] - plain["x"]).max() < 2.0 and np.abs(etrs["y"] - plain["y"]).max() < 2.0
    assert np.abs(etrs["heading_deg"] - 270.0).max() < 1e-3  # same grid: no rotation


def test_geo_fcd_is_detected_and_projected(tmp_path: Path) -> None:
    utm = read_fcd(SAMPLE, crs="EPSG:32632")
    geo_file = tmp_path / "geo.xml"
    write_fcd(geo_file, utm, crs="EPSG:32632", geo=True)
    text = geo_file.read_text(encoding="utf-8")
    assert 'x="11.090773584"' in text and 'y="48.836229437"' in text  # lon/lat, 9 decimals
    back = read_fcd(geo_file, crs="EPSG:32632")  # detected from the values
    assert any("geo FCD" in n for n in back.attrs["notes"])
    _assert_same_points(back, utm, 1.0)
    with pytest.raises(InputError, match=r"longitude/latitude.*crs="):
        read_fcd(geo_file)
    assert not np.allclose(read_fcd(geo_file, geo=False)["x"], utm["x"])  # forced off: degrees as they are


def test_geo_detection_needs_motion_not_range(tmp_path: Path) -> None:
    """A small cartesian network near (0, 0) has x, y within +-180/+-90 but is not lon/lat: the speeds tell."""
    pts = _tracks(3, 30, origin=(40.0, 30.0), unit=1.0)
    pts[["x", "y"]] = pts[["x", "y"]].clip(-170, 80)
    f = tmp_path / "small.xml"
    write_fcd(f, pts, crs=None)
    back = read_fcd(f)
    assert not any("geo" in n for n in back.attrs["notes"])
    _assert_same_points(back, pts, 1.0)


# ---------------------------------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("mode", ["plain", "plain_feet", "geo_feet", "net_feet", "net_same", "net_none", "geo_net"])
def test_write_read_round_trip(tmp_path: Path, mode: str) -> None:
    feet = mode.endswith("feet")
    pts = _tracks(unit=FEET if feet else 1.0,
                  origin=(2230000.0, 1375000.0) if feet else (741000.0, 3731000.0))  # Atlanta: 2240 ft / UTM 16N m
    crs = "EPSG:2240" if feet else "EPSG:32616"
    net = None
    if mode.startswith("net") or mode == "geo_net":
        net = _net(tmp_path / "n.net.xml", proj="!" if mode == "net_none" else UTM16)
    geo = mode.startswith("geo")
    f = tmp_path / "fcd.xml"
    write_fcd(f, pts, crs=crs, net=net, geo=geo)
    head = f.read_text(encoding="utf-8")[:600]
    assert "<fcd-export" in head and '<timestep time="0.000">' in head and not list(tmp_path.glob(".*tmp*"))
    back = read_fcd(f, net=net, crs=crs, geo=geo if mode == "geo_feet" else None)
    _assert_same_points(back, pts, FEET if feet else 1.0)
    assert pyproj.CRS(back.attrs["crs"]).to_epsg() == int(crs.split(":")[1]) or mode == "net_none"
    if mode == "net_feet":  # network coordinates are metres near the origin, not feet
        sumo = read_fcd(f)
        assert np.abs(sumo["x"]).max() < 50000 and np.abs(sumo["y"]).max() < 50000
        assert any("reprojected" in n for n in back.attrs["notes"])
        assert np.abs(sumo["heading_deg"] - pts["heading_deg"]).max() > 0.1  # grid north of UTM 16N differs


def test_write_format_and_order(tmp_path: Path) -> None:
    pts = _tracks(3, 5, unit=1.0, origin=(741000.0, 3731000.0)).sample(frac=1.0, random_state=1)
    f = tmp_path / "fcd.xml"
    write_fcd(f, pts, crs="EPSG:32616")
    lines = f.read_text(encoding="utf-8").splitlines()
    steps = [float(ln.split('"')[1]) for ln in lines if ln.startswith("    <timestep")]
    assert steps == sorted(set(pts["time"]))
    veh = [ln for ln in lines if ln.startswith("        <vehicle")]
    assert len(veh) == len(pts)
    assert veh[0].startswith('        <vehicle id="v0" x="') and ' angle="' in veh[0] and ' type="car"' in veh[0]
    assert 'id="veh&amp;1"' in "".join(veh)  # XML-escaped
    names = [a.split("=")[0] for a in veh[0].removesuffix("/>").split()[1:]]
    assert names == ["id", "x", "y", "z", "angle", "type", "speed", "lane", "slope"]  # SUMO's order
    speed = float(veh[0].split('speed="')[1].split('"')[0])
    row = pts[(pts["track_id"] == "v0")].sort_values("time").iloc[0]
    assert speed == pytest.approx(row["speed_kmh"] / 3.6, abs=1e-4)  # m/s
    assert all("type=" in ln for ln in veh) and sum('type=""' in ln for ln in veh) == 5  # class "": type=""


def test_front_offset_moves_to_bumper(tmp_path: Path) -> None:
    pts = _tracks(4, 10).sort_values(["track_id", "time"]).reset_index(drop=True)
    lengths = np.where(pts["class"] == "truck", 12.0, 4.5)
    f = tmp_path / "fcd.xml"
    write_fcd(f, pts, crs="EPSG:2240", front_offset_m=lengths / 2)
    back = read_fcd(f, crs="EPSG:2240").sort_values(["track_id", "time"]).reset_index(drop=True)
    assert list(back["track_id"]) == list(pts["track_id"]) and np.allclose(back["time"], pts["time"])
    h = np.radians(pts["heading_deg"].to_numpy())
    np.testing.assert_allclose((back["x"] - pts["x"]).to_numpy() * FEET, lengths / 2 * np.sin(h), atol=1e-3)
    np.testing.assert_allclose((back["y"] - pts["y"]).to_numpy() * FEET, lengths / 2 * np.cos(h), atol=1e-3)
    write_fcd(f, back, crs="EPSG:2240", front_offset_m=2.0)  # already at the bumper: not moved again
    _assert_same_points(read_fcd(f, crs="EPSG:2240"), back, FEET)


# ---------------------------------------------------------------------------------------------------- real SUMO
@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> tuple[RoadSpec, SumoRun]:
    road = RoadSpec()
    run = run_sumo_world(tmp_path_factory.mktemp("world"), road, Demand(900.0), duration_s=20.0, step_s=0.1,
                         warmup_s=30.0, seed=4)
    return road, run


def _centres(df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    half = np.array([VEHICLE_CLASSES[c].length for c in df["class"]]) / 2
    h = np.radians(df["heading_deg"].to_numpy())
    return df["x"].to_numpy() - half * np.sin(h), df["y"].to_numpy() - half * np.cos(h)


def _matched(df: pd.DataFrame, run: SumoRun, warmup: float = 30.0) -> pd.DataFrame:
    tr = run.trajectories
    truth = pd.DataFrame({"track_id": tr.vehicle, "time": np.round(tr.time, 6), "tx": tr.x, "ty": tr.y,
                          "th": tr.heading_deg, "tv": tr.speed})
    cx, cy = _centres(df)
    got = pd.DataFrame({"track_id": df["track_id"], "time": np.round(df["time"] - warmup, 6), "cx": cx, "cy": cy,
                        "h": df["heading_deg"], "v": df["speed_kmh"]})
    m = truth.merge(got, on=["track_id", "time"], how="left")
    assert len(m) == len(truth) > 1000 and m["cx"].notna().all()
    return m


@pytest.mark.slow
def test_real_sumo_fcd_matches_world_reader(world: tuple[RoadSpec, SumoRun]) -> None:
    road, run = world
    loc = read_net_location(run.net)
    assert loc.offset == (-road.origin[0], -road.origin[1]) and loc.crs is not None
    df = read_fcd(run.fcd, net=run.net, crs=road.crs)
    assert df.attrs["notes"] == []  # the net's PROJ string is EPSG:2949's projection: no reprojection
    m = _matched(df, run)
    assert np.abs(m["cx"] - m["tx"]).max() < 0.01 and np.abs(m["cy"] - m["ty"]).max() < 0.01
    np.testing.assert_allclose(m["h"], m["th"], atol=1e-9)
    np.testing.assert_allclose(m["v"], m["tv"] * 3.6, atol=1e-9)
    assert read_fcd(run.fcd, net=run.net)["x"].equals(df["x"])  # default CRS: the network's


@pytest.mark.slow
def test_real_sumo_fcd_in_feet(world: tuple[RoadSpec, SumoRun]) -> None:
    """The same FCD in US survey feet (EPSG:2240) with the net's true CRS given: pyproj's transform of the metre
    positions (with the NAD83(CSRS) -> NAD83 datum step), headings rotated to the new grid north."""
    road, run = world
    metres = read_fcd(run.fcd, net=run.net, crs=road.crs)
    feet = read_fcd(run.fcd, net=run.net, net_crs=road.crs, crs="EPSG:2240")
    t = pyproj.Transformer.from_crs(road.crs, "EPSG:2240", always_xy=True)
    x, y = t.transform(metres["x"].to_numpy(), metres["y"].to_numpy())
    assert np.hypot(feet["x"] - x, feet["y"] - y).max() * FEET < 0.001
    h = np.radians(metres["heading_deg"].to_numpy())
    ax, ay = t.transform(metres["x"].to_numpy() + 10 * np.sin(h), metres["y"].to_numpy() + 10 * np.cos(h))
    want = np.degrees(np.arctan2(ax - x, ay - y)) % 360
    dh = (feet["heading_deg"] - want + 180) % 360 - 180
    assert np.abs(dh).max() < 1e-4 and abs(float(np.median(feet["heading_deg"] - metres["heading_deg"]))) > 0.5
    assert np.allclose(feet["speed_kmh"], metres["speed_kmh"])


# ---------------------------------------------------------------------------------------------------- mean data
@pytest.fixture(scope="module")
def meandata(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("meandata")
    (d / "n.nod.xml").write_text(
        '<nodes>\n    <location netOffset="0,0" convBoundary="0,0,600,0" origBoundary="0,0,600,0" projParameter="!"/>\n'
        '    <node id="A" x="0" y="0"/>\n    <node id="B" x="300" y="0"/>\n    <node id="C" x="600" y="0"/>\n'
        "</nodes>\n", encoding="utf-8")
    (d / "n.edg.xml").write_text('<edges>\n    <edge id="ab" from="A" to="B" numLanes="2" speed="13.89"/>\n'
                                 '    <edge id="bc" from="B" to="C" numLanes="2" speed="13.89"/>\n</edges>\n',
                                 encoding="utf-8")
    (d / "r.rou.xml").write_text('<routes>\n    <route id="r" edges="ab bc"/>\n    <flow id="f" route="r" begin="0" '
                                 'end="90" period="exp(0.4)" departLane="random" departSpeed="desired"/>\n</routes>\n',
                                 encoding="utf-8")
    (d / "add.xml").write_text(f'<additional>\n    <edgeData id="e" file="{d / "edges.xml"}" period="30"/>\n'
                               f'    <laneData id="l" file="{d / "lanes.xml"}" period="30"/>\n</additional>\n',
                               encoding="utf-8")
    _run_tool("netconvert", ["--node-files", str(d / "n.nod.xml"), "--edge-files", str(d / "n.edg.xml"),
                             "--no-turnarounds", "--output-file", str(d / "n.net.xml")], 60.0)
    _run_tool("sumo", ["-n", str(d / "n.net.xml"), "-r", str(d / "r.rou.xml"), "-a", str(d / "add.xml"), "-b", "0",
                       "-e", "90", "--seed", "1", "--no-step-log", "--fcd-output", str(d / "fcd.xml")], 60.0)
    return {k: d / f"{k}.xml" for k in ("edges", "lanes", "fcd")} | {"net": d / "n.net.xml"}


@pytest.mark.slow
def test_read_meandata_edges_and_lanes(meandata: dict[str, Path]) -> None:
    edges, lanes = read_meandata(meandata["edges"]), read_meandata(meandata["lanes"])
    for t in (edges, lanes):
        assert list(t.columns[:len(MEANDATA_COLUMNS)]) == MEANDATA_COLUMNS and "sampledSeconds" in t.columns
        assert sorted(set(zip(t["interval_begin"], t["interval_end"], strict=True))) == [(0, 30), (30, 60), (60, 90)]
    assert (edges["lane"] == "").all() and set(edges["edge"]) == {"ab", "bc"} and len(edges) == 6
    assert set(lanes["lane"]) == {"ab_0", "ab_1", "bc_0", "bc_1"} and len(lanes) == 12
    assert set(edges["interval_id"]) == {"e"} and set(lanes["interval_id"]) == {"l"}
    # lanes add up to their edge
    by_lane = lanes.groupby(["interval_begin", "edge"])[["entered", "left", "sampledSeconds"]].sum()
    by_edge = edges.set_index(["interval_begin", "edge"])[["entered", "left", "sampledSeconds"]]
    np.testing.assert_allclose(by_lane.loc[by_edge.index].to_numpy(), by_edge.to_numpy(), atol=0.02)
    # entered on edge bc = vehicles first seen on bc in that interval (FCD of the same run)
    fcd = read_fcd(meandata["fcd"], net=meandata["net"])
    on_bc = fcd[fcd["sumo_lane"].str.startswith("bc_")]
    first = on_bc.groupby("track_id")["time"].min().to_numpy()
    bc = edges[edges["edge"] == "bc"].sort_values("interval_begin")
    assert list(bc["entered"]) == list(np.histogram(first, bins=[0, 30, 60, 90])[0]) and bc["entered"].sum() > 5
    # speed: SUMO's m/s mean over the sampled seconds, in km/h; the FCD's mean over 1 s steps agrees closely
    for _, row in bc.iterrows():
        sel = on_bc[(on_bc["time"] >= row["interval_begin"]) & (on_bc["time"] < row["interval_end"])]
        if len(sel) > 20:
            assert sel["speed_kmh"].mean() == pytest.approx(row["speed_kmh"], rel=0.03)
    empty = lanes[lanes["sampledSeconds"] == 0]
    assert empty["speed_kmh"].isna().all()  # SUMO writes no speed for a lane nobody used


# ---------------------------------------------------------------------------------------------------- parsing
def _fcd_text(body: str) -> str:
    return f'<?xml version="1.0" encoding="UTF-8"?>\n<!-- x -->\n<fcd-export>\n{body}</fcd-export>\n'


def test_sumo_files_take_the_fast_path(monkeypatch: pytest.MonkeyPatch, world: tuple[RoadSpec, SumoRun],
                                       tmp_path: Path) -> None:
    def no_expat(p: Path) -> None:
        raise AssertionError(f"{p} went through the slow expat parser")

    monkeypatch.setattr(fcd_parse, "_parse_fcd_expat", no_expat)
    _, run = world
    assert len(read_fcd(run.fcd, net=run.net)) > 1000
    assert len(read_fcd(SAMPLE)) == 15
    f = tmp_path / "w.xml"
    write_fcd(f, _tracks(), crs="EPSG:2240")
    assert len(read_fcd(f, crs="EPSG:2240")) == 240


def test_slow_path_equals_fast_path(tmp_path: Path) -> None:
    pts = _tracks(4, 12)
    fast = tmp_path / "fast.xml"
    write_fcd(fast, pts, crs="EPSG:2240")
    text = fast.read_text(encoding="utf-8")
    slow = tmp_path / "slow.xml"
    slow.write_text(text.replace("<timestep", "<!-- c --><timestep", 1), encoding="utf-8")  # a comment: expat
    a, b = read_fcd(fast, crs="EPSG:2240"), read_fcd(slow, crs="EPSG:2240")
    pd.testing.assert_frame_equal(a, b)
    assert "veh&1" in set(a["track_id"])


def test_human_readable_time_persons_and_mixed_attributes(tmp_path: Path) -> None:
    f = tmp_path / "f.xml"
    f.write_text(_fcd_text(
        '    <timestep time="00:01:00.50">\n'
        '        <vehicle id="a" x="1" y="2" angle="90" type="car" speed="10" lane="e_0"/>\n'
        '        <person id="p" x="5" y="5" angle="0" speed="1" edge="e"/>\n'
        '        <vehicle id="b" x="3" y="4" z="7.5" speed="5"/>\n'
        "    </timestep>\n    <timestep time=\"1:00:01:00\"/>\n"), encoding="utf-8")
    df = read_fcd(f, crs="EPSG:32616")
    assert list(df["track_id"]) == ["a", "b"] and list(df["time"]) == [60.5, 60.5]
    assert list(df["class"]) == ["car", ""] and list(df["sumo_lane"]) == ["e_0", ""]
    assert np.isnan(df["heading_deg"].iloc[1]) and df["z"].iloc[1] == 7.5 and np.isnan(df["z"].iloc[0])


def test_empty_fcd(tmp_path: Path) -> None:
    f = tmp_path / "f.xml"
    f.write_text(_fcd_text('    <timestep time="0.00"/>\n'), encoding="utf-8")
    df = read_fcd(f)
    assert df.empty and list(df.columns) == FCD_COLUMNS
    write_fcd(tmp_path / "w.xml", df, crs=None)
    assert read_fcd(tmp_path / "w.xml").empty


@pytest.mark.parametrize(("content", "match"), [
    (None, "not found"),
    ("hello, not xml\n", "not an XML file"),
    ('<?xml version="1.0"?>\n<net version="1.20"/>\n', "not <fcd-export>"),
    (_fcd_text('    <timestep time="0">\n        <vehicle id="a" y="2"/>\n    </timestep>\n'), "without attribute x"),
    (_fcd_text('    <timestep time="0">\n        <vehicle id="a" x="east" y="2"/>\n    </timestep>\n'),
     "x='east' is not a number"),
    (_fcd_text('    <timestep time="0">\n        <vehicle id="a" x="1" y="2"/>\n    </timestep>\n')[:-25],
     "broken XML"),
    (_fcd_text('    <timestep time="soon">\n        <vehicle id="a" x="1" y="2"/>\n    </timestep>\n'),
     "time 'soon'"),
])
def test_read_fcd_errors(tmp_path: Path, content: str | None, match: str) -> None:
    f = tmp_path / "f.xml"
    if content is not None:
        f.write_text(content, encoding="utf-8")
    with pytest.raises(InputError, match=match):
        read_fcd(f)


def test_crs_and_net_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="geographic"):
        read_fcd(SAMPLE, crs="EPSG:4326")
    with pytest.raises(InputError, match="SUMO built-in projection"):
        read_fcd(SAMPLE, net=_net(tmp_path / "a.net.xml", proj="-"))
    with pytest.raises(InputError, match="not a PROJ string"):
        read_net_location(_net(tmp_path / "b.net.xml", proj="+proj=nonsense"))
    with pytest.raises(InputError, match="no <net><location"):
        read_net_location(SAMPLE)
    for offset in ("nan,0.00", "0,inf"):  # issue 42: a NaN offset ended in a GEOS exception in sumo-demand
        with pytest.raises(InputError, match="is not a finite 'x,y'"):
            read_net_location(_net(tmp_path / "nan.net.xml", offset=offset))
    with pytest.raises(InputError, match="net_crs is given without net"):
        read_fcd(SAMPLE, net_crs="EPSG:32632")
    none = _net(tmp_path / "c.net.xml", proj="!")
    with pytest.raises(InputError, match="needs a projection"):
        read_fcd(SAMPLE, net=none, geo=True)
    with pytest.raises(InputError, match="needs a projection"):
        write_fcd(tmp_path / "o.xml", _tracks(1, 3), crs="EPSG:2240", net=none, geo=True)


def test_write_fcd_errors(tmp_path: Path) -> None:
    pts = _tracks(2, 4)
    out = tmp_path / "o.xml"
    with pytest.raises(InputError, match=r"lack column.*heading_deg"):
        write_fcd(out, pts.drop(columns=["heading_deg"]), crs="EPSG:2240")
    with pytest.raises(InputError, match="two points at time"):
        write_fcd(out, pd.concat([pts, pts.iloc[:1]]), crs="EPSG:2240")
    bad = pts.copy()
    bad.loc[2, "x"] = np.nan
    with pytest.raises(InputError, match="row 2: x"):
        write_fcd(out, bad, crs="EPSG:2240")
    with pytest.raises(InputError, match="geo=True needs crs"):
        write_fcd(out, pts, crs=None, geo=True)
    with pytest.raises(InputError, match="front_offset_m has 3 values"):
        write_fcd(out, pts, crs="EPSG:2240", front_offset_m=[1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="decimals"):
        write_fcd(out, pts, crs="EPSG:2240", decimals=-1)
    assert not out.exists()


def test_read_meandata_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        read_meandata(tmp_path / "missing.xml")
    with pytest.raises(InputError, match="not <meandata>"):
        read_meandata(SAMPLE)
    f = tmp_path / "m.xml"
    f.write_text('<meandata>\n    <interval begin="0" end="60" id="x">\n        <edge id="a" entered="3"/>\n'
                 "    </interval>\n</meandata>\n", encoding="utf-8")
    t = read_meandata(f)
    assert t[["edge", "lane", "entered"]].values.tolist() == [["a", "", 3]] and np.isnan(t["speed_kmh"].iloc[0])
    f.write_text('<meandata><interval end="60"><edge id="a"/></interval></meandata>', encoding="utf-8")
    with pytest.raises(InputError, match="lacks begin or end"):
        read_meandata(f)


# ---------------------------------------------------------------------------------------------------- large files
@pytest.mark.slow
def test_read_fcd_large_file(tmp_path: Path) -> None:
    """1e5 vehicle rows come back complete and in place (its speed: benchmarks/bench_fcd.py)."""
    rng = np.random.default_rng(1)
    n_veh, n_steps = 100, 1000
    pts = pd.DataFrame({
        "track_id": np.tile([f"d1_car.{k}" for k in range(n_veh)], n_steps),
        "time": np.repeat(np.arange(n_steps) * 0.04, n_veh),
        "x": rng.uniform(-200, 200, n_veh * n_steps), "y": rng.uniform(-200, 200, n_veh * n_steps),
        "speed_kmh": 50.0, "heading_deg": 30.0, "class": "car", "sumo_lane": "d1_0"})
    f = tmp_path / "big.xml"
    write_fcd(f, pts, crs="EPSG:32616", decimals=3)
    df = read_fcd(f, crs="EPSG:32616")
    assert len(df) == n_veh * n_steps
    df = df.sort_values(["time", "track_id"]).reset_index(drop=True)
    pts = pts.sort_values(["time", "track_id"]).reset_index(drop=True)
    np.testing.assert_allclose(df[["time", "x", "y"]], pts[["time", "x", "y"]], atol=5e-4)
    assert (df["track_id"] == pts["track_id"]).all()
