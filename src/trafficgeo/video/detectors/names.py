"""The names of the vehicle detectors, in one table (light: the command line imports it for its help).

:func:`detector_kind` tells what a ``--detector`` value names;
:func:`trafficgeo.video.detectors.factory.make_detector` builds it.
"""

from __future__ import annotations

from pathlib import Path

from trafficgeo.errors import InputError

ONNX_HINT = ("trafficgeo never downloads weights: export a detector to ONNX on a machine of your choice (YOLOv5/v7, "
             "YOLOv8/11, YOLOv10/YOLO26, YOLOX, RT-DETR, D-FINE, DEIM, RF-DETR or NanoDet; e.g. ultralytics "
             "yolo export model=yolo11n.pt format=onnx), give its path as `detector` (PATH.onnx), and "
             "detector_format NAME if its layout is not recognised")
#: the parameters :data:`ONNX_HINT` names (for :class:`~trafficgeo.errors.InputError`)
DETECTOR_PARAMETERS = ("detector", "detector_format")
# The detector names a user may give, and the kind each stands for ("mog2"/"knn": BackgroundDetector's method).
DETECTOR_NAMES: dict[str, str] = {"nanodet": "nanodet", "learned": "nanodet", "background": "mog2", "bg": "mog2",
                                  "mog2": "mog2", "knn": "knn"}
DETECTOR_HELP = ("'nanodet' (the built-in learned detector, NanoDet-g, shipped with trafficgeo; tiled over the far "
                 "road around the counting lines, lanes or ROI given; also 'learned'), 'background' (MOG2 "
                 "background subtraction for a fixed camera; also 'bg' or 'mog2'), 'knn' (KNN background "
                 "subtraction), or the path of an .onnx model")


def detector_kind(spec: str) -> str:
    """What a detector spec names: ``"nanodet"`` (the built-in learned detector), ``"mog2"`` or ``"knn"``
    (:class:`BackgroundDetector` methods; all from the names of :data:`DETECTOR_NAMES`, case-insensitive) or
    ``"onnx"`` (the path of an existing ``.onnx`` file); an InputError for anything else. Checks the name only: an
    ONNX file is opened by :func:`make_detector`."""
    s = str(spec).strip()
    key = s.lower()
    if key in DETECTOR_NAMES:
        return DETECTOR_NAMES[key]
    path = Path(s)
    if key.endswith(".onnx") or path.is_file():
        if path.is_dir() or not path.is_file():
            raise InputError(f"detector {s}: ONNX model not found; put the .onnx file there ({ONNX_HINT})",
                             parameters=DETECTOR_PARAMETERS)
        if not key.endswith(".onnx"):
            raise InputError(f"detector {s}: a detector model must be an .onnx file; {ONNX_HINT}",
                             parameters=DETECTOR_PARAMETERS)
        return "onnx"
    raise InputError(f"detector {s!r} is not known; use {DETECTOR_HELP}", parameters=DETECTOR_PARAMETERS)


def is_background(spec: object) -> bool:
    """Does ``spec`` name a background subtraction detector (which learns the background before detecting)? A
    detector object says so itself (``learns_background``, default False)."""
    if not isinstance(spec, str):
        return bool(getattr(spec, "learns_background", False))
    return detector_kind(spec) in ("mog2", "knn")


def detector_name(detector: object) -> str:
    """What a run records as its detector: the name or ONNX path it was given, or a detector object's ``name``
    (else its class's name)."""
    if isinstance(detector, str):
        return detector
    return str(getattr(detector, "name", None) or type(detector).__qualname__)
