"""Vehicle detectors behind one interface, ``detect(image, time_s) -> Detections``
(:mod:`trafficgeo.video.detections`), and the factory that builds one from a ``--detector`` value.

Images are (H, W, 3) uint8 **BGR** frames (OpenCV order). Boxes are ``x1, y1, x2, y2`` in full-frame pixels in the
OpenCV pixel-centre convention (pixel (0, 0) is the *centre* of the top-left pixel, so a blob covering pixel columns
``i..j`` spans ``x1 = i - 0.5`` to ``x2 = j + 0.5``); scores are in [0, 1]; classes are the names used downstream
(``car, van, truck, bus, motorcycle, bicycle``; ``""`` = unknown).

One concept per module:

* :mod:`.names` - the table of detector names (light: the command line imports it for its help).
* :mod:`.factory` - :func:`make_detector` builds a detector from a short spec (a name of
  :data:`~trafficgeo.video.detectors.names.DETECTOR_NAMES` or the path of an ``.onnx`` file), and
  :func:`check_detector` checks one before a run writes anything.
* :mod:`.background` - :class:`BackgroundDetector` (no weights needed) for a **fixed** camera: background
  subtraction (OpenCV MOG2 or KNN with shadow detection) on a downscaled frame, then morphology, connected
  components, an optional region of interest, the merging of a vehicle's parts and the splitting of blobs of
  touching vehicles (:mod:`.blobs`), and, given a calibrated camera and a road surface, a size filter and a
  size-based class in metres on the ground (:mod:`.sizes`). It finds what moves: vehicles that touch in the image
  often stay one blob.
* :mod:`.onnx` - :class:`OnnxDetector` runs an ONNX export with onnxruntime, in any layout of :mod:`.onnx_formats`
  (YOLOv5/v7, YOLOv8/11, end-to-end YOLOv10/YOLO26, YOLOX, RT-DETR/D-FINE/DEIM, RF-DETR, NanoDet), recognised from
  the model or named with ``detector_format``. trafficgeo never downloads weights: bring your own ``.onnx`` file.
* :mod:`.builtin` - the models shipped inside the package (NanoDet-g) and where their files are.
* :mod:`.learned` - the built-in learned detector as ``process`` runs it (:func:`make_learned_detector`), tiled
  over the counted road by :mod:`.tiling` (square tiles) or :mod:`.tile_bands` (zoom bands) into a
  :class:`~trafficgeo.video.detectors.tile_plan.TilePlan`, run by
  :class:`~trafficgeo.video.detectors.tiled.TiledDetector`.

Names are imported on first use (the modules pull in OpenCV, SciPy and shapely), so importing
:mod:`.names` for the command line's help stays light.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# name -> module of this package that defines it
_EXPORTS: dict[str, str] = {
    "make_detector": "factory",
    "check_detector": "factory",
    "DETECTOR_NAMES": "names",
    "DETECTOR_HELP": "names",
    "ONNX_HINT": "names",
    "detector_kind": "names",
    "is_background": "names",
    "BackgroundDetector": "background",
    "WARMUP_S": "background",
    "SizeRules": "sizes",
    "OnnxDetector": "onnx",
    "LAYOUTS": "onnx_formats",
    "FORMAT_HELP": "onnx_formats",
    "BUILTIN_MODELS": "builtin",
    "builtin_model_path": "builtin",
    "SizeClasses": "learned",
    "make_learned_detector": "learned",
    "detector_plan": "learned",
    "TiledDetector": "tiled",
    "TilePlan": "tile_plan",
    "plan_tiles": "tiling",
    "plan_bands": "tile_bands",
}

__all__ = [
    "BUILTIN_MODELS",
    "DETECTOR_HELP",
    "DETECTOR_NAMES",
    "FORMAT_HELP",
    "LAYOUTS",
    "ONNX_HINT",
    "WARMUP_S",
    "BackgroundDetector",
    "OnnxDetector",
    "SizeClasses",
    "SizeRules",
    "TilePlan",
    "TiledDetector",
    "builtin_model_path",
    "check_detector",
    "detector_kind",
    "detector_plan",
    "is_background",
    "make_detector",
    "make_learned_detector",
    "plan_bands",
    "plan_tiles",
]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # imported once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


if TYPE_CHECKING:  # for type checkers and IDEs; at run time the names come from __getattr__
    from trafficgeo.video.detectors.background import WARMUP_S, BackgroundDetector
    from trafficgeo.video.detectors.builtin import BUILTIN_MODELS, builtin_model_path
    from trafficgeo.video.detectors.factory import check_detector, make_detector
    from trafficgeo.video.detectors.learned import SizeClasses, detector_plan, make_learned_detector
    from trafficgeo.video.detectors.names import DETECTOR_HELP, DETECTOR_NAMES, ONNX_HINT, detector_kind, is_background
    from trafficgeo.video.detectors.onnx import OnnxDetector
    from trafficgeo.video.detectors.onnx_formats import FORMAT_HELP, LAYOUTS
    from trafficgeo.video.detectors.sizes import SizeRules
    from trafficgeo.video.detectors.tile_bands import plan_bands
    from trafficgeo.video.detectors.tile_plan import TilePlan
    from trafficgeo.video.detectors.tiled import TiledDetector
    from trafficgeo.video.detectors.tiling import plan_tiles
