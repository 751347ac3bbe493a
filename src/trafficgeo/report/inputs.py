"""The inputs of a report: the files of a run folder (and beside the camera JSON), found by name unless given
(see :mod:`trafficgeo.report.html` for the names and the order of the search), as plain dataclasses."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from trafficgeo.calibration.report import REPORT_FORMAT, CalibrationReport
from trafficgeo.camera.calibrated import CalibratedCamera
from trafficgeo.errors import InputError
from trafficgeo.io.json_text import loads_json
from trafficgeo.io.run_manifest import MANIFEST, RunIncompleteError
from trafficgeo.run.folder import RunFolder
from trafficgeo.run.records import CompareSummary, ProcessRecord, RunSummary, SimulationRecord

CAMERA_NAMES = ("camera.json",)
REPORT_NAMES = ("report.json", "calibration_report.json", "calibration.json")
FRAME_NAMES = ("frame.png", "frame.jpg", "frame.jpeg")
FRAME_KEYS = ("frame", "frame_path", "frame_image")
VIDEO_NAMES = ("video.mp4", "video.mov", "video.mkv", "video.avi")
ORTHO_NAMES = ("ortho.tif", "ortho.tiff", "orthophoto.tif", "orthophoto.tiff", "ortho.vrt")
DEM_NAMES = ("dem.tif", "dem.tiff")
ACCURACY_NAMES = ("accuracy.tif",)
SITE_NAMES = ("site.gpkg",)


@dataclass(frozen=True)
class TrafficRun:
    """An ``analyze``/``process`` output folder (read through :class:`~trafficgeo.run.folder.RunFolder`):
    its ``summary.json`` and, for process runs, ``process.json``, as typed records."""

    folder: Path
    summary: RunSummary
    process: ProcessRecord | None = None
    compare: bool = False  # compare-sumo results are in the folder and match their manifest
    compare_problem: str | None = None  # why compare-sumo results in the folder are not used
    simulation: SimulationRecord | None = None  # sumo-validate's record: the comparison is of a trafficgeo scenario
    compare_summary: CompareSummary | None = None  # compare-sumo's compare_summary.json, when compare
    run_folder: RunFolder | None = field(default=None, repr=False, compare=False)  # the checked folder, if read

    @property
    def run(self) -> RunFolder:
        """The run folder, to read its tables (its manifest checked once)."""
        return self.run_folder if self.run_folder is not None else RunFolder(self.folder)


@dataclass(frozen=True)
class ReportInputs:
    """The files a report is built from (None: not given and not found)."""

    run_dir: Path
    camera: Path | None = None
    calibration_report: Path | CalibrationReport | None = None  # a file, or the report itself
    frame: Path | None = None
    frame_given: bool = False
    video: Path | None = None
    video_given: bool = False
    video_time_s: float = 0.0
    ortho: Path | None = None
    dem: Path | None = None
    accuracy: Path | None = None
    site: Path | None = None
    traffic: tuple[TrafficRun, ...] = ()
    refine_report: Path | None = None  # the orthophoto refinement report (trafficgeo refine --report)
    refine_named: str | None = None  # the file the camera JSON's refinement block names, when not found
    calibrated: CalibratedCamera | None = None  # the camera JSON ``camera``, read once here

    @property
    def empty(self) -> bool:
        """True when there is nothing to report (no calibration, accuracy map or traffic run)."""
        return (self.camera is None and self.calibration_report is None and self.accuracy is None
                and not self.traffic and self.refine_report is None)


def _subfolders(folder: Path) -> list[Path]:
    try:
        return sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    except OSError:
        return []


def _find(dirs: list[Path], names: tuple[str, ...]) -> Path | None:
    for d in dirs:
        for name in names:
            if (d / name).is_file():
                return d / name
    return None


def _given_file(path: str | Path | None, option: str, hint: str) -> Path | None:
    if path is None:
        return None
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{option} {p}: file not found; {hint}", parameters=(option,))
    return p


def _resolve(text: Any, bases: list[Path]) -> Path | None:
    """A path named in a JSON file: as given (absolute or from the working folder), else from ``bases`` (a
    ``process`` run stores its paths as typed, relative to the folder it ran in)."""
    if not isinstance(text, str) or not text:
        return None
    p = Path(text)
    if p.is_file():
        return p
    if not p.is_absolute():
        for b in bases:
            if (b / p).is_file():
                return b / p
    return None


def _traffic_runs(dirs: list[Path]) -> tuple[TrafficRun, ...]:
    runs = []
    for d in dirs:
        if (d / MANIFEST).is_file() or ((d / "summary.json").is_file() and (
                (d / "vehicles.csv").is_file() or (d / "trajectories.csv").is_file())):
            run = RunFolder(d)  # its manifest refuses a half-written run or a mix of two runs' files
            if not run.has("summary.json"):
                continue
            summary, process = run.summary(), run.process()
            compare, problem, simulation, compared = False, None, None, None
            if (d / "compare_counts.csv").is_file():
                try:
                    found = run.comparison
                except RunIncompleteError:
                    found = None
                compare = found is not None and found.has("compare_counts.csv")
                if compare:
                    simulation, compared = run.simulation_record(), run.compare_summary()
                else:
                    problem = ("compare-sumo results incomplete or from an earlier run of this folder; run "
                               "'trafficgeo compare-sumo' again")
            runs.append(TrafficRun(d, summary, process, compare, problem, simulation, compared, run))
    return tuple(runs)


def find_inputs(run_dir: str | Path, *, camera: str | Path | None = None,
                calibration_report: str | Path | CalibrationReport | Mapping[str, Any] | None = None,
                frame: str | Path | None = None, ortho: str | Path | None = None, dem: str | Path | None = None,
                video: str | Path | None = None, refine_report: str | Path | None = None) -> ReportInputs:
    """The files of a run folder (see the module docstring); given paths override what is found.

    The orthophoto refinement report is ``refine_report``, else the file the camera JSON's ``refinement.report``
    key names beside it (``trafficgeo refine --report``); none when the camera JSON has no refinement.

    ``calibration_report`` may also be the report itself, or its report.json document as a dictionary.

    Raises:
        InputError: ``run_dir`` is not a folder, a given file does not exist, or a given dictionary is not a
            calibration report.
    """
    root = Path(run_dir)
    if not root.is_dir():
        raise InputError(f"{root}: not a folder; give the output folder of 'trafficgeo calibrate', 'analyze' or "
                         "'process'")
    dirs = [root, *_subfolders(root)]
    cam = _given_file(camera, "camera", "give the camera JSON written by 'trafficgeo calibrate'") or \
        _find(dirs, CAMERA_NAMES)
    traffic = _traffic_runs(dirs)
    if cam is None:  # a process run names its camera
        for run in traffic:
            if run.process is None:
                continue
            cam = _resolve(run.process.camera, [run.folder, root, run.folder.resolve().parent])
            if cam is not None:
                break
    calibrated = CalibratedCamera.read(cam) if cam is not None else None  # the one read of the camera JSON
    extra = [cam.parent] if cam is not None and cam.parent.resolve() not in {d.resolve() for d in dirs} else []
    site_dirs = dirs + extra
    rep: Path | CalibrationReport | None
    if isinstance(calibration_report, CalibrationReport):
        rep = calibration_report
    elif isinstance(calibration_report, Mapping):
        rep = CalibrationReport.from_dict(calibration_report, "calibration_report")
    else:
        rep = _given_file(calibration_report, "calibration_report", "give the report JSON of 'trafficgeo "
                          "calibrate --report'")
        if rep is None:
            for d in site_dirs:
                found = _find([d], REPORT_NAMES)
                if found is not None and _is_calibration_report(found):
                    rep = found
                    break
    frame_path = _given_file(frame, "frame", "give a PNG or JPEG of the video frame the GCPs were clicked on")
    frame_given = frame_path is not None
    if frame_path is None and cam is not None and calibrated is not None:
        extras = calibrated.extras
        for key in FRAME_KEYS:
            frame_path = _resolve(extras.get(key), [cam.parent])
            if frame_path is not None:
                break
    frame_path = frame_path or _find(site_dirs, FRAME_NAMES)
    refine_path = _given_file(refine_report, "refine_report", "give the report JSON of 'trafficgeo refine --report'")
    refine_named = None
    if refine_path is None and cam is not None and calibrated is not None:
        refine_path, refine_named = _refine_report_of(cam, calibrated)
    video_path = _given_file(video, "video", "give the video file")
    video_given = video_path is not None
    time_s = 0.0
    if video_path is None:
        for run in traffic:
            if run.process is None:
                continue
            video_path = _resolve(run.process.video, [run.folder, root, run.folder.resolve().parent])
            if video_path is not None:
                start = run.process.options.start_s
                time_s = start if start is not None and math.isfinite(start) else 0.0
                break
    video_path = video_path or _find(site_dirs, VIDEO_NAMES)
    ortho_path = _given_file(ortho, "ortho", "give the orthophoto GeoTIFF") or _find(site_dirs, ORTHO_NAMES)
    dem_path = _given_file(dem, "dem", "give the DEM GeoTIFF") or _find(site_dirs, DEM_NAMES)
    return ReportInputs(run_dir=root, camera=cam, calibration_report=rep, frame=frame_path, frame_given=frame_given,
                        video=video_path, video_given=video_given, video_time_s=time_s, ortho=ortho_path,
                        dem=dem_path, accuracy=_find(site_dirs, ACCURACY_NAMES), site=_find(site_dirs, SITE_NAMES),
                        traffic=traffic, refine_report=refine_path, refine_named=refine_named, calibrated=calibrated)


def _refine_report_of(camera: Path, calibrated: CalibratedCamera) -> tuple[Path | None, str | None]:
    """The refinement report the camera JSON at ``camera`` (read as ``calibrated``) names in its
    ``refinement.report`` key, beside it: (the file, None) when it exists, (None, the name) when it does not,
    (None, None) without such a key."""
    verdict = calibrated.refinement
    name = verdict.report if verdict is not None else None
    if not name:
        return None, None
    found = camera.parent / name
    return (found, None) if found.is_file() else (None, name)


def _is_calibration_report(path: Path) -> bool:
    try:
        doc = loads_json(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return isinstance(doc, dict) and doc.get("format") == REPORT_FORMAT

