""""Refine from orthophoto" in ``trafficgeo gcp-ui``: the session's live calibration refined by registering the
orthophoto to the frame (:func:`trafficgeo.registration.refine.refine_camera`), answered as the JSON the page draws,
and the refined camera saved on request.

What it runs on:

* the camera, the GCP table (with roles), the parameter model and the control points kept of the session's live
  calibration at the current revision of the pairs;
* a still without traffic: when the session was opened on a video, the temporal mode of
  :data:`BACKGROUND_FRAMES` frames over :data:`BACKGROUND_SPAN_S` seconds around the frame's time
  (:func:`trafficgeo.video.background_frame.background_frame`), else (or when that fails) the session's frame;
* the orthophoto read at full resolution from its file (the session only holds its display image);
* the session's ground (DEM, or the ground DEM of the point cloud), else the plane through the GCPs the drawings use.

Units: frame pixels ``(u, v)`` with ``(0, 0)`` = centre of the top-left pixel; held-out ground errors in metres.
Errors a user can fix raise :class:`~trafficgeo.ui.session.SessionError` (409 when the state does not allow it) or
:class:`~trafficgeo.errors.InputError` (400); a refusal of the refinement is an answer, not an error.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from trafficgeo.errors import OutputError
from trafficgeo.geo.raster import GeoRaster, read_raster
from trafficgeo.geo.surface import PlaneSurface
from trafficgeo.io.atomic import to_json_safe
from trafficgeo.registration.refine import OrthoRefinement, RefineOptions, refine_camera
from trafficgeo.registration.run import write_refinement
from trafficgeo.ui.inputs import FrameImage, Orthophoto
from trafficgeo.ui.live import drawing_surface
from trafficgeo.ui.session import CAMERA_SUFFIXES, ConflictError, Session, SessionError

log = logging.getLogger(__name__)

#: Seconds of video around the frame's time whose temporal mode is the still matched against the orthophoto.
BACKGROUND_SPAN_S = 30.0
#: Frames whose temporal mode is that still.
BACKGROUND_FRAMES = 25
#: Default name of the refined camera JSON; the report and the frame it was matched on are written beside it.
CAMERA_NAME = "camera_refined.json"
REPORT_NAME = "refine.json"


def _num(value: float, digits: int = 4) -> float | None:
    return round(float(value), digits) if np.isfinite(value) else None


def still_frame(frame: FrameImage, *, span_s: float = BACKGROUND_SPAN_S,
                n_frames: int = BACKGROUND_FRAMES) -> tuple[np.ndarray, str]:
    """The (H, W, 3) BGR still to match and a line saying what it is: the temporal mode of the video around the
    frame's time when the session was opened on a video, else the session's frame."""
    if frame.video is None or frame.time_s is None:
        return frame.image, f"the session's frame ({frame.source})"
    from trafficgeo.video.background_frame import background_frame

    start_s = max(0.0, frame.time_s - span_s / 2.0)
    try:
        still = background_frame(frame.video, start_s=start_s, duration_s=span_s, n_frames=n_frames)
    except Exception as exc:  # a video that cannot give a still: the frame itself still works
        log.warning("no still without traffic from %s: %s", frame.video, exc)
        return frame.image, f"the session's frame (no still without traffic from {frame.video.name}: {exc})"
    if still.shape != frame.image.shape:
        return frame.image, (f"the session's frame (the still of {frame.video.name} is {still.shape[1]}x"
                             f"{still.shape[0]} px, not the frame's size)")
    return still, (f"the scene without traffic: temporal mode of {n_frames} frames of {frame.video.name} over "
                   f"{start_s:g}-{start_s + span_s:g} s")


def read_ortho_raster(ortho: Orthophoto) -> GeoRaster:
    """The session's orthophoto at full resolution, read again from its file (the session holds its display
    image only); a missing file or one changed since the session started is refused with one line."""
    path = Path(ortho.source) if ortho.source else None
    if path is None or not path.is_file():
        raise ConflictError(f"no orthophoto file to refine with: {ortho.source or 'the session has none'} is not on "
                            "disk (moved or deleted?); put it back or restart gcp-ui with --ortho")
    raster = read_raster(path)
    if (raster.cols, raster.rows) != (ortho.cols, ortho.rows):
        raise ConflictError(f"the orthophoto {path} changed on disk since gcp-ui started ({raster.cols}x"
                            f"{raster.rows} px, was {ortho.cols}x{ortho.rows}); restart gcp-ui")
    return raster


def match_rows(result: OrthoRefinement) -> list[dict[str, Any]]:
    """The automatic matches of the last pass for drawing: found frame pixel ``u, v``, where the camera of that pass
    predicted it ``u_predicted, v_predicted`` (px), ``kept`` by the re-fit, ``ncc`` score."""
    m = result.matches
    kept = result.kept if len(result.kept) == len(m) else np.zeros(len(m), dtype=bool)
    return [{"u": round(float(m.pixels[i, 0]), 3), "v": round(float(m.pixels[i, 1]), 3),
             "u_predicted": round(float(m.predicted[i, 0]), 3), "v_predicted": round(float(m.predicted[i, 1]), 3),
             "kept": bool(kept[i]), "ncc": round(float(m.ncc[i]), 3)} for i in range(len(m))]


def refine_answer(result: OrthoRefinement, *, revision: int, frame_note: str, surface_note: str,
                  elapsed_s: float) -> dict[str, Any]:
    """The page's answer: ``accepted``, ``reason``, ``before`` / ``after`` (held-out errors at the user's points,
    :meth:`~trafficgeo.registration.judge.HeldOutErrors.to_dict`), ``passes``, ``matches`` (:func:`match_rows`),
    ``n_matches``, ``n_kept``, the ``revision`` of the pairs it ran on, what frame and surface it used, the time."""
    return to_json_safe({
        "revision": revision,
        "accepted": result.accepted,
        "reason": result.reason,
        "before": result.before.to_dict(),
        "after": None if result.after is None else result.after.to_dict(),
        "passes": [{"search_px": p.search_px, "tried": p.tried, "matched": p.matched, "kept": p.kept,
                    "rmse_px": _num(p.rmse_px, 3), "moved_px": _num(p.moved_px, 3)} for p in result.passes],
        "n_matches": len(result.matches),
        "n_kept": result.n_kept,
        "matches": match_rows(result),
        "frame": frame_note,
        "surface": surface_note,
        "elapsed_s": round(elapsed_s, 2),
        "camera_name": CAMERA_NAME,
    })


@dataclass(frozen=True)
class RefineOutcome:
    """The last refinement of a session: the pairs' revision it ran on, the result, its options, the still."""

    revision: int
    result: OrthoRefinement
    options: RefineOptions
    frame: np.ndarray


class SessionRefiner:
    """Runs "Refine from orthophoto" on a :class:`~trafficgeo.ui.session.Session` (one refinement at a time) and
    saves the last accepted one. Thread-safe: the server calls :meth:`refine` from a worker thread."""

    def __init__(self, session: Session, options: RefineOptions | None = None) -> None:
        self.session = session
        self.options = options or RefineOptions()
        self._running = threading.Lock()
        self._lock = threading.Lock()
        self._last: RefineOutcome | None = None
        self._ortho: tuple[tuple[str, float], GeoRaster] | None = None
        self._still: tuple[np.ndarray, str] | None = None

    def _ortho_raster(self) -> GeoRaster:
        path = Path(self.session.ortho.source)
        key = (str(path), path.stat().st_mtime if path.is_file() else -1.0)
        if self._ortho is None or self._ortho[0] != key:
            self._ortho = (key, read_ortho_raster(self.session.ortho))
        return self._ortho[1]

    def _surface(self, run: Any) -> tuple[Any, str]:
        ground = self.session.ground
        if ground is not None:
            return ground.surface, ground.describe()
        surface = drawing_surface(run, None, self.session.crs)
        n = int(np.count_nonzero(run.calibration.inlier))
        if isinstance(surface, PlaneSurface):
            return surface, f"no --dem or --cloud: the plane through the {n} control GCPs"
        return surface, "no --dem or --cloud: a level plane at the GCPs' median height"

    def refine(self) -> dict[str, Any]:
        """Refine the live calibration of the current pairs (blocking, 1-10 s); the answer of :func:`refine_answer`.

        Raises :class:`ConflictError` while another refinement runs, before the pairs calibrate, or without the
        orthophoto file.
        """
        if not self._running.acquire(blocking=False):
            raise ConflictError("a refinement is already running; wait for its answer")
        try:
            t0 = time.perf_counter()
            payload, run = self.session.calibration_run()
            if run is None:
                raise ConflictError(f"cannot refine yet: {payload['message']}")
            revision = int(payload["revision"])
            cal = run.calibration
            ortho = self._ortho_raster()
            surface, surface_note = self._surface(run)
            if self._still is None:
                self._still = still_frame(self.session.frame)
            frame, frame_note = self._still
            result = refine_camera(cal.camera, cal.gcps, frame, ortho, surface, model=cal.fit.model, use=cal.inlier,
                                   options=self.options)
            with self._lock:
                self._last = RefineOutcome(revision, result, self.options, frame)
            answer = refine_answer(result, revision=revision, frame_note=frame_note, surface_note=surface_note,
                                   elapsed_s=time.perf_counter() - t0)
            log.info("refinement at revision %d: %s", revision, result.reason)
            return answer
        finally:
            self._running.release()

    def save(self, name: str | None = None) -> dict[str, Any]:
        """Write the last accepted refinement into the working folder, each file atomically: the refined camera
        JSON ``name`` (default :data:`CAMERA_NAME`; the calibration keys of ``trafficgeo calibrate`` and a
        ``refinement`` block), the report :data:`REPORT_NAME` beside it (format of
        :func:`trafficgeo.registration.run.refinement_record`) and the frame it was matched on
        (``refine_frame.jpg``); the camera last."""
        path = self.session.resolve(name or CAMERA_NAME, CAMERA_SUFFIXES)
        with self._lock:
            last = self._last
        if last is None:
            raise ConflictError("no refinement to save: press Refine from orthophoto first")
        result = last.result
        if not result.accepted or result.calibration is None:
            raise ConflictError(f"the refinement was refused ({result.reason}); there is no refined camera to save "
                                "(Save camera writes the session's own)")
        if last.revision != self.session.revision:
            raise ConflictError("the pairs changed since the refinement; refine again before saving")
        report = path.with_name(REPORT_NAME)
        frame_file = report.with_name(report.stem + "_frame.jpg")
        try:
            write_refinement(result, path, last.frame, report_path=report, options=last.options)
        except (OSError, OutputError) as exc:
            raise SessionError(f"cannot write {path.parent} ({getattr(exc, 'strerror', None) or exc}); check the "
                               "folder's permissions or give another name") from None
        return {"path": self.session.display_name(path), "report": self.session.display_name(report),
                "frame": self.session.display_name(frame_file), "revision": last.revision}


__all__ = ["BACKGROUND_FRAMES", "BACKGROUND_SPAN_S", "CAMERA_NAME", "REPORT_NAME", "RefineOutcome", "SessionRefiner",
           "match_rows", "read_ortho_raster", "refine_answer", "still_frame"]
