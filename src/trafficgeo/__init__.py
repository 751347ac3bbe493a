"""trafficgeo: georeferenced, lane-level traffic data from a fixed camera and common GIS data.

The library is the product; the ``trafficgeo`` command is a thin skin over these functions (each takes objects or
paths, returns plain dataclasses and tables, and raises :class:`InputError` naming the parameter or file at fault)::

    import trafficgeo as tg

    camera = tg.load_camera("camera.json")      # a CalibratedCamera; or tg.calibrate(gcps, size).calibrated_camera()
    surface = tg.load_surface("cloud.laz", "camera.json")        # a number, "plane", a DEM or a point cloud
    site = tg.Site.load(camera, surface, lanes="lanes.gpkg", lines="lines.gpkg")  # loaded once, passed on
    run = tg.process_video("video.mp4", site, "run")
    run.traffic.counts                                           # per line, lane, direction and interval
    tg.RunFolder("run").vehicles()                               # read back, typed by one schema

Names are imported on first use, so ``import trafficgeo`` stays light.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from trafficgeo.errors import CalibrationError, InputError, OutputError, TrafficgeoError
from trafficgeo.version import __version__

# name -> module that defines it (the curated public API; one concept per module)
_API: dict[str, str] = {
    # camera and calibration
    "Camera": "trafficgeo.camera.model",
    "CalibratedCamera": "trafficgeo.camera.calibrated",
    "calibrate": "trafficgeo.calibration.pipeline",
    "Calibration": "trafficgeo.calibration.pipeline",
    "CalibrationOptions": "trafficgeo.calibration.pipeline",
    "CalibrationReport": "trafficgeo.calibration.report",
    "read_gcps": "trafficgeo.calibration.gcp_read",
    "GCPTable": "trafficgeo.calibration.gcp_table",
    # ground
    "georeference": "trafficgeo.geo.mapping",
    "GroundPoints": "trafficgeo.geo.mapping",
    "ConstantSurface": "trafficgeo.geo.surface",
    # the site and the tracks, from paths or objects
    "Site": "trafficgeo.site.site",
    "load_camera": "trafficgeo.site.site",
    "load_surface": "trafficgeo.site.surface",
    "load_lanes": "trafficgeo.site.site",
    "load_lines": "trafficgeo.site.site",
    "Lanes": "trafficgeo.site.lanes",
    "CountLine": "trafficgeo.site.lines",
    "load_tracks": "trafficgeo.traffic.tracks",
    "ImageTracks": "trafficgeo.run.tracks",
    # traffic
    "analyze_tracks": "trafficgeo.traffic.analyze",
    "AnalysisOptions": "trafficgeo.traffic.analyze",
    "TrafficResult": "trafficgeo.traffic.analyze",
    "write_analysis": "trafficgeo.traffic.analyze",
    "TrajectoryOptions": "trafficgeo.traffic.trajectories",
    "JourneyOptions": "trafficgeo.traffic.journeys",
    "join_fragments": "trafficgeo.traffic.journeys",
    "RunFolder": "trafficgeo.run.folder",
    "RunWriter": "trafficgeo.run.folder",
    "SCHEMAS": "trafficgeo.run.schema",
    "compare_with_sumo": "trafficgeo.traffic.validation",
    "Comparison": "trafficgeo.traffic.validation",
    "export_fcd": "trafficgeo.traffic.validation",
    # closing the loop with SUMO
    "build_sumo_net": "trafficgeo.simulation.network",
    "SumoNet": "trafficgeo.simulation.network",
    "build_sumo_scenario": "trafficgeo.simulation.scenario",
    "SumoScenario": "trafficgeo.simulation.scenario",
    "validate_sumo_scenario": "trafficgeo.simulation.loop",
    "SumoValidation": "trafficgeo.simulation.loop",
    "close_sumo_loop": "trafficgeo.simulation.loop",
    "SumoLoopResult": "trafficgeo.simulation.loop",
    # orthophoto registration
    "refine_camera": "trafficgeo.registration.refine",
    "RefineOptions": "trafficgeo.registration.refine",
    "OrthoRefinement": "trafficgeo.registration.refine",
    "calibrate_from_ortho": "trafficgeo.registration.from_ortho",
    "OrthoPoseOptions": "trafficgeo.registration.from_ortho",
    "OrthoCalibration": "trafficgeo.registration.from_ortho",
    "drape_orthophoto": "trafficgeo.geo.drape",
    "background_frame": "trafficgeo.video.background_frame",
    # video
    "process_video": "trafficgeo.pipeline.run",
    "ProcessResult": "trafficgeo.pipeline.run",
    "ProcessOptions": "trafficgeo.video.pipeline",
    "RunCallbacks": "trafficgeo.pipeline.run",
    "stitch": "trafficgeo.pipeline.run",
    "make_detector": "trafficgeo.video.detectors.factory",
    "Detections": "trafficgeo.video.detections",
    # many cameras (batch)
    "plan_batch": "trafficgeo.batch.manifest",
    "read_tasks": "trafficgeo.batch.manifest",
    "BatchPlan": "trafficgeo.batch.manifest",
    "run_batch": "trafficgeo.batch.runner",
    "RunOptions": "trafficgeo.batch.runner",
    "BatchReport": "trafficgeo.batch.runner",
    "read_table": "trafficgeo.batch.dataset",
    "summarize_dataset": "trafficgeo.batch.dataset",
}

__all__ = [
    "SCHEMAS",
    "AnalysisOptions",
    "BatchPlan",
    "BatchReport",
    "CalibratedCamera",
    "Calibration",
    "CalibrationError",
    "CalibrationOptions",
    "CalibrationReport",
    "Camera",
    "Comparison",
    "ConstantSurface",
    "CountLine",
    "Detections",
    "GCPTable",
    "GroundPoints",
    "ImageTracks",
    "InputError",
    "JourneyOptions",
    "Lanes",
    "OrthoCalibration",
    "OrthoPoseOptions",
    "OrthoRefinement",
    "OutputError",
    "ProcessOptions",
    "ProcessResult",
    "RefineOptions",
    "RunCallbacks",
    "RunFolder",
    "RunOptions",
    "RunWriter",
    "Site",
    "SumoLoopResult",
    "SumoNet",
    "SumoScenario",
    "SumoValidation",
    "TrafficResult",
    "TrafficgeoError",
    "TrajectoryOptions",
    "__version__",
    "analyze_tracks",
    "background_frame",
    "build_sumo_net",
    "build_sumo_scenario",
    "calibrate",
    "calibrate_from_ortho",
    "close_sumo_loop",
    "compare_with_sumo",
    "drape_orthophoto",
    "export_fcd",
    "georeference",
    "join_fragments",
    "load_camera",
    "load_lanes",
    "load_lines",
    "load_surface",
    "load_tracks",
    "make_detector",
    "plan_batch",
    "process_video",
    "read_gcps",
    "read_table",
    "read_tasks",
    "refine_camera",
    "run_batch",
    "stitch",
    "summarize_dataset",
    "validate_sumo_scenario",
    "write_analysis",
]


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'trafficgeo' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # imported once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))


if TYPE_CHECKING:  # for type checkers and IDEs; at run time the names come from __getattr__
    from trafficgeo.calibration.gcp_read import read_gcps
    from trafficgeo.calibration.gcp_table import GCPTable
    from trafficgeo.calibration.pipeline import Calibration, CalibrationOptions, calibrate
    from trafficgeo.calibration.report import CalibrationReport
    from trafficgeo.camera.calibrated import CalibratedCamera
    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.drape import drape_orthophoto
    from trafficgeo.geo.mapping import GroundPoints, georeference
    from trafficgeo.geo.surface import ConstantSurface
    from trafficgeo.pipeline.run import ProcessResult, RunCallbacks, process_video, stitch
    from trafficgeo.registration.from_ortho import OrthoCalibration, OrthoPoseOptions, calibrate_from_ortho
    from trafficgeo.registration.refine import OrthoRefinement, RefineOptions, refine_camera
    from trafficgeo.run.folder import RunFolder, RunWriter
    from trafficgeo.run.schema import SCHEMAS
    from trafficgeo.run.tracks import ImageTracks
    from trafficgeo.simulation.loop import SumoLoopResult, SumoValidation, close_sumo_loop, validate_sumo_scenario
    from trafficgeo.simulation.network import SumoNet, build_sumo_net
    from trafficgeo.simulation.scenario import SumoScenario, build_sumo_scenario
    from trafficgeo.site.lanes import Lanes
    from trafficgeo.site.lines import CountLine
    from trafficgeo.site.site import Site, load_camera, load_lanes, load_lines
    from trafficgeo.site.surface import load_surface
    from trafficgeo.traffic.analyze import AnalysisOptions, TrafficResult, analyze_tracks, write_analysis
    from trafficgeo.traffic.journeys import JourneyOptions, join_fragments
    from trafficgeo.traffic.tracks import load_tracks
    from trafficgeo.traffic.trajectories import TrajectoryOptions
    from trafficgeo.traffic.validation import Comparison, compare_with_sumo, export_fcd
    from trafficgeo.video.background_frame import background_frame
    from trafficgeo.video.detections import Detections
    from trafficgeo.video.detectors.factory import make_detector
    from trafficgeo.video.pipeline import ProcessOptions
