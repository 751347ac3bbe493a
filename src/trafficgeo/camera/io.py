"""Camera JSON, format ``trafficgeo.camera/1``.

Keys (units in brackets)::

    format        "trafficgeo.camera/1"
    image_size    [W, H]                      [px]
    K             3x3 intrinsic matrix        [px]
    dist          [k1, k2, p1, p2, k3]        OpenCV order, normalized-coordinate model
    R             3x3 world->camera rotation  OpenCV camera axes (x right, y down, z forward)
    position      camera centre [X, Y, Z]     [CRS units]; a point projects as Xc = R (Xw - position)
    crs           "EPSG:...", WKT or null: the text the camera was given (see Camera.crs_text)
    orientation   {heading_deg, tilt_deg, roll_deg}   (informative; R is authoritative)
    rvec, tvec    OpenCV Rodrigues rvec [rad] and tvec [CRS units] mapping absolute world to camera
    ...           the calibration's gcps, stats, model, uncertainty, covariance, refinement and any further keys:
                  read and written by :class:`~trafficgeo.camera.calibrated.CalibratedCamera`

Only ``image_size``, ``K``, ``R`` and ``position`` are required when reading; ``dist`` defaults to zeros.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.io.atomic import write_json_atomic

FORMAT = "trafficgeo.camera/1"


def camera_to_dict(camera: Camera) -> dict[str, Any]:
    """The JSON-ready dictionary of a camera (no extras)."""
    rvec, tvec = camera.rvec_tvec()
    return {
        "format": FORMAT,
        "image_size": list(camera.image_size),
        "K": camera.K.tolist(),
        "dist": camera.dist.tolist(),
        "R": camera.R.tolist(),
        "position": camera.position.tolist(),
        "crs": camera.crs_text,
        "orientation": camera.orientation.to_dict(),
        "rvec": rvec.tolist(),
        "tvec": tvec.tolist(),
    }


def write_camera_json(path: str | Path, camera: Camera, extra: dict[str, Any] | None = None) -> None:
    """Write ``camera`` (and extra keys) to ``path`` atomically."""
    doc = camera_to_dict(camera)
    if extra:
        doc.update(extra)
    write_json_atomic(path, doc)


def _matrix(doc: dict[str, Any], key: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    if key not in doc:
        raise InputError(f"{where}: key '{key}' is missing; write the camera with 'trafficgeo calibrate'")
    try:
        arr = np.asarray(doc[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: '{key}' is not numeric; expected a {shape} array of numbers") from None
    if arr.shape != shape:
        raise InputError(f"{where}: '{key}' has shape {arr.shape}, expected {shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: '{key}' has non-finite values")
    return arr


def camera_from_dict(doc: Any, where: str = "camera JSON") -> Camera:
    """The camera of a camera JSON document (its other keys are left to
    :class:`~trafficgeo.camera.calibrated.CalibratedCamera`); ``where`` names it in messages."""
    if not isinstance(doc, dict):
        raise InputError(f"{where}: expected a JSON object with the camera keys")
    fmt = doc.get("format", FORMAT)
    if fmt != FORMAT:
        raise InputError(f"{where}: format is '{fmt}', this version reads '{FORMAT}'")
    size = _matrix(doc, "image_size", (2,), where)
    if np.any(size <= 0) or np.any(size != np.round(size)):
        raise InputError(f"{where}: image_size must be two positive integers [W, H]")
    K = _matrix(doc, "K", (3, 3), where)
    R = _matrix(doc, "R", (3, 3), where)
    position = _matrix(doc, "position", (3,), where)
    dist = _matrix(doc, "dist", (5,), where) if "dist" in doc else np.zeros(5)
    crs = doc.get("crs")
    if crs is not None and not isinstance(crs, str):
        raise InputError(f"{where}: 'crs' must be a string such as \"EPSG:2949\" or null")
    try:
        return Camera(image_size=(int(size[0]), int(size[1])), K=K, dist=dist, R=R, position=position, crs=crs)
    except ValueError as exc:  # InputError (an unknown CRS) is a ValueError too
        raise InputError(f"{where}: 'crs': {exc}" if isinstance(exc, InputError) else f"{where}: {exc}") from None
