"""gcp-ui in a real headless Chromium: markers are drawn on their points, and a GCP never moves unless dragged.

Uses the browser, scene and page fixtures of test_ui_browser (Debian's Chromium through Playwright; without it
these tests FAIL unless TRAFFICGEO_SKIP_BROWSER=1).
"""

from __future__ import annotations

import numpy as np
import pytest

import test_ui_browser
from test_ui_browser import CLICK_JS, SYNCED_JS, ZOOM, pick

pytestmark = pytest.mark.slow  # drives Chromium (the fixtures of test_ui_browser)

# the browser, scene and page fixtures of test_ui_browser
browser, scene, app_page = test_ui_browser.browser, test_ui_browser.scene, test_ui_browser.app_page

# For every GCP marker of one map: the centre of its element and of its cross, and the screen point of its pair.
MARKER_OFFSETS_JS = """kind => {
  const m = kind === "frame" ? gcpui.frameMap : gcpui.orthoMap;
  const out = [];
  for (const p of gcpui.state.pairs) {
    const mk = gcpui.markers.get(p.id)[kind];
    const ll = kind === "frame" ? L.latLng(-p.v, p.u) : L.latLng(-p.row, p.col);
    const want = m.latLngToContainerPoint(ll);
    const c = m.getContainer().getBoundingClientRect();
    const x0 = c.left + m.getContainer().clientLeft + want.x, y0 = c.top + m.getContainer().clientTop + want.y;
    for (const el of [mk.getElement(), mk.getElement().querySelector(".cross")]) {
      const r = el.getBoundingClientRect();
      out.push([p.id, r.left + r.width / 2 - x0, r.top + r.height / 2 - y0, getComputedStyle(el).position]);
    }
  }
  return out;
}"""


def add_pairs(session, n: int, seed: int = 7) -> None:
    """n pairs at random frame pixels and orthophoto positions (where they are is all these tests look at)."""
    rng = np.random.default_rng(seed)
    w, h = session.frame.image.shape[1], session.frame.image.shape[0]
    rows, cols = session.ortho.rows, session.ortho.cols
    for _ in range(n):
        session.add_pair(float(rng.uniform(5, w - 5)), float(rng.uniform(5, h - 5)),
                         float(rng.uniform(5, cols - 5)), float(rng.uniform(5, rows - 5)))


def reload(page, n: int) -> None:
    page.reload()
    page.wait_for_function("window.gcpui && window.gcpui.ready")
    page.wait_for_function(SYNCED_JS, arg=n)


def test_markers_are_drawn_on_their_points_on_both_maps_at_several_zooms(app_page):
    page, session, _, _ = app_page
    add_pairs(session, 24)
    reload(page, 24)
    for kind in ("frame", "ortho"):
        fit = page.evaluate(f"gcpui.{kind}Map.getZoom()")
        for zoom in (fit, fit + 1.25, 0, 2, 4):
            page.evaluate(f"""z => {{ const m = gcpui.{kind}Map;
                const p = gcpui.state.pairs[5]; const ll = "{kind}" === "frame" ? L.latLng(-p.v, p.u)
                  : L.latLng(-p.row, p.col);
                m.setView(ll, z, {{animate: false}}); }}""", zoom)
            rows = page.evaluate(MARKER_OFFSETS_JS, kind)
            assert len(rows) == 48
            off = [(pid, dx, dy) for pid, dx, dy, _ in rows if abs(dx) > 1.0 or abs(dy) > 1.0]
            assert not off, f"{kind} map at zoom {zoom}: markers off their points by (dx, dy) screen px: {off[:6]}"
            assert {pos for *_, pos in rows} == {"absolute"}


def test_the_maps_do_not_move_when_messages_titles_or_readouts_change(app_page):
    """The maps stay put whatever is written above them, so a click lands where the user aimed."""
    page, _, _, _ = app_page
    rects = """() => ["frame-map", "ortho-map"].map(id => {
        const r = document.getElementById(id).getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })"""
    before = page.evaluate(rects)
    long = "a long line that does not fit " * 12
    for el_id, text in [("message", long), ("message", long + "\n" + long), ("frame-title", long),
                        ("ortho-title", long), ("frame-readout", "u 1234.56  v 1234.56"),
                        ("ortho-readout", "col 12345.67  row 12345.67")]:
        page.evaluate("([id, t]) => { document.getElementById(id).textContent = t; }", [el_id, text])
        assert page.evaluate(rects) == before, f"the maps moved when #{el_id} changed"


def test_first_quick_clicks_land_where_aimed(app_page, scene):
    """Moving into a map and clicking at once (the readout appears on the way in) records the aimed pixel."""
    page, session, _, _ = app_page
    page.evaluate("""() => { document.getElementById("frame-title").textContent += " " + "x".repeat(40); }""")
    page.mouse.move(5, 5)
    for i in range(3):
        pick(page, scene, i, n=i + 1)
    uv = np.array([(p.u, p.v) for p in session.pairs])
    np.testing.assert_allclose(uv, scene.truth_pixels[:3], atol=0.15)  # 1 screen px = 0.125 image px


def marker_xy(page, kind: str, index: int = 0) -> tuple[float, float]:
    return tuple(page.evaluate("""([kind, i]) => { const r = gcpui.markers.get(gcpui.state.pairs[i].id)[kind]
        .getElement().getBoundingClientRect(); return [r.left + r.width / 2, r.top + r.height / 2]; }""",
                               [kind, index]))


def test_a_small_slip_while_clicking_a_marker_does_not_move_it(app_page, scene):
    page, session, _, _ = app_page
    pick(page, scene, 0, n=1)
    before = session.pairs[0]
    page.evaluate(CLICK_JS, ["frame", before.u, before.v, ZOOM])
    for dx, dy in [(2, 2), (-3, 2), (0, -5), (5, 0)]:  # under 6 screen px (|dx| + |dy|): a click, not a drag
        x, y = marker_xy(page, "frame")
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + dx, y + dy)
        page.mouse.up()
        page.wait_for_function("gcpui.selected === 'P1'")
    # A move past the threshold is a drag: the pair follows by the whole move (24 screen px = 3 frame px).
    x, y = marker_xy(page, "frame")
    page.mouse.move(x, y)
    page.mouse.down()
    for k in range(1, 7):
        page.mouse.move(x + 4 * k, y)
    page.mouse.up()
    page.wait_for_function("gcpui.state.revision >= 2 && gcpui.state.pairs[0].u !== " + repr(before.u))
    assert session.revision == 2  # the slips changed nothing
    assert session.pairs[0].u - before.u == pytest.approx(3.0, abs=0.15)
    assert session.pairs[0].v == pytest.approx(before.v, abs=0.15)


def test_markers_are_not_moved_or_redrawn_under_a_pressed_pointer(app_page, scene):
    page, session, _, _ = app_page
    pick(page, scene, 0, n=1)
    before = session.pairs[0]
    page.evaluate(CLICK_JS, ["frame", before.u, before.v, ZOOM])
    x, y = marker_xy(page, "frame")
    element = page.evaluate_handle("gcpui.markers.get('P1').frame.getElement()")
    page.mouse.move(x, y)
    page.mouse.down()
    # Meanwhile the pair moves on the server (another tab, a file load) and the page refreshes (here: a role change
    # made in the table, which refreshes the page's state from the server).
    session.update_pair("P1", u=before.u + 4.0)
    page.evaluate("""() => { const s = document.querySelector('#pairs tr[data-id="P1"] select');
        s.value = "check"; s.dispatchEvent(new Event("change")); }""")
    page.wait_for_function("gcpui.state.pairs[0].role === 'check' && gcpui.state.pairs[0].u !== " + repr(before.u))
    page.wait_for_timeout(100)
    assert marker_xy(page, "frame") == (x, y)  # still under the pointer, where it was pressed
    assert page.evaluate("e => e === gcpui.markers.get('P1').frame.getElement()", element)
    page.mouse.up()
    # Released without moving: a click (selects it), the pair keeps the server's change, the marker goes there.
    page.wait_for_function("gcpui.selected === 'P1'")
    page.wait_for_function("gcpui.markers.get('P1').frame.getElement().classList.contains('check')")
    assert marker_xy(page, "frame")[0] == pytest.approx(x + 4.0 * 2**ZOOM, abs=1.0)
    assert page.evaluate("e => e === gcpui.markers.get('P1').frame.getElement()", element)  # never re-created
    assert session.pairs[0].u == before.u + 4.0 and session.pairs[0].v == before.v
