"""The report's Orthophoto refinement section: a refinement of a generated scene (rough GCPs, the orthophoto and
DEM as GeoTIFFs, ``refine_camera_files``) shown on the page with the refine JSON's numbers; a refused one (the
orthophoto of another place); a missing frame; a damaged refine JSON; a report without refinement."""

from __future__ import annotations

import base64
import json
import math
import re
import shutil
from dataclasses import replace
from html import unescape
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest
from affine import Affine

from cli_support import invoke
from trafficgeo.calibration.run import run_calibration
from trafficgeo.camera.calibrated import CalibratedCamera
from trafficgeo.errors import InputError
from trafficgeo.geo.raster import write_geotiff
from trafficgeo.registration.refine_record import read_refine_record
from trafficgeo.registration.run import refine_camera_files
from trafficgeo.report import refine_figures as RF
from trafficgeo.report.context import ReportContext
from trafficgeo.report.html import build_page
from trafficgeo.report.inputs import find_inputs
from trafficgeo.report.refine_section import TITLE, refinement_section
from trafficgeo.synth.registration_scene import RegistrationSceneOptions, make_registration_scene

pytestmark = pytest.mark.slow  # two generated scenes, a refinement and a few report pages
DPI = 60  # the figures' resolution: small pages build faster

# 960x540: at 640x360 the refine defaults find fewer than 30 matches (25-27 on seeds 1-2); the orthophoto at 0.1 m
# instead of 0.05 m makes the scene twice as fast and still gives ~140 matches.
ACCEPTED = RegistrationSceneOptions(seed=1, image_size=(960, 540), ortho_resolution=0.1, supersample=2)
WRONG_PLACE = RegistrationSceneOptions(seed=1, image_size=(640, 360), ortho_resolution=0.1, half_size=60.0,
                                       supersample=1, vehicles=0, wrong_place=True)


def _refine(opts: RegistrationSceneOptions, root: Path) -> dict:
    """Calibrate the scene's rough GCPs (cal/camera.json), write its orthophoto and DEM (site/, in the orthophoto's CRS:
    the surface has none), refine into
    run/camera.json with run/refine.json beside it."""
    scene = make_registration_scene(opts)
    cal, site, run = root / "cal", root / "site", root / "run"
    for d in (cal, site, run):
        d.mkdir(parents=True)
    calibration = run_calibration(scene.gcps, scene.camera.image_size, camera_path=cal / "camera.json")
    o, s = scene.ortho, scene.surface
    write_geotiff(site / "ortho.tif", o.data, o.transform, o.crs)
    write_geotiff(site / "dem.tif", s.values, Affine(s.xres, 0.0, s.left, 0.0, -s.yres, s.top), o.crs)
    result = refine_camera_files(cal / "camera.json", scene.frame, site / "ortho.tif", str(site / "dem.tif"),
                                 run / "camera.json", report_path=run / "refine.json")
    doc = json.loads((run / "refine.json").read_text())
    return {"scene": scene, "calibration": calibration, "result": result, "doc": doc, "cal": cal, "run": run}


@pytest.fixture(scope="module")
def accepted(tmp_path_factory: pytest.TempPathFactory) -> dict:
    out = _refine(ACCEPTED, tmp_path_factory.mktemp("refine_ok"))
    assert out["result"].accepted, out["result"].reason  # the scene's orthophoto is of the right place
    out["page"] = build_page(out["run"], dpi=DPI)
    return out


@pytest.fixture(scope="module")
def refused(tmp_path_factory: pytest.TempPathFactory) -> dict:
    return _refine(WRONG_PLACE, tmp_path_factory.mktemp("refine_wrong"))


class _Section(HTMLParser):
    """The tables (rows of cell texts), paragraphs and images of one section of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: list[list[list[str]]] = []
        self.paragraphs: list[str] = []
        self.images: list[str] = []
        self._cell: list[str] | None = None
        self._p: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self.tables[-1].append([])
        elif tag in ("td", "th"):
            self._cell = []
        elif tag == "p":
            self._p = []
        elif tag == "img":
            self.images.append(dict(attrs)["src"] or "")

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1][-1].append("".join(self._cell))
            self._cell = None
        elif tag == "p" and self._p is not None:
            self.paragraphs.append("".join(self._p))
            self._p = None

    def handle_data(self, data: str) -> None:
        for buf in (self._cell, self._p):
            if buf is not None:
                buf.append(data)


def _section(html: str) -> _Section:
    m = re.search(r'<section id="refinement">(.*?)</section>', html, re.S)
    assert m is not None, "no refinement section on the page"
    parsed = _Section()
    parsed.feed(m.group(1))
    return parsed


def _f3(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def _f2(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def test_the_section_shows_the_refine_json(accepted: dict) -> None:
    page, doc, result = accepted["page"], accepted["doc"], accepted["result"]
    assert TITLE in page.sections
    assert page.sections.index(TITLE) == page.sections.index("GCPs and residuals") + 1
    sec = _section(page.html)
    assert sec.paragraphs[0].startswith("Accepted") and doc["reason"] in sec.paragraphs[0]
    assert "does not match" not in page.html  # the camera JSON's refinement block describes this report
    rms, per_point, passes, model = sec.tables
    for row, label, key in zip(rms[1:], ("check points (never fitted)", "control points, leave-one-out",
                                         "all the user's points"), ("check_rmse", "loo_rmse", "rmse"), strict=True):
        assert row[0] == label
        assert row[1:3] == [_f2(doc["before"][f"{key}_px"]), _f2(doc["after"][f"{key}_px"])]
        assert row[4:6] == [_f3(doc["before"][f"{key}_m"]), _f3(doc["after"][f"{key}_m"])]
    assert float(rms[3][2]) < float(rms[3][1])  # accepted: the pixel error went down
    # per point: the user's points (the GCPs the rough calibration kept, and the check points), in order
    judged = [g for g, ok, role in zip(accepted["scene"].gcps.ids, accepted["calibration"].calibration.inlier,
                                       accepted["scene"].gcps.roles, strict=True) if ok or role == "check"]
    assert [r[0] for r in per_point[1:]] == judged == [p["id"] for p in doc["before"]["points"]]
    for row, b, a in zip(per_point[1:], doc["before"]["points"], doc["after"]["points"], strict=True):
        assert row[1:4] == [b["role"], _f3(b["ground_error_m"]), _f3(a["ground_error_m"])]
    found, kept = len(doc["matches"]["rows"]), doc["matches_kept"]
    assert kept == result.n_kept > 30
    assert f"{found} automatic correspondences" in sec.paragraphs[2] and f"{kept} kept" in sec.paragraphs[2]
    assert [[int(r[0]), int(r[2]), int(r[3]), int(r[4])] for r in passes[1:]] == [
        [k + 1, p["tried"], p["matched"], p["kept"]] for k, p in enumerate(doc["passes"])]
    assert passes[-1][4] == str(kept)
    assert ", ".join(doc["model"]) in sec.paragraphs[3]
    assert model[1][:3] == ["focal length fx", f'{doc["original_camera"]["K"][0][0]:.1f}',
                            f'{doc["refined_camera"]["K"][0][0]:.1f}']
    # the figure: the frame with the matches, embedded as PNG, the factor stated
    (src,) = sec.images
    png = cv2.imdecode(np.frombuffer(base64.b64decode(src.removeprefix("data:image/png;base64,")), np.uint8),
                       cv2.IMREAD_COLOR)
    assert png is not None and png.shape[1] == round(RF.FIGURE_WIDTH_IN * DPI)
    assert "magnified x5" in page.html
    assert ("orthophoto refinement report", str(accepted["run"] / "refine.json")) in [
        tuple(r) for r in re.findall(r"<tr><th>input: ([^<]*)</th><td>([^<]*)</td></tr>", page.html)]
    assert not [s for s, _ in page.left_out if "refinement" in s or "matches" in s]


def test_a_refused_refinement_says_so_and_why(refused: dict, tmp_path: Path) -> None:
    doc, run = refused["doc"], refused["run"]
    assert doc["accepted"] is False and doc["reason"]
    camera = json.loads((run / "camera.json").read_text())  # the original camera, its refinement naming the report
    assert camera["refinement"]["accepted"] is False and find_inputs(run).refine_report == run / "refine.json"
    for name in ("refine.json", "refine_frame.jpg"):  # the page of the refinement alone: no calibration figures
        shutil.copy(run / name, tmp_path / name)
    page = build_page(tmp_path, refine_report=tmp_path / "refine.json", dpi=DPI)
    assert page.sections == (TITLE,)
    sec = _section(page.html)
    assert sec.paragraphs[0] == f"Refused: the camera JSON keeps the original camera. Reason: {doc['reason']}."
    assert unescape(doc["reason"]) in unescape(page.html)
    rms = sec.tables[0]
    assert rms[3][1:3] == [_f2(doc["before"]["rmse_px"]), _f2(doc["after"] and doc["after"]["rmse_px"])]
    assert rms[3][4:6] == [_f3(doc["before"]["rmse_m"]), _f3(doc["after"] and doc["after"]["rmse_m"])]


def test_the_section_without_its_frame_says_so(accepted: dict, tmp_path: Path) -> None:
    shutil.copy(accepted["run"] / "refine.json", tmp_path / "refine.json")  # not its refine_frame.jpg
    page = build_page(tmp_path, refine_report=tmp_path / "refine.json", dpi=DPI)
    assert page.sections == (TITLE,)
    sec = _section(page.html)
    assert len(sec.images) == 1 and any("drawn without the picture" in p for p in sec.paragraphs)
    assert any(s == "frame behind the orthophoto matches" and "refine_frame.jpg is missing" in r
               for s, r in page.left_out)


def test_the_figure_draws_known_matches() -> None:
    found = np.array([[100.0, 50.0], [200.0, 80.0], [300.0, 120.0]])
    predicted = found + [[1.0, 0.0], [0.0, -2.0], [0.5, 0.5]]
    kept = np.array([True, False, True])
    fig = RF.matches_on_frame(found, predicted, kept, (640, 360))
    ax = fig.axes[0]
    by_gid = {a.get_gid(): a for a in [*ax.collections]}
    assert len(by_gid["refine-kept"].get_offsets()) == 2 and len(by_gid["refine-rejected"].get_offsets()) == 1
    segments = by_gid["refine-shift-kept"].get_segments()
    np.testing.assert_allclose([s[0] for s in segments], found[kept] + 5.0 * (predicted[kept] - found[kept]))
    np.testing.assert_allclose([s[1] for s in segments], found[kept])
    np.testing.assert_allclose(by_gid["refine-shift-rejected"].get_segments()[0], [[200.0, 70.0], [200.0, 80.0]])
    assert "x5" in ax.get_title()


@pytest.mark.parametrize("damage, key", [
    (lambda d: d["before"].update(rmse_m="1.2 m"), "before.rmse_m"),
    (lambda d: d.pop("passes"), "passes"),
    (lambda d: d["matches"]["rows"][0].__setitem__(10, "yes"), "matches.rows[0].kept"),
    (lambda d: d.update(format="trafficgeo-refine/0"), "format"),
    (lambda d: d.update(frame="../elsewhere.jpg"), "frame"),
])
def test_a_damaged_refine_json_is_a_one_line_error(accepted: dict, tmp_path: Path, damage: object, key: str) -> None:
    doc = json.loads(json.dumps(accepted["doc"]))
    damage(doc)  # type: ignore[operator]
    bad = tmp_path / "refine.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(InputError) as err:
        read_refine_record(bad)
    msg = str(err.value)
    assert "\n" not in msg and str(bad) in msg and f"'{key}'" in msg
    code, _, stderr = invoke("report", tmp_path, "-o", tmp_path / "r.html", "--refine-report", bad)
    assert code == 2 and stderr.strip() == f"trafficgeo: error: {msg}" and not (tmp_path / "r.html").exists()


def test_a_broken_report_named_by_the_camera_fails_before_any_work(accepted: dict, tmp_path: Path) -> None:
    shutil.copy(accepted["run"] / "camera.json", tmp_path / "camera.json")
    (tmp_path / "refine.json").write_text('{"format": "trafficgeo-refine/1", "accepted": ')
    with pytest.raises(InputError, match=r"refine\.json: not readable JSON"):
        build_page(tmp_path)


def test_a_report_without_refinement_has_no_section(accepted: dict) -> None:
    page = build_page(accepted["cal"], dpi=DPI)  # the rough calibration's camera JSON: no refinement block
    assert TITLE not in page.sections and 'id="refinement"' not in page.html
    assert page.sections == tuple(s for s in accepted["page"].sections if s != TITLE)
    assert not [s for s, r in page.left_out if "refine" in s.lower() or "refine" in r.lower()]


def test_a_camera_json_from_another_refinement_is_pointed_out(accepted: dict) -> None:
    run = accepted["run"]
    b = ReportContext(inputs=find_inputs(run), dpi=DPI)
    camera = CalibratedCamera.read(run / "camera.json")
    other = replace(camera.refinement, matches_kept=camera.refinement.matches_kept + 5, after_rmse_m=math.nan)
    b.calibrated = replace(camera, refinement=other)
    section = refinement_section(b, read_refine_record(run / "refine.json"))
    assert section is not None
    (warning,) = [x.text for x in section.parts[0] if getattr(x, "css", "") == "warn"]
    kept = accepted["doc"]["matches_kept"]
    assert f"matches_kept {kept + 5} against {kept}" in warning and "after_rmse_m None against" in warning
    assert "accepted" not in warning and "before_rmse_m" not in warning


def test_a_missing_report_named_by_the_camera_is_noted(accepted: dict, tmp_path: Path) -> None:
    shutil.copy(accepted["run"] / "camera.json", tmp_path / "camera.json")  # names refine.json, not copied
    inputs = find_inputs(tmp_path)
    assert inputs.refine_report is None and inputs.refine_named == "refine.json"
    b = ReportContext(inputs=inputs, dpi=100)
    assert refinement_section(b, None) is None
    assert [s for s, r in b.left_out] == ["orthophoto refinement"] and "--refine-report" in b.left_out[0][1]
    assert find_inputs(tmp_path, refine_report=accepted["run"] / "refine.json").refine_report == \
        accepted["run"] / "refine.json"
