"""The ONNX detector layouts :class:`trafficgeo.video.detectors.onnx.OnnxDetector` decodes: one small spec each
(:class:`Layout`): how a model is recognised (output names, shapes, ``metadata_props``), its pre-processing
(:class:`Preprocess`: colour order, mean/std, letterbox centred / top-left / plain resize, pad value) and a
vectorised decode of its outputs to boxes ``x1, y1, x2, y2`` in model-input pixels (corner origin), scores and
class ids, only for the asked class ids and scores >= ``conf``.

============== ============================================= ============================ ======================
format          outputs                                        input image                  class ids
============== ============================================= ============================ ======================
yolov8          ``[1, 4 + nc, A]`` (or ``[1, A, 4 + nc]``)     RGB 0-1, centred letterbox   COCO-80 (0-based) or
                cx, cy, w, h (input px), class scores          grey 114                     the metadata ``names``
end2end         ``[1, K, 6]``: x1, y1, x2, y2 (input px),      as yolov8                    as yolov8
                score, class (YOLOv10, YOLO26, ``nms=True``)
yolov5          ``[1, 3 A, 5 + nc]``: cx, cy, w, h, objectness as yolov8                    as yolov8
                class scores; score = obj x cls (YOLOv5/v7)
yolox           ``[1, A, 5 + nc]``, raw (grid decoded here) or BGR 0-255, top-left           COCO-80
                decoded                                        letterbox grey 114
rtdetr          ``labels`` [1, Q], ``boxes`` [1, Q, 4] x1y1x2y2 RGB 0-1, plain resize       COCO-80
                in frame px given ``orig_target_sizes`` (w, h), (RT-DETR/v2, D-FINE, DEIM)
                ``scores`` [1, Q]
rtdetr-ultra    ``[1, Q, 4 + nc]``: cx, cy, w, h normalised,   RGB 0-1, plain resize        as yolov8
                class scores (an ultralytics RT-DETR export)
rfdetr          ``dets`` [1, Q, 4] cxcywh normalised,          RGB, ImageNet mean/std,      COCO-91 category ids
                ``labels`` [1, Q, C] logits (sigmoid)          plain resize                 (index = id)
nanodet         per stride 8/16/32: class scores [1, N, nc]    BGR, NanoDet mean/std,       COCO-80
                (sigmoid) and side distributions [1, N, 44]    centred letterbox grey 114
============== ============================================= ============================ ======================

A = anchors of a stride-8/16/32 (or -64) head at the input size (8400 at 640 px). Default score thresholds: 0.3
(YOLO layouts), 0.4 (DETR layouts), 0.25 (NanoDet, whose scores are IoU-quality scores). NanoDet is letterboxed:
on the 91 real NGSIM US-101 frames of the project's data it finds 16.0 and 26.2 vehicles a frame (two views)
against 10.8 and 22.8 with a plain resize, the boxes fitting the vehicles. RF-DETR: the logit at index
``i`` is COCO category id ``i`` (1 person, 2 bicycle, 3 car, 4 motorcycle, 6 bus, 8 truck; index 0 and the ids
COCO skips name no class), so no offset is applied.
"""

from __future__ import annotations

import ast
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.video.detections import COCO_VEHICLES

COCO91_VEHICLES: dict[int, str] = {2: "bicycle", 3: "car", 4: "motorcycle", 6: "bus", 8: "truck"}
# Class names (a model's metadata ``names``, lower case) of road vehicles, and their trafficgeo names.
VEHICLE_NAMES: dict[str, str] = {"car": "car", "van": "van", "truck": "truck", "bus": "bus", "motorcycle": "motorcycle",
                                 "motorbike": "motorcycle", "motor": "motorcycle", "bicycle": "bicycle"}
P5, P6 = (8, 16, 32), (8, 16, 32, 64)
Raw = tuple[np.ndarray, np.ndarray, np.ndarray]  # boxes (N, 4) input px, scores (N,), class ids (N,) int64


# ---------------------------------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class Geometry:
    """Where a frame lands in the model input: resized to ``size`` (w, h) px, at ``offset`` (left, top) px;
    ``scale`` (x, y) = input px per frame px."""

    size: tuple[int, int]
    scale: tuple[float, float]
    offset: tuple[int, int]

    def to_frame(self, boxes: np.ndarray) -> np.ndarray:
        """Boxes (N, 4) in input px (corner origin) -> full-frame px (pixel-centre convention: -0.5)."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        sx, sy = self.scale
        left, top = self.offset
        return (b - [left, top, left, top]) / [sx, sy, sx, sy] - 0.5


IDENTITY = Geometry((0, 0), (1.0, 1.0), (0, 0))


@dataclass(frozen=True)
class Preprocess:
    """How a layout turns (H, W, 3) uint8 BGR frames into its ``[B, 3, h, w]`` float input: channel order
    (``rgb``), ``(x - mean) / std`` with ``mean``/``std`` in 0-255 units of the model's channel order, and the fit:
    ``"letterbox"`` (aspect kept, centred on a ``pad`` border), ``"topleft"`` (aspect kept, border right and
    bottom) or ``"stretch"`` (plain resize)."""

    rgb: bool
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    resize: str
    pad: int = 114

    def geometry(self, h: int, w: int, input_hw: tuple[int, int]) -> Geometry:
        """Where an ``h`` x ``w`` frame lands in an input of ``input_hw`` (h, w) px."""
        ih, iw = input_hw
        if self.resize == "stretch":
            return Geometry((iw, ih), (iw / w, ih / h), (0, 0))
        r = min(ih / h, iw / w)
        if self.resize == "topleft":  # YOLOX: truncated size, image at the top-left corner
            return Geometry((max(1, int(w * r)), max(1, int(h * r))), (r, r), (0, 0))
        nw, nh = round(w * r), round(h * r)  # ultralytics letterbox
        return Geometry((nw, nh), (r, r), (round((iw - nw) / 2 - 0.1), round((ih - nh) / 2 - 0.1)))

    def canvas(self, image: np.ndarray, input_hw: tuple[int, int]) -> tuple[np.ndarray, Geometry]:
        """``image`` resized and padded to ``input_hw`` (uint8 BGR) and its :class:`Geometry`."""
        import cv2

        h, w = image.shape[:2]
        g = self.geometry(h, w, input_hw)
        (nw, nh), (left, top) = g.size, g.offset
        resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR) if (nw, nh) != (w, h) else image
        if (nw, nh) == (input_hw[1], input_hw[0]):
            return resized, g
        out = np.full((input_hw[0], input_hw[1], 3), self.pad, dtype=np.uint8)
        out[top:top + nh, left:left + nw] = resized
        return out, g

    def blob(self, images: list[np.ndarray], input_hw: tuple[int, int]) -> tuple[np.ndarray, Geometry]:
        """Equally sized frames -> the ``[B, 3, h, w]`` float32 input and their common :class:`Geometry`."""
        canvases, geoms = zip(*(self.canvas(im, input_hw) for im in images), strict=True)
        x = np.stack(canvases)  # (B, h, w, 3) uint8 BGR
        # Channel by channel into the [B, 3, h, w] input, in place: the same float32 values as
        # (x - mean) * (1 / std) on the whole array, in 0.4 ms instead of 4 ms for one 416 x 416 image (its float
        # copies and the transpose cost more than the arithmetic).
        out = np.empty((x.shape[0], 3, x.shape[1], x.shape[2]), dtype=np.float32)
        mean, inv_std = np.float32(self.mean), 1.0 / np.float32(self.std)
        for c in range(3):
            plane = out[:, c]
            plane[...] = x[..., 2 - c if self.rgb else c]
            plane -= mean[c]
            plane *= inv_std[c]
        return out, geoms[0]


YOLO_PRE = Preprocess(True, (0.0, 0.0, 0.0), (255.0, 255.0, 255.0), "letterbox")
YOLOX_PRE = Preprocess(False, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), "topleft")
DETR_PRE = Preprocess(True, (0.0, 0.0, 0.0), (255.0, 255.0, 255.0), "stretch")
IMAGENET_PRE = Preprocess(True, (123.675, 116.28, 103.53), (58.395, 57.12, 57.375), "stretch")
NANODET_PRE = Preprocess(False, (103.53, 116.28, 123.675), (57.375, 57.12, 58.395), "letterbox")


# ---------------------------------------------------------------------------------------------------- the model
@dataclass(frozen=True)
class Port:
    """An input or output of the model: name, shape (None where dynamic) and ONNX type."""

    name: str
    shape: tuple[int | None, ...]
    type: str = "tensor(float)"


@dataclass(frozen=True)
class ModelIO:
    """What recognition sees: the image input, other inputs, the outputs, ``metadata_props`` and the input size
    (h, w) px the detector feeds."""

    image: Port
    extra: tuple[Port, ...]
    outputs: tuple[Port, ...]
    metadata: Mapping[str, str]
    input_hw: tuple[int, int]

    @property
    def names(self) -> dict[int, str] | None:
        """The class names of the metadata (``{0: 'person', ...}``, as ultralytics and YOLOv5 store them)."""
        return parse_names(self.metadata.get("names"))

    @property
    def ultralytics(self) -> bool:
        """Exported by ultralytics 8 or later (its metadata has a ``task``; YOLOv5's has ``names`` and
        ``stride`` only)."""
        return "task" in self.metadata or "ultralytics" in self.metadata.get("author", "").lower()

    @property
    def end2end(self) -> bool:
        """Metadata of an export whose output is already final boxes (YOLOv10/YOLO26 ``end2end``, ``nms=True``)."""
        if str(self.metadata.get("end2end", "")).lower() == "true":
            return True
        args = parse_literal(self.metadata.get("args"))
        return isinstance(args, dict) and bool(args.get("nms"))

    def output(self, name: str) -> Port:
        return next(p for p in self.outputs if p.name == name)


def parse_literal(text: str | None) -> object:
    """A Python or JSON literal from a metadata string, or None."""
    if not text:
        return None
    for parse in (ast.literal_eval, json.loads):
        try:
            return parse(text)
        except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
            continue
    return None


def parse_names(text: str | None) -> dict[int, str] | None:
    """Class names from a metadata string (a dict id -> name or a list), or None."""
    value = parse_literal(text)
    if isinstance(value, list | tuple):
        value = dict(enumerate(value))
    if not isinstance(value, dict) or not value:
        return None
    try:
        return {int(k): str(v) for k, v in value.items()}
    except (TypeError, ValueError):
        return None


def vehicle_classes(names: Mapping[int, str]) -> dict[int, str]:
    """Model class id -> trafficgeo vehicle name, for the ``names`` that are road vehicles."""
    return {k: VEHICLE_NAMES[v.strip().lower()] for k, v in names.items() if v.strip().lower() in VEHICLE_NAMES}


def anchor_count(input_hw: tuple[int, int], strides: tuple[int, ...]) -> int:
    """Anchors (grid cells) of a head with ``strides`` on an input of ``input_hw`` (h, w) px."""
    return sum(math.ceil(input_hw[0] / s) * math.ceil(input_hw[1] / s) for s in strides)


def grid_centres(input_hw: tuple[int, int], strides: tuple[int, ...], offset: float) -> np.ndarray:
    """(A, 3) ``x, y, stride`` of every grid cell, stride by stride, row-major; x, y = (cell + offset) x stride."""
    parts = []
    for s in strides:
        gh, gw = math.ceil(input_hw[0] / s), math.ceil(input_hw[1] / s)
        yy, xx = np.divmod(np.arange(gh * gw), gw)
        parts.append(np.column_stack([(xx + offset) * s, (yy + offset) * s, np.full(gh * gw, s)]))
    return np.concatenate(parts).astype(np.float64)


# ---------------------------------------------------------------------------------------------------- layouts
@dataclass(frozen=True)
class Fit:
    """How a model fits a layout: ``roles`` (role -> output name), ``sure`` (by names/metadata, not shapes
    alone), ``classes`` (class slots the model scores, when known) and layout ``options``."""

    roles: dict[str, str]
    sure: bool
    classes: int | None = None
    options: dict[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class Decoding:
    """What a decode needs: the model class ids to keep (sorted), the score threshold and the input (h, w) px."""

    ids: np.ndarray
    conf: float
    input_hw: tuple[int, int]
    options: Mapping[str, object]


@dataclass(frozen=True)
class Layout:
    """One ONNX output layout (see the module table). ``fit(io, forced)`` says whether a model has it (``forced``:
    the user named the format, so shape heuristics are relaxed); ``decode`` runs per image on its outputs (batch
    dimension removed); ``settle`` (optional) looks at the outputs of a blank frame to finish the fit;
    ``sizes_input``: it takes the frame size (w, h) as a second input and returns boxes in frame px."""

    name: str
    title: str
    pre: Preprocess
    coco91: bool
    conf: float
    fit: Callable[[ModelIO, bool], Fit | None]
    decode: Callable[[Mapping[str, np.ndarray], Decoding], Raw]
    names_index: bool = False
    sizes_input: bool = False
    settle: Callable[[ModelIO, Fit, Mapping[str, np.ndarray], bool], Fit] | None = None

    @property
    def default_classes(self) -> dict[int, str]:
        return dict(COCO91_VEHICLES if self.coco91 else COCO_VEHICLES)


def _main3d(io: ModelIO) -> Port | None:
    """The first output when it is 3-D and any other output is 4-D (segmentation prototypes)."""
    first = io.outputs[0]
    if io.extra or len(first.shape) != 3 or any(len(p.shape) != 4 for p in io.outputs[1:]):
        return None
    return first


def _dims(port: Port) -> tuple[int, ...]:
    return tuple(d if d is not None else -1 for d in port.shape)


def _pick(scores: np.ndarray, ids: np.ndarray, conf: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows whose best asked-class score (``scores`` (N, K) over ``ids``) reaches ``conf``: rows, score, id."""
    if scores.shape[0] == 0 or ids.size == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
    best = np.argmax(scores, axis=1)
    score = scores[np.arange(scores.shape[0]), best]
    rows = np.flatnonzero(score >= conf)
    return rows, score[rows].astype(np.float64), ids[best[rows]]


def _xyxy(cxcywh: np.ndarray) -> np.ndarray:
    c = np.asarray(cxcywh, dtype=np.float64)
    half = 0.5 * c[:, 2:4]
    return np.column_stack([c[:, :2] - half, c[:, :2] + half])


# --- YOLOv8 / YOLO11
def _fit_yolov8(io: ModelIO, forced: bool) -> Fit | None:
    p = _main3d(io)
    if p is None or (io.end2end and not forced):
        return None
    _b, c, a = _dims(p)
    names = io.names
    nc = len(names) if names else None
    counts = (anchor_count(io.input_hw, P5), anchor_count(io.input_hw, P6))
    sure = io.ultralytics and nc is not None
    if c >= 5 and a > c and (forced or a in counts) and (nc is None or c >= 4 + nc):
        return Fit({"pred": p.name}, sure, nc or c - 4, {"transposed": False})
    wanted = (4 + nc, 4 + nc + 32) if nc is not None and io.ultralytics else (84,)
    if a >= 5 and c > a and (forced or (c in counts and a in wanted)):
        return Fit({"pred": p.name}, sure, nc or a - 4, {"transposed": True})
    return None


def _decode_yolov8(out: Mapping[str, np.ndarray], d: Decoding) -> Raw:
    p = out["pred"]
    p = p.T if d.options.get("transposed") else p  # (4 + nc, A)
    rows, score, cls = _pick(p[4 + d.ids].T, d.ids, d.conf)
    return _xyxy(p[:4, rows].T), score, cls


# --- end-to-end: final boxes
def _fit_end2end(io: ModelIO, forced: bool) -> Fit | None:
    p = _main3d(io)
    if p is None:
        return None
    _b, k, c = _dims(p)
    if not (c == 6 or (forced and c > 6)) or k == 6:
        return None
    return Fit({"pred": p.name}, io.end2end, len(io.names) if io.names else None)


def _decode_end2end(out: Mapping[str, np.ndarray], d: Decoding) -> Raw:
    p = np.asarray(out["pred"], dtype=np.float64)
    cls = np.rint(p[:, 5]).astype(np.int64)
    rows = np.flatnonzero(np.isin(cls, d.ids) & (p[:, 4] >= d.conf))
    return p[rows, :4], p[rows, 4], cls[rows]


# --- YOLOv5 / YOLOv7 (objectness), and YOLOX
def _fit_yolov5(io: ModelIO, forced: bool) -> Fit | None:
    p = _main3d(io)
    if p is None or (io.ultralytics and not forced):
        return None
    _b, a, c = _dims(p)
    if c < 6 or a <= c:
        return None
    names = io.names
    if names is not None and c not in (5 + len(names), 5 + len(names) + 32) and not forced:
        return None
    three = a in (3 * anchor_count(io.input_hw, P5), 3 * anchor_count(io.input_hw, P6))
    if names is None and not three and not forced:
        return None
    return Fit({"pred": p.name}, names is not None, len(names) if names else c - 5)


def _decode_yolov5(out: Mapping[str, np.ndarray], d: Decoding) -> Raw:
    p = out["pred"]
    rows, score, cls = _pick(p[:, 5 + d.ids] * p[:, 4:5], d.ids, d.conf)
    return _xyxy(p[rows, :4]), score, cls


def _fit_yolox(io: ModelIO, forced: bool) -> Fit | None:
    p = _main3d(io)
    if p is None or ((io.names is not None or io.ultralytics) and not forced):
        return None
    _b, a, c = _dims(p)
    if c < 6 or a <= c or (not forced and (a != anchor_count(io.input_hw, P5) or c == 84)):
        return None
    return Fit({"pred": p.name}, False, c - 5, {"decoded": None})


def looks_decoded(pred: np.ndarray, input_hw: tuple[int, int]) -> bool:
    """Do the box centres of a YOLOX output (A, 5 + nc) follow the stride 8/16/32 grid (decoded in the graph)
    rather than being raw offsets near 0? Decided on the whole output, whatever the image shows."""
    grid = grid_centres(input_hw, P5, 0.5)
    if grid.shape[0] != pred.shape[0]:
        return bool(np.abs(pred[:, :2]).max(initial=0.0) > 2 * P5[-1])
    xy = np.asarray(pred[:, :2], dtype=np.float64)
    return bool(np.abs(xy - grid[:, :2]).mean() < np.abs(xy).mean())


def _settle_yolox(io: ModelIO, fit: Fit, out: Mapping[str, np.ndarray], forced: bool) -> Fit:
    decoded = looks_decoded(out["pred"], io.input_hw)
    if decoded and not forced:
        shape = list(io.output(fit.roles["pred"]).shape)
        raise InputError(f"outputs {fit.roles['pred']} {shape} hold decoded boxes with an objectness score: a "
                         "YOLOX export with decoding or a YOLOv5/YOLOv6-style export, which differ in colour order "
                         "and padding; pass detector_format yolox or detector_format yolov5",
                         parameters=("detector_format",))
    return replace(fit, options={"decoded": decoded})


def _decode_yolox(out: Mapping[str, np.ndarray], d: Decoding) -> Raw:
    p = out["pred"]
    rows, score, cls = _pick(p[:, 5 + d.ids] * p[:, 4:5], d.ids, d.conf)
    box = np.asarray(p[rows, :4], dtype=np.float64)
    if not d.options.get("decoded"):
        grid = grid_centres(d.input_hw, P5, 0.0)
        if grid.shape[0] != p.shape[0]:
            raise InputError(f"a YOLOX output of {p.shape[0]} anchors does not fit the stride 8/16/32 grid of a "
                             f"{d.input_hw[1]}x{d.input_hw[0]} input ({grid.shape[0]} anchors)")
        g = grid[rows]
        box = np.column_stack([box[:, :2] * g[:, 2:3] + g[:, :2], np.exp(box[:, 2:4]) * g[:, 2:3]])  # (raw + cell) s
    return _xyxy(box), score, cls


# --- RT-DETR family (labels, boxes, scores) and the ultralytics RT-DETR export
def _fit_rtdetr(io: ModelIO, forced: bool) -> Fit | None:
    if len(io.extra) != 1 or io.extra[0].shape[-1:] not in ((2,), (None,)) or len(io.outputs) != 3:
        return None
    by = {p.name.lower(): p for p in io.outputs}
    if {"labels", "boxes", "scores"} <= set(by):
        roles, sure = {k: by[k].name for k in ("labels", "boxes", "scores")}, True
    else:
        boxes = [p for p in io.outputs if len(p.shape) == 3 and p.shape[2] == 4]
        flat = [p for p in io.outputs if len(p.shape) == 2]
        ints = [p for p in flat if "int" in p.type]
        if len(boxes) != 1 or len(flat) != 2 or len(ints) != 1:
            return None
        roles = {"boxes": boxes[0].name, "labels": ints[0].name, "scores": next(p for p in flat if p not in ints).name}
        sure = False
    b = io.output(roles["boxes"])
    if len(b.shape) != 3 or b.shape[2] != 4:
        return None
    return Fit(roles, sure)


def _decode_rtdetr(out: Mapping[str, np.ndarray], d: Decoding) -> Raw:
    labels = np.asarray(out["labels"]).reshape(-1).astype(np.int64)
    scores = np.asarray(out["scores"], dtype=np.float64).reshape(-1)
    rows = np.flatnonzero(np.isin(labels, d.ids) & (scores >= d.conf))
    return np.asarray(out["boxes"], dtype=np.float64).reshape(-1, 4)[rows], scores[rows], labels[rows]


def _fit_rtdetr_ultra(io: ModelIO, forced: bool) -> Fit | None:
    p = _main3d(io)
    if p is None:
        return None
    _b, _q, c = _dims(p)
    said = "rtdetr" in io.metadata.get("description", "").lower().replace("-", "")
    if c < 5 or not (said or forced):
        return None
    return Fit({"pred": p.name}, said, len(io.names) if io.names else c - 4)


def _decode_rtdetr_ultra(out: Mapping[str, np.ndarray], d: Decoding) -> Raw:
    p = out["pred"]
    rows, score, cls = _pick(p[:, 4 + d.ids], d.ids, d.conf)
    ih, iw = d.input_hw
    return _xyxy(np.asarray(p[rows, :4], dtype=np.float64) * [iw, ih, iw, ih]), score, cls


# --- RF-DETR
def _fit_rfdetr(io: ModelIO, forced: bool) -> Fit | None:
    if io.extra or len(io.outputs) != 2 or any(len(p.shape) != 3 for p in io.outputs):
        return None
    by = {p.name.lower(): p for p in io.outputs}
    if {"dets", "labels"} <= set(by):
        dets, labels, sure = by["dets"], by["labels"], True
    elif forced:
        fours = [p for p in io.outputs if p.shape[2] == 4]
        if len(fours) != 1:
            return None
        dets, labels, sure = fours[0], next(p for p in io.outputs if p is not fours[0]), False
    else:
        return None
    if dets.shape[2] != 4 or labels.shape[2] is None or labels.shape[2] < 2:
        return None
    return Fit({"dets": dets.name, "labels": labels.name}, sure, labels.shape[2])


def _decode_rfdetr(out: Mapping[str, np.ndarray], d: Decoding) -> Raw:
    logits = np.asarray(out["labels"], dtype=np.float64)[:, d.ids]
    rows, score, cls = _pick(1.0 / (1.0 + np.exp(-logits)), d.ids, d.conf)
    ih, iw = d.input_hw
    return _xyxy(np.asarray(out["dets"], dtype=np.float64)[rows] * [iw, ih, iw, ih]), score, cls


# --- NanoDet (GFL head): per stride, class scores and distributions of the four sides
NANODET_BINS = (8, 11, 17)  # reg_max + 1 of the common NanoDet heads (7, 10, 16)


def _fit_nanodet(io: ModelIO, forced: bool) -> Fit | None:
    outs = io.outputs
    if io.extra or len(outs) < 2 or len(outs) % 2 or any(len(p.shape) != 3 or None in p.shape[1:] for p in outs):
        return None
    levels: dict[int, list[Port]] = {}
    for p in outs:
        levels.setdefault(int(p.shape[1]), []).append(p)
    roles, strides, bins, ncs = {}, [], set(), set()
    for n, pair in sorted(levels.items(), reverse=True):
        stride = next((s for s in P6 if anchor_count(io.input_hw, (s,)) == n), None)
        if len(pair) != 2 or stride is None:
            return None
        is_reg = [p.shape[2] % 4 == 0 and p.shape[2] // 4 in NANODET_BINS for p in pair]
        if is_reg[0] == is_reg[1]:
            is_reg = [any(k in p.name.lower() for k in ("reg", "box", "dis")) for p in pair]
            if is_reg[0] == is_reg[1]:
                return None
        reg, cls = (pair[0], pair[1]) if is_reg[0] else (pair[1], pair[0])
        roles[f"cls{stride}"], roles[f"reg{stride}"] = cls.name, reg.name
        strides.append(stride)
        bins.add(int(reg.shape[2]) // 4)
        ncs.add(int(cls.shape[2]))
    if len(bins) != 1 or len(ncs) != 1:
        return None
    return Fit(roles, True, ncs.pop(), {"strides": tuple(strides), "bins": bins.pop()})


def _decode_nanodet(out: Mapping[str, np.ndarray], d: Decoding) -> Raw:
    boxes, scores, classes = [], [], []
    nbins = int(d.options["bins"])
    for s in d.options["strides"]:
        rows, score, cls = _pick(np.asarray(out[f"cls{s}"])[:, d.ids], d.ids, d.conf)
        dist = np.asarray(out[f"reg{s}"], dtype=np.float64)[rows].reshape(-1, 4, nbins)
        dist = np.exp(dist - dist.max(axis=2, keepdims=True))
        sides = (dist / dist.sum(axis=2, keepdims=True)) @ np.arange(nbins, dtype=np.float64) * s  # (k, 4) px
        gw = math.ceil(d.input_hw[1] / s)
        cy, cx = np.divmod(rows, gw)
        cx, cy = (cx + 0.5) * s, (cy + 0.5) * s
        boxes.append(np.column_stack([cx - sides[:, 0], cy - sides[:, 1], cx + sides[:, 2], cy + sides[:, 3]]))
        scores.append(score)
        classes.append(cls)
    return np.concatenate(boxes), np.concatenate(scores), np.concatenate(classes)


LAYOUTS: dict[str, Layout] = {lay.name: lay for lay in (
    Layout("yolov8", "YOLOv8/YOLO11 [1, 4 + classes, anchors]", YOLO_PRE, False, 0.3, _fit_yolov8,
           _decode_yolov8, names_index=True),
    Layout("end2end", "end-to-end YOLOv10/YOLO26/nms=True [1, K, 6]", YOLO_PRE, False, 0.3, _fit_end2end,
           _decode_end2end, names_index=True),
    Layout("yolov5", "YOLOv5/YOLOv7 [1, 3 x anchors, 5 + classes]", YOLO_PRE, False, 0.3, _fit_yolov5,
           _decode_yolov5, names_index=True),
    Layout("yolox", "YOLOX [1, anchors, 5 + classes]", YOLOX_PRE, False, 0.3, _fit_yolox, _decode_yolox,
           settle=_settle_yolox),
    Layout("rtdetr", "RT-DETR/D-FINE/DEIM labels + boxes + scores (inputs images + orig_target_sizes)", DETR_PRE,
           False, 0.4, _fit_rtdetr, _decode_rtdetr, sizes_input=True),
    Layout("rtdetr-ultra", "ultralytics RT-DETR [1, queries, 4 + classes]", DETR_PRE, False, 0.4,
           _fit_rtdetr_ultra, _decode_rtdetr_ultra, names_index=True),
    Layout("rfdetr", "RF-DETR dets [1, Q, 4] + labels [1, Q, 91]", IMAGENET_PRE, True, 0.4, _fit_rfdetr,
           _decode_rfdetr),
    Layout("nanodet", "NanoDet class scores [1, N, classes] + side distributions [1, N, 4 x bins] per stride",
           NANODET_PRE, False, 0.25, _fit_nanodet, _decode_nanodet),
)}
FORMAT_ALIASES: dict[str, str] = {"yolo11": "yolov8", "ultralytics": "yolov8", "yolov10": "end2end",
                                  "yolo26": "end2end", "nms": "end2end", "yolov7": "yolov5", "rtdetrv2": "rtdetr",
                                  "d-fine": "rtdetr", "dfine": "rtdetr", "deim": "rtdetr", "rf-detr": "rfdetr"}
SUPPORTED = "supported: " + "; ".join(lay.title for lay in LAYOUTS.values())
FORMAT_HELP = ("ONNX output layout: 'auto' (from the model's output names, shapes and metadata) or one of "
               + ", ".join(f"'{n}'" for n in LAYOUTS) + " (also " + ", ".join(f"'{a}'" for a in FORMAT_ALIASES)
               + ")")


def format_name(name: str | None) -> str | None:
    """The layout a ``--detector-format`` value names (None for ``auto``), or an InputError."""
    key = "auto" if name is None else str(name).strip().lower()
    if key == "auto":
        return None
    key = FORMAT_ALIASES.get(key, key)
    if key not in LAYOUTS:
        raise InputError(f"detector_format {name!r} is not known; use {FORMAT_HELP}", parameters=("detector_format",))
    return key


def _shapes(io: ModelIO) -> str:
    return ", ".join(f"{p.name} {[d if d is not None else '?' for d in p.shape]}" for p in io.outputs)


def recognise(io: ModelIO, fmt: str | None = None) -> tuple[Layout, Fit]:
    """The layout of a model (the one named by ``fmt``, else the best fit by names/metadata, then shapes) and
    how it fits; an InputError (one line, naming the outputs found) when none or several fit equally."""
    task = io.metadata.get("task")
    if task and task not in ("detect", "segment") and fmt is None:
        raise InputError(f"the model is a {task!r} model (metadata task), not a detector; export a detection model")
    name = format_name(fmt)
    if name is not None:
        fit = LAYOUTS[name].fit(io, True)
        if fit is None:
            raise InputError(f"outputs {_shapes(io)} (input {io.input_hw[1]}x{io.input_hw[0]}) do not fit "
                             f"detector_format {name} ({LAYOUTS[name].title})", parameters=("detector_format",))
        return LAYOUTS[name], fit
    fits = [(lay, f) for lay in LAYOUTS.values() if (f := lay.fit(io, False)) is not None]
    if not fits:
        raise InputError(f"outputs {_shapes(io)} (input {io.input_hw[1]}x{io.input_hw[0]}) are a layout trafficgeo "
                         f"cannot decode; {SUPPORTED}")
    best = [(lay, f) for lay, f in fits if f.sure] or fits
    if len(best) > 1:
        raise InputError(f"outputs {_shapes(io)} fit several layouts (" + ", ".join(lay.name for lay, _ in best)
                         + "); pass detector_format with one of them", parameters=("detector_format",))
    return best[0]
