"""Refine a camera JSON with an orthophoto and write the results: the one call behind ``trafficgeo refine``.

Outputs (each written atomically, nothing on bad input):

* the camera JSON ``out_camera``: the refined camera with the calibration keys of ``trafficgeo calibrate`` (``stats``,
  ``model``, ``uncertainty``, ``covariance`` of the whole re-fit; ``gcps`` lists the user's points with their
  residuals under the refined camera, the automatic correspondences are in the report) and a ``refinement`` block; when
  the refinement is refused, the original camera and its keys, with the ``refinement`` block saying why;
* with ``report_path``: the refinement report (:data:`REFINE_FORMAT`): the verdict, the user's points' held-out
  errors before and after, each pass, every automatic correspondence (world, pixel, where the camera predicted it,
  its score, whether the re-fit kept it, where the refined camera projects it), and the frame it was matched on
  beside it (``<report stem>_frame.jpg``), for the HTML report and the GCP web app.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from trafficgeo.calibration.camera_record import calibrated_camera
from trafficgeo.calibration.gcp_read import read_gcps
from trafficgeo.calibration.gcp_table import ROLE_CHECK, ROLE_CONTROL, GCPTable
from trafficgeo.camera.calibrated import CalibratedCamera, RefinementSummary, load_calibrated_camera
from trafficgeo.camera.io import camera_to_dict
from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError, OutputError
from trafficgeo.geo.mapping import Surface
from trafficgeo.geo.raster import GeoRaster, open_raster, pixel_to_map, read_raster, to_pyproj_crs
from trafficgeo.io.atomic import atomic_path, write_json_atomic
from trafficgeo.registration.from_ortho import OrthoCalibration, OrthoPoseOptions, calibrate_from_ortho, review_gcps
from trafficgeo.registration.judge import model_from_names
from trafficgeo.registration.matching import Matches
from trafficgeo.registration.refine import AUTO_PREFIX, OrthoRefinement, RefineOptions, match_sigma_px, refine_camera
from trafficgeo.site.surface import load_surface

REFINE_FORMAT = "trafficgeo-refine/1"
MATCH_COLUMNS = ("x", "y", "z", "u", "v", "u_predicted", "v_predicted", "ncc", "roundness", "sigma_px", "kept",
                 "u_refined", "v_refined")


def user_gcps(camera: CalibratedCamera) -> tuple[GCPTable, np.ndarray]:
    """The user's GCPs stored in a camera JSON by ``trafficgeo calibrate`` (its ``gcps`` list), without automatic
    correspondences of an earlier refinement; and which control points that calibration kept (its ``inlier``)."""
    rows = [g for g in camera.gcps or () if not g.id.startswith(AUTO_PREFIX) and g.source != "auto"]
    if not rows:
        auto = any(g.source == "auto" for g in camera.gcps or ())
        raise InputError(f"{camera.where}: the camera JSON lists no GCPs of the user's to judge the refinement by"
                         + (" (only the automatic correspondences of 'trafficgeo calibrate-ortho')" if auto else "")
                         + "; give a GCP file of points you measured (`gcps`)", parameters=("gcps",))
    table = GCPTable(ids=tuple(g.id for g in rows), world=np.array([(g.x, g.y, g.z) for g in rows]),
                     pixels=np.array([(g.u, g.v) for g in rows]),
                     roles=tuple(ROLE_CHECK if g.role == ROLE_CHECK else ROLE_CONTROL for g in rows),
                     sigma_px=np.array([g.sigma_px if np.isfinite(g.sigma_px) else 1.0 for g in rows]),
                     crs=camera.camera.crs, source=camera.where, lines=(0,) * len(rows))
    return table, np.array([g.inlier is not False for g in rows])


def read_frame_image(path: str | Path) -> np.ndarray:
    """A frame from an image file (PNG, JPEG, TIFF) as (H, W, 3) BGR uint8."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: frame image not found; give a still of the calibrated video (PNG or JPEG)",
                         parameters=("frame",))
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"{p}: not an image OpenCV can read; give a PNG or JPEG still of the video",
                         parameters=("frame",))
    return img


def _num(v: float) -> float | None:
    return round(float(v), 4) if np.isfinite(v) else None


def match_rows(m: Matches, kept: np.ndarray, camera: Camera | None, sigma_px: float) -> list[list[Any]]:
    """The rows of a report's ``matches`` table (:data:`MATCH_COLUMNS`): each automatic correspondence, whether the
    fit kept it, and where ``camera`` (the re-fitted one, if any) projects it."""
    projected = camera.project(m.world) if camera is not None and len(m) else np.full((len(m), 2), np.nan)
    sigma = match_sigma_px(m, sigma_px)
    return [[*(round(float(a), 4) for a in m.world[i]), *(round(float(a), 3) for a in m.pixels[i]),
             *(round(float(a), 3) for a in m.predicted[i]), round(float(m.ncc[i]), 3),
             round(float(m.roundness[i]), 3), round(float(sigma[i]), 3), bool(kept[i]) if len(kept) else False,
             *(_num(a) for a in projected[i])] for i in range(len(m))]


def refinement_record(result: OrthoRefinement, options: RefineOptions) -> dict[str, Any]:
    """The refinement report as a JSON object (format :data:`REFINE_FORMAT`)."""
    rows = match_rows(result.matches, result.kept, result.refined, options.match_sigma_px)
    return {
        "format": REFINE_FORMAT,
        "accepted": result.accepted,
        "reason": result.reason,
        "matches_kept": result.n_kept,
        "before": result.before.to_dict(),
        "after": None if result.after is None else result.after.to_dict(),
        "passes": [{"search_px": p.search_px, "tried": p.tried, "matched": p.matched, "kept": p.kept,
                    "rmse_px": _num(p.rmse_px), "moved_px": _num(p.moved_px)} for p in result.passes],
        "model": None if result.calibration is None else list(result.calibration.fit.model.names),
        "original_camera": camera_to_dict(result.original),
        "refined_camera": None if result.refined is None else camera_to_dict(result.refined),
        "matches": {"columns": list(MATCH_COLUMNS), "rows": rows},
    }


def write_refinement(result: OrthoRefinement, out_camera: str | Path, frame: np.ndarray, *,
                     report_path: str | Path | None = None, options: RefineOptions | None = None,
                     original: CalibratedCamera | None = None) -> None:
    """Write a refinement's files (see the module docstring): with ``report_path`` the report and the frame it was
    matched on beside it, then the camera JSON ``out_camera`` last: the refined camera when accepted, else the
    ``original`` (the camera JSON it was read from, with what its calibration knew)."""
    options = options or RefineOptions()
    if report_path is not None:
        report = Path(report_path)
        frame_file = report.with_name(report.stem + "_frame.jpg")
        with atomic_path(frame_file) as tmp:  # the temporary name keeps the .jpg suffix OpenCV goes by
            if not cv2.imwrite(str(tmp), frame, [cv2.IMWRITE_JPEG_QUALITY, 92]):
                raise OutputError(f"{frame_file}: OpenCV could not write the frame image; check the folder")
        record = refinement_record(result, options)
        record["frame"] = frame_file.name
        write_json_atomic(report, record)
    block = RefinementSummary(accepted=result.accepted, reason=result.reason, matches_kept=result.n_kept,
                              before_rmse_m=result.before.rmse_m,
                              after_rmse_m=math.nan if result.after is None else result.after.rmse_m,
                              report=None if report_path is None else Path(report_path).name)
    if result.accepted and result.calibration is not None:
        refined = calibrated_camera(result.calibration)
        # The user's points only (their residuals under the refined camera); the automatic ones are in the report.
        kept = replace(refined, gcps=tuple(g for g in refined.gcps or () if not g.id.startswith(AUTO_PREFIX)))
    else:
        kept = replace(original, camera=result.camera) if original is not None else CalibratedCamera(result.camera)
    replace(kept, refinement=block).write(out_camera)


def refine_camera_files(camera_path: CalibratedCamera | str | Path, frame: np.ndarray, ortho: str | Path | GeoRaster,
                        surface: str | Surface, out_camera: str | Path, *, gcps: str | Path | GCPTable | None = None,
                        report_path: str | Path | None = None, options: RefineOptions | None = None,
                        progress: Callable[[str], None] | None = None) -> OrthoRefinement:
    """Refine the camera JSON at ``camera_path`` (or a CalibratedCamera read from it) against ``frame`` (H, W, 3
    BGR) with the orthophoto and surface (objects, or paths / a surface spec as ``trafficgeo georef`` takes), write
    ``out_camera`` and, if given, the report; see the module docstring. The user's GCPs come from ``gcps`` (a file
    in the camera's CRS or a table) or else from the camera JSON."""
    options = options or RefineOptions()
    calibrated = load_calibrated_camera(camera_path)
    camera = calibrated.camera
    if gcps is None:
        table, use = user_gcps(calibrated)
    else:
        table = gcps if isinstance(gcps, GCPTable) else read_gcps(gcps, crs=camera.crs)
        use = np.ones(table.n, dtype=bool)
    if isinstance(ortho, GeoRaster):
        raster = ortho
    else:
        ds, transform = open_raster(ortho, "ortho")  # the geotransform, else a world file's
        with ds:
            file_crs, size = to_pyproj_crs(ds.crs), (ds.width, ds.height)
        xs, ys = pixel_to_map(transform, [0, size[0], size[0], 0], [0, 0, size[1], size[1]])
        left, right, bottom, top = min(xs), max(xs), min(ys), max(ys)
        if file_crs is not None and camera.crs is not None and not file_crs.equals(camera.crs):
            raise InputError(f"{ortho}: the orthophoto's CRS is not the camera's ({camera.crs_text}); reproject it "
                             "(gdalwarp -t_srs) or calibrate in its CRS", parameters=("ortho",))
        # only what the matching can reach: max_distance_m around the camera, with room for the search
        reach = (options.max_distance_m + 50.0) / (metres_per_unit(camera.crs) if camera.crs is not None else 1.0)
        x, y = float(camera.position[0]), float(camera.position[1])
        if not (left < x + reach and x - reach < right and bottom < y + reach and y - reach < top):
            raise InputError(f"{ortho}: the orthophoto does not cover what the camera sees; give the orthophoto of "
                             "this camera's site, in its CRS", parameters=("ortho",))
        raster = read_raster(ortho, bounds=(x - reach, y - reach, x + reach, y + reach))
    ground = surface if not isinstance(surface, str) else load_surface(surface, calibrated)
    model = model_from_names(calibrated.model.free_parameters if calibrated.model is not None else None)
    result = refine_camera(camera, table, frame, raster, ground, model=model, use=use, options=options,
                           progress=progress)
    write_refinement(result, out_camera, frame, report_path=report_path, options=options, original=calibrated)
    return result


# ------------------------------------------------------------------------------------------ calibrate-ortho
ORTHO_CALIBRATION_FORMAT = "trafficgeo-calibrate-ortho/1"
VIEW_COLUMNS = ("focal_px", "tilt_deg", "keypoints", "matched", "agreeing", "height_m", "x", "y")


def ortho_calibration_record(result: OrthoCalibration, near_xy: tuple[float, float],
                             checks: GCPTable | None) -> dict[str, Any]:
    """The ``calibrate-ortho`` report as a JSON object (format :data:`ORTHO_CALIBRATION_FORMAT`): the verdict, the
    ground views tried (best first), the registration passes, every automatic correspondence (as in the refinement
    report) and the check points' ground errors."""
    cam = result.calibration.camera if result.calibration is not None else None
    rows = match_rows(result.matches, result.kept, cam, RefineOptions().match_sigma_px)
    e = result.check_errors_m
    finite = e[np.isfinite(e)]
    return {
        "format": ORTHO_CALIBRATION_FORMAT,
        "accepted": result.accepted,
        "reason": result.reason,
        "position_given": [float(near_xy[0]), float(near_xy[1])],
        "offset_m": _num(result.offset_m),
        "matches_kept": int(np.count_nonzero(result.kept)),
        "camera": None if cam is None else camera_to_dict(cam),
        "views": {"columns": list(VIEW_COLUMNS),
                  "rows": [[round(v.focal_px, 1), v.tilt_deg, v.keypoints, v.matched, v.agreeing,
                            round(v.height_m, 2), round(v.position[0], 3), round(v.position[1], 3)]
                           for v in result.views[:50]]},
        "passes": [{"search_px": p.search_px, "tried": p.tried, "matched": p.matched, "kept": p.kept,
                    "rmse_px": _num(p.rmse_px), "moved_px": _num(p.moved_px)} for p in result.passes],
        "matches": {"columns": list(MATCH_COLUMNS), "rows": rows},
        "checks": None if checks is None else {
            "median_m": _num(float(np.median(finite))) if finite.size else None,
            "rmse_m": _num(float(np.sqrt(np.mean(finite ** 2)))) if finite.size else None,
            "points": [{"id": i, "ground_error_m": _num(float(x))} for i, x in zip(checks.ids, e, strict=True)]},
    }


def calibrate_ortho_files(frame: np.ndarray, ortho: str | Path | GeoRaster, surface: str | Surface,
                          near_xy: tuple[float, float], out_camera: str | Path, *,
                          checks: str | Path | GCPTable | None = None, report_path: str | Path | None = None,
                          gcps_out: str | Path | None = None, options: OrthoPoseOptions | None = None,
                          surface_crs: str | None = None,
                          resolution_m: float = 0.25, progress: Callable[[str], None] | None = None
                          ) -> OrthoCalibration:
    """Calibrate from the orthophoto alone (:func:`~trafficgeo.registration.from_ortho.calibrate_from_ortho`) and
    write: with ``report_path`` the report (:func:`ortho_calibration_record`) and the frame beside it
    (``<report stem>_frame.jpg``); when accepted, the camera JSON ``out_camera`` as ``trafficgeo calibrate`` writes
    it, its GCPs the automatic correspondences (``source`` "auto"), and with ``gcps_out`` 40 of them spread over the
    frame as a GCP file to review in ``trafficgeo gcp-ui`` (:func:`~.from_ortho.review_gcps`). A refused calibration
    writes no camera and no GCP file."""
    raster = ortho if isinstance(ortho, GeoRaster) else read_raster(ortho)
    if raster.crs is None:
        raise InputError(f"{ortho}: the orthophoto has no CRS; give a GeoTIFF georeferenced in a projected CRS",
                         parameters=("ortho",))
    if isinstance(surface, str):
        from trafficgeo.site.surface import surface_in_crs

        ground = surface_in_crs(surface, raster.crs, surface_crs=surface_crs, resolution_m=resolution_m)
    else:
        ground = surface
    table = None
    if checks is not None:
        table = checks if isinstance(checks, GCPTable) else read_gcps(checks, crs=raster.crs)
        if table.columns_note and progress is not None:
            progress(f"{checks}: columns read as {table.columns_note}")
        table = GCPTable(ids=table.ids, world=table.world, pixels=table.pixels, roles=(ROLE_CHECK,) * table.n,
                         sigma_px=table.sigma_px, crs=table.crs, source=table.source, lines=table.lines)
    result = calibrate_from_ortho(frame, raster, ground, near_xy, crs=raster.crs, checks=table, options=options,
                                  progress=progress)
    if report_path is not None:
        report = Path(report_path)
        frame_file = report.with_name(report.stem + "_frame.jpg")
        with atomic_path(frame_file) as tmp:
            if not cv2.imwrite(str(tmp), frame, [cv2.IMWRITE_JPEG_QUALITY, 92]):
                raise OutputError(f"{frame_file}: OpenCV could not write the frame image; check the folder")
        record = ortho_calibration_record(result, near_xy, table)
        record["frame"] = frame_file.name
        write_json_atomic(report, record)
    if result.accepted and result.calibration is not None:
        found = calibrated_camera(result.calibration)
        gcps = tuple(replace(g, source="auto") for g in found.gcps or ())
        e = result.check_errors_m
        extras = {"calibrate_ortho": {"reason": result.reason, "position_given": [float(near_xy[0]),
                                                                                  float(near_xy[1])],
                                      "offset_m": _num(result.offset_m),
                                      "check_median_m": _num(float(np.nanmedian(e))) if np.isfinite(e).any()
                                      else None,
                                      "report": None if report_path is None else Path(report_path).name}}
        if gcps_out is not None:
            review_gcps(result).to_csv(gcps_out)
        replace(found, gcps=gcps, extras=extras).write(out_camera)
    return result
