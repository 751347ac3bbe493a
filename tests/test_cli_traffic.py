"""``trafficgeo analyze`` end to end on a generated scene with known vehicles, and its bad input."""

from __future__ import annotations

import json
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely

from cli_support import invoke
from trafficgeo.camera.io import write_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.geo.cuboids import cuboid_boxes

E0, N0, Z0 = 500000.0, 5000000.0, 100.0  # where conftest's roadside_camera stands (ROADSIDE_ORIGIN)
CRS = "EPSG:32633"
FPS = 25.0
# (track, lane centre x offset from E0, start y, speed m/s, class, dims); lanes: x in [-7, -3.5] and [-3.5, 0]
VEHICLES = [("1", -1.75, 10.0, 50 / 3.6, "car", (4.5, 1.8, 1.5)),
            ("2", -5.25, 5.0, 70 / 3.6, "car", (4.5, 1.8, 1.5)),
            ("3", -1.75, -10.0, 40 / 3.6, "truck", (12.0, 2.55, 3.8))]


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory, roadside_camera: Camera) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("traffic_scene")
    cam = roadside_camera
    write_camera_json(root / "camera.json", cam)
    rng = np.random.default_rng(0)
    rows = []
    t = np.arange(0.0, 6.0, 1.0 / FPS)
    for tid, x, y0, speed, cls, (length, width, height) in VEHICLES:
        centre = np.column_stack([np.full(t.size, E0 + x), N0 + y0 + speed * t, np.full(t.size, Z0)])
        box = cuboid_boxes(cam, centre, np.zeros(t.size), np.full(t.size, length), np.full(t.size, width),
                           np.full(t.size, height)) + rng.normal(0, 1.0, (t.size, 4))
        inside = (box[:, 0] > 3) & (box[:, 2] < 1916) & (box[:, 3] < 1076) & (box[:, 1] > 0)
        for k in np.flatnonzero(inside):
            rows.append({"frame": k, "track_id": tid, "class": cls, "x1": box[k, 0], "y1": box[k, 1],
                         "x2": box[k, 2], "y2": box[k, 3]})
    pd.DataFrame(rows).to_csv(root / "tracks.csv", index=False)
    lanes = gpd.GeoDataFrame({"lane": ["inner", "outer"]}, geometry=[
        shapely.box(E0 - 3.5, N0 - 50, E0, N0 + 300), shapely.box(E0 - 7.0, N0 - 50, E0 - 3.5, N0 + 300)], crs=CRS)
    lanes.to_crs("EPSG:4326").to_file(root / "lanes.geojson")  # GeoJSON is lon/lat: reprojected on reading
    line_px = cam.project(np.array([[E0 - 8.0, N0 + 40.0, Z0], [E0 + 1.0, N0 + 40.0, Z0]]))
    pd.DataFrame({"line": ["north40", "north40"], "u": line_px[:, 0], "v": line_px[:, 1]}).to_csv(
        root / "lines.csv", index=False)
    return {"root": root, "camera": root / "camera.json", "tracks": root / "tracks.csv",
            "lanes": root / "lanes.geojson", "lines": root / "lines.csv"}


@pytest.mark.slow
def test_analyze_writes_vehicles_counts_and_trajectories(scene: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    code, stdout, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                                  "--lanes", scene["lanes"], "--lines", scene["lines"], "--interval", 60, "--out", out)
    assert code == 0, stderr
    assert "3 vehicles" in stdout and "north40" in stdout
    veh = pd.read_csv(out / "vehicles.csv", dtype={"track_id": str, "lane": str}).set_index("track_id")
    for tid, _x, _y0, speed, cls, _dims in VEHICLES:
        assert veh.loc[tid, "speed_kmh"] == pytest.approx(3.6 * speed, abs=1.0), tid
        assert veh.loc[tid, "class"] == cls
    assert veh.loc["1", "lane"] == "inner" and veh.loc["2", "lane"] == "outer" and veh.loc["3", "lane"] == "inner"
    assert (veh["lane_changes"] == 0).all()
    # lengths from the boxes where the view determines them (measured 4.70 and 4.49 m; the truck is seen end-on)
    cars = veh.loc[["1", "2"], "length_m"]
    assert cars.notna().all() and np.allclose(cars, 4.5, atol=0.5)
    cr = pd.read_csv(out / "crossings.csv", dtype={"track_id": str, "lane": str, "line": str})
    assert sorted(cr["track_id"]) == ["1", "2", "3"]
    c1 = cr.set_index("track_id").loc["1"]
    assert c1["time"] == pytest.approx((40.0 - 10.0) / (50 / 3.6), abs=0.05)  # truth: 2.16 s
    assert c1["speed_kmh"] == pytest.approx(50.0, abs=1.5)
    counts = pd.read_csv(out / "counts.csv", dtype={"lane": str})
    assert counts.groupby("lane")["count"].sum().to_dict() == {"inner": 2, "outer": 1}
    assert counts["count_truck"].sum() == 1
    pts = pd.read_csv(out / "trajectories.csv", dtype={"track_id": str})
    assert {"x", "y", "z", "lon", "lat", "speed_kmh", "heading_deg", "lane"} <= set(pts.columns)
    layers = set(gpd.list_layers(out / "trajectories.gpkg")["name"])
    assert layers == {"points", "paths", "lanes", "count_lines"}
    paths = gpd.read_file(out / "trajectories.gpkg", layer="paths")
    assert len(paths) == 3 and paths.crs.to_epsg() == 32633
    assert len(gpd.read_parquet(out / "trajectories.parquet")) == len(pts)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["vehicles"] == 3
    assert summary["hidden_crossings"] == 0 and summary["options"]["coast_hidden_s"] == 3.0  # nothing hidden here


@pytest.mark.slow
def test_box_correction_moves_points_to_the_footprint_centre(scene: dict[str, Path], tmp_path: Path) -> None:
    """Without the cuboid fit the ground point is the box's bottom: ~half a car length short of the centre."""
    on, off = tmp_path / "on", tmp_path / "off"
    for out, flag in ((on, "--box-correction"), (off, "--no-box-correction")):
        code, _, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                                 "--out", out, flag)
        assert code == 0, stderr
    err = {}
    for name, out in (("on", on), ("off", off)):
        pts = pd.read_csv(out / "trajectories.csv", dtype={"track_id": str})
        car = pts[pts["track_id"] == "1"]
        truth_y = N0 + 10.0 + 50 / 3.6 * car["frame"].to_numpy() / FPS
        err[name] = float(np.median(np.abs(car["y"].to_numpy() - truth_y)))
    assert err["on"] < 0.25 and err["off"] > 1.0, err


@pytest.mark.slow
def test_boundary_lines_and_mot_input(scene: dict[str, Path], tmp_path: Path) -> None:
    bounds = gpd.GeoDataFrame(geometry=[shapely.LineString([(E0 + x, N0 - 50), (E0 + x, N0 + 300)])
                                        for x in (0.0, -7.0, -3.5)], crs=CRS)
    bounds.to_file(tmp_path / "bounds.gpkg")
    df = pd.read_csv(scene["tracks"])
    mot = pd.DataFrame({"frame": df["frame"] + 1, "id": df["track_id"], "x": df["x1"], "y": df["y1"],
                        "w": df["x2"] - df["x1"], "h": df["y2"] - df["y1"], "conf": 1.0, "a": -1, "b": -1, "c": -1})
    mot.to_csv(tmp_path / "tracks.txt", header=False, index=False)
    out = tmp_path / "out"
    code, _stdout, stderr = invoke("analyze", scene["camera"], tmp_path / "tracks.txt", "--fps", FPS,
                                  "--surface", Z0, "--lanes", tmp_path / "bounds.gpkg", "--out", out)
    assert code == 0, stderr
    veh = pd.read_csv(out / "vehicles.csv", dtype={"track_id": str, "lane": str}).set_index("track_id")
    # boundaries ordered left to right looking north: lane 1 is x in [-7, -3.5]
    assert veh.loc["2", "lane"] == "1" and veh.loc["1", "lane"] == "2"


BAD = {
    "no_fps": (lambda s, t: [], "--fps"),
    "bad_interval": (lambda s, t: ["--fps", 25, "--interval", 0], "--interval"),
    "missing_lanes": (lambda s, t: ["--fps", 25, "--lanes", t / "nope.gpkg"], "not found"),
    "points_as_lanes": (lambda s, t: ["--fps", 25, "--lanes", _points_file(t)], "lane polygons"),
    "line_off_road": (lambda s, t: ["--fps", 25, "--lines", _sky_line(t)], "does not map to the road"),
    "bad_sigma": (lambda s, t: ["--fps", 25, "--pixel-sigma", -1], "option --pixel-sigma=-1.0 is out of range"),
    "bad_coast": (lambda s, t: ["--fps", 25, "--coast-hidden", -2], "option --coast-hidden=-2.0 is out of range"),
    "bad_box_sigma": (lambda s, t: ["--fps", 25, "--box-sigma-share", -0.05],
                      "option --box-sigma-share=-0.05 is out of range"),
}


def _points_file(tmp: Path) -> Path:
    gpd.GeoDataFrame(geometry=[shapely.Point(E0, N0)], crs=CRS).to_file(tmp / "pts.gpkg")
    return tmp / "pts.gpkg"


def _sky_line(tmp: Path) -> Path:
    pd.DataFrame({"line": ["a", "a"], "u": [100.0, 900.0], "v": [5.0, 5.0]}).to_csv(tmp / "sky.csv", index=False)
    return tmp / "sky.csv"


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_exits_2_with_one_line_and_nothing_written(case: str, scene: dict[str, Path],
                                                              tmp_path: Path) -> None:
    extra, expect = BAD[case]
    out = tmp_path / "out"
    code, _stdout, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--surface", Z0, "--out", out,
                                   *extra(scene, tmp_path))
    assert code == 2, stderr
    assert expect in stderr and "Traceback" not in stderr
    assert len(stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_a_time_far_from_the_others_is_refused_before_the_work(scene: dict[str, Path], tmp_path: Path) -> None:
    """Issue 43: one row at 1e9 s (a frame number off by a factor) made analyze build counts tables without bound
    (9 GB in 2 minutes at --interval 1); the number of counting intervals is now capped, checked before the work."""
    from trafficgeo.errors import InputError
    from trafficgeo.traffic.counts import MAX_INTERVALS, interval_edges

    assert interval_edges(0.0, MAX_INTERVALS * 1.0, 1.0).size == MAX_INTERVALS + 1
    with pytest.raises(InputError, match="counting intervals"):
        interval_edges(0.0, 1e9, 1.0)
    df = pd.read_csv(scene["tracks"])
    far = df.iloc[[-1]].copy()
    far["frame"] = int(FPS) * 10**9
    pd.concat([df, far]).to_csv(tmp_path / "far.csv", index=False)
    out = tmp_path / "out"
    code, _stdout, stderr = invoke("analyze", scene["camera"], tmp_path / "far.csv", "--fps", FPS, "--surface", Z0,
                                   "--interval", 1, "--out", out)
    assert code == 2, stderr
    assert "counting intervals" in stderr and "--fps" in stderr and "--interval" in stderr
    assert len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr
    assert not out.exists()


HOLD = """
import sys
from trafficgeo.io.folder_lock import hold_folder
with hold_folder(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.read()
"""


def test_analyze_is_refused_while_another_run_writes_its_folder(scene: dict[str, Path], tmp_path: Path) -> None:
    """Issue 43: analyze took no folder lock, so run beside process into one --out both exited 0 and process's
    results were silently replaced. Every writer of a run folder now holds its lock: analyze is refused at once,
    and so are the library's writers (the run's tables, a comparison) called from another process."""
    import os
    import subprocess
    import sys

    from trafficgeo.errors import InputError
    from trafficgeo.run.folder import RunFolder

    run = tmp_path / "run"
    code, _stdout, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                                   "--lines", scene["lines"], "--out", run)
    assert code == 0, stderr
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file() and p.name != ".lock"}
    src = Path(__file__).resolve().parents[1] / "src"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(run)], env={**os.environ, "PYTHONPATH": str(src)},
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        code, _stdout, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                                       "--out", run)
        assert code == 2 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr
        assert f"another trafficgeo run (pid {holder.pid}) is writing to this folder" in stderr
        folder = RunFolder(run)
        with pytest.raises(InputError, match="another trafficgeo run"):
            folder.write_comparison({}, None)  # refused before it looks at what it writes
        with pytest.raises(InputError, match="another trafficgeo run"), folder.writing("analyze"):
            pass  # refused before the block runs
    finally:
        holder.kill()
        holder.wait(timeout=30)
    assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file() and p.name != ".lock"} == before


def test_analyze_cleans_up_what_a_killed_writer_left(scene: dict[str, Path], tmp_path: Path) -> None:
    """Issue 43: the temporary files (and a temporary GeoPackage's SQLite journal) of a writer killed mid-write
    survived every rerun of analyze; whoever takes the folder's lock now removes them, and nothing of the user's."""
    from trafficgeo.io.atomic import atomic_path, is_temporary_name

    run = tmp_path / "run"
    writer = atomic_path(run / "trajectories.gpkg")
    tmp = writer.__enter__()  # entered and never left: a writer killed mid-write
    tmp.write_text("half")
    journal = tmp.with_name(tmp.name + "-journal")
    journal.write_text("half")
    mine = [run / "notes-journal", run / ".trajectories.gpkg.ABCDEFGH.tmp.gpkg-journal"]
    for p in mine:
        p.write_text("mine")
    assert is_temporary_name(tmp.name) and is_temporary_name(journal.name)
    assert not any(is_temporary_name(p.name) for p in mine)
    code, _stdout, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                                   "--out", run)
    assert code == 0, stderr
    assert not tmp.exists() and not journal.exists() and all(p.exists() for p in mine)


@pytest.mark.slow
def test_export_fcd_and_compare_sumo_round_trip(scene: dict[str, Path], tmp_path: Path) -> None:
    """The observed trajectories exported as SUMO FCD and compared with themselves: every GEH is 0, speeds agree;
    a simulation shifted by 30 s in time no longer matches."""
    run = tmp_path / "run"
    code, _, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                             "--lanes", scene["lanes"], "--lines", scene["lines"], "--interval", 2, "--out", run)
    assert code == 0, stderr
    fcd = tmp_path / "observed.fcd.xml"
    code, stdout, stderr = invoke("export-fcd", run, "-o", fcd)
    assert code == 0, stderr
    assert "3 vehicles" in stdout
    assert fcd.read_text().startswith("<?xml") and "<fcd-export" in fcd.read_text()
    from trafficgeo.io.fcd_read import read_fcd

    back = read_fcd(fcd, crs=CRS)
    pts = pd.read_csv(run / "trajectories.csv", dtype={"track_id": str})
    assert len(back) == len(pts) and set(back["track_id"]) == {"1", "2", "3"}
    # SUMO positions are front bumpers: half the vehicle's estimated length (else its class's) ahead of the
    # footprint centre, northbound
    first = back[back["track_id"] == "1"].iloc[0]
    p0 = pts[pts["track_id"] == "1"].iloc[0]
    length = pd.read_csv(run / "vehicles.csv", dtype={"track_id": str}).set_index("track_id").loc["1", "length_m"]
    assert first["y"] - p0["y"] == pytest.approx(0.5 * length, abs=0.01)
    cmp_dir = tmp_path / "cmp"
    code, stdout, stderr = invoke("compare-sumo", run, fcd, "--out", cmp_dir)
    assert code == 0, stderr
    table = pd.read_csv(cmp_dir / "compare_counts.csv", dtype={"lane": str})
    assert (table["geh"] == 0).all() and table["observed"].sum() == 3 == table["simulated"].sum()
    speeds = pd.read_csv(cmp_dir / "compare_speeds.csv", dtype={"lane": str})
    assert np.allclose(speeds["observed_mean_kmh"], speeds["simulated_mean_kmh"], atol=0.5)
    code, stdout, stderr = invoke("compare-sumo", run, fcd, "--time-offset", 30, "--out", tmp_path / "cmp2")
    assert code == 0, stderr
    assert pd.read_csv(tmp_path / "cmp2" / "compare_counts.csv")["simulated"].sum() == 0


@pytest.mark.slow
@pytest.mark.parametrize("case", ["not_a_run", "bad_suffix", "missing_fcd"])
def test_sumo_commands_bad_input(case: str, scene: dict[str, Path], tmp_path: Path) -> None:
    run = tmp_path / "run"
    code, _, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                             "--lines", scene["lines"], "--out", run)
    assert code == 0, stderr
    if case == "not_a_run":
        args = ("compare-sumo", tmp_path, tmp_path / "x.xml")
    elif case == "bad_suffix":
        args = ("export-fcd", run, "-o", tmp_path / "out.csv")
    else:
        args = ("compare-sumo", run, tmp_path / "missing.fcd.xml", "--out", tmp_path / "cmp")
    code, _, stderr = invoke(*args)
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr, stderr
    assert not (tmp_path / "out.csv").exists() and not (tmp_path / "cmp").exists()


@pytest.mark.slow
def test_a_counting_line_beyond_the_usable_range_is_warned_about(scene: dict[str, Path], tmp_path: Path) -> None:
    """A line 260 m away, where one pixel spans ~5 m of road, counts nobody: analyze says so and why."""
    far = gpd.GeoDataFrame({"name": ["far"]}, geometry=[shapely.LineString([(E0 - 8, N0 + 250), (E0 + 1, N0 + 250)])],
                           crs=CRS)
    far.to_file(tmp_path / "far.gpkg")
    out = tmp_path / "out"
    code, stdout, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                                  "--lines", tmp_path / "far.gpkg", "--out", out)
    assert code == 0, stderr
    words = " ".join(stdout.split())
    assert "counting line far: 100% of it lies farther than where one pixel spans 1.5 m" in words
    assert json.loads((out / "summary.json").read_text())["warnings"]
    code, stdout, _ = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                             "--lines", scene["lines"], "--out", tmp_path / "near")
    assert "warning" not in stdout


@pytest.mark.slow
def test_a_line_nobody_crossed_is_listed_with_zeros_and_warned_about(scene: dict[str, Path], tmp_path: Path) -> None:
    """Issue 29: a line without vehicles must not vanish from the counts (0 vehicles vs not loaded), the run warns
    about it, and 6 s of video give no flow for a 60 s interval."""
    lines = gpd.GeoDataFrame({"name": ["north40", "aside"]}, geometry=[
        shapely.LineString([(E0 - 8, N0 + 40), (E0 + 1, N0 + 40)]),
        shapely.LineString([(E0 + 5, N0 + 40), (E0 + 14, N0 + 40)])], crs=CRS)  # beside the road
    lines.to_file(tmp_path / "lines.gpkg")
    out = tmp_path / "out"
    code, stdout, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                                  "--lanes", scene["lanes"], "--lines", tmp_path / "lines.gpkg", "--interval", 60,
                                  "--out", out)
    assert code == 0, stderr
    words = " ".join(stdout.split())
    assert "counting line aside: no vehicle crossed it" in words and "counting line north40: no" not in words
    assert "no flows (veh/h)" in words
    counts = pd.read_csv(out / "counts.csv", dtype={"lane": str}, keep_default_na=False, na_values=[""])
    aside = counts[counts["line"] == "aside"]
    assert sorted(zip(aside["lane"], aside["direction"], strict=True)) == [
        ("inner", -1), ("inner", 1), ("outer", -1), ("outer", 1)]
    assert (aside["count"] == 0).all() and aside["time_mean_speed_kmh"].isna().all()
    assert len(counts) == 8 and counts["count"].sum() == 3
    assert counts["flow_veh_h"].isna().all() and counts["observed_s"].lt(30.0).all()  # ~6 s of a 60 s interval
    summary = json.loads((out / "summary.json").read_text())
    assert {(c["line"], c["count"]) for c in summary["crossings"] if c["line"] == "aside"} == {("aside", 0)}
    assert any(w.startswith("counting line aside: no vehicle crossed it") for w in summary["warnings"])


def test_a_bad_input_leaves_the_finished_run_in_its_folder(scene: dict[str, Path], tmp_path: Path) -> None:
    """The run folder's manifest is removed only once the new run starts writing: tracks that cannot be read leave
    the earlier run there, readable."""
    from trafficgeo.run.folder import RunFolder

    run = tmp_path / "run"
    code, _stdout, stderr = invoke("analyze", scene["camera"], scene["tracks"], "--fps", FPS, "--surface", Z0,
                                   "--out", run)
    assert code == 0, stderr
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file() and p.name != ".lock"}
    (tmp_path / "bad.csv").write_text("frame,time,track_id,u\n1,0.0,7,abc\n")
    code, _stdout, stderr = invoke("analyze", scene["camera"], tmp_path / "bad.csv", "--fps", FPS, "--surface", Z0,
                                   "--out", run)
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr
    assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file() and p.name != ".lock"} == before
    assert len(RunFolder(run).vehicles()) > 0
