"""Bring-your-own ONNX detectors run with onnxruntime on the CPU (:class:`OnnxDetector`). trafficgeo never
downloads weights. Pixels follow :mod:`trafficgeo.video.detections`."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.video.detections import COCO_VEHICLES, Detections, check_image, in_roi
from trafficgeo.video.detector_names import ONNX_HINT


# ---------------------------------------------------------------------------------------------------- ONNX
def letterbox(image: np.ndarray, size: int, pad_value: int = 114) -> tuple[np.ndarray, float, tuple[int, int]]:
    """Resize ``image`` to fit a ``size`` x ``size`` square keeping its aspect, centred on a ``pad_value`` border
    (the ultralytics letterbox). Returns the square image, the scale and the (left, top) padding in pixels."""
    h, w = image.shape[:2]
    r = min(size / h, size / w)
    nw, nh = round(w * r), round(h * r)
    left = round((size - nw) / 2 - 0.1)
    top = round((size - nh) / 2 - 0.1)
    resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR) if (nw, nh) != (w, h) else image
    out = cv2.copyMakeBorder(resized, top, size - nh - top, left, size - nw - left, cv2.BORDER_CONSTANT,
                             value=(pad_value, pad_value, pad_value))
    return out, r, (left, top)


ONNX_SHAPES = ("supported: [1, 4 + classes, anchors] with 3 or 4 strides' anchors (a YOLOv8/YOLO11 detection "
               "export without NMS, e.g. [1, 84, 8400] at 640 px); not exports with NMS ([1, 300, 6]), transposed "
               "outputs ([1, 8400, 84]) or outputs with an objectness score ([1, 25200, 85])")


def yolo_anchor_counts(input_size: int) -> tuple[int, int]:
    """Anchors of a YOLOv8/YOLO11 head on a square input of ``input_size`` px: strides 8, 16, 32 (P5 models) and
    8 to 64 (P6 models)."""
    p5 = sum(math.ceil(input_size / st) ** 2 for st in (8, 16, 32))
    return p5, p5 + math.ceil(input_size / 64) ** 2


def check_output_shape(path: str | Path, shape: Sequence[object], input_size: int) -> None:
    """InputError unless an ONNX output shape (dimensions: ints, or names/None where dynamic) is one
    :class:`OnnxDetector` decodes: ``[1, 4 + classes, anchors]``, the anchors those of its head at
    ``input_size`` px (:func:`yolo_anchor_counts`) and more than the values per anchor."""
    dims = list(shape)
    fixed = [d if isinstance(d, int) and not isinstance(d, bool) and d > 0 else None for d in dims]
    ok = len(dims) == 3 and fixed[0] in (1, None)
    if ok and fixed[1] is not None and fixed[1] < 5:
        ok = False
    if ok and fixed[2] is not None:
        ok = fixed[2] in yolo_anchor_counts(input_size) and (fixed[1] is None or fixed[2] > fixed[1])
    if not ok:
        found = "[" + ", ".join(str(d) if f is not None else "?" for d, f in zip(dims, fixed, strict=True)) + "]"
        raise InputError(f"{path}: the model's output has shape {found} (input {input_size} px), which trafficgeo "
                         f"cannot decode; {ONNX_SHAPES}; {ONNX_HINT}")


class OnnxDetector:
    """A YOLOv8/YOLO11-style ONNX detector run with onnxruntime on the CPU (2 intra-op threads).

    The model takes a ``[1, 3, S, S]`` float32 RGB image scaled to 0..1 and letterboxed (aspect kept, grey 114
    border) and returns ``[1, 4 + nc, A]``: per anchor the box centre and size ``cx, cy, w, h`` in letterboxed
    input pixels, then one score per class (no objectness; the ultralytics export without NMS). Only classes in
    ``class_map`` (model class id -> trafficgeo name; default the COCO vehicles) are kept; boxes scoring at least
    ``conf`` go through non-maximum suppression at IoU ``iou`` (across classes with ``agnostic=True``, so that one
    vehicle is not reported as both a car and a truck), then back to full-frame pixels. The model's pixel
    coordinates have their origin at the top-left *corner* of the image; 0.5 px is subtracted for the pixel-centre
    convention. A model with a fixed input size uses it (``input_size`` is for dynamic inputs).
    """

    def __init__(self, model_path: str | Path, *, input_size: int = 640, conf: float = 0.3, iou: float = 0.5,
                 class_map: Mapping[int, str] | None = None, agnostic: bool = True, roi: np.ndarray | None = None,
                 threads: int = 2) -> None:
        p = Path(model_path)
        if not p.is_file():
            raise InputError(f"{p}: ONNX model not found; put the .onnx file there or pass its path with "
                             f"--detector PATH.onnx ({ONNX_HINT})")
        if int(input_size) != input_size or input_size < 32:
            raise InputError(f"OnnxDetector: input_size {input_size!r} must be a whole number of pixels >= 32")
        for name, value in (("conf", conf), ("iou", iou)):
            if not (np.isfinite(value) and 0 <= value <= 1):
                raise InputError(f"OnnxDetector: {name} {value!r} must be in [0, 1]")
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        try:
            self._session = ort.InferenceSession(str(p), sess_options=opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            msg = " ".join(str(exc).split())[:200]
            raise InputError(f"{p}: not a usable ONNX model ({msg}); {ONNX_HINT}") from None
        inputs, outputs = self._session.get_inputs(), self._session.get_outputs()
        in_shape = inputs[0].shape if len(inputs) == 1 else []
        if len(in_shape) != 4 or (isinstance(in_shape[1], int) and in_shape[1] != 3):
            shapes = [i.shape for i in inputs]
            raise InputError(f"{p}: expected one input of shape [1, 3, S, S] (a YOLOv8/YOLO11 detection export), "
                             f"found {shapes}; {ONNX_HINT}")
        if not outputs:
            raise InputError(f"{p}: the model has no output; {ONNX_SHAPES}; {ONNX_HINT}")
        if inputs[0].type != "tensor(float)":
            raise InputError(f"{p}: the model's input is {inputs[0].type}, not float32; export it without half "
                             f"precision; {ONNX_HINT}")
        shape = inputs[0].shape
        fixed = [d for d in shape[2:] if isinstance(d, int) and d > 0]
        if len(fixed) == 2 and fixed[0] != fixed[1]:
            raise InputError(f"{p}: input {shape} is not square; export with a square imgsz (e.g. imgsz=640)")
        self.input_size = int(fixed[0]) if fixed else int(input_size)
        check_output_shape(p, outputs[0].shape, self.input_size)
        self._input_name = inputs[0].name
        self._output_name = outputs[0].name
        cmap = dict(COCO_VEHICLES if class_map is None else class_map)
        if not cmap:
            raise InputError("OnnxDetector: class_map is empty; map at least one model class id to a vehicle name")
        self.class_map = {int(k): str(v) for k, v in cmap.items()}
        nc_out = outputs[0].shape[1]
        if isinstance(nc_out, int) and nc_out - 4 <= max(self.class_map):
            raise InputError(f"{p}: the model has {nc_out - 4} classes but class_map uses class id "
                             f"{max(self.class_map)}; give a class_map for this model")
        self.conf, self.iou, self.agnostic = float(conf), float(iou), bool(agnostic)
        self.roi = None if roi is None else np.asarray(roi)
        self.path = p

    def detect(self, image: np.ndarray, time_s: float = 0.0) -> Detections:
        """Vehicles in ``image`` ((H, W, 3) uint8 BGR); ``time_s`` is not used."""
        image = check_image(image)
        h, w = image.shape[:2]
        lb, r, (left, top) = letterbox(image, self.input_size)
        blob = cv2.dnn.blobFromImage(lb, scalefactor=1.0 / 255.0, swapRB=True)  # (1, 3, S, S) float32 RGB
        try:
            out = np.asarray(self._session.run([self._output_name], {self._input_name: blob})[0])
        except Exception as exc:  # onnxruntime's own exception types (shape mismatch inside the graph, ...)
            msg = " ".join(str(exc).split())[:200]
            raise InputError(f"{self.path}: the model failed on a {w}x{h} frame letterboxed to {self.input_size} px "
                             f"({msg}); {ONNX_HINT}") from None
        check_output_shape(self.path, list(out.shape), self.input_size)
        if out.shape[1] - 4 <= max(self.class_map):
            raise InputError(f"{self.path}: output of shape {list(out.shape)} has {out.shape[1] - 4} classes but "
                             f"class_map uses class id {max(self.class_map)}; give a class_map for this model")
        pred = out[0]
        ids = np.array(sorted(self.class_map), dtype=np.int64)
        cls_scores = pred[4 + ids, :]  # (K, A)
        best = np.argmax(cls_scores, axis=0)
        score = cls_scores[best, np.arange(pred.shape[1])]
        keep = np.flatnonzero(score >= self.conf)
        if keep.size == 0:
            return Detections.empty()
        cx, cy, bw, bh = pred[0, keep], pred[1, keep], pred[2, keep], pred[3, keep]
        x1 = (cx - 0.5 * bw - left) / r - 0.5
        y1 = (cy - 0.5 * bh - top) / r - 0.5
        x2 = (cx + 0.5 * bw - left) / r - 0.5
        y2 = (cy + 0.5 * bh - top) / r - 0.5
        boxes = np.column_stack([x1, y1, x2, y2]).astype(np.float64)
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], -0.5, w - 0.5)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], -0.5, h - 0.5)
        score = score[keep].astype(np.float64)
        cls_id = ids[best[keep]]
        xywh = np.column_stack([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]])
        if self.agnostic:
            picked = cv2.dnn.NMSBoxes(xywh.tolist(), score.tolist(), self.conf, self.iou)
        else:
            picked = cv2.dnn.NMSBoxesBatched(xywh.tolist(), score.tolist(), cls_id.tolist(), self.conf, self.iou)
        picked = np.asarray(picked, dtype=np.int64).reshape(-1)
        picked = picked[np.argsort(-score[picked], kind="stable")]
        names = np.array([self.class_map[int(c)] for c in cls_id[picked]], dtype=object)
        det = Detections(boxes[picked], np.clip(score[picked], 0.0, 1.0), names)
        if self.roi is not None and len(det):
            det = det.select(in_roi(self.roi, det.bottom_centres, (h, w)))
        return det

