/* trafficgeo gcp-ui: pick GCP pairs between a video frame and an orthophoto, calibrate live.
 *
 * Both maps use Leaflet's L.CRS.Simple, one map unit = one image pixel, latitude pointing up:
 *   frame map: latLng = (-v, u), with (u, v) camera pixels, (0, 0) = centre of the top-left pixel;
 *   ortho map: latLng = (-row, col), with (col, row) full-resolution raster positions, (0, 0) = top-left corner.
 * World coordinates are computed by the server (float64, from the orthophoto's affine transform); this page only
 * sends pixel positions and shows what the server returns.
 *
 * A GCP moves only when the user drags its marker on purpose: a press on a marker becomes a drag only after the
 * pointer has moved DRAG_THRESHOLD_PX screen pixels (|dx| + |dy|), and while a pointer is pressed no marker is
 * moved, re-styled or re-created (updates wait for the release).
 *
 * "Refine from orthophoto" asks the server to match the orthophoto to the frame and re-fit the camera; its
 * automatic matches are drawn on the frame with the GCP markers' transform (frameLL): a dot at the found pixel
 * (green kept by the re-fit, red rejected) and a line towards where the camera predicted it, MATCH_VECTOR_SCALE
 * times longer.
 */
"use strict";
(function () {
  const DRAG_THRESHOLD_PX = 6;
  const MATCH_VECTOR_SCALE = 5;
  const app = window.gcpui = {
    ready: false, info: null, state: null, calibration: null, selected: null, refine: null, refining: false,
    pending: {frame: null, ortho: null}, frameMap: null, orthoMap: null, layers: {}, markers: new Map(),
    tableStale: false, pressed: false, markersStale: false,
  };

  const $ = (id) => document.getElementById(id);
  const finite = (x) => typeof x === "number" && Number.isFinite(x);
  const fmt = (x, digits) => (finite(x) ? x.toFixed(digits) : "–");
  const esc = (s) => String(s).replace(/[&<>"']/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;",
    "'": "&#39;"}[c]));
  const frameLL = (u, v) => L.latLng(-v, u);
  const orthoLL = (col, row) => L.latLng(-row, col);

  function message(text, kind) {
    const m = $("message");
    m.textContent = text || "";
    m.className = kind || "";
  }

  async function api(method, url, body) {
    const opts = {method, headers: {Accept: "application/json"}};
    if (body !== undefined) {
      opts.headers["Content-Type"] = "application/json";
      opts.body = JSON.stringify(body);
    }
    const r = await fetch(url, opts);
    let data = null;
    try { data = await r.json(); } catch (e) { data = null; }
    if (!r.ok) throw new Error((data && data.detail) || `${r.status} ${r.statusText}`);
    return data;
  }

  function makeMap(el, bounds, url) {
    const map = L.map(el, {
      crs: L.CRS.Simple, minZoom: -10, maxZoom: 7, zoomSnap: 0.25, zoomDelta: 0.5, wheelPxPerZoomLevel: 90,
      doubleClickZoom: false, boxZoom: false, attributionControl: false, inertia: false,
    });
    L.imageOverlay(url, bounds, {interactive: false}).addTo(map);
    map.fitBounds(bounds);
    map.setMinZoom(Math.min(Math.floor(map.getZoom()) - 2, 0));
    const crisp = () => el.classList.toggle("crisp", map.getZoom() >= 1);
    map.on("zoomend", crisp);
    crisp();
    return map;
  }

  // ------------------------------------------------------------------------------------------------ picking
  function inside(kind, p) {
    if (kind === "frame") {
      const f = app.info.frame;
      return p.u >= -0.5 && p.u <= f.width - 0.5 && p.v >= -0.5 && p.v <= f.height - 0.5;
    }
    const o = app.info.ortho;
    return p.col >= 0 && p.col <= o.cols && p.row >= 0 && p.row <= o.rows;
  }

  async function pick(kind, ll) {
    const p = kind === "frame" ? {u: ll.lng, v: -ll.lat} : {col: ll.lng, row: -ll.lat};
    if (!inside(kind, p)) {
      message(`that point is outside the ${kind === "frame" ? "frame" : "orthophoto"}`, "error");
      return;
    }
    app.pending[kind] = p;
    drawPending();
    if (!(app.pending.frame && app.pending.ortho)) {
      message(kind === "frame" ? "now click the same feature on the orthophoto (Esc cancels)"
        : "now click the same feature in the frame (Esc cancels)");
      return;
    }
    const body = Object.assign({}, app.pending.frame, app.pending.ortho);
    app.pending = {frame: null, ortho: null};
    drawPending();
    try {
      const pair = await api("POST", "/api/pairs", body);
      app.selected = pair.id;
      const g = pair.ground;
      message(`pair ${pair.id} added: z ${fmt(pair.z, 3)}` + (g ? ` from the ground (roughness ±${fmt(g.spread_m, 2)} m`
        + (g.check !== "ok" ? `, ${g.check}` : "") + ")" : " (no ground given: type z)"), "ok");
    } catch (err) {
      message(err.message, "error");
    }
    await refresh();
  }

  function drawPending() {
    const lay = app.layers;
    lay.pendingFrame.clearLayers();
    lay.pendingOrtho.clearLayers();
    const p = app.pending;
    if (p.frame) L.marker(frameLL(p.frame.u, p.frame.v), {icon: icon("new", "pending"), interactive: false})
      .addTo(lay.pendingFrame);
    if (p.ortho) L.marker(orthoLL(p.ortho.col, p.ortho.row), {icon: icon("new", "pending"), interactive: false})
      .addTo(lay.pendingOrtho);
  }

  function icon(label, cls) {
    return L.divIcon({
      className: "gcp-icon " + cls, iconSize: [24, 24], iconAnchor: [12, 12],
      html: `<div class="cross"></div><span class="lbl">${esc(label)}</span>`,
    });
  }

  // ------------------------------------------------------------------------------------------------ server state
  let refreshSeq = 0;

  async function refresh() {
    const seq = ++refreshSeq;
    try {
      const state = await api("GET", "/api/state");
      if (seq !== refreshSeq) return;
      app.state = state;
      if (app.selected && !state.pairs.some((p) => p.id === app.selected)) app.selected = null;
      render();
      if (state.autosave.error) message(state.autosave.error, "error");
      const cal = await api("GET", "/api/calibration");
      if (seq !== refreshSeq) return;
      app.calibration = cal;
      render();
    } catch (err) {
      message(err.message, "error");
    }
  }

  async function change(id, body) {
    try {
      const pair = await api("PATCH", "/api/pairs/" + encodeURIComponent(id), body);
      if (app.selected === id) app.selected = pair.id;
      message(`pair ${pair.id} changed`, "ok");
    } catch (err) {
      message(err.message, "error");
    }
    await refresh();
  }

  async function remove(id) {
    try {
      await api("DELETE", "/api/pairs/" + encodeURIComponent(id));
      if (app.selected === id) app.selected = null;
      message(`pair ${id} deleted`, "ok");
    } catch (err) {
      message(err.message, "error");
    }
    await refresh();
  }

  function select(id, pan) {
    app.selected = id;
    render();
    const p = app.state && app.state.pairs.find((q) => q.id === id);
    if (p && pan) {
      app.frameMap.panTo(frameLL(p.u, p.v));
      app.orthoMap.panTo(orthoLL(p.col, p.row));
    }
  }

  // ------------------------------------------------------------------------------------------------ rendering
  function calPoint(id) {
    const cal = app.calibration;
    if (!cal || cal.status !== "ok" || !app.state || cal.revision !== app.state.revision) return null;
    return cal.points.find((p) => p.id === id) || null;
  }

  function render() {
    renderMarkers();
    renderTable();
    renderCalibration();
    renderRefinePanel();
  }

  // Markers are made once and then updated in place (position, classes, label): their elements are never
  // re-created, and nothing is changed while a pointer is pressed (see pointerPressed), so a press stays a click
  // and a drag survives a refresh.
  function makeMarker(kind, entry, layer, ll) {
    const mk = L.marker(ll, {icon: icon(entry.id, ""), draggable: true, autoPan: true}).addTo(layer);
    mk.dragging._draggable.options.clickTolerance = DRAG_THRESHOLD_PX;
    mk.on("click", () => select(entry.id, false));
    mk.on("dragstart", () => { mk.gcpDragging = true; });
    mk.on("dragend", () => {
      mk.gcpDragging = false;
      const ll = mk.getLatLng();
      change(entry.id, kind === "frame" ? {u: ll.lng, v: -ll.lat} : {col: ll.lng, row: -ll.lat});
    });
    mk.gcpClass = "";
    mk.gcpLabel = entry.id;
    return mk;
  }

  function styleMarker(mk, label, cls) {
    if (mk.gcpClass === cls && mk.gcpLabel === label) return;
    const el = mk.getElement();
    for (const c of ["check", "outlier", "selected"]) el.classList.toggle(c, cls.split(" ").includes(c));
    el.querySelector(".lbl").textContent = label;
    mk.options.icon = icon(label, cls);  // what Leaflet would draw if it ever re-created the element
    mk.gcpClass = cls;
    mk.gcpLabel = label;
  }

  function renderMarkers() {
    if (app.pressed) {
      app.markersStale = true;  // never move a marker under a pressed pointer; render after the release
      return;
    }
    app.markersStale = false;
    const pairs = app.state ? app.state.pairs : [];
    const seen = new Set();
    for (const p of pairs) {
      seen.add(p.id);
      let entry = app.markers.get(p.id);
      if (!entry) {
        entry = {id: p.id};
        entry.frame = makeMarker("frame", entry, app.layers.frameMarkers, frameLL(p.u, p.v));
        entry.ortho = makeMarker("ortho", entry, app.layers.orthoMarkers, orthoLL(p.col, p.row));
        app.markers.set(p.id, entry);
      }
      const cp = calPoint(p.id);
      const selected = app.selected === p.id;
      const cls = [p.role === "check" ? "check" : "", cp && cp.status === "outlier" ? "outlier" : "",
        selected ? "selected" : ""].filter(Boolean).join(" ");
      for (const [mk, ll] of [[entry.frame, frameLL(p.u, p.v)], [entry.ortho, orthoLL(p.col, p.row)]]) {
        if (mk.gcpDragging) continue;
        if (!mk.getLatLng().equals(ll, 0)) mk.setLatLng(ll);
        styleMarker(mk, p.id, cls);
        if (mk.options.zIndexOffset !== (selected ? 1000 : 0)) mk.setZIndexOffset(selected ? 1000 : 0);
      }
    }
    for (const [id, entry] of app.markers) {
      if (seen.has(id)) continue;
      app.layers.frameMarkers.removeLayer(entry.frame);
      app.layers.orthoMarkers.removeLayer(entry.ortho);
      app.markers.delete(id);
    }
  }

  function cell(tr, text, cls, title) {
    const td = document.createElement("td");
    td.textContent = text;
    if (cls) td.className = cls;
    if (title) td.title = title;
    tr.appendChild(td);
    return td;
  }

  function groundText(p) {
    const g = p.ground;
    if (!g) return ["no ground", ""];
    let text = `±${fmt(g.spread_m, 2)} m`;
    if (finite(g.slope_deg)) text += ` ${fmt(g.slope_deg, 1)}°`;
    if (g.points >= 0) text += ` ${g.points} pts`;
    if (!p.z_auto && finite(g.dz_m)) text += ` dz ${g.dz_m >= 0 ? "+" : ""}${fmt(g.dz_m, 2)} m`;
    if (g.check !== "ok") text += ` ${g.check}`;
    const title = `ground z ${fmt(g.z, 3)}; roughness ${fmt(g.spread_m, 3)} m (robust std within the radius); ` +
      `slope ${fmt(g.slope_deg, 1)}°` + (g.points >= 0 ? `; ${g.points} lidar ground points` : "") +
      (g.check !== "ok" ? `; ${g.check}` : "");
    return [text, title];
  }

  function commitOnEnter(input) {
    input.addEventListener("keydown", (e) => {
      if (e.key === "Enter") input.blur();  // blurring fires "change"
    });
  }

  function renderTable() {
    const body = document.querySelector("#pairs tbody");
    const active = document.activeElement;
    if (active && body.contains(active) && ["INPUT", "SELECT"].includes(active.tagName)) {
      app.tableStale = true;  // do not replace the field being edited; render when it loses the focus
      return;
    }
    app.tableStale = false;
    body.textContent = "";
    if (!app.state) return;
    const hasGround = !!app.info.ground;
    for (const p of app.state.pairs) {
      const cp = calPoint(p.id);
      const tr = document.createElement("tr");
      tr.dataset.id = p.id;
      tr.className = [p.role, cp ? cp.status : "", app.selected === p.id ? "selected" : ""].join(" ");
      tr.addEventListener("click", (e) => {
        if (!["INPUT", "SELECT", "BUTTON", "OPTION"].includes(e.target.tagName)) select(p.id, true);
      });
      const idTd = cell(tr, "", "id");
      const idIn = document.createElement("input");
      idIn.className = "id";
      idIn.value = p.id;
      idIn.addEventListener("change", () => change(p.id, {id: idIn.value.trim()}));
      commitOnEnter(idIn);
      idTd.appendChild(idIn);
      const roleTd = cell(tr, "", "role");
      const roleSel = document.createElement("select");
      for (const r of app.info.roles) {
        const o = document.createElement("option");
        o.value = o.textContent = r;
        roleSel.appendChild(o);
      }
      roleSel.value = p.role;
      roleSel.addEventListener("change", () => {
        roleSel.blur();
        change(p.id, {role: roleSel.value});
      });
      roleTd.appendChild(roleSel);
      cell(tr, fmt(p.u, 2), "u");
      cell(tr, fmt(p.v, 2), "v");
      cell(tr, fmt(p.x, 3), "x");
      cell(tr, fmt(p.y, 3), "y");
      const zTd = cell(tr, "", "z");
      const zIn = document.createElement("input");
      zIn.className = "z" + (p.z_auto ? "" : " typed");
      zIn.value = fmt(p.z, 3);
      zIn.title = p.z_auto ? "from the ground; type a value to override" : "typed (or read from a file)";
      zIn.addEventListener("change", () => {
        const z = Number(zIn.value);
        if (zIn.value.trim() === "" || !Number.isFinite(z)) {
          message(`z "${zIn.value}" is not a number`, "error");
          zIn.value = fmt(p.z, 3);
          return;
        }
        change(p.id, {z});
      });
      commitOnEnter(zIn);
      zTd.appendChild(zIn);
      if (!p.z_auto && hasGround) {
        const b = document.createElement("button");
        b.type = "button";
        b.className = "reset";
        b.textContent = "⟲";
        b.title = "take z from the ground";
        b.addEventListener("click", () => change(p.id, {z_auto: true}));
        zTd.appendChild(b);
      }
      const [gText, gTitle] = groundText(p);
      cell(tr, gText, "ground" + (p.ground && p.ground.check !== "ok" ? ` flag-${p.ground.check}` : ""), gTitle);
      cell(tr, cp ? fmt(cp.error_px, 2) : "", "err", cp ? `du ${fmt(cp.du, 2)}, dv ${fmt(cp.dv, 2)} px` : "");
      cell(tr, cp ? fmt(cp.loo_error_px, 2) : "", "loo");
      cell(tr, cp ? fmt(cp.loo_ground_error_m, 3) : "", "loo-m");
      cell(tr, cp ? cp.status : "", "status", cp && cp.reason ? cp.reason : "");
      const delTd = cell(tr, "", "actions");
      const del = document.createElement("button");
      del.type = "button";
      del.className = "delete";
      del.textContent = "✕";
      del.title = "delete this pair";
      del.addEventListener("click", () => remove(p.id));
      delTd.appendChild(del);
      body.appendChild(tr);
    }
  }

  function renderCalibration() {
    const lay = app.layers;
    lay.residuals.clearLayers();
    lay.frameGrid.clearLayers();
    lay.orthoGrid.clearLayers();
    lay.footprint.clearLayers();
    const status = $("calib-status");
    const details = $("calib-details");
    details.textContent = "";
    const cal = app.calibration;
    if (!cal) return;
    status.className = cal.status;
    status.textContent = cal.status === "ok" ? "Calibrated" : cal.status === "waiting" ? "Waiting for pairs"
      : "Calibration failed";
    const add = (tag, text, cls) => {
      const el = document.createElement(tag);
      el.textContent = text;
      if (cls) el.className = cls;
      details.appendChild(el);
      return el;
    };
    add("div", cal.message);
    if (cal.status !== "ok") return;
    const s = cal.stats;
    const c = cal.camera;
    add("div", `${s.n_inliers} of ${s.n_control} control points used, ${s.n_outliers} outlier(s), ` +
      `${cal.check.n} check point(s)`);
    add("div", `RMSE ${fmt(s.rmse_px, 2)} px, leave-one-out ${fmt(s.loo_rmse_px, 2)} px ` +
      `(${fmt(s.loo_ground_median_m, 3)} m median on the ground)`);
    if (cal.check.n) add("div", `check points: ${fmt(cal.check.rmse_px, 2)} px, ${fmt(cal.check.ground_rmse_m, 3)} m RMS`);
    add("div", `focal ${fmt(c.focal_px, 1)} px; heading ${fmt(c.orientation.heading_deg, 2)}°, tilt ` +
      `${fmt(c.orientation.tilt_deg, 2)}°, roll ${fmt(c.orientation.roll_deg, 2)}°; ${cal.model}`);
    if (cal.grid && cal.grid.spacing) add("div", `grid every ${cal.grid.spacing} ${cal.grid.unit}`);
    if (cal.overlay_error) add("div", cal.overlay_error, "warn");
    if (cal.warnings.length) {
      const ul = add("ul", "", "warn");
      for (const w of cal.warnings) { const li = document.createElement("li"); li.textContent = w; ul.appendChild(li); }
    }
    if (cal.recommendations.length) {
      const ul = add("ul", "");
      for (const r of cal.recommendations) { const li = document.createElement("li"); li.textContent = r; ul.appendChild(li); }
    }
    if (cal.revision !== (app.state && app.state.revision)) return;
    const scale = Number($("residual-scale").value) || 1;
    for (const p of cal.points) {
      if (!finite(p.du) || !finite(p.dv)) continue;
      const u = p.u_proj - p.du;
      const v = p.v_proj - p.dv;
      const color = p.status === "outlier" ? "#ff3b3b" : p.status === "check" ? "#4aa3ff" : "#39ff14";
      L.polyline([frameLL(u, v), frameLL(u + scale * p.du, v + scale * p.dv)],
        {color, weight: 2, interactive: false, className: "residual residual-" + p.status}).addTo(lay.residuals);
    }
    if ($("show-grid").checked && cal.grid) {
      const style = {color: "#00e5ff", weight: 1, opacity: 0.75, interactive: false, className: "grid-line"};
      for (const line of cal.grid.frame) L.polyline(line.points.map(([u, v]) => frameLL(u, v)), style).addTo(lay.frameGrid);
      for (const line of cal.grid.ortho) L.polyline(line.points.map(([c, r]) => orthoLL(c, r)), style).addTo(lay.orthoGrid);
    }
    if ($("show-footprint").checked && cal.footprint.length) {
      L.polygon(cal.footprint.map((rings) => rings.map((ring) => ring.map(([c, r]) => orthoLL(c, r)))),
        {color: "#ffd600", weight: 1.5, fillOpacity: 0.07, interactive: false, className: "footprint"})
        .addTo(lay.footprint);
    }
  }

  // ------------------------------------------------------------------------------------------------ files
  async function saveCsv() {
    try {
      const r = await api("POST", "/api/gcps/save", {name: $("csv-name").value.trim()});
      message(`saved ${r.n} GCPs to ${r.path}`, "ok");
    } catch (err) {
      message(err.message, "error");
    }
  }

  async function loadCsv() {
    const name = $("csv-name").value.trim();
    const n = app.state ? app.state.pairs.length : 0;
    if (n && !window.confirm(`Replace the ${n} pairs by those in ${name}?`)) return;
    try {
      const r = await api("POST", "/api/gcps/load", {name});
      app.selected = null;
      message(`loaded ${r.n} GCPs from ${r.path}`, "ok");
    } catch (err) {
      message(err.message, "error");
    }
    await refresh();
  }

  async function saveCamera() {
    try {
      const r = await api("POST", "/api/camera/save", {name: $("camera-name").value.trim()});
      message(`saved the camera to ${r.path}`, "ok");
    } catch (err) {
      message(err.message, "error");
    }
  }

  // ------------------------------------------------------------------------------------------------ refinement
  async function refineFromOrtho() {
    if (app.refining) return;
    app.refining = true;
    $("refine").disabled = true;
    renderRefinePanel();
    message("refining the camera from the orthophoto (a few seconds)…");
    try {
      const r = await api("POST", "/api/refine", {});
      app.refine = r;
      message(`refinement ${r.accepted ? "accepted" : "refused"}: ${r.reason}`, r.accepted ? "ok" : "");
    } catch (err) {
      message(err.message, "error");
    } finally {
      app.refining = false;
      $("refine").disabled = false;
      renderRefinePanel();
      renderRefineMatches();
    }
  }

  function renderRefinePanel() {
    const status = $("refine-status");
    const details = $("refine-details");
    const r = app.refine;
    details.textContent = "";
    $("refine-save").hidden = true;
    if (app.refining) {
      status.textContent = "Refining from the orthophoto…";
      status.className = "busy";
      return;
    }
    if (!r) {
      status.textContent = "";
      status.className = "";
      return;
    }
    status.textContent = r.accepted ? "Refinement accepted" : "Refinement refused";
    status.className = r.accepted ? "ok" : "refused";
    const add = (text, cls) => {
      const el = document.createElement("div");
      el.textContent = text;
      if (cls) el.className = cls;
      details.appendChild(el);
    };
    add(r.reason);
    add(`held-out error at your GCPs: ${fmt(r.before.rmse_px, 2)} px → ` +
      `${r.after ? fmt(r.after.rmse_px, 2) : "–"} px (on the ground ${fmt(r.before.rmse_m, 3)} m → ` +
      `${r.after ? fmt(r.after.rmse_m, 3) : "–"} m)`);
    add(`${r.n_kept} of ${r.n_matches} matches kept; ${r.passes.length} pass(es), ${fmt(r.elapsed_s, 1)} s`);
    add(`frame: ${r.frame}`);
    add(`surface: ${r.surface}`);
    const stale = !!app.state && r.revision !== app.state.revision;
    if (stale) add("the pairs changed since: refine again to save a refined camera", "warn");
    $("refine-save").hidden = !r.accepted || stale;
  }

  function renderRefineMatches() {
    const layer = app.layers.refineMatches;
    layer.clearLayers();
    const r = app.refine;
    if (!r || !$("show-matches").checked) return;
    const s = MATCH_VECTOR_SCALE;
    for (const m of r.matches) {
      const kind = m.kept ? "kept" : "rejected";
      const color = m.kept ? "#39ff14" : "#ff3b3b";
      const du = m.u - m.u_predicted;
      const dv = m.v - m.v_predicted;
      L.polyline([frameLL(m.u - s * du, m.v - s * dv), frameLL(m.u, m.v)],
        {color, weight: 1.5, interactive: false, className: "refine-vector refine-" + kind}).addTo(layer);
      L.circleMarker(frameLL(m.u, m.v), {radius: 3, color: "#111", weight: 1, fillColor: color, fillOpacity: 1,
        interactive: false, className: "refine-match refine-" + kind}).addTo(layer);
    }
  }

  async function saveRefined() {
    try {
      const r = await api("POST", "/api/refine/save", {name: $("refined-name").value.trim()});
      message(`saved the refined camera to ${r.path} (report ${r.report}, frame ${r.frame})`, "ok");
    } catch (err) {
      message(err.message, "error");
    }
  }

  // While any pointer (mouse button, pen, finger) is pressed, markers are left as they are; the release renders them.
  function watchPointer() {
    const press = () => { app.pressed = true; };
    const release = () => {
      if (!app.pressed) return;
      app.pressed = false;
      // after Leaflet's own mouseup/click handlers (a click selects, a drag ends) have run
      setTimeout(() => { if (!app.pressed && app.markersStale) renderMarkers(); }, 0);
    };
    document.addEventListener("pointerdown", press, true);
    document.addEventListener("pointerup", release, true);
    document.addEventListener("pointercancel", release, true);
    window.addEventListener("blur", release);
  }

  // ------------------------------------------------------------------------------------------------ start
  async function start() {
    try {
      app.info = await api("GET", "/api/info");
    } catch (err) {
      message(err.message, "error");
      return;
    }
    const f = app.info.frame;
    const o = app.info.ortho;
    $("frame-title").textContent = $("frame-title").title = `Frame ${f.width}×${f.height} px — ${f.source}`;
    $("ortho-title").textContent = $("ortho-title").title = `Orthophoto ${o.cols}×${o.rows} px — ${app.info.crs}` +
      (app.info.ground ? ` — Z: ${app.info.ground.describe}` : " — no DEM or cloud: type Z");
    app.frameMap = makeMap($("frame-map"), L.latLngBounds(frameLL(-0.5, f.height - 0.5), frameLL(f.width - 0.5, -0.5)),
      "/api/frame.png");
    app.orthoMap = makeMap($("ortho-map"), L.latLngBounds(orthoLL(0, o.extent_rows), orthoLL(o.extent_cols, 0)),
      "/api/ortho.png");
    const lay = app.layers;
    lay.footprint = L.layerGroup().addTo(app.orthoMap);
    lay.orthoGrid = L.layerGroup().addTo(app.orthoMap);
    lay.frameGrid = L.layerGroup().addTo(app.frameMap);
    lay.residuals = L.layerGroup().addTo(app.frameMap);
    lay.refineMatches = L.layerGroup().addTo(app.frameMap);
    lay.frameMarkers = L.layerGroup().addTo(app.frameMap);
    lay.orthoMarkers = L.layerGroup().addTo(app.orthoMap);
    lay.pendingFrame = L.layerGroup().addTo(app.frameMap);
    lay.pendingOrtho = L.layerGroup().addTo(app.orthoMap);
    app.frameMap.on("click", (e) => pick("frame", e.latlng));
    app.orthoMap.on("click", (e) => pick("ortho", e.latlng));
    app.frameMap.on("mousemove", (e) => {
      $("frame-readout").textContent = `u ${fmt(e.latlng.lng, 2)}  v ${fmt(-e.latlng.lat, 2)}`;
    });
    app.orthoMap.on("mousemove", (e) => {
      $("ortho-readout").textContent = `col ${fmt(e.latlng.lng, 2)}  row ${fmt(-e.latlng.lat, 2)}`;
    });
    watchPointer();
    $("residual-scale").addEventListener("change", renderCalibration);
    $("show-grid").addEventListener("change", renderCalibration);
    $("show-footprint").addEventListener("change", renderCalibration);
    $("save-csv").addEventListener("click", saveCsv);
    $("load-csv").addEventListener("click", loadCsv);
    $("save-camera").addEventListener("click", saveCamera);
    $("refine").addEventListener("click", refineFromOrtho);
    $("show-matches").addEventListener("change", renderRefineMatches);
    $("save-refined").addEventListener("click", saveRefined);
    document.querySelector("#pairs tbody").addEventListener("focusout", () => {
      if (app.tableStale) setTimeout(renderTable, 0);
    });
    $("csv-name").value = app.info.gcps_name;
    $("camera-name").value = app.info.camera_name;
    $("refined-name").value = app.info.refined_camera_name || "camera_refined.json";
    document.addEventListener("keydown", (e) => {
      if (["INPUT", "SELECT", "TEXTAREA"].includes(e.target.tagName)) return;
      if (e.key === "Escape") {
        app.pending = {frame: null, ortho: null};
        drawPending();
        app.selected = null;
        render();
        message("");
      } else if ((e.key === "Delete" || e.key === "Backspace") && app.selected) {
        e.preventDefault();
        remove(app.selected);
      }
    });
    if (o.note) message(o.note);
    await refresh();
    app.ready = true;
  }

  document.addEventListener("DOMContentLoaded", start);
})();
