"""Traffic commands: analyze (image tracks -> trajectories, lanes, counts) and compare-sumo (thin wrappers over
:mod:`trafficgeo.traffic`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli import app, console
from trafficgeo.cli.geo import ResolutionOpt, SurfaceCrsOpt, SurfaceOpt, _camera, _surface
from trafficgeo.errors import InputError


def _check_out_dir(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder; give a folder for the outputs")


def print_analysis(analysis) -> None:
    """Totals and per-line counts on the terminal."""
    from rich.table import Table

    from trafficgeo.traffic.analyze import summary

    s = summary(analysis)
    t0, t1 = s["period_s"]
    dropped = ", ".join(f"{k} {v}" for k, v in s["dropped_points"].items()) or "none"
    speed = f"{s['mean_speed_kmh']:.1f} km/h" if s["mean_speed_kmh"] is not None else "-"
    classes = ", ".join(f"{k or 'unknown'} {v}" for k, v in s["classes"].items())
    console.print(f"{s['vehicles']} vehicles ({classes}) in {t1 - t0:.1f} s; {s['points']} track points, "
                  f"{s['outlier_points']} rejected as outliers; not used: {dropped}")
    console.print(f"mean speed over the observed paths: {speed}; lane changes: {s['lane_changes']}")
    if s["crossings"]:
        table = Table(title="crossings per counting line")
        for col in ("line", "lane", "direction", "vehicles", "flow veh/h", "mean speed km/h"):
            table.add_column(col, justify="right")
        dur = max(t1 - t0, 1e-9)
        cr = analysis.crossings
        for row in s["crossings"]:
            sel = cr[(cr["line"] == row["line"]) & (cr["lane"] == row["lane"]) & (cr["direction"] == row["direction"])]
            table.add_row(row["line"], row["lane"] or "-", f"{row['direction']:+d}", str(row["count"]),
                          f"{row['count'] * 3600.0 / dur:.0f}", f"{sel['speed_kmh'].mean():.1f}")
        console.print(table)


@app.command()
def analyze(
    camera: Annotated[Path, typer.Argument(help="camera JSON from 'trafficgeo calibrate'")],
    tracks: Annotated[Path, typer.Argument(help="tracks: CSV (frame,track_id and u,v or x1,y1,x2,y2; optional "
                                           "class,score,time) or MOT Challenge .txt")],
    surface: SurfaceOpt,
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    fps: Annotated[float | None, typer.Option(help="frame rate when the tracks have no time column")] = None,
    lanes: Annotated[Path | None, typer.Option(help="lane polygons or boundary lines (GIS file), or boundary "
                                               "lines drawn in the image (CSV line,u,v)")] = None,
    lines: Annotated[Path | None, typer.Option(help="counting lines (GIS file, or CSV line,u,v in the image)")] = None,
    interval: Annotated[float, typer.Option(help="counting interval (s), e.g. 60 or 900")] = 60.0,
    pixel_sigma: Annotated[float, typer.Option(help="noise of a track's ground point in the image (px)")] = 2.0,
    accel_sigma: Annotated[float, typer.Option(help="how hard vehicles may accelerate/turn in the smoother "
                                               "(m/s^2)")] = 1.5,
    box_correction: Annotated[bool, typer.Option(help="fit a vehicle cuboid to each box for its footprint "
                                                 "centre")] = True,
    surface_crs: SurfaceCrsOpt = None,
    resolution: ResolutionOpt = 0.25,
) -> None:
    """Image tracks to world trajectories, true speeds (km/h), lanes and counts at counting lines."""
    from rich.progress import Progress

    from trafficgeo.traffic.analyze import analyze as run_analysis
    from trafficgeo.traffic.analyze import write_analysis
    from trafficgeo.traffic.lanes import read_lanes
    from trafficgeo.traffic.lines import read_count_lines
    from trafficgeo.traffic.tracks import read_tracks
    from trafficgeo.traffic.trajectories import TrajectoryOptions

    _check_out_dir(out)
    if not interval > 0:
        raise InputError(f"--interval {interval} must be a positive number of seconds, e.g. 60")
    opts = TrajectoryOptions(pixel_sigma=pixel_sigma, accel_sigma=accel_sigma, box_correction=box_correction)
    cam, doc = _camera(camera)
    image_tracks = read_tracks(tracks, fps=fps)
    surf = _surface(surface, cam, doc, surface_crs, resolution, str(camera))
    lane_set = read_lanes(lanes, cam, surf) if lanes is not None else None
    count_lines = read_count_lines(lines, cam, surf) if lines is not None else None
    console.print(f"surface: {surf.describe()}")
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("tracks", total=len(image_tracks.track_ids))
        analysis = run_analysis(cam, surf, image_tracks, lanes=lane_set, lines=count_lines, interval_s=interval,
                                options=opts, progress=lambda i, n: progress.update(task, completed=i))
    written = write_analysis(out, analysis, cam)
    print_analysis(analysis)
    console.print(f"wrote {', '.join(p.name for p in written)} in {out}")
