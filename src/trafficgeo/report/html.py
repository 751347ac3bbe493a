"""``trafficgeo report``: one self-contained HTML page of a run folder - figures embedded as PNG, tables, no links.

A run folder may hold any subset of what trafficgeo writes; every section whose inputs exist is included and the
page lists the ones left out, with the reason and the option that would add them. Files are found by name in the
folder, then in its sub-folders (then beside the camera JSON), unless given explicitly:

* calibration: ``camera.json`` (``--camera``) and the validation report ``report.json`` (``--calibration-report``);
  from them the per-GCP residuals, fit statistics, parameter uncertainty, warnings and recommendations, the
  residual vectors on a frame of the video and the GCPs, camera and footprint on the map;
* a frame to draw on: ``--frame``, a ``frame`` key of the camera JSON, ``frame.png``/``.jpg``, or a frame of the
  video named in a process run's ``process.json`` (or ``--video``, or a ``video.mp4`` in the folder);
* ``accuracy.tif`` (``trafficgeo accuracy``), or else the accuracy map computed from the camera JSON's covariance
  on the DEM (``dem.tif``, ``--dem``) or on the GCP plane; ``site.gpkg`` for the footprint;
* an orthophoto (``ortho.tif``, ``--ortho``) behind the plan views, reprojected on the fly when its CRS differs;
* an orthophoto refinement: the report JSON of ``trafficgeo refine --report`` that the camera JSON's
  ``refinement.report`` key names beside it (``--refine-report``), with its ``<stem>_frame.jpg``;
* traffic runs: every folder (the run folder or a sub-folder) with the outputs of ``analyze``/``process``
  (``summary.json`` with ``vehicles.csv``/``trajectories.csv``, ``counts.csv``, ``crossings.csv``, ``process.json``);
  with a junction's gates also ``movements.csv``, ``turning_movements.csv`` and the ``gates`` layer of
  ``trajectories.gpkg`` (its turning movements, :mod:`trafficgeo.report.movement_section`);
  a comparison with SUMO in it (``compare_counts.csv``...) is part of its traffic section, or, when
  ``sumo-validate`` wrote it (``compare_simulation.json``), a Simulation section of its own.

Units: pixels (px) in the image; positions in the CRS's units (m or ft) relative to a local origin on the plan
views; ground errors and distances in metres; speeds in km/h; times in seconds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from trafficgeo.calibration.report import CalibrationReport
from trafficgeo.errors import InputError
from trafficgeo.registration.refine_record import read_refine_record
from trafficgeo.report.blocks import Section
from trafficgeo.report.context import ReportContext, load_context, read_background
from trafficgeo.report.inputs import ReportInputs, TrafficRun, find_inputs
from trafficgeo.report.refine_section import refinement_section
from trafficgeo.report.render import render_page
from trafficgeo.report.sections import accuracy_section, calibration_sections
from trafficgeo.report.simulation_section import simulation_section
from trafficgeo.report.traffic_sections import comparison_table, traffic_section

__all__ = ["ReportInputs", "ReportPage", "TrafficRun", "build_page", "build_report", "find_inputs", "read_background",
           "write_report_html"]


@dataclass(frozen=True)
class ReportPage:
    """A built page: the HTML text, the section titles included, and (section, reason) for those left out."""

    html: str
    sections: tuple[str, ...]
    left_out: tuple[tuple[str, str], ...]


def _header(b: ReportContext, about: Sequence[tuple[str, str]] = ()) -> list[tuple[str, str]]:
    """(label, value) rows at the top of the page: the folder (or what ``about`` says the page is about), when, the
    version, the CRS and the inputs used."""
    from trafficgeo.crs import crs_label
    from trafficgeo.version import __version__

    unit = b.axes.unit if b.m_per_unit == 1.0 else f"{b.axes.unit} (1 {b.axes.unit} = {b.m_per_unit:.10g} m)"
    crs = (f"{crs_label(b.crs)}; units {unit}; ground errors and distances in m, speeds in km/h"
           if b.crs is not None else "none (local coordinates, taken as metres)")
    rows = [*(about or [("run folder", str(b.inputs.run_dir.resolve()))]),
            ("created", datetime.now().astimezone().isoformat(timespec="seconds")),
            ("trafficgeo version", str(__version__)), ("CRS", crs),
            ("plan-view origin", f"easting {b.axes.origin[0]:.0f}, northing {b.axes.origin[1]:.0f} ({b.axes.unit})")]
    return rows + [(f"input: {what}", str(path)) for what, path in b.used]


def build_page(run_dir: str | Path, *, camera: str | Path | None = None,
               calibration_report: str | Path | CalibrationReport | Mapping[str, Any] | None = None,
               frame: str | Path | None = None, ortho: str | Path | None = None, dem: str | Path | None = None,
               video: str | Path | None = None, refine_report: str | Path | None = None, dpi: int = 100,
               title: str | None = None, about: Sequence[tuple[str, str]] = ()) -> ReportPage:
    """The page with its list of sections and of those left out (see :func:`build_report`); ``title`` replaces the
    page's title (the folder's name) and ``about`` rows (label, value) the header's run folder row."""
    inputs = find_inputs(run_dir, camera=camera, calibration_report=calibration_report, frame=frame, ortho=ortho,
                         dem=dem, video=video, refine_report=refine_report)
    if inputs.empty:
        raise InputError(f"{inputs.run_dir}: nothing to report: no camera.json, calibration report.json, "
                         "accuracy.tif or analyze/process outputs (summary.json with vehicles.csv) in it or its "
                         "sub-folders; give such a folder, or `camera` / calibration_report",
                         parameters=("camera", "calibration_report"))
    refine = read_refine_record(inputs.refine_report) if inputs.refine_report is not None else None  # fail early
    b = load_context(inputs, dpi)
    sections: list[Section] = calibration_sections(b)
    refinement = refinement_section(b, refine)
    if refinement is not None:
        sections.append(refinement)
    accuracy = accuracy_section(b)
    if accuracy is not None:
        sections.append(accuracy)
    if not inputs.traffic:
        b.skip("traffic", "no analyze/process outputs (summary.json with vehicles.csv / trajectories.csv) in the "
               "folder or its sub-folders: run 'trafficgeo analyze' or 'process' with --out in it")
    for k, run in enumerate(inputs.traffic):
        sections.append(traffic_section(b, run, k + 1))
        compare = comparison_table(run, "compare_counts.csv") if run.simulation is not None else None
        if compare is not None and len(compare):
            sections.append(simulation_section(b, run, k + 1, compare))
    left = list(dict.fromkeys(b.left_out))
    html = render_page(title or f"trafficgeo report: {inputs.run_dir.resolve().name}", _header(b, about), sections,
                       left)
    return ReportPage(html, tuple(s.title for s in sections), tuple(left))


def build_report(run_dir: str | Path, *, camera: str | Path | None = None,
                 calibration_report: str | Path | CalibrationReport | Mapping[str, Any] | None = None,
                 frame: str | Path | None = None, ortho: str | Path | None = None, dem: str | Path | None = None,
                 video: str | Path | None = None, refine_report: str | Path | None = None, dpi: int = 100) -> str:
    """One self-contained HTML page (figures as base64 PNG, inline CSS, no links out) of what ``run_dir`` holds.

    ``calibration_report`` may be the report itself (:class:`~trafficgeo.calibration.CalibrationReport`) or its
    report.json document as a dictionary. Files not given are looked for by name (module
    docstring).

    Raises:
        InputError: ``run_dir`` is not a folder, there is nothing to report, or an input cannot be read.
    """
    return build_page(run_dir, camera=camera, calibration_report=calibration_report, frame=frame, ortho=ortho,
                      dem=dem, video=video, refine_report=refine_report, dpi=dpi).html


def write_report_html(path: str | Path, run_dir: str | Path, **options: Any) -> ReportPage:
    """Build the page (:func:`build_page`, same options) and write it to ``path`` atomically; nothing is written
    when building fails."""
    from trafficgeo.io.atomic import write_text_atomic

    page = build_page(run_dir, **options)
    write_text_atomic(path, page.html)
    return page
