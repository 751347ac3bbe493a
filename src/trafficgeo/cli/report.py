"""Report command: ``trafficgeo report RUN_DIR -o report.html`` (a thin wrapper over :mod:`trafficgeo.report.html`),
and the ``--report-html`` check shared by calibrate, analyze and process."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from trafficgeo.cli.app import app, console
from trafficgeo.errors import InputError

HTML_SUFFIXES = (".html", ".htm")


def check_html_path(path: Path | None, option: str = "--report-html") -> None:
    """Fail early (before any work) when the page could not be written where asked."""
    if path is None:
        return
    if path.suffix.lower() not in HTML_SUFFIXES:
        raise InputError(f"{option} {path}: the report is an HTML page; name it .html (e.g. report.html)")
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder; give the file to write, e.g. {path / 'report.html'}")
    from trafficgeo.io.run_manifest import check_writable_file

    check_writable_file(path, option)


def write_page(path: Path, run_dir: Path, **options: object) -> None:
    """Build the page from ``run_dir`` (options as :func:`trafficgeo.report.html.build_page`), write it atomically
    and say what it holds and what it left out."""
    from trafficgeo.report.html import write_report_html

    page = write_report_html(path, run_dir, **options)
    size = len(page.html.encode("utf-8")) / 1e6
    console.print(f"wrote {path} ({size:.1f} MB): {', '.join(page.sections)}", markup=False, highlight=False)
    for section, reason in page.left_out:
        console.print(f"  left out: {section}: {reason}", markup=False, highlight=False)


@app.command()
def report(
    run_dir: Annotated[Path, typer.Argument(help="output folder of calibrate / analyze / process (or one holding "
                                            "several of them in sub-folders)")],
    output: Annotated[Path, typer.Option("--output", "-o", help="HTML page to write")],
    camera: Annotated[Path | None, typer.Option(help="camera JSON (default: camera.json in RUN_DIR)")] = None,
    calibration_report: Annotated[Path | None, typer.Option(help="calibration report JSON from 'calibrate --report' "
                                                            "(default: report.json in RUN_DIR)")] = None,
    frame: Annotated[Path | None, typer.Option(help="image of the video frame the GCPs were clicked on (PNG/JPEG)")
                     ] = None,
    video: Annotated[Path | None, typer.Option(help="video to take that frame from, when there is no image")] = None,
    ortho: Annotated[Path | None, typer.Option(help="orthophoto GeoTIFF behind the maps (default: ortho.tif)")
                     ] = None,
    dem: Annotated[Path | None, typer.Option(help="DEM GeoTIFF for the accuracy map when RUN_DIR has no "
                                             "accuracy.tif (default: dem.tif; else the GCP plane)")] = None,
    refine_report: Annotated[Path | None, typer.Option(help="report JSON of 'trafficgeo refine --report' (default: "
                                                       "the one the camera JSON's refinement names)")] = None,
) -> None:
    """One self-contained HTML page of a run: calibration, orthophoto refinement, accuracy map and traffic figures and
    tables.

    Every section whose inputs exist is included; the page lists the ones left out and why. Files are found by
    name in RUN_DIR and its sub-folders; the options override them.
    """
    check_html_path(output, "--output")
    write_page(output, run_dir, camera=camera, calibration_report=calibration_report, frame=frame, video=video,
               ortho=ortho, dem=dem, refine_report=refine_report)
