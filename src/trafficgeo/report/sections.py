"""The calibration sections of a report as data (:mod:`trafficgeo.report.blocks`): the camera and its fit, the
GCPs with their residuals, and the accuracy map.

Units: pixels (px) in the image; positions in the CRS's units relative to the plan-view origin; ground errors in
metres.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from trafficgeo.calibration.report import CalibrationReport
from trafficgeo.camera.calibrated import FitModel, PoseUncertainty
from trafficgeo.report import figures as F
from trafficgeo.report.blocks import Block, Heading, Part, Section, Text, figure, items, num, table
from trafficgeo.report.context import ReportContext, frame_image


def calibration_sections(b: ReportContext) -> list[Section]:
    """The calibration section and the GCP section (none, and a note, without a camera or calibration report)."""
    rep, g = b.report, b.gcps
    cal = b.calibrated
    if rep is None and b.camera is None:
        b.skip("calibration", "no camera.json or calibration report.json found: pass --camera / --calibration-report "
               "(the outputs of 'trafficgeo calibrate')")
        return []
    parts: list[Part] = []
    if rep is not None and rep.summary:
        parts.append((Text(rep.summary, "summary"),))
    elif rep is None:
        b.skip("calibration report tables (leave-one-out ground errors, check points, warnings)",
               "no calibration report.json found: pass --calibration-report (calibrate --report)")
    parts.append(_camera_table(b))
    if rep is not None:
        parts.append((Heading("Fit statistics"), _stats_table(rep, b)))
    elif cal is not None and cal.stats is not None:
        s = cal.stats
        parts.append((Heading("Fit statistics"), table(["quantity", "value", "unit"], [
            ["control points / inliers", f"{_or_dash(s.n_control)} / {_or_dash(s.n_inliers)}", ""],
            ["mean residual", _finite(s.mean_px), "px"], ["RMSE", _finite(s.rmse_px), "px"],
            ["leave-one-out RMSE", _finite(s.loo_rmse_px), "px"]])))
    if rep is not None:
        parts.append((Heading("Parameter uncertainty"), *_report_uncertainty_blocks(rep)))
    elif cal is not None and cal.uncertainty is not None:  # the camera JSON holds no per-parameter table
        parts.append((Heading("Parameter uncertainty"), *_uncertainty_blocks([], [], False)))
    if rep is not None:
        if rep.outliers:
            parts.append((Heading("Outliers"), items([f"{o.id}: {o.reason}" for o in rep.outliers], "warn")))
        if rep.warnings:
            parts.append((Heading("Warnings"), items(list(rep.warnings), "warn")))
        if rep.recommendations:
            parts.append((Heading("Recommendations"), items(list(rep.recommendations))))
    sections = [Section("calibration", "Calibration", tuple(parts))]
    if g is None:
        b.skip("GCP figures and table", "the calibration lists no GCPs")
        return sections
    sections.append(_gcp_section(b))
    return sections


def _gcp_section(b: ReportContext) -> Section:
    """The GCPs on the frame and on the map, the residual histograms and the per-GCP table."""
    rep, g = b.report, b.gcps
    assert g is not None
    size = tuple(b.camera.image_size) if b.camera is not None else tuple(rep.image_size)  # type: ignore[union-attr]
    image = frame_image(b)
    ok = np.isfinite(g["u"]) & np.isfinite(g["v"])
    on_frame = figure(F.residuals_on_frame(g[ok], size, image),
                      "GCPs where they were clicked, with their residual vectors (projected survey point minus "
                      "clicked pixel, px) magnified by the factor in the title; red crosses are outliers left "
                      "out of the fit, blue squares check points.", b.dpi)
    cam_xy, heading = None, None
    if b.camera is not None:
        cam_xy, heading = (float(b.camera.position[0]), float(b.camera.position[1])), b.camera.orientation.heading_deg
    elif rep is not None:
        p = rep.camera.position
        cam_xy, heading = (float(p[0]), float(p[1])), float(rep.camera.orientation.heading_deg)
    xs = [g["x"].to_numpy(float)] + ([np.array([cam_xy[0]])] if cam_xy else [])
    ys = [g["y"].to_numpy(float)] + ([np.array([cam_xy[1]])] if cam_xy else [])
    for part in F.geometry_parts(b.footprint):
        fx, fy = np.asarray(part.exterior.coords).T[:2]
        xs.append(fx)
        ys.append(fy)
    if b.footprint is None:
        b.skip("camera footprint on the GCP map", "no site.gpkg and no accuracy map: pass --dem (or run 'trafficgeo "
               "accuracy ... --gis site.gpkg')")
    bg = b.background(xs, ys, "GCP map")
    on_map = figure(F.gcps_on_map(g, b.axes, camera_xy=cam_xy, heading_deg=heading, footprint=b.footprint,
                                  background=bg),
                    f"GCPs at their surveyed positions, the camera (triangle, arrow: viewing direction) and the "
                    f"ground it sees (footprint). Arrows: where each clicked pixel's ray meets the point's "
                    f"elevation, minus the survey point (magnified). Axes in {b.axes.unit} from the local "
                    "origin.", b.dpi)
    histograms = figure(F.residual_histograms(g),
                        "Fit residuals and leave-one-out errors of the inlier GCPs, in the image (px) and on the "
                        "ground (m). The leave-one-out error (the camera fitted without that point) is the honest "
                        "error to expect for a new point.", b.dpi)
    return Section("gcps", "GCPs and residuals", ((on_frame,), (on_map,), (histograms, *_gcp_residual_table(b))))


def _camera_table(b: ReportContext) -> Part:
    rep, cal = b.report, b.calibrated
    if rep is not None:
        unc = rep.uncertainty
        ps: Any = unc.position_std_m
        angles_std = (unc.orientation_std_deg.heading, unc.orientation_std_deg.tilt, unc.orientation_std_deg.roll)
        focal_std: Any = unc.focal_std_px
        model = rep.model
        desc = model.description or ", ".join(model.free_parameters)
        reasons = list(model.reasons)
    else:  # the camera JSON's copy of the report's blocks
        unc = (cal.uncertainty if cal is not None else None) or PoseUncertainty()
        fit = (cal.model if cal is not None else None) or FitModel()
        ps = unc.position_std_m or [float("nan")] * 3
        angles_std = unc.orientation_std_deg or (None, None, None)
        focal_std = unc.focal_std_px
        desc = fit.description or ", ".join(fit.free_parameters or [])
        reasons = list(fit.reasons or [])
    if b.camera is not None:
        pos, o, f = b.camera.position, b.camera.orientation, b.camera.focal_px
        dist, size = b.camera.dist, b.camera.image_size
    else:
        assert rep is not None  # the calibration section needs a camera or a report
        c = rep.camera
        pos, o, f, dist, size = c.position, c.orientation, c.focal_px, c.dist, rep.image_size
    u = b.axes.unit
    rows = [
        ["position X, Y, Z", ", ".join(num(v, 3) for v in pos), u, ", ".join(num(v, 2) for v in ps) + " m"],
        ["heading (clockwise from grid north)", (o.heading_deg, 2), "deg", num(angles_std[0], 3) + " deg"],
        ["tilt (below the horizon)", (o.tilt_deg, 2), "deg", num(angles_std[1], 3) + " deg"],
        ["roll", (o.roll_deg, 2), "deg", num(angles_std[2], 3) + " deg"],
        ["focal length", (f, 1), "px", num(focal_std, 1) + " px"],
        ["k1, k2", f"{num(dist[0], 4)}, {num(dist[1], 4)}", "", ""],
        ["image size", f"{size[0]} x {size[1]}", "px", ""],
    ]
    if desc:
        rows.append(["free parameters", desc, "", ""])
    return Heading("Camera"), table(["quantity", "value", "unit", "1-sigma"], rows), items(reasons, "note")


def _stats_table(rep: CalibrationReport, b: ReportContext) -> Block:
    s, c, d = rep.stats, rep.check, rep.distance_ratios
    rows = [
        ["control points / inliers / outliers", f"{s.n_control} / {s.n_inliers} / {s.n_outliers}", ""],
        ["mean / RMSE / max residual (inliers)", f"{num(s.mean_px)} / {num(s.rmse_px)} / {num(s.max_px)}", "px"],
        ["sigma0 (1 = residuals match the stated noise)", (s.sigma0, 2), ""],
        ["redundancy (observations - parameters)", s.redundancy, ""],
        ["leave-one-out RMSE", (s.loo_rmse_px, 2), "px"],
        ["leave-one-out ground error: RMSE / median", f"{num(s.loo_ground_rmse_m, 3)} / "
                                                      f"{num(s.loo_ground_median_m, 3)}", "m"],
    ]
    if c.n:
        rows += [["check points (not in the fit)", c.n, ""],
                 ["check points: RMSE / max", f"{num(c.rmse_px)} / {num(c.max_px)}", "px"],
                 ["check points: ground RMSE", (c.ground_rmse_m, 3), "m"]]
    if d.n_pairs:
        rows.append([f"distance ratio error (eq. 15, {d.n_pairs} pairs): mean / median / max",
                     f"{num(d.mean_pct)} / {num(d.median_pct)} / {num(d.max_pct)}", "%"])
    p = rep.pose_consistency
    if p.available:
        sp, ang = p.position_spread_m, p.angle_spread_deg
        rows += [[f"pose spread over {p.n_fits} leave-one-out fits: X, Y, Z", ", ".join(num(v, 3) for v in sp), "m"],
                 ["pose spread: heading, tilt, roll", ", ".join(num(v, 3) for v in (ang.heading, ang.tilt, ang.roll)),
                  "deg"],
                 [f"largest camera shift (without {p.most_influential_gcp})", (p.max_position_deviation_m, 3), "m"]]
    if b.grid is not None and b.gcps is not None and "predicted_m" in b.gcps.columns:
        inl = b.gcps[b.gcps["status"] == "inlier"]
        rows.append(["predicted 1-sigma ground error at the inlier GCPs (accuracy map), median",
                     (float(np.nanmedian(inl["predicted_m"])) if inl["predicted_m"].notna().any() else float("nan"),
                      3), "m"])
    return table(["quantity", "value", "unit"], rows)


def _report_uncertainty_blocks(rep: CalibrationReport) -> Part:
    """The per-parameter table and the high correlations of the report."""
    unc = rep.uncertainty
    params = [(name, p.value, p.std) for name, p in unc.parameters.items()]
    high = [(h.a, h.b, h.correlation) for h in unc.high_correlations]
    return _uncertainty_blocks(params, high, unc.scaled_by_variance_factor)


def _or_dash(value: Any) -> Any:
    return "-" if value is None else value


def _finite(value: float | None) -> float | None:
    """A number for a table cell; None (an empty cell) where the file has none or null."""
    return value if value is not None and math.isfinite(value) else None


def _uncertainty_blocks(params: list[tuple[str, Any, Any]], high: list[tuple[str, str, float]], scaled: bool) -> Part:
    rows = []
    for name, v, s in params:
        rel = abs(s / v) * 100 if isinstance(v, int | float) and isinstance(s, int | float) and v else float("nan")
        rows.append([name, (v, 6), (s, 6), (rel, 2)])
    out: list[Block] = []
    if rows:
        out.append(table(["parameter", "value", "1-sigma", "1-sigma / |value| (%)"], rows,
                         caption="free parameters (rotation vector rad; translation in CRS units; focal px; "
                                 "distortion unitless); from the fit covariance"
                                 + (", scaled by sigma0^2" if scaled else "")))
    if high:
        out.append(items([f"parameters {a} and {b_} are {abs(corr):.3f} correlated" for a, b_, corr in high], "warn"))
    if not params:
        out.append(Text("Only the propagated 1-sigma of position, angles and focal length are stored in the camera "
                        "JSON (see the camera table); the per-parameter table needs the calibration report.", "note"))
    return tuple(out)


def _gcp_residual_table(b: ReportContext) -> Part:
    g = b.gcps
    assert g is not None
    has_pred = "predicted_m" in g.columns
    cols = ["id", "role", "status", "u", "v", "du", "dv", "|e| px", "LOO px", "ground m", "LOO ground m"]
    cols += ["predicted 1-sigma m"] if has_pred else []
    cols += ["outlier / reason"]
    rows, classes = [], []
    for r in g.to_dict("records"):
        row = [r["id"], r["role"], r["status"], (r["u"], 1), (r["v"], 1), (r["du"], 2), (r["dv"], 2),
               (r["error_px"], 2), (r["loo_error_px"], 2), (r["ground_error_m"], 3), (r["loo_ground_error_m"], 3)]
        if has_pred:
            row.append((r["predicted_m"], 3))
        row.append(("OUTLIER: " if r["status"] == "outlier" else "") + r["reason"])
        rows.append(row)
        classes.append(r["status"] if r["status"] in ("outlier", "check") else "")
    note = ("du, dv: projected minus clicked (px). Ground: horizontal distance (m) from the surveyed X, Y to where "
            "the clicked pixel's ray meets the point's elevation; LOO: with the camera fitted without the point."
            + (" Predicted 1-sigma: the accuracy map at the point (calibration covariance and 1 px pixel noise), "
               "to compare with the leave-one-out ground error." if has_pred else ""))
    return Heading("Per-GCP residuals"), table(cols, rows, row_classes=classes), Text(note, "note")


def accuracy_section(b: ReportContext) -> Section | None:
    """The accuracy map with what it predicts at the GCPs against what was measured there; None without one."""
    if b.grid is None:
        return None
    values, bounds = b.grid.values, b.grid.bounds
    left, bottom, right, top = bounds
    cam_xy = (float(b.camera.position[0]), float(b.camera.position[1])) if b.camera is not None else None
    gxy = b.gcps[["x", "y"]].to_numpy(float) if b.gcps is not None else None
    xs = [np.array([left, right])] + ([np.array([cam_xy[0]])] if cam_xy else [])
    ys = [np.array([bottom, top])] + ([np.array([cam_xy[1]])] if cam_xy else [])
    bg = b.background(xs, ys, "accuracy map")
    finite = values[np.isfinite(values)]
    text = [f"Source: {b.grid.source}."]
    if finite.size:
        text.append(f"Over the visible ground the expected 1-sigma horizontal error ranges from {finite.min():.2f} m "
                    f"to {finite.max():.2f} m (median {np.median(finite):.2f} m).")
    if b.gcps is not None and "predicted_m" in b.gcps.columns and b.report is not None:
        s = b.report.stats
        inl = b.gcps[b.gcps["status"] == "inlier"]
        if inl["predicted_m"].notna().any():
            text.append(f"At the inlier GCPs it predicts {np.nanmedian(inl['predicted_m']):.3f} m (median); the "
                        f"leave-one-out ground error measured there is {num(s.loo_ground_median_m, 3)} m "
                        f"(median), RMSE {num(s.loo_ground_rmse_m, 3)} m.")
        c = b.report.check
        if c.n:
            text.append(f"Check points, never used in the fit: ground RMSE {num(c.ground_rmse_m, 3)} m.")
    fig = F.accuracy_map(values, bounds, b.axes, background=bg, camera_xy=cam_xy, gcps_xy=gxy)
    shown = figure(fig, "Expected 1-sigma horizontal ground error (m) of a point seen by the camera: calibration "
                   "uncertainty and pixel noise carried through the ray-surface intersection; contours in metres.",
                   b.dpi)
    return Section("accuracy", "Accuracy map", ((Text(" ".join(text)), shown),))
