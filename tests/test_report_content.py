"""What the report page says, read back from the HTML as a browser shows it (tags, decoded text), against truth known
from how the inputs were made (not from the report code): the sections and their figures, the per-line table of a
traffic run, the vehicles per class and lane, the counts per interval, and the per-GCP table of a calibration."""

from __future__ import annotations

from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cli_support import invoke
from test_report_html import BAD_ID, SIZE, _gcps, _synthetic_run
from trafficgeo.camera.model import Camera
from trafficgeo.report.html import build_page

pytestmark = pytest.mark.slow  # renders full report pages with figures

# _synthetic_run's vehicles: (lane, speed m/s, start s), points every 1 s for 8 s, a line at y = 50 m crossed by all
LANES = [("a", 10.0, 0.0), ("a", 12.0, 3.0), ("a", 8.0, 6.0), ("b", -11.0, 1.0), ("b", -9.0, 4.0)]
PERIOD_S = 18.0


class Page(HTMLParser):
    """The page as sections: for each section id, its headings, figures (img alt), tables (rows of cell texts),
    paragraphs and list items, all as decoded text."""

    def __init__(self, html: str) -> None:
        super().__init__(convert_charrefs=True)
        self.sections: dict[str, dict[str, list]] = {}
        self.nav: list[str] = []
        self.header: dict[str, str] = {}
        self._sec: dict[str, list] | None = None
        self._text: list[str] | None = None
        self._row: list[str] | None = None
        self._table: list[list[str]] | None = None
        self._stack: list[str] = []
        self.feed(html)
        self.close()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        self._stack.append(tag)
        if tag == "section":
            self._sec = self.sections.setdefault(a["id"] or "", {"h2": [], "h3": [], "h4": [], "img": [], "table": [],
                                                                 "p": [], "li": []})
        elif tag == "a" and "nav" in self._stack:
            self.nav.append((a.get("href") or "").lstrip("#"))
        elif tag == "img" and self._sec is not None:
            self._sec["img"].append(a.get("alt") or "")
        elif tag == "table":
            self._table = []
        elif tag == "tr":
            self._row = []
        if tag in ("h2", "h3", "h4", "p", "li", "td", "th"):
            self._text = []

    def handle_data(self, data: str) -> None:
        if self._text is not None:
            self._text.append(data)

    def handle_endtag(self, tag: str) -> None:
        self._stack.pop()
        text = "".join(self._text) if self._text is not None else ""
        if tag in ("td", "th") and self._row is not None:
            self._row.append(text)
        elif tag == "tr" and self._table is not None and self._row is not None:
            self._table.append(self._row)
            if self._sec is None and len(self._row) == 2:  # the header's (label, value) rows
                self.header[self._row[0]] = self._row[1]
        elif tag == "table" and self._sec is not None and self._table is not None:
            self._sec["table"].append(self._table)
        elif tag in ("h2", "h3", "h4", "p", "li") and self._sec is not None:
            self._sec[tag].append(text)
        elif tag == "section":
            self._sec = None
        if tag in ("h2", "h3", "h4", "p", "li", "td", "th"):
            self._text = None


def _table(sec: dict[str, list], *columns: str) -> list[list[str]]:
    """The one table of the section whose header starts with ``columns``."""
    (t,) = [t for t in sec["table"] if t[0][:len(columns)] == list(columns)]
    return t


def _f(x: float, nd: int) -> str:
    return f"{x:.{nd}f}"


@pytest.fixture(scope="module")
def feet_page(tmp_path_factory: pytest.TempPathFactory) -> Page:
    folder = tmp_path_factory.mktemp("content") / "run"
    _synthetic_run(folder, "EPSG:2994", 0.3048)
    return Page(build_page(folder, dpi=30).html)


def test_traffic_page_sections_figures_and_header(feet_page: Page) -> None:
    assert list(feet_page.sections) == ["traffic-1", "left-out"] and feet_page.nav == ["traffic-1", "left-out"]
    sec = feet_page.sections["traffic-1"]
    assert sec["h2"] == ["Traffic"] and sec["h3"] == ["Vehicles", "Counts and speeds per line and lane",
                                                      "Counts per interval"]
    assert [alt.split(" ")[0] for alt in sec["img"]] == ["World", "Time-space", "Distribution", "Vehicles"]
    assert "EPSG:2994" in feet_page.header["CRS"] and "units ft (1 ft = 0.3048 m)" in feet_page.header["CRS"]
    assert "a <b>warning</b>" in sec["li"]  # shown as text
    left = feet_page.sections["left-out"]["li"]
    assert any(x.startswith("calibration: no camera.json") for x in left)


def test_per_line_table_matches_the_crossings(feet_page: Page) -> None:
    rows = _table(feet_page.sections["traffic-1"], "line", "lane", "direction", "vehicles", "flow veh/h")[1:]
    expect = []
    for lane, direction in (("a", "+1"), ("b", "-1")):
        v = [(abs(s) * 3.6, t0 + (50.0 - (0.0 if s > 0 else 100.0)) / s) for ln, s, t0 in LANES if ln == lane]
        kmh = np.array([k for k, _ in v])
        times = np.sort([t for _, t in v])
        expect.append(["L", lane, direction, str(len(v)), _f(len(v) * 3600.0 / PERIOD_S, 0), _f(kmh.mean(), 1),
                       _f(len(kmh) / np.sum(1.0 / kmh), 1), _f(np.percentile(kmh, 85), 1),
                       _f((times[-1] - times[0]) / (len(times) - 1), 1)])
    assert rows == expect
    assert expect[0][3:6] == ["3", "600", "36.0"] and expect[1][3:5] == ["2", "400"]  # the truth itself, by hand


def test_vehicle_tables_per_class_and_lane(feet_page: Page) -> None:
    sec = feet_page.sections["traffic-1"]
    speeds = np.array([abs(s) * 3.6 for _, s, _ in LANES])
    (row,) = _table(sec, "class")[1:]
    assert row == ["car", "5", _f(np.median(speeds), 1), _f(speeds.mean(), 1), _f(np.percentile(speeds, 15), 1),
                   _f(np.percentile(speeds, 85), 1), "0.50", "-", "-", "8.0", _f(np.median(speeds * 8 / 3.6), 1)]
    lanes = _table(sec, "main lane")[1:]
    for lane, row in zip(("a", "b"), lanes, strict=True):
        sp = np.array([abs(s) * 3.6 for ln, s, _ in LANES if ln == lane])
        assert row == [lane, str(sp.size), _f(np.median(sp), 1), _f(np.percentile(sp, 15), 1),
                       _f(np.percentile(sp, 85), 1), "0.50", "0"]


def test_counts_per_interval_and_run_summary(feet_page: Page) -> None:
    sec = feet_page.sections["traffic-1"]
    counts = _table(sec, "line", "lane", "direction", "from s", "to s", "vehicles")
    expect = []
    for lane, direction in (("a", "+1"), ("b", "-1")):
        times = [t0 + (50.0 - (0.0 if s > 0 else 100.0)) / s for ln, s, t0 in LANES if ln == lane]
        for e in (0.0, 5.0, 10.0, 15.0):
            expect.append(["L", lane, direction, _f(e, 1), _f(e + 5, 1), str(sum(e <= t < e + 5 for t in times))])
    assert counts[0] == ["line", "lane", "direction", "from s", "to s", "vehicles"] and counts[1:] == expect
    summary = {r[0]: r[1:] for r in _table(sec, "quantity")[1:]}
    assert summary["observed period"] == ["0.00 to 18.00", "s"] and summary["vehicles"] == ["5", ""]
    assert summary["track points / rejected as outliers"] == [f"{5 * 9} / 0", ""]
    assert summary["points not used, by reason"] == ["too_far 3", ""]
    assert summary["counting interval"] == ["5.00", "s"]


def test_calibration_page_gcp_table_and_camera(tmp_path: Path, roadside_camera: Camera) -> None:
    cam = roadside_camera
    gcps = _gcps(cam)
    gcps.to_csv(tmp_path / "gcps.csv", index=False)
    (tmp_path / "cal").mkdir()
    code, _, err = invoke("calibrate", tmp_path / "gcps.csv", "--image-size", "1920x1080", "--crs", "EPSG:32633",
                          "-o", tmp_path / "cal" / "camera.json", "--report", tmp_path / "cal" / "report.json", "-q")
    assert code == 0, err
    page = Page(build_page(tmp_path / "cal", dpi=30).html)
    assert list(page.sections) == ["calibration", "gcps", "accuracy", "left-out"]
    assert [len(page.sections[s]["img"]) for s in page.sections] == [0, 3, 1, 0]
    cal = page.sections["calibration"]
    camera = {r[0]: r[1:] for r in _table(cal, "quantity", "value", "unit", "1-sigma")[1:]}
    pos = [float(v) for v in camera["position X, Y, Z"][0].split(", ")]
    np.testing.assert_allclose(pos, cam.position, atol=0.5)  # the camera the GCPs were made with
    assert camera["image size"][0] == f"{SIZE[0]} x {SIZE[1]}"
    table = _table(page.sections["gcps"], "id")
    head, rows = table[0], table[1:]
    got = pd.DataFrame(rows, columns=head)
    assert got["id"].tolist() == gcps["id"].tolist() and BAD_ID in got["id"].tolist()
    assert got["role"].tolist() == gcps["role"].tolist()
    assert got.loc[got["id"] == "P3", "status"].item() == "outlier"  # the 30 px wrong click
    assert (got.loc[got["role"] == "check", "status"] == "check").all()
    np.testing.assert_allclose(got["u"].astype(float), gcps["u"], atol=0.051)  # the clicked pixels, 1 decimal
    true_du = cam.project(gcps[["x", "y", "z"]].to_numpy())[:, 0] - gcps["u"].to_numpy()
    inl = (got["status"] == "inlier").to_numpy()
    np.testing.assert_allclose(got["du"].astype(float)[inl], true_du[inl], atol=1.5)  # 0.5 px noise + fit error
    assert float(got.loc[got["id"] == "P3", "du"].item()) == pytest.approx(-30.0, abs=3.0)


def test_per_line_table_names_directions_lists_zeros_and_gives_flows_only_over_a_long_enough_window() -> None:
    """Issue 42: the report printed 1588 veh/h from a 6.8 s clip, left out lines nobody crossed and said only
    +1/-1. A line drawn west to east: +1 (left to right looking along it) is south-bound."""
    from types import SimpleNamespace

    from shapely.geometry import LineString

    from trafficgeo.report.traffic_sections import _crossing_table, crossing_bound

    east = LineString([(0.0, 0.0), (10.0, 0.0)])
    assert (crossing_bound(east, 1), crossing_bound(east, -1)) == ("S-bound", "N-bound")
    diagonal = LineString([(5e6, 5e6), (5e6 + 3.0, 5e6 + 3.0)])  # SW -> NE, far from the origin
    assert (crossing_bound(diagonal, 1), crossing_bound(diagonal, -1)) == ("SE-bound", "NW-bound")
    crossings = pd.DataFrame({"line": ["L", "L", "L"], "lane": ["", "", ""], "direction": [1, 1, 1],
                              "time": [1.0, 3.0, 5.0], "speed_kmh": [40.0, 42.0, 44.0], "class": ["car"] * 3,
                              "vehicle": ["1", "2", "3"], "track_id": ["1", "2", "3"]})
    lines = {"L": east, "quiet": LineString([(0.0, 50.0), (0.0, 60.0)])}

    def rows(period_s: float) -> tuple[list[list[str]], list[str]]:
        summary = SimpleNamespace(period_s=(0.0, period_s), options={"interval_s": 60.0})
        part = _crossing_table(crossings, summary, lines)  # type: ignore[arg-type]
        tab = part[0]
        return [[c.text for c in r] for r in tab.rows], [
            getattr(b, "text", "") for b in part[1:]]

    short, notes = rows(6.8)
    assert [r[:5] for r in short] == [["L", "-", "+1 (S-bound)", "3", "-"], ["quiet", "-", "-1 (W-bound)", "0", "-"],
                                      ["quiet", "-", "+1 (E-bound)", "0", "-"]]
    assert any("No flows (veh/h): 6.8 s were observed" in t for t in notes)
    long, notes = rows(60.0)
    assert long[0][4] == "180" and long[1][4] == "0" and not notes
