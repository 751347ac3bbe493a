"""gcp-ui end to end in a real headless Chromium (Debian's /usr/bin/chromium driven by Playwright; no download).

The server runs in-process on a free port over a generated scene with known truth. GCPs are picked by clicking in
the two Leaflet maps at the true positions of lane-marking corners (click positions come from the map's own
latLngToContainerPoint), then the autosaved CSV, the live residuals in the page and the saved camera are checked.

Without Chromium these tests FAIL (set TRAFFICGEO_SKIP_BROWSER=1 to skip them); TRAFFICGEO_CHROMIUM points at
another Chromium binary.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from trafficgeo.calibration import read_gcps
from trafficgeo.camera.calibrated import read_camera_json
from trafficgeo.ui.server import BackgroundServer, create_app
from trafficgeo.ui.startup import open_session
from ui_support import CRS, ORTHO_RES, Scene, shared_scene

pytestmark = pytest.mark.slow  # drives Chromium

CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
ZOOM = 3  # 8 screen pixels per image pixel while clicking
TIMEOUT_MS = 15_000

CLICK_JS = """([kind, a, b, zoom]) => {
  const m = kind === "frame" ? gcpui.frameMap : gcpui.orthoMap;
  const ll = L.latLng(-b, a);
  m.setView(ll, zoom, {animate: false});
  const p = m.latLngToContainerPoint(ll);
  const c = m.getContainer();
  const r = c.getBoundingClientRect();
  return [r.left + c.clientLeft + p.x, r.top + c.clientTop + p.y];
}"""
SYNCED_JS = """n => gcpui.state && gcpui.state.pairs.length === n && gcpui.calibration
  && gcpui.calibration.revision === gcpui.state.revision"""


def chromium_executable() -> str:
    """The Chromium to drive; fails (does not skip) when it is missing, unless TRAFFICGEO_SKIP_BROWSER=1."""
    if os.environ.get("TRAFFICGEO_SKIP_BROWSER") == "1":
        pytest.skip("browser tests skipped: TRAFFICGEO_SKIP_BROWSER=1")
    path = os.environ.get("TRAFFICGEO_CHROMIUM") or "/usr/bin/chromium"
    if not (Path(path).is_file() and os.access(path, os.X_OK)):
        pytest.fail(f"Chromium not found at {path}: the gcp-ui browser tests need it. Install Debian's chromium "
                    "('make test' does: apt-get install chromium), set TRAFFICGEO_CHROMIUM to another Chromium "
                    "binary, or set TRAFFICGEO_SKIP_BROWSER=1 to skip these tests.", pytrace=False)
    return path


def test_chromium_is_available():
    assert Path(chromium_executable()).is_file()


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Scene:
    return shared_scene(tmp_path_factory)


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    exe = chromium_executable()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        ctx = pw.chromium.launch_persistent_context(
            str(tmp_path_factory.mktemp("chromium-profile")), executable_path=exe, args=CHROMIUM_ARGS,
            headless=True, viewport={"width": 1400, "height": 900}, timeout=30_000)
        try:
            yield ctx
        finally:
            ctx.close()


@pytest.fixture()
def app_page(browser, scene, tmp_path):
    """A fresh session and server for one test, and a page showing it; yields (page, session, work, requests)."""
    for p in (scene.frame, scene.ortho, scene.dem):
        shutil.copy(p, tmp_path / p.name)
    session, _ = open_session(frame=tmp_path / "frame.png", ortho=tmp_path / "ortho.tif", dem=tmp_path / "dem.tif",
                              gcps=tmp_path / "gcps.csv")
    with BackgroundServer(create_app(session)) as url:
        page = browser.new_page()
        page.set_default_timeout(TIMEOUT_MS)
        requests: list[str] = []
        errors: list[str] = []
        page.on("request", lambda r: requests.append(r.url))
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        page.wait_for_function("window.gcpui && window.gcpui.ready")
        try:
            yield page, session, tmp_path, requests
            assert not errors, errors
            assert requests and all(r.startswith(url) for r in requests), requests  # nothing from outside
        finally:
            page.close()


def click(page, kind: str, a: float, b: float) -> None:
    """Click the frame at pixel (u=a, v=b) or the orthophoto at raster position (col=a, row=b)."""
    x, y = page.evaluate(CLICK_JS, [kind, float(a), float(b), ZOOM])
    page.mouse.click(x, y)


def pick(page, scene: Scene, i: int, j: int | None = None, n: int | None = None) -> None:
    """Pair the frame pixel of feature i with the orthophoto position of feature j (default i)."""
    j = i if j is None else j
    click(page, "frame", *scene.truth_pixels[i])
    click(page, "ortho", *scene.truth_ortho[j])
    if n is not None:
        page.wait_for_function(SYNCED_JS, arg=n)


def cell(page, pair_id: str, name: str) -> str:
    return page.locator(f'#pairs tr[data-id="{pair_id}"] td.{name}').inner_text()


def test_pick_pairs_by_clicking_and_calibrate_live(app_page, scene):
    page, _, work, _ = app_page
    for i in range(7):
        pick(page, scene, i, n=i + 1)
    assert page.inner_text("#calib-status") == "Calibrated"
    # The autosaved CSV: ids, the clicked pixels, x, y of the features, z from the DEM.
    t = read_gcps(work / "gcps.autosave.csv", crs=CRS)
    assert t.ids == tuple(f"P{k}" for k in range(1, 8)) and set(t.roles) == {"control"}
    np.testing.assert_allclose(t.pixels, scene.truth_pixels[:7], atol=0.15)  # 1 screen px = 0.125 image px
    np.testing.assert_allclose(t.world[:, :2], scene.truth_world[:7, :2], atol=0.15 * ORTHO_RES)
    np.testing.assert_allclose(t.world[:, 2], scene.dem_surface.elevation(t.world[:, 0], t.world[:, 1]), atol=1e-9)
    np.testing.assert_allclose(t.world[:, 2], scene.truth_world[:7, 2], atol=0.01)
    # Live residuals in the page: small for correct pairs, with vectors on the frame, a grid and a footprint.
    for k in range(1, 8):
        assert float(cell(page, f"P{k}", "err")) < 1.0
        assert float(cell(page, f"P{k}", "loo")) < 3.0
        assert cell(page, f"P{k}", "status") == "inlier"
    assert page.locator("#frame-map path.residual").count() == 7
    assert page.locator("#frame-map path.grid-line").count() >= 4
    assert page.locator("#ortho-map path.grid-line").count() >= 4
    assert page.locator("#ortho-map path.footprint").count() == 1
    # A deliberately wrong pair: large residual, flagged as outlier in the table and on both maps.
    pick(page, scene, 8, 9, n=8)
    row = page.locator('#pairs tr[data-id="P8"]')
    assert "outlier" in (row.get_attribute("class") or "")
    assert cell(page, "P8", "status") == "outlier"
    assert float(cell(page, "P8", "err")) > 20
    assert "wrong click" in page.locator('#pairs tr[data-id="P8"] td.status').get_attribute("title")
    assert max(float(cell(page, f"P{k}", "err")) for k in range(1, 8)) < 1.0
    assert page.locator(".gcp-icon.outlier").count() == 2
    assert page.locator("#frame-map path.residual-outlier").count() == 1
    # Delete it with its button, rename and re-role others in the table.
    page.locator('#pairs tr[data-id="P8"] button.delete').click()
    page.wait_for_function(SYNCED_JS, arg=7)
    page.locator('#pairs tr[data-id="P1"] input.id').fill("A1")
    page.locator('#pairs tr[data-id="P1"] input.id').press("Enter")
    page.wait_for_selector('#pairs tr[data-id="A1"]')
    page.locator('#pairs tr[data-id="P7"] select').select_option("check")
    page.wait_for_function("gcpui.calibration.n_check === 1 && gcpui.calibration.revision === gcpui.state.revision")
    assert cell(page, "P7", "status") == "check"
    t = read_gcps(work / "gcps.autosave.csv", crs=CRS)
    assert t.ids == ("A1", "P2", "P3", "P4", "P5", "P6", "P7") and t.roles[-1] == "check"
    # Save the GCPs and the calibrated camera from the page.
    page.locator("#save-csv").click()
    page.wait_for_function("document.getElementById('message').textContent.startsWith('saved 7 GCPs')")
    assert read_gcps(work / "gcps.csv", crs=CRS).ids == t.ids
    page.locator("#camera-name").fill("cam.json")
    page.locator("#save-camera").click()
    page.wait_for_function("document.getElementById('message').textContent.startsWith('saved the camera')")
    cam = read_camera_json(work / "cam.json")
    np.testing.assert_allclose(cam.position, scene.camera.position, atol=0.5)
    # A bad file name is refused with the server's message, shown in the page.
    page.locator("#camera-name").fill("../cam.json")
    page.locator("#save-camera").click()
    page.wait_for_function("document.getElementById('message').className === 'error'")
    assert "leaves the working folder" in page.inner_text("#message")
    assert not (work.parent / "cam.json").exists()


def test_drag_markers_and_cancel_a_pending_click(app_page, scene):
    page, session, work, _ = app_page
    # Esc cancels a half-made pair.
    click(page, "frame", *scene.truth_pixels[3])
    assert page.locator(".gcp-icon.pending").count() == 1
    page.keyboard.press("Escape")
    assert page.locator(".gcp-icon.pending").count() == 0
    pick(page, scene, 0, n=1)
    before = session.pairs[0]
    # Drag the frame marker by (+16, +8) screen pixels = (+2, +1) frame pixels at zoom 3.
    x, y = page.evaluate(CLICK_JS, ["frame", before.u, before.v, ZOOM])
    page.mouse.move(x, y)
    page.mouse.down()
    for k in range(1, 5):
        page.mouse.move(x + 4 * k, y + 2 * k)
    page.mouse.up()
    page.wait_for_function("gcpui.state.revision >= 2 && gcpui.state.pairs[0].u !== " + repr(before.u))
    moved = session.pairs[0]
    assert moved.u - before.u == pytest.approx(2.0, abs=0.15) and moved.v - before.v == pytest.approx(1.0, abs=0.15)
    assert (moved.x, moved.y, moved.z) == (before.x, before.y, before.z)
    # Drag the orthophoto marker by (-24, +16) screen pixels = (-3, +2) orthophoto pixels: x, y and z follow.
    col, row = scene.truth_ortho[0]
    x, y = page.evaluate(CLICK_JS, ["ortho", col, row, ZOOM])
    page.mouse.move(x, y)
    page.mouse.down()
    for k in range(1, 5):
        page.mouse.move(x - 6 * k, y + 4 * k)
    page.mouse.up()
    page.wait_for_function("gcpui.state.pairs[0].x !== " + repr(before.x))
    after = session.pairs[0]
    assert after.x - before.x == pytest.approx(-3 * ORTHO_RES, abs=0.02)
    assert after.y - before.y == pytest.approx(-2 * ORTHO_RES, abs=0.02)
    assert after.z == pytest.approx(float(scene.dem_surface.elevation(after.x, after.y)), abs=1e-9)
    t = read_gcps(work / "gcps.autosave.csv", crs=CRS)
    assert tuple(t.world[0]) == (after.x, after.y, after.z) and tuple(t.pixels[0]) == (after.u, after.v)
