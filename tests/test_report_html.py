"""``trafficgeo report`` and ``--report-html``: the figures alone on known data, and the page on a generated site
(calibration from GCPs with a planted blunder, a frame, an orthophoto, an ``analyze`` run), on a traffic run in
feet, and on bad input."""

from __future__ import annotations

import base64
import json
from html import unescape
from html.parser import HTMLParser
from pathlib import Path

import cv2
import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely

from cli_support import invoke
from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.geo.cuboids import cuboid_boxes
from trafficgeo.geo.raster import write_geotiff
from trafficgeo.io.run_manifest import MANIFEST, publish_outputs
from trafficgeo.report import figures as F
from trafficgeo.report.html import build_page, build_report

pytestmark = pytest.mark.slow  # its site fixture runs calibrate and analyze and renders full report pages

E0, N0, Z0 = 500000.0, 5000000.0, 100.0  # where conftest's roadside_camera stands (ROADSIDE_ORIGIN)
CRS = "EPSG:32633"
FPS = 25.0
SIZE = (1920, 1080)
# (track, x offset of the lane centre from E0, start y, speed m/s (negative: southbound), class)
VEHICLES = [("1", -1.75, 10.0, 50 / 3.6, "car"), ("2", -5.25, 5.0, 70 / 3.6, "car"),
            ("3", -1.75, -10.0, 40 / 3.6, "truck"), ("4", -5.25, 110.0, -45 / 3.6, "car")]
DIMS = {"car": (4.5, 1.8, 1.5), "truck": (12.0, 2.55, 3.8)}
BAD_ID = "C<0>&"  # a check point whose id must be escaped in the page


def _gcps(cam: Camera) -> pd.DataFrame:
    """Road-marking GCPs with 0.5 px noise, two pole tops, a 30 px wrong click (P3) and two check points."""
    rng = np.random.default_rng(3)
    spots = [(-6, 8, 0), (-1, 8, 0), (2, 12, 0), (-6, 20, 0), (0, 25, 0), (-3, 35, 0), (2, 40, 0), (-7, 50, 0),
             (1, 60, 0), (-4, 70, 0), (3, 80, 0), (-6, 90, 0), (0, 15, 0), (-2, 55, 0), (4, 30, 4.0), (-9, 45, 5.0)]
    rows = []
    for k, (x, y, h) in enumerate(spots):
        w = np.array([E0 + x, N0 + y, Z0 + h + rng.normal(0, 0.01)])
        uv = cam.project(w[None])[0] + rng.normal(0, 0.5, 2)
        rows.append({"id": f"P{k}", "x": w[0], "y": w[1], "z": w[2], "u": uv[0], "v": uv[1], "role": "control"})
    rows[3]["u"] += 30.0
    for name, (x, y) in ((BAD_ID, (-2, 30)), ("C1", (1, 45))):
        uv = cam.project(np.array([[E0 + x, N0 + y, Z0]]))[0] + rng.normal(0, 0.5, 2)
        rows.append({"id": name, "x": E0 + x, "y": N0 + y, "z": Z0, "u": uv[0], "v": uv[1], "role": "check"})
    return pd.DataFrame(rows)


def _tracks(cam: Camera) -> pd.DataFrame:
    rng = np.random.default_rng(0)
    rows = []
    t = np.arange(0.0, 6.0, 1.0 / FPS)
    for tid, x, y0, speed, cls in VEHICLES:
        length, width, height = DIMS[cls]
        centre = np.column_stack([np.full(t.size, E0 + x), N0 + y0 + speed * t, np.full(t.size, Z0)])
        heading = np.full(t.size, 0.0 if speed > 0 else 180.0)
        box = cuboid_boxes(cam, centre, heading, np.full(t.size, length), np.full(t.size, width),
                           np.full(t.size, height)) + rng.normal(0, 1.0, (t.size, 4))
        inside = (box[:, 0] > 3) & (box[:, 2] < SIZE[0] - 4) & (box[:, 3] < SIZE[1] - 4) & (box[:, 1] > 0)
        for k in np.flatnonzero(inside):
            rows.append({"frame": k, "track_id": tid, "class": cls, "x1": box[k, 0], "y1": box[k, 1],
                         "x2": box[k, 2], "y2": box[k, 3]})
    return pd.DataFrame(rows)


def _ortho(path: Path, crs: str = CRS) -> None:
    """A 0.5 m grey-green orthophoto with a dark road strip, 200 x 200 m around the scene."""
    res, n = 0.5, 400
    img = np.zeros((3, n, n), dtype=np.uint8)
    img[1] = 120
    cols = (E0 - 100 + (np.arange(n) + 0.5) * res)
    road = (cols > E0 - 7.5) & (cols < E0 + 0.5)
    img[:, :, road] = 70
    write_geotiff(path, img, (res, 0.0, E0 - 100, 0.0, -res, N0 + 150), crs, descriptions=("red", "green", "blue"))


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory, roadside_camera: Camera) -> dict[str, Path]:
    """project/: camera.json, report.json and calibration.html (calibrate --report-html), frame.png, ortho.tif,
    lanes and lines, and run/ (analyze --report-html run/report.html)."""
    root = tmp_path_factory.mktemp("report_site")
    proj = root / "project"
    proj.mkdir()
    cam = roadside_camera
    _gcps(cam).to_csv(root / "gcps.csv", index=False)
    frame = np.full((SIZE[1], SIZE[0], 3), 90, dtype=np.uint8)
    frame[SIZE[1] // 2:] = (60, 120, 60)
    cv2.imwrite(str(proj / "frame.png"), frame)
    _ortho(proj / "ortho.tif")
    code, _, err = invoke("calibrate", root / "gcps.csv", "--image-size", "1920x1080", "--crs", CRS, "-o",
                          proj / "camera.json", "--report", proj / "report.json", "--report-html",
                          proj / "calibration.html", "-q")
    assert code == 0, err
    _tracks(cam).to_csv(root / "tracks.csv", index=False)
    lanes = gpd.GeoDataFrame({"lane": ["inner", "outer"]}, geometry=[
        shapely.box(E0 - 3.5, N0 - 50, E0, N0 + 300), shapely.box(E0 - 7.0, N0 - 50, E0 - 3.5, N0 + 300)], crs=CRS)
    lanes.to_file(root / "lanes.gpkg")
    lines = gpd.GeoDataFrame({"name": ["n40"]}, geometry=[shapely.LineString([(E0 - 8, N0 + 40), (E0 + 1, N0 + 40)])],
                             crs=CRS)
    lines.to_file(root / "lines.gpkg")
    code, out, err = invoke("analyze", proj / "camera.json", root / "tracks.csv", "--fps", FPS, "--surface", Z0,
                            "--lanes", root / "lanes.gpkg", "--lines", root / "lines.gpkg", "--interval", 2,
                            "--out", proj / "run", "--report-html", proj / "run" / "report.html")
    assert code == 0, err
    assert "wrote" in out and "report.html" in out
    return {"root": root, "project": proj, "run": proj / "run", "camera": proj / "camera.json",
            "report": proj / "report.json"}


def _synthetic_run(folder: Path, crs: str, unit_m: float) -> dict[str, pd.DataFrame]:
    """analyze-like outputs without a camera: 3 northbound vehicles in lane 'a' and 2 southbound in 'b' on a
    straight road along y, 1 s points, constant speeds; a counting line at y = 50 m, intervals of 5 s."""
    folder.mkdir(parents=True, exist_ok=True)
    x0, y0 = 1_000_000.0, 500_000.0  # CRS units
    pts, veh, cross = [], [], []
    for k, (lane, speed, start) in enumerate([("a", 10.0, 0.0), ("a", 12.0, 3.0), ("a", 8.0, 6.0),
                                               ("b", -11.0, 1.0), ("b", -9.0, 4.0)]):
        t = np.arange(start, start + 9.0, 1.0)
        y_m = (0.0 if speed > 0 else 100.0) + speed * (t - start)
        x_m = np.where(speed > 0, 2.0, -2.0)
        tid = f"v{k}"
        pts.append(pd.DataFrame({"track_id": tid, "time": t, "x": x0 + x_m / unit_m, "y": y0 + y_m / unit_m,
                                 "speed_kmh": abs(speed) * 3.6, "lane": lane, "class": "car"}))
        veh.append({"track_id": tid, "class": "car", "lane": lane, "speed_kmh": abs(speed) * 3.6,
                    "speed_std_kmh": 0.5, "lane_changes": 0, "duration_s": 8.0, "path_length_m": abs(speed) * 8})
        tc = start + (50.0 - (0.0 if speed > 0 else 100.0)) / speed
        cross.append({"line": "L", "track_id": tid, "class": "car", "lane": lane, "direction": 1 if speed > 0 else -1,
                      "time": tc, "speed_kmh": abs(speed) * 3.6, "x": x0, "y": y0 + 50 / unit_m})
    points, vehicles, crossings = pd.concat(pts, ignore_index=True), pd.DataFrame(veh), pd.DataFrame(cross)
    edges = np.arange(0.0, 20.0, 5.0)
    counts = pd.DataFrame([{"line": "L", "lane": c["lane"], "direction": c["direction"], "interval_start": e,
                            "interval_end": e + 5.0,
                            "count": int(((crossings["lane"] == c["lane"]) & (crossings["time"] >= e)
                                          & (crossings["time"] < e + 5.0)).sum())}
                           for _, c in crossings.drop_duplicates("lane").iterrows() for e in edges])
    import pyproj

    for name, table in (("trajectories.csv", points), ("vehicles.csv", vehicles), ("crossings.csv", crossings),
                        ("counts.csv", counts)):
        table.to_csv(folder / name, index=False)
    (folder / "summary.json").write_text(json.dumps({
        "period_s": [0.0, 18.0], "vehicles": 5, "points": len(points), "dropped_points": {"too_far": 3},
        "outlier_points": 0, "mean_speed_kmh": float(vehicles["speed_kmh"].mean()), "classes": {"car": 5},
        "lane_changes": 0, "crossings": [], "options": {"interval_s": 5.0}, "warnings": ["a <b>warning</b>"],
        "crs": pyproj.CRS.from_user_input(crs).to_wkt()}))
    publish_outputs(folder, [p.name for p in folder.iterdir() if p.is_file()], command="analyze")
    return {"points": points, "vehicles": vehicles, "crossings": crossings, "counts": counts}


@pytest.fixture(scope="module")
def feet_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, pd.DataFrame]]:
    folder = tmp_path_factory.mktemp("report_feet") / "run"
    return folder, _synthetic_run(folder, "EPSG:2994", 0.3048)  # NAD83(HARN) / Oregon GIC Lambert (ft)


# ------------------------------------------------------------------------------------------------ page parsing
class _Refs(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.refs: list[tuple[str, str, str]] = []
        self.tags: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        for name, value in attrs:
            if name in ("src", "href", "srcset", "data", "action", "poster"):
                self.refs.append((tag, name, value or ""))


def _refs(page: str) -> _Refs:
    p = _Refs()
    p.feed(page)
    return p


def _pngs(page: str) -> list[np.ndarray]:
    out = []
    for tag, _name, value in _refs(page).refs:
        if tag == "img":
            assert value.startswith("data:image/png;base64,"), value[:40]
            raw = base64.b64decode(value.split(",", 1)[1], validate=True)
            assert raw[:8] == b"\x89PNG\r\n\x1a\n"
            img = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_UNCHANGED)
            assert img is not None and img.shape[0] > 100 and img.shape[1] > 100
            out.append(img)
    return out


def _left_out(page: str) -> str:
    return page[page.index('<section id="left-out">'):]


# ------------------------------------------------------------------------------------------------ figures
def _gid(fig, gid: str) -> list:
    return [a for ax in fig.axes for a in [*ax.collections, *ax.patches, *ax.images] if a.get_gid() == gid]


def test_residual_arrows_one_per_gcp_along_the_residuals(site: dict[str, Path]) -> None:
    rep = json.loads(site["report"].read_text())
    g = pd.DataFrame(rep["gcps"])
    fig = F.residuals_on_frame(g, SIZE, np.zeros((540, 960, 3)), scale=10.0)
    (q,) = _gid(fig, "residuals")
    assert q.N == len(g) == 18
    np.testing.assert_allclose(q.U, 10.0 * g["du"], atol=1e-9)
    np.testing.assert_allclose(q.V, 10.0 * g["dv"], atol=1e-9)
    np.testing.assert_allclose(q.get_offsets(), g[["u", "v"]].to_numpy(), atol=1e-9)
    assert fig.axes[0].get_ylim()[0] > fig.axes[0].get_ylim()[1]  # v down, like the image


def test_gcp_map_draws_camera_footprint_and_ground_residuals(site: dict[str, Path]) -> None:
    rep = json.loads(site["report"].read_text())
    g = pd.DataFrame(rep["gcps"]).assign(gdx=0.1, gdy=-0.2)
    axes = F.MapAxes(origin=(E0 - 100, N0 - 100), unit="m", crs_label=CRS)
    foot = shapely.box(E0 - 20, N0, E0 + 20, N0 + 100)
    fig = F.gcps_on_map(g, axes, camera_xy=(E0 + 5, N0 - 10), heading_deg=350.0, footprint=foot, scale=5.0)
    (q,) = _gid(fig, "ground-residuals")
    assert q.N == len(g)
    np.testing.assert_allclose(q.get_offsets()[:, 0], g["x"] - (E0 - 100))
    np.testing.assert_allclose(q.U, 0.5)
    ax = fig.axes[0]
    fill = [p for p in ax.patches if p.get_xy().shape[0] == 5]
    assert fill and np.allclose(fill[0].get_xy()[:, 0].min(), 80.0)  # footprint left edge in local coordinates
    assert "easting - 499900 (m)" == ax.get_xlabel()


def test_residual_histograms_count_every_inlier(site: dict[str, Path]) -> None:
    g = pd.DataFrame(json.loads(site["report"].read_text())["gcps"])
    fig = F.residual_histograms(g)
    n_inl = int((g["status"] == "inlier").sum())
    px, ground = fig.axes[0], fig.axes[1]
    for ax in (px, ground):
        fit = sum(p.get_height() for p in ax.patches if p.get_gid() == "fit")
        loo = sum(p.get_height() for p in ax.patches if p.get_gid() == "loo")
        assert fit == loo == n_inl


def test_accuracy_map_shows_the_grid_masked() -> None:
    values = np.arange(1, 13, dtype=float).reshape(3, 4) / 10
    values[0, 0] = np.nan
    axes = F.MapAxes(origin=(E0, N0))
    fig = F.accuracy_map(values, (E0, N0, E0 + 40, N0 + 30), axes, camera_xy=(E0 - 5, N0 - 5))
    (im,) = _gid(fig, "accuracy")
    arr = im.get_array()
    assert arr.mask[0, 0] and not arr.mask[1:].any()
    np.testing.assert_allclose(arr.filled(np.nan)[1:], values[1:])
    assert im.get_extent() == [0.0, 40.0, 0.0, 30.0]


def test_trajectory_segments_and_colours(feet_run: tuple[Path, dict[str, pd.DataFrame]]) -> None:
    pts = feet_run[1]["points"]
    axes = F.MapAxes(origin=(1_000_000.0, 500_000.0), unit="ft")
    fig = F.trajectories_map(pts, axes, lines=[("L", shapely.LineString([(999_990, 500_164), (1_000_010, 500_164)]))])
    (lc,) = _gid(fig, "trajectories")
    segs = lc.get_segments()
    assert len(segs) == len(pts) - pts["track_id"].nunique()
    speeds = lc.get_array()
    assert set(np.round(speeds, 6)) == set(np.round(pts["speed_kmh"].unique(), 6))  # constant speed per vehicle
    assert "(ft)" in fig.axes[0].get_xlabel()
    thin = F.trajectories_map(pts, axes, max_points=-(-len(pts) // 2))  # every 2nd point of a track, and its last
    (lc,) = _gid(thin, "trajectories")
    assert len(lc.get_segments()) == pts.groupby("track_id").size().map(lambda n: (n + 1) // 2 + (n % 2 == 0) - 1).sum()


def test_the_trajectories_map_is_framed_on_what_was_seen() -> None:
    """A run with an ROI sees 30 m of road, its counting line spans 400 m of it and one stray point lies 300 m off:
    the map is framed on the 30 m where vehicles were (the line only where it crosses them), not half blank."""
    t = np.arange(0.0, 3.0, 0.1)
    pts = pd.concat([pd.DataFrame({"track_id": str(k), "time": t, "x": E0 + 2.0 * k, "y": N0 + 10.0 * t,
                                   "speed_kmh": 36.0}) for k in range(8)], ignore_index=True)
    pts.loc[len(pts)] = {"track_id": "stray", "time": 0.0, "x": E0 + 300.0, "y": N0 + 300.0, "speed_kmh": 36.0}
    line = ("L", shapely.LineString([(E0 - 200.0, N0 + 15.0), (E0 + 200.0, N0 + 15.0)]))
    axes = F.MapAxes(origin=(E0, N0))
    ax = F.trajectories_map(pts, axes, lines=[line]).axes[0]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert -10.0 < x0 <= 0.0 and 14.0 <= x1 < 30.0, (x0, x1)  # vehicles at 0-14 m east, the line cut near them
    assert -10.0 < y0 <= 0.0 and 29.0 <= y1 < 45.0, (y0, y1)
    fx, fy = F.seen_frame(np.zeros(0), np.zeros(0), [line])  # nothing seen: the lines frame the map
    assert fy.min() == fy.max() == N0 + 15.0
    assert fx.min() == E0 - 200.0 and fx.max() == E0 + 200.0


def test_speed_histograms_per_lane(feet_run: tuple[Path, dict[str, pd.DataFrame]]) -> None:
    veh = feet_run[1]["vehicles"]
    fig = F.speed_histograms(veh)
    for lane, n in veh.groupby("lane").size().items():
        bars = [p for ax in fig.axes for p in ax.patches if p.get_gid() == f"speed-{lane}"]
        assert sum(p.get_height() for p in bars) == n


def test_counts_over_time_bars(feet_run: tuple[Path, dict[str, pd.DataFrame]]) -> None:
    counts = feet_run[1]["counts"]
    fig = F.counts_over_time(counts)
    for (lane, direction), g in counts.groupby(["lane", "direction"]):
        bars = [p for p in fig.axes[0].patches if p.get_gid() == f"count-L-{lane}-{direction}"]
        assert len(bars) == len(g)
        assert [p.get_height() for p in sorted(bars, key=lambda p: p.get_x())] == g["count"].tolist()


def test_time_space_one_point_per_trajectory_point_split_by_direction(
        feet_run: tuple[Path, dict[str, pd.DataFrame]]) -> None:
    pts = feet_run[1]["points"]
    fig = F.time_space_diagram(pts, metres_per_unit=0.3048)
    up, down = _gid(fig, "time-space")
    assert len(up.get_offsets()) + len(down.get_offsets()) == len(pts)
    assert len(up.get_offsets()) == int((pts["lane"] == "a").sum())  # northbound: distance grows
    off = np.asarray(up.get_offsets())
    d = off[:9]  # first vehicle, 10 m/s for 8 s: distances in metres although the data are in feet
    np.testing.assert_allclose(np.diff(d[:, 1]), 10.0, atol=0.05)


def test_road_stations_follow_a_curved_road() -> None:
    """Points on a 400 m radius arc: distances along the road equal arc lengths (not chords or projections)."""
    r, arc = 400.0, np.linspace(0.0, 250.0, 120)
    ang = arc / r  # heading turns by 36 deg: a chord or a straight axis would be off by metres
    side = np.random.default_rng(1).choice([-1.75, 1.75], arc.size)  # the two lanes, either side of the axis
    x = 3e5 + r * np.sin(ang) - side * np.sin(ang)
    y = 5e6 + r * (1 - np.cos(ang)) + side * np.cos(ang)
    s, _ = F.road_stations(x, y)
    np.testing.assert_allclose(s - s[0], arc, atol=0.3)


# ------------------------------------------------------------------------------------------------ the page
def test_full_page_has_every_section_self_contained(site: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "page.html"
    code, stdout, stderr = invoke("report", site["project"], "-o", out)
    assert code == 0, stderr
    assert "wrote" in stdout and "Accuracy map" in stdout and "left out" not in stdout
    html = out.read_text(encoding="utf-8")
    assert html.startswith("<!DOCTYPE html>") and html.rstrip().endswith("</html>")
    titles = [t.split("</h2>")[0] for t in html.split("<h2>")[1:]]
    assert titles == ["Calibration", "GCPs and residuals", "Accuracy map", "Traffic: run", "Left out"]
    refs = _refs(html)
    assert all(v.startswith(("data:image/png;base64,", "#")) for _, _, v in refs.refs), refs.refs
    assert not {"script", "link", "iframe", "object"} & set(refs.tags)
    assert "url(" not in html and "@import" not in html
    assert len(_pngs(html)) == 8  # frame, map, histograms, accuracy, trajectories, time-space, speeds, counts
    # escaped: the check point's id and the report's texts
    assert "C&lt;0&gt;&amp;" in html and BAD_ID not in html
    # header: folder, version, CRS with units
    assert str(site["project"].resolve()) in html and "EPSG:32633" in html and "units m" in html
    # tables: per-GCP outlier flag with its reason; predicted error beside the leave-one-out one
    assert '<tr class="outlier"><td>P3</td>' in html and "OUTLIER: pixel residual" in html
    assert "predicted 1-sigma m" in html and "leave-one-out ground error" in html
    assert "time-mean speed km/h" in html and "median speed 1-sigma km/h" in html
    assert "Nothing: every section had its inputs." in html


def test_calibrate_and_analyze_write_their_pages(site: dict[str, Path]) -> None:
    cal = (site["project"] / "calibration.html").read_text()
    assert "Per-GCP residuals" in cal and "Accuracy map" in cal
    run = (site["run"] / "report.html").read_text()
    # analyze: its folder plus the camera given on its command line, and the calibration beside it
    assert '<section id="traffic-1"><h2>Traffic</h2>' in run and '<section id="calibration">' in run
    assert len(_pngs(run)) >= 7
    assert "orthophoto behind the maps: no orthophoto" not in run  # ortho.tif beside the camera JSON


def test_calibration_only_folder_lists_what_is_missing(site: dict[str, Path], tmp_path: Path) -> None:
    for name in ("camera.json", "report.json"):
        (tmp_path / name).write_bytes((site["project"] / name).read_bytes())
    page = build_page(tmp_path, dpi=40)
    assert page.sections == ("Calibration", "GCPs and residuals", "Accuracy map")
    left = dict(page.left_out)
    assert "--ortho" in left["orthophoto behind the maps"]
    assert "--frame" in left["frame behind the GCP residuals"]
    assert "traffic" in left
    assert "computed here from the camera JSON's covariance on the GCP plane" in unescape(page.html)
    lo = _left_out(page.html)
    assert "pass --ortho" in lo and "pass --frame" in lo


def test_camera_json_alone_still_reports(site: dict[str, Path], tmp_path: Path) -> None:
    (tmp_path / "camera.json").write_bytes(site["camera"].read_bytes())
    html = build_report(tmp_path, frame=site["project"] / "frame.png", dpi=40)
    assert "<h2>GCPs and residuals</h2>" in html and "<h2>Accuracy map</h2>" in html
    assert "calibration report tables" in _left_out(html)
    cam = read_camera_json(site["camera"])
    assert f"{cam.position[0]:.3f}" in html


def test_traffic_only_run_in_feet(feet_run: tuple[Path, dict[str, pd.DataFrame]]) -> None:
    page = build_page(feet_run[0], dpi=40)
    assert page.sections == ("Traffic",)
    assert "units ft" in page.html and "EPSG:2994" in page.html
    assert "a &lt;b&gt;warning&lt;/b&gt;" in page.html
    assert dict(page.left_out)["calibration"].startswith("no camera.json")
    assert len(_pngs(page.html)) == 4


def test_ortho_in_another_crs_is_reprojected(site: dict[str, Path], tmp_path: Path) -> None:
    """An orthophoto in UTM 34N (same place, other CRS) is warped to the camera's UTM 33N behind the map."""
    from trafficgeo.report.context import read_background

    _ortho(tmp_path / "o33.tif")
    import rasterio
    from rasterio.warp import calculate_default_transform, reproject

    with rasterio.open(tmp_path / "o33.tif") as src:
        tr, w, h = calculate_default_transform(src.crs, "EPSG:32634", src.width, src.height, *src.bounds)
        data = np.zeros((3, h, w), dtype=np.uint8)
        reproject(src.read(), data, src_transform=src.transform, src_crs=src.crs, dst_transform=tr,
                  dst_crs="EPSG:32634")
    write_geotiff(tmp_path / "o34.tif", data, tr, "EPSG:32634")
    import pyproj

    bounds = (E0 - 20, N0, E0 + 20, N0 + 40)
    a = read_background(tmp_path / "o33.tif", bounds, pyproj.CRS(CRS))
    b = read_background(tmp_path / "o34.tif", bounds, pyproj.CRS(CRS))
    assert a is not None and b is not None
    np.testing.assert_allclose(b.bounds, a.bounds, atol=1.0)
    assert np.mean(np.abs(a.image[..., :3] - cv2.resize(b.image[..., :3], a.image.shape[1::-1]))) < 0.05


# ------------------------------------------------------------------------------------------------ CLI, bad input
@pytest.mark.parametrize("case", ["missing_folder", "empty_folder", "unreadable_ortho", "missing_ortho", "not_html"])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(case: str, site: dict[str, Path],
                                                            tmp_path: Path) -> None:
    out = tmp_path / "page.html"
    (tmp_path / "empty").mkdir()
    (tmp_path / "bad.tif").write_text("not a raster")
    args = {"missing_folder": [tmp_path / "nope"], "empty_folder": [tmp_path / "empty"],
            "unreadable_ortho": [site["project"], "--ortho", tmp_path / "bad.tif"],
            "missing_ortho": [site["project"], "--ortho", tmp_path / "none.tif"],
            "not_html": [site["project"]]}[case]
    target = tmp_path / "page.txt" if case == "not_html" else out
    code, _, stderr = invoke("report", *args, "-o", target)
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("trafficgeo: error:"), stderr
    assert not target.exists() and not list(tmp_path.glob(".page*"))
    expect = {"missing_folder": "not a folder", "empty_folder": "nothing to report", "unreadable_ortho": "GDAL",
              "missing_ortho": "not found", "not_html": ".html"}[case]
    assert expect in lines[0]


def test_analyze_rejects_a_bad_report_path_before_running(site: dict[str, Path], tmp_path: Path) -> None:
    code, _, stderr = invoke("analyze", site["camera"], site["root"] / "tracks.csv", "--fps", FPS, "--surface", Z0,
                             "--out", tmp_path / "o", "--report-html", tmp_path / "r.pdf")
    assert code == 2 and "--report-html" in stderr
    assert not (tmp_path / "o").exists()


def _tiny_video(path: Path, size: tuple[int, int] = (320, 180), frames: int = 5) -> None:
    """A few grey H.264 frames with a bright square: something to take a frame from."""
    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = size[0], size[1], "yuv420p"
        for k in range(frames):
            img = np.full((size[1], size[0], 3), 100, dtype=np.uint8)
            img[40:80, 20 + 10 * k:60 + 10 * k] = 230
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def test_process_run_names_its_camera_and_video(site: dict[str, Path], tmp_path: Path) -> None:
    """A process folder alone: the camera and the frame come from process.json (the calibration beside it)."""
    run = tmp_path / "proc"
    run.mkdir()
    for p in site["run"].iterdir():
        if p.is_file() and p.suffix != ".html":
            (run / p.name).write_bytes(p.read_bytes())
    cal = tmp_path / "cal"  # the calibration without its frame.png: the frame must come from the video
    cal.mkdir()
    for name in ("camera.json", "report.json"):
        (cal / name).write_bytes((site["project"] / name).read_bytes())
    _tiny_video(tmp_path / "clip.mp4")
    (run / "process.json").write_text(json.dumps({
        "video": str(tmp_path / "clip.mp4"), "camera": str(cal / "camera.json"),
        "options": {"detector": "background", "start_s": 0.1, "end_s": None, "every": 1}, "seconds": 1.5,
        "detections": 10, "track_rows": 8}))
    publish_outputs(run, [p.name for p in run.iterdir() if p.name != MANIFEST], command="process")
    page = build_page(run, dpi=40)
    assert page.sections == ("Calibration", "GCPs and residuals", "Accuracy map", "Traffic")
    assert f"{tmp_path / 'clip.mp4'} at 0.08 s" in page.html  # the frame shown at start_s (25 fps)
    assert "<h3>Video processing</h3>" in page.html and "background" in page.html
    assert not [s for s, _ in page.left_out if s.startswith(("frame", "calibration"))]
    assert [s for s, _ in page.left_out] == ["orthophoto behind the maps"]


def test_process_rejects_a_bad_report_path_before_running(site: dict[str, Path], tmp_path: Path) -> None:
    code, _, stderr = invoke("process", tmp_path / "none.mp4", "--camera", site["camera"], "--surface", Z0,
                             "--out", tmp_path / "o", "--report-html", tmp_path / "r.txt")
    assert code == 2 and "--report-html" in stderr and ".html" in stderr
    assert not (tmp_path / "o").exists()


def test_geh_band_limits_and_flow_points() -> None:
    from trafficgeo.traffic.compare import geh

    m = np.array([0.0, 50.0, 600.0, 2400.0])
    lo, hi = F.geh_limits(m)
    np.testing.assert_allclose(geh(m, hi), 5.0, rtol=1e-9)
    np.testing.assert_allclose(geh(m[1:], lo[1:]), 5.0, rtol=1e-9)  # at 0 veh/h the band starts at 0
    table = pd.DataFrame({"observed_flow_veh_h": [600.0, 600.0, 1200.0], "simulated_flow_veh_h": [620.0, 900.0, 0.0],
                          "geh": geh(np.array([600.0, 600.0, 1200.0]), np.array([620.0, 900.0, 0.0]))})
    fig = F.observed_vs_simulated(table)
    assert len(_gid(fig, "geh-ok")[0].get_offsets()) == 1 and len(_gid(fig, "geh-high")[0].get_offsets()) == 2


def test_compare_sumo_results_are_shown(feet_run: tuple[Path, dict[str, pd.DataFrame]], tmp_path: Path) -> None:
    import shutil

    run = tmp_path / "run"
    shutil.copytree(feet_run[0], run)
    counts = pd.DataFrame({"line": ["A", "A"], "lane": ["1", "2"], "direction": [1, 1], "interval_start": [0.0, 0.0],
                           "interval_end": [60.0, 60.0], "observed": [10, 12], "simulated": [11, 30],
                           "observed_flow_veh_h": [600.0, 720.0], "simulated_flow_veh_h": [660.0, 1800.0],
                           "geh": [2.4, 30.4], "geh_ok": [True, False]})
    from trafficgeo.run.folder import RunFolder
    from trafficgeo.run.records import CompareSummary, CountSummary

    RunFolder(run).write_comparison({"compare_counts.csv": counts}, CompareSummary(CountSummary(
        rows=2, share_geh_below_5=0.5, mean_geh=16.4, total_observed=22, total_simulated=41, geh_total=8.3),
        travel_times=None, crs="EPSG:2994"))
    page = build_page(run, dpi=40)
    assert "Observed vs simulated (compare-sumo)" in page.html and "50.0 % with GEH &lt; 5" in page.html
    assert page.html.count('<tr class="outlier">') == 1
    assert len(_pngs(page.html)) == 5  # the four traffic figures and the flows figure
