"""Vehicle detectors behind one interface, ``detect(image, time_s) -> Detections`` (:mod:`.detections`), and the
factory that builds one from a ``--detector`` value. The detectors live in their own modules
(:mod:`.background`, :mod:`.onnx_detect`); their names are re-exported here.

Images are (H, W, 3) uint8 **BGR** frames (OpenCV order). Boxes are ``x1, y1, x2, y2`` in full-frame pixels in the
OpenCV pixel-centre convention (pixel (0, 0) is the *centre* of the top-left pixel, so a blob covering pixel columns
``i..j`` spans ``x1 = i - 0.5`` to ``x2 = j + 0.5``); scores are in [0, 1]; classes are the names used downstream
(``car, van, truck, bus, motorcycle, bicycle``; ``""`` = unknown).

* :class:`BackgroundDetector` (the default, no weights needed) for a **fixed** camera: background subtraction
  (OpenCV MOG2 or KNN with shadow detection) on a downscaled frame, then morphology, connected components, an
  optional region of interest, the merging of a vehicle's parts and the splitting of blobs of touching vehicles,
  and, given a calibrated camera and a road surface, a size filter and a size-based class in metres on the ground
  (rules in the class docstring). It finds what moves: vehicles that touch in the image often stay one blob.
* :class:`OnnxDetector` runs an ONNX export with onnxruntime, in any layout of :mod:`.onnx_formats` (YOLOv5/v7,
  YOLOv8/11, end-to-end YOLOv10/YOLO26, YOLOX, RT-DETR/D-FINE/DEIM, RF-DETR, NanoDet), recognised from the model or
  named with ``detector_format``. trafficgeo never downloads weights: bring your own ``.onnx`` file.
* :func:`make_detector` builds either from a short spec (a name of
  :data:`trafficgeo.video.detector_names.DETECTOR_NAMES` or the path of an ``.onnx`` file).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.video.background import (  # noqa: F401 (re-exported)
    GAIN_STEP,
    WARMUP_FRAMES,
    WARMUP_S,
    BackgroundDetector,
    temporal_mode,
)
from trafficgeo.video.blobs import (  # noqa: F401 (re-exported)
    BlobSizes,
    SizeRules,
    _Blobs,
    blob_ground_size,
    classify_sizes,
    group_pairs,
    merge_candidates,
    split_mask,
)
from trafficgeo.video.detections import (  # noqa: F401 (re-exported)
    COCO_VEHICLES,
    Detections,
    Detector,
    box_iou,
    check_image,
    check_roi,
    in_roi,
)
from trafficgeo.video.detector_names import DETECTOR_NAMES, ONNX_HINT, detector_kind  # noqa: F401 (re-exported)
from trafficgeo.video.onnx_detect import (  # noqa: F401 (re-exported)
    ONNX_SHAPES,
    OnnxDetector,
    letterbox,
    yolo_anchor_counts,
)
from trafficgeo.video.onnx_formats import format_name

if TYPE_CHECKING:
    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.mapping import Surface
    from trafficgeo.traffic.lanes import Lanes


# ---------------------------------------------------------------------------------------------------- factory
def _check_format(kind: str, spec: str, detector_format: str | None) -> str | None:
    """The ONNX layout name of ``detector_format`` (None for auto); an InputError when one is given for a
    background subtraction detector."""
    fmt = format_name(detector_format)
    if fmt is not None and kind != "onnx":
        raise InputError(f"--detector-format {detector_format} applies to an ONNX model (--detector PATH.onnx), "
                         f"not to --detector {spec}")
    return fmt


def check_detector(spec: str, detector_format: str | None = None) -> str:
    """:func:`detector_kind` of ``spec``, having opened an ONNX model (read as ``detector_format``, default auto)
    to check that it can be used (an InputError if not): a run checks its detector before it writes anything."""
    kind = detector_kind(spec)
    fmt = _check_format(kind, spec, detector_format)
    if kind == "onnx":
        OnnxDetector(str(spec).strip(), format=fmt, threads=1)
    elif kind == "nanodet":
        from trafficgeo.video.learned import BUILTIN, builtin_model_path

        builtin_model_path(BUILTIN)
    return kind


def make_detector(spec: str = "background", *, camera: Camera | None = None, surface: Surface | None = None,
                  roi: np.ndarray | None = None, scale: float = 0.5, warmup_s: float = WARMUP_S,
                  learning_rate: float | None = None, rules: SizeRules | None = None, conf: float | None = None,
                  iou: float = 0.5, input_size: int | None = None, class_map: Mapping[int, str] | None = None,
                  detector_format: str | None = None, road: Lanes | None = None, tiles: bool = True,
                  tiling: str = "squares") -> Detector:
    """A detector from a short spec (:func:`detector_kind`): a background subtraction name
    (:class:`BackgroundDetector` with MOG2 for "background", "bg" or "mog2", with KNN for "knn") or the path of a
    ``.onnx`` model (:class:`OnnxDetector` of layout ``detector_format``, default recognised from the model;
    ``conf`` default the layout's; ``camera`` and ``surface`` are not used, ``roi`` keeps detections whose bottom
    centre lies inside it), or "nanodet", the built-in learned detector
    (:func:`trafficgeo.video.learned.make_learned_detector`: tiled over the counted ``road`` (lanes, else ``roi``)
    when ``tiles`` and a calibrated ``camera`` and ``surface`` are given). ``warmup_s``: the background detector's
    warm-up (s of video)."""
    kind = detector_kind(spec)
    fmt = _check_format(kind, spec, detector_format)
    if kind == "nanodet":
        from trafficgeo.video.learned import make_learned_detector

        return make_learned_detector(camera=camera, surface=surface, road=road, roi=roi, tiles=tiles, conf=conf,
                                     iou=iou, tiling=tiling)
    if kind == "onnx":
        return OnnxDetector(str(spec).strip(), format=fmt, input_size=input_size, conf=conf, iou=iou,
                            class_map=class_map, roi=roi)
    return BackgroundDetector(method=kind, scale=scale, warmup_s=warmup_s, learning_rate=learning_rate,
                              camera=camera, surface=surface, roi=roi, rules=rules)
