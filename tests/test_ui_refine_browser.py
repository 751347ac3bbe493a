"""gcp-ui "Refine from orthophoto" in a real headless Chromium: the button, its busy state, the verdict, the match
dots drawn on their frame pixels, the toggle that hides them, and saving the refined camera.

Uses the browser fixture of test_ui_browser (Debian's Chromium through Playwright; without it these tests FAIL
unless TRAFFICGEO_SKIP_BROWSER=1) and the registration scene of ui_refine_support.
"""

from __future__ import annotations

import json
import shutil

import pytest

import test_ui_browser
from test_ui_browser import SYNCED_JS, TIMEOUT_MS
from trafficgeo.ui.server import BackgroundServer, create_app
from trafficgeo.ui.startup import open_session
from ui_refine_support import shared_refine_scene

pytestmark = pytest.mark.slow  # drives Chromium over a generated registration scene

browser = test_ui_browser.browser  # the browser fixture of test_ui_browser

# For every drawn match dot: the centre of its element on the screen mapped back to a frame pixel through the map,
# the screen offset of that centre from the screen point of the dot's own pixel, and whether the dot is kept.
DOTS_JS = """() => {
  const m = gcpui.frameMap, c = m.getContainer(), box = c.getBoundingClientRect();
  const out = [];
  for (const layer of gcpui.layers.refineMatches.getLayers()) {
    if (!(layer instanceof L.CircleMarker)) continue;
    const el = layer.getElement();
    const r = el.getBoundingClientRect();
    if (!r.width) continue;  // outside the view
    const x = r.left + r.width / 2 - box.left - c.clientLeft, y = r.top + r.height / 2 - box.top - c.clientTop;
    const ll = m.containerPointToLatLng([x, y]);
    const want = m.latLngToContainerPoint(layer.getLatLng());
    out.push([ll.lng, -ll.lat, x - want.x, y - want.y, el.classList.contains("refine-kept")]);
  }
  return out;
}"""


@pytest.fixture(scope="module")
def refine_page(browser, tmp_path_factory):
    """A session on the registration scene with the user's 11 rough GCPs, and a page showing it."""
    rs = shared_refine_scene(tmp_path_factory)
    work = tmp_path_factory.mktemp("refine-browser")
    for p in (rs.frame, rs.ortho, rs.dem, rs.gcps):
        shutil.copy(p, work / p.name)
    session, _ = open_session(frame=work / "frame.png", ortho=work / "ortho.tif", dem=work / "dem.tif",
                              gcps=work / "gcps.csv")
    with BackgroundServer(create_app(session)) as url:
        page = browser.new_page()
        page.set_default_timeout(TIMEOUT_MS)
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        page.wait_for_function("window.gcpui && window.gcpui.ready")
        page.wait_for_function(SYNCED_JS, arg=rs.scene.gcps.n)
        try:
            yield page, session, work
            assert not errors, errors
        finally:
            page.close()


def test_refine_button_draws_the_matches_on_their_pixels(refine_page):
    page, session, work = refine_page
    assert page.locator("#refine-status").inner_text() == ""
    page.locator("#refine").click()
    page.wait_for_function("gcpui.refining && document.getElementById('refine').disabled")
    assert page.locator("#refine-status").inner_text().startswith("Refining")
    page.wait_for_function("!gcpui.refining", timeout=90_000)
    assert page.locator("#refine-status").inner_text() == "Refinement accepted", page.inner_text("#message")
    assert not page.locator("#refine").is_disabled()
    ans = page.evaluate("gcpui.refine")
    n_kept, n = ans["n_kept"], ans["n_matches"]
    assert n_kept > 30
    details = page.inner_text("#refine-details")
    assert f"{n_kept} of {n} matches kept" in details and "held-out error at your GCPs" in details
    assert f"{ans['before']['rmse_px']:.2f} px → {ans['after']['rmse_px']:.2f} px" in details
    assert f"{ans['before']['rmse_m']:.3f} m → {ans['after']['rmse_m']:.3f} m" in details
    assert page.locator("#frame-map path.refine-match.refine-kept").count() == n_kept
    assert page.locator("#frame-map path.refine-match.refine-rejected").count() == n - n_kept
    assert page.locator("#frame-map path.refine-vector").count() == n
    # Every dot sits on its frame pixel: its screen centre maps back to the pixel of a match within 1 frame px at
    # the fitted zoom, and lies within 1 screen px (1/8 frame px) of the pixel's screen point at zoom 3.
    kept = [(m["u"], m["v"]) for m in ans["matches"] if m["kept"]]
    rows = page.evaluate(DOTS_JS)
    assert len(rows) == n
    for u, v, dx, dy, is_kept in rows:
        nearest = min(kept if is_kept else [(m["u"], m["v"]) for m in ans["matches"]],
                      key=lambda p: (p[0] - u) ** 2 + (p[1] - v) ** 2)
        assert abs(nearest[0] - u) <= 1.0 and abs(nearest[1] - v) <= 1.0, (u, v, nearest)
        assert abs(dx) <= 1.0 and abs(dy) <= 1.0
    u0, v0 = kept[len(kept) // 2]
    page.evaluate("([u, v]) => gcpui.frameMap.setView(L.latLng(-v, u), 3, {animate: false})", [u0, v0])
    rows = [r for r in page.evaluate(DOTS_JS) if r[4]]
    assert rows
    u, v, dx, dy, _ = min(rows, key=lambda r: (r[0] - u0) ** 2 + (r[1] - v0) ** 2)
    assert abs(u - u0) <= 0.125 and abs(v - v0) <= 0.125 and abs(dx) <= 1.0 and abs(dy) <= 1.0
    # The toggle hides and shows them.
    page.locator("#show-matches").uncheck()
    assert page.locator("#frame-map path.refine-match").count() == 0
    page.locator("#show-matches").check()
    assert page.locator("#frame-map path.refine-match").count() == n
    # Save the refined camera from the page.
    page.locator("#refined-name").fill("cam_refined.json")
    page.locator("#save-refined").click()
    page.wait_for_function("document.getElementById('message').textContent.startsWith('saved the refined camera')")
    doc = json.loads((work / "cam_refined.json").read_text())
    assert doc["refinement"]["accepted"] is True and doc["refinement"]["matches_kept"] == n_kept
    assert (work / "refine.json").is_file() and (work / "refine_frame.jpg").is_file()
    # A changed pair makes the refinement stale: no save button until refined again.
    p = session.pairs[0]
    session.update_pair(p.id, u=p.u + 0.5)
    page.evaluate("() => document.querySelector('#pairs tr select').dispatchEvent(new Event('change'))")
    page.wait_for_function("gcpui.state.revision !== gcpui.refine.revision")
    page.wait_for_function("document.getElementById('refine-save').hidden")
    assert "refine again" in page.inner_text("#refine-details")
