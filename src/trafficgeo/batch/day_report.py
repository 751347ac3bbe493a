"""The HTML report of a camera-day (``DATASET/reports/camera=<id>/date=<day>/report.html``).

The track task writes the day's merged analysis (:func:`trafficgeo.batch.dataset.merge_day`: times in seconds since
the camera's local midnight, positions in the camera's CRS) as an ``analyze`` run folder in
``DATASET/_work/reports/<camera>_<day>/``, builds the page of ``trafficgeo report`` from it and the camera JSON (with
the calibration report found beside it), writes the page atomically and removes the run folder. The page is one of
the task's outputs (checksummed in its ``_SUCCESS.json``); the camera option ``"report": false`` turns it off.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

__all__ = ["REPORTS", "report_path", "write_day_report"]

REPORTS = "reports"


def report_path(dataset: str | os.PathLike, camera_id: str, day: str) -> Path:
    """Where the report of camera ``camera_id`` on ``day`` (YYYY-MM-DD, local) goes in ``dataset``."""
    return Path(dataset) / REPORTS / f"camera={camera_id}" / f"date={day}" / "report.html"


def write_day_report(dataset: str | os.PathLike, camera_id: str, day: str, timezone: str, analysis: Any,
                     camera: Any, camera_file: str | os.PathLike) -> Path:
    """Write the report of one camera-day (``day`` in the camera's ``timezone``) from its merged ``analysis`` (a
    TrafficResult) and its ``camera`` (read from ``camera_file``); returns the page's path. Nothing is left in the
    work folder, whatever happens."""
    from trafficgeo.report.html import write_report_html
    from trafficgeo.traffic.analyze import write_analysis

    work = Path(dataset) / "_work" / REPORTS / f"{camera_id}_{day}"
    if work.exists():
        shutil.rmtree(work)
    try:
        write_analysis(work, analysis, camera)
        path = report_path(dataset, camera_id, day)
        path.parent.mkdir(parents=True, exist_ok=True)
        about = [("camera, day", f"{camera_id}, {day} ({timezone}); times in s since local midnight"),
                 ("dataset", str(Path(dataset).resolve()))]
        write_report_html(path, work, camera=camera_file, title=f"trafficgeo report: camera {camera_id}, {day}",
                          about=about)
    finally:
        shutil.rmtree(work, ignore_errors=True)
        for folder in (work.parent, work.parent.parent):  # _work/reports and _work, when empty
            try:
                folder.rmdir()
            except OSError:
                pass
    return path
