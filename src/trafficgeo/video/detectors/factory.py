"""The detector factory: :func:`make_detector` builds a detector from a ``--detector`` value (a name of
:data:`~trafficgeo.video.detectors.names.DETECTOR_NAMES` or the path of an ``.onnx`` file) and
:func:`check_detector` checks one before a run writes anything. The detectors themselves are described in
:mod:`trafficgeo.video.detectors`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.video.detections import Detector
from trafficgeo.video.detectors.background import WARMUP_S, BackgroundDetector
from trafficgeo.video.detectors.names import detector_kind
from trafficgeo.video.detectors.onnx import OnnxDetector
from trafficgeo.video.detectors.onnx_formats import format_name
from trafficgeo.video.detectors.sizes import SizeRules

if TYPE_CHECKING:
    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.mapping import Surface
    from trafficgeo.site.lanes import Lanes
    from trafficgeo.site.lines import CountLine


# ---------------------------------------------------------------------------------------------------- factory
def _check_format(kind: str, spec: str, detector_format: str | None) -> str | None:
    """The ONNX layout name of ``detector_format`` (None for auto); an InputError when one is given for a
    background subtraction detector."""
    fmt = format_name(detector_format)
    if fmt is not None and kind != "onnx":
        raise InputError(f"detector_format {detector_format} applies to an ONNX model (`detector` PATH.onnx), "
                         f"not to `detector` {spec}", parameters=("detector_format", "detector"))
    return fmt


def check_detector(spec: str, detector_format: str | None = None) -> str:
    """:func:`detector_kind` of ``spec``, having opened an ONNX model (read as ``detector_format``, default auto)
    to check that it can be used (an InputError if not): a run checks its detector before it writes anything."""
    kind = detector_kind(spec)
    fmt = _check_format(kind, spec, detector_format)
    if kind == "onnx":
        OnnxDetector(str(spec).strip(), format=fmt, threads=1)
    elif kind == "nanodet":
        from trafficgeo.video.detectors.builtin import builtin_model_path
        from trafficgeo.video.detectors.learned import BUILTIN

        builtin_model_path(BUILTIN)
    return kind


def make_detector(spec: str = "background", *, camera: Camera | None = None, surface: Surface | None = None,
                  roi: np.ndarray | None = None, scale: float = 0.5, warmup_s: float = WARMUP_S,
                  learning_rate: float | None = None, rules: SizeRules | None = None, conf: float | None = None,
                  iou: float = 0.5, input_size: int | None = None, class_map: Mapping[int, str] | None = None,
                  detector_format: str | None = None, road: Lanes | None = None, tiles: bool = True,
                  tiling: str = "squares", lines: list[CountLine] | None = None, backend: str | None = None
                  ) -> Detector:
    """A detector from a short spec (:func:`detector_kind`): a background subtraction name
    (:class:`BackgroundDetector` with MOG2 for "background", "bg" or "mog2", with KNN for "knn") or the path of a
    ``.onnx`` model (:class:`OnnxDetector` of layout ``detector_format``, default recognised from the model;
    ``conf`` default the layout's; ``camera`` and ``surface`` are not used, ``roi`` keeps detections whose bottom
    centre lies inside it), or "nanodet", the built-in learned detector
    (:func:`trafficgeo.video.detectors.learned.make_learned_detector`: tiled over the counted ``road`` (lanes,
    else ``roi``, else a band around each of the counting ``lines``) when ``tiles`` and a calibrated ``camera`` and
    ``surface`` are given; its plan tells what it reaches at the ``lines``). ``warmup_s``: the
    background detector's warm-up (s of video). ``backend``: the runtime of a learned detector
    (:mod:`trafficgeo.video.detectors.backends`: "auto", "onnxruntime", "onnxruntime-int8", "openvino"; None:
    onnxruntime, untimed)."""
    kind = detector_kind(spec)
    fmt = _check_format(kind, spec, detector_format)
    if kind == "nanodet":
        from trafficgeo.video.detectors.learned import make_learned_detector

        return make_learned_detector(camera=camera, surface=surface, road=road, roi=roi, tiles=tiles, conf=conf,
                                     iou=iou, tiling=tiling, lines=lines, backend=backend)
    if kind == "onnx":
        return OnnxDetector(str(spec).strip(), format=fmt, input_size=input_size, conf=conf, iou=iou,
                            class_map=class_map, roi=roi, backend=backend)
    return BackgroundDetector(method=kind, scale=scale, warmup_s=warmup_s, learning_rate=learning_rate,
                              camera=camera, surface=surface, roi=roi, rules=rules)
