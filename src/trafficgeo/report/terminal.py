"""Readable terminal tables of a calibration report (rich)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.table import Table

if TYPE_CHECKING:
    from trafficgeo.calibration.report import CalibrationReport


def _f(x: Any, nd: int = 2) -> str:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return "-"
    return "-" if v != v else f"{v:.{nd}f}"


def print_calibration_report(report: CalibrationReport, console: Console | None = None) -> None:
    """Print the camera, per-GCP residuals, accuracy figures, warnings and recommendations."""
    con = console or Console()
    cam = report.camera
    o = cam.orientation
    pos = cam.position
    unc = report.uncertainty
    ps = unc.position_std_m
    con.print(f"[bold]Camera[/bold]  ({report.crs or 'local coordinates'}, image {report.image_size[0]}x"
              f"{report.image_size[1]})")
    con.print(f"  focal {cam.focal_px:.1f} +/- {unc.focal_std_px:.1f} px, field of view "
              f"{cam.fov_deg[0]:.1f} x {cam.fov_deg[1]:.1f} deg, k1 {cam.dist[0]:.4f} k2 {cam.dist[1]:.4f}")
    con.print(f"  position X {pos[0]:.3f}  Y {pos[1]:.3f}  Z {pos[2]:.3f}  "
              f"(+/- {ps[0]:.2f}, {ps[1]:.2f}, {ps[2]:.2f} m)")
    os_ = unc.orientation_std_deg
    con.print(f"  heading {o.heading_deg:.2f} +/- {os_.heading:.2f} deg, tilt {o.tilt_deg:.2f} +/- "
              f"{os_.tilt:.2f} deg, roll {o.roll_deg:.2f} +/- {os_.roll:.2f} deg")
    con.print(f"  model: {report.model.description}")
    for reason in report.model.reasons:
        con.print(f"    - {reason}")

    t = Table(title="GCP residuals (px: projected - observed; ground: metres)", show_lines=False)
    for col in ("id", "role", "status", "du", "dv", "|e| px", "LOO px", "ground m", "LOO ground m"):
        t.add_column(col, justify="right" if col not in ("id", "role", "status") else "left")
    for r in report.gcps:
        style = "red" if r.status == "outlier" else ("cyan" if r.status == "check" else None)
        t.add_row(r.id, r.role, r.status, _f(r.du, 1), _f(r.dv, 1), _f(r.error_px, 2), _f(r.loo_error_px, 2),
                  _f(r.ground_error_m, 3), _f(r.loo_ground_error_m, 3), style=style)
    con.print(t)

    s = report.stats
    con.print(f"[bold]Fit[/bold]: {s.n_inliers} of {s.n_control} control points kept in the final fit; "
              f"mean {s.mean_px:.2f} px, RMSE {s.rmse_px:.2f} px, max {s.max_px:.2f} px; "
              f"leave-one-out RMSE {s.loo_rmse_px:.2f} px = {s.loo_ground_rmse_m:.3f} m on the ground; "
              f"redundancy {s.redundancy}; sigma0 {s.sigma0:.2f}")
    c = report.check
    if c.n:
        con.print(f"[bold]Check points[/bold] ({c.n}, not used in the fit): RMSE {c.rmse_px:.2f} px, ground "
                  f"RMSE {c.ground_rmse_m:.3f} m, max {c.ground_max_m:.3f} m")
    d = report.distance_ratios
    if d.n_pairs:
        con.print(f"[bold]Distance ratios[/bold] (eq. 15, {d.n_pairs} pairs): mean {d.mean_pct:.2f} %, median "
                  f"{d.median_pct:.2f} %, max {d.max_pct:.2f} %")
    p = report.pose_consistency
    if p.available:
        sp = p.position_spread_m
        ang = p.angle_spread_deg
        con.print(f"[bold]Pose consistency[/bold] over {p.n_fits} leave-one-out fits: position spread "
                  f"{sp[0]:.2f}, {sp[1]:.2f}, {sp[2]:.2f} m (max shift {p.max_position_deviation_m:.2f} m without "
                  f"{p.most_influential_gcp}); heading {ang.heading:.2f}, tilt {ang.tilt:.2f}, roll "
                  f"{ang.roll:.2f} deg")
    for ol in report.outliers:
        con.print(f"[red]outlier[/red] {ol.id}: {ol.reason}")
    for w in report.warnings:
        con.print(f"[yellow]warning[/yellow]: {w}")
    con.print("[bold]Recommendations[/bold]")
    for rec in report.recommendations:
        con.print(f"  - {rec}")
    con.print(f"[bold]{report.summary}[/bold]")
