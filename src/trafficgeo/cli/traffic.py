"""Traffic commands: analyze (image tracks -> trajectories, lanes, counts) and compare-sumo (thin wrappers over
:mod:`trafficgeo.traffic`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console
from trafficgeo.cli.geo import ResolutionOpt, SurfaceCrsOpt, SurfaceOpt, camera_argument
from trafficgeo.errors import InputError

LanesOpt = Annotated[Path | None, typer.Option(help="lane polygons or boundary lines (GIS), or boundary lines drawn "
                                               "in the image (CSV line,u,v)")]
LinesOpt = Annotated[Path | None, typer.Option(help="counting lines (GIS file, or CSV line,u,v in the image)")]
GatesOpt = Annotated[Path | None, typer.Option(help="a junction's gates for turning movements: one line across each "
                                               "arm with an 'arm' attribute (GIS file in any CRS, or CSV line,u,v "
                                               "in the image: the line name is the arm); writes movements.csv, "
                                               "movement_counts.csv and turning_movements.csv")]
MovementIntervalOpt = Annotated[float, typer.Option(help="interval of the turning-movement counts (s); 900 = the "
                                                    "15 minutes of junction studies")]
IntervalOpt = Annotated[float, typer.Option(help="counting interval (s), e.g. 60 or 900")]
ReportHtmlOpt = Annotated[Path | None, typer.Option(help="also write an HTML report of the run (figures and tables, "
                                                    "see 'trafficgeo report')")]



def check_out_dir(out: Path) -> None:
    """Fail before any work when ``--out`` cannot be written."""
    from trafficgeo.io.run_manifest import check_writable_folder

    check_writable_folder(out, "--out")


@app.command()
def analyze(
    camera: Annotated[Path, typer.Argument(help="camera JSON from 'trafficgeo calibrate'")],
    tracks: Annotated[Path, typer.Argument(help="tracks: CSV (frame,track_id and u,v or x1,y1,x2,y2; optional "
                                           "class,score,time) or MOT Challenge .txt")],
    surface: SurfaceOpt,
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    fps: Annotated[float | None, typer.Option(help="frame rate when the tracks have no time column")] = None,
    lanes: LanesOpt = None,
    lines: LinesOpt = None,
    gates: GatesOpt = None,
    interval: IntervalOpt = 60.0,
    movement_interval: MovementIntervalOpt = 900.0,
    pixel_sigma: Annotated[float | None, typer.Option(help="noise of a track's ground point in the image (px); "
                                                      "default 2, 3 with --gates")] = None,
    box_sigma_share: Annotated[float | None, typer.Option(help="more noise for bigger boxes: this share of a box's "
                                                          "height (px) added to --pixel-sigma in quadrature; "
                                                          "default 0, 0.05 with --gates")] = None,
    accel_sigma: Annotated[float | None, typer.Option(help="how hard vehicles may accelerate/turn in the smoother "
                                                      "(m/s^2); default 1.5")] = None,
    box_correction: Annotated[bool, typer.Option(help="fit a vehicle cuboid to each box for its footprint "
                                                 "centre")] = True,
    max_metres_per_px: Annotated[float, typer.Option(help="points farther away, where one pixel spans more road "
                                                     "(m), are not used")] = 1.5,
    coast_hidden: Annotated[float, typer.Option(help="seconds a vehicle that vanishes behind a nearer one is "
                                                "carried on, to count the lines it passes unseen (0: off)")] = 3.0,
    join_gap: Annotated[float, typer.Option(help="the longest time (s) a vehicle may go unseen between two pieces "
                                            "of its track that are joined into one vehicle (0: not joined)")] = 4.0,
    surface_crs: SurfaceCrsOpt = None,
    resolution: ResolutionOpt = 0.25,
    report_html: ReportHtmlOpt = None,
) -> None:
    """Image tracks to world trajectories, true speeds (km/h), lanes, counts at counting lines and, with --gates,
    turning movements."""
    from rich.progress import Progress

    from trafficgeo.cli.report import check_html_path
    from trafficgeo.io.folder_lock import hold_folder
    from trafficgeo.report.traffic import print_analysis
    from trafficgeo.run.folder import RunFolder
    from trafficgeo.site.surface import check_resolution, load_surface
    from trafficgeo.traffic.analyze import analyze_tracks
    from trafficgeo.traffic.counts import check_interval
    from trafficgeo.traffic.journeys import JourneyOptions
    from trafficgeo.traffic.movements import check_movement_interval
    from trafficgeo.traffic.outputs import write_traffic
    from trafficgeo.traffic.tracks import read_tracks
    from trafficgeo.traffic.trajectories import TrajectoryOptions

    check_out_dir(out)
    check_html_path(report_html)
    check_interval(interval)
    check_movement_interval(movement_interval)
    check_resolution(resolution)
    journeys = JourneyOptions.with_gap(join_gap, at_junction=gates is not None)  # before any work
    given = {k: v for k, v in (("pixel_sigma", pixel_sigma), ("box_sigma_share", box_sigma_share),
                               ("accel_sigma", accel_sigma)) if v is not None}
    smoother = TrajectoryOptions.at_junction if gates is not None else TrajectoryOptions  # its defaults
    opts = smoother(**given, box_correction=box_correction, max_metres_per_px=max_metres_per_px,
                    coast_hidden_s=coast_hidden)
    calibrated = camera_argument(camera)  # a bad camera file is named before the tracks are read
    folder = RunFolder(out)
    with hold_folder(out):  # refused at once while another run writes this folder; a run there stays until written
        image_tracks = read_tracks(tracks, fps=fps)
        surf = load_surface(surface, calibrated, surface_crs=surface_crs, resolution_m=resolution)
        console.print(f"surface: {surf.describe()}")
        with Progress(console=console, transient=True) as progress:
            task = progress.add_task("tracks", total=len(image_tracks.track_ids))
            analysis = analyze_tracks(calibrated, surf, image_tracks, lanes, lines, interval_s=interval,
                                      options=opts, progress=lambda i, n: progress.update(task, completed=i),
                                      journeys=journeys, gates=gates, movement_interval_s=movement_interval)
        with folder.writing("analyze") as run:
            written = write_traffic(run, analysis, calibrated)
    print_analysis(analysis, console)
    console.print(f"wrote {', '.join(p.name for p in written)} in {out}")
    if report_html is not None:
        from trafficgeo.cli.report import write_page

        write_page(report_html, out, camera=camera)


@app.command("compare-sumo")
def compare_sumo(
    observed: Annotated[Path, typer.Argument(help="output folder of 'trafficgeo analyze'")],
    fcd: Annotated[Path, typer.Argument(help="SUMO FCD output (--fcd-output) of the simulation")],
    net: Annotated[Path | None, typer.Option(help="the simulation's .net.xml (network coordinates -> world)")] = None,
    net_crs: Annotated[str | None, typer.Option(help="CRS of the network's projection when its PROJ string is not "
                                                "enough, e.g. EPSG:2949")] = None,
    lines: Annotated[Path | None, typer.Option(help="counting lines (GIS file in world coordinates); default: the "
                                               "ones analyze used")] = None,
    time_offset: Annotated[float, typer.Option(help="simulation time minus observed time (s)")] = 0.0,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="output folder (default: OBSERVED)")] = None,
) -> None:
    """Observed vs simulated traffic: per-lane counts (GEH), spot speeds (KS) and travel times."""
    import math

    from trafficgeo.report.traffic import print_comparison
    from trafficgeo.traffic.validation import compare_with_sumo, read_observed_run, write_comparison

    out = out or observed
    check_out_dir(out)
    if not math.isfinite(time_offset):
        raise InputError(f"--time-offset {time_offset}: give the simulation's time minus the observed time as a "
                         "finite number of seconds, e.g. 0")
    run = read_observed_run(observed)
    comparison = compare_with_sumo(run, fcd, net=net, net_crs=net_crs, lines=lines, time_offset_s=time_offset)
    written = write_comparison(out, comparison, run.crs)
    print_comparison(comparison, console)
    console.print(f"wrote {', '.join(p.name for p in written)} in {out}")


@app.command("export-fcd")
def export_fcd(
    run: Annotated[Path, typer.Argument(help="output folder of 'trafficgeo analyze'")],
    output: Annotated[Path, typer.Option("--output", "-o", help="SUMO FCD file to write (.xml)")],
    net: Annotated[Path | None, typer.Option(help="write in this SUMO network's coordinates (.net.xml)")] = None,
    net_crs: Annotated[str | None, typer.Option(help="CRS of the network's projection, e.g. EPSG:2949")] = None,
    geo: Annotated[bool, typer.Option(help="write lon/lat (like sumo --fcd-output.geo)")] = False,
) -> None:
    """Export the observed trajectories as SUMO FCD (front bumpers, m/s) for replay and comparison in SUMO."""
    from trafficgeo.io.run_manifest import check_writable_file
    from trafficgeo.run.folder import RunFolder
    from trafficgeo.traffic.validation import export_fcd as write_observed_fcd

    if output.suffix.lower() != ".xml":
        raise InputError(f"--output {output}: SUMO FCD is XML; name it .xml (e.g. observed.fcd.xml)")
    check_writable_file(output)
    n = write_observed_fcd(run, output, net=net, net_crs=net_crs, geo=geo)
    vehicles = RunFolder(run).table("trajectories.csv", required=("track_id",))["track_id"].nunique()
    console.print(f"{vehicles} vehicles, {n} points -> wrote {output}")
