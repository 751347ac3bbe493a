"""The live calibration of ``trafficgeo gcp-ui``: a session's GCP table calibrated with the project's calibration
(:func:`trafficgeo.calibration.run_calibration`), answered as the JSON the page draws.

A failure is an answer, not an error: ``status`` "waiting" (too few control pairs) or "failed" with the reason.
Units: pixel residuals ``du, dv`` = projected - clicked (px); ground errors in metres; the footprint and the grid
in orthophoto positions (see :mod:`trafficgeo.ui.overlays`).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from trafficgeo.calibration import CalibrationOptions, CalibrationReport, GCPTable
from trafficgeo.calibration.gcp_table import ROLE_CONTROL
from trafficgeo.calibration.run import CalibrationRun, run_calibration
from trafficgeo.errors import CalibrationError, InputError
from trafficgeo.geo.surface import ConstantSurface, PlaneSurface
from trafficgeo.ui.inputs import Ground, Orthophoto
from trafficgeo.ui.overlays import footprint, grid

log = logging.getLogger(__name__)


def calibration_answer(table: GCPTable, image_size: tuple[int, int], options: CalibrationOptions, *,
                       revision: int, min_control: int) -> tuple[dict[str, Any], CalibrationRun | None]:
    """Calibrate ``table`` (revision ``revision`` of the session's pairs) for a ``image_size`` (w, h) frame.

    The answer holds ``revision``, ``n_control``, ``n_check``, ``min_control``, ``status`` ("ok", "waiting",
    "failed"), ``message``, and when ok the report's part (:func:`report_answer`) and empty ``footprint``, ``grid``
    and ``overlay_error`` for :func:`draw_overlays` to fill. The run is None unless ok.
    """
    n_control = sum(role == ROLE_CONTROL for role in table.roles)
    base: dict[str, Any] = {"revision": revision, "n_control": n_control, "n_check": table.n - n_control,
                            "min_control": min_control}
    if n_control < min_control:
        more = min_control - n_control
        return {**base, "status": "waiting",
                "message": f"{more} more control pair{'s' if more > 1 else ''} needed to calibrate (at least "
                           f"{min_control}; check points do not count)"}, None
    try:
        run = run_calibration(table, image_size, options)
    except (InputError, CalibrationError) as exc:
        return {**base, "status": "failed", "message": str(exc)}, None
    except Exception as exc:  # a numerical failure is an answer, not a crash of the server
        log.exception("calibration failed")
        return {**base, "status": "failed",
                "message": f"the calibration failed ({type(exc).__name__}: {exc}); check the pairs"}, None
    answer = {**base, "status": "ok", "message": run.report.summary, **report_answer(run.report),
              "footprint": [], "grid": None, "overlay_error": None}
    return answer, run


def report_answer(rep: CalibrationReport) -> dict[str, Any]:
    """The report's part of the answer: ``summary``, ``stats``, ``check``, ``camera`` (the report's blocks),
    ``model`` (in words), ``warnings``, ``recommendations``, ``points`` (per pair: the projected pixel, the residual
    ``du, dv``, ``error_px``, ``loo_error_px``, the ground errors, ``status`` inlier/outlier/check and the outlier's
    ``reason``) and ``outliers`` (ids)."""
    points = [{"id": r.id, "role": r.role, "status": r.status, "inlier": r.inlier, "u_proj": r.u_proj,
               "v_proj": r.v_proj, "du": r.du, "dv": r.dv, "error_px": r.error_px, "loo_error_px": r.loo_error_px,
               "ground_error_m": r.ground_error_m, "loo_ground_error_m": r.loo_ground_error_m, "reason": r.reason}
              for r in rep.gcps]
    return {"summary": rep.summary, "stats": rep.stats.to_dict(), "check": rep.check.to_dict(),
            "camera": rep.camera.to_dict(), "model": rep.model.description, "warnings": list(rep.warnings),
            "recommendations": list(rep.recommendations), "points": points,
            "outliers": [o.id for o in rep.outliers]}


def draw_overlays(answer: dict[str, Any], run: CalibrationRun, *, ortho: Orthophoto, ground: Ground | None,
                  crs: Any, unit: str, max_distance_m: float) -> None:
    """Fill the answer's ``footprint`` (orthophoto polygons of the ground seen within ``max_distance_m``) and
    ``grid`` (see :func:`trafficgeo.ui.overlays.grid`); a failure is said in ``overlay_error`` (the calibration
    stands without the drawings)."""
    camera = run.calibration.camera
    try:
        surface = drawing_surface(run, ground, crs)
        seen, answer["footprint"] = footprint(camera, surface, ortho, max_distance_m)
        answer["grid"] = grid(camera, surface, ortho, seen, unit)
    except Exception as exc:  # the drawings are extras
        log.exception("footprint/grid failed")
        answer["overlay_error"] = f"the footprint and grid could not be drawn ({type(exc).__name__}: {exc})"


def drawing_surface(run: CalibrationRun, ground: Ground | None, crs: Any) -> Any:
    """The ground for drawing: the DEM, the cloud's ground DEM, else a plane through the inlier GCPs (else their
    median height)."""
    if ground is not None:
        return ground.surface
    cal = run.calibration
    pts = cal.gcps.world[cal.inlier]
    if pts.shape[0] >= 3:
        try:
            return PlaneSurface.fit(pts, crs=crs)
        except (ValueError, np.linalg.LinAlgError):
            pass
    return ConstantSurface(float(np.median(cal.gcps.world[:, 2])), crs=crs)
