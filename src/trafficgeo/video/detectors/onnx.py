"""Bring-your-own ONNX detectors run with onnxruntime (:class:`OnnxDetector`), in every common export layout
(:mod:`trafficgeo.video.detectors.onnx_formats`: YOLOv5/v7, YOLOv8/11, end-to-end YOLOv10/YOLO26, YOLOX,
RT-DETR/D-FINE/DEIM, ultralytics RT-DETR, RF-DETR, NanoDet). trafficgeo never downloads weights. Pixels follow
:mod:`trafficgeo.video.detections`."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.video.checkpoint import sha256_file
from trafficgeo.video.detections import Detections, check_image, in_roi
from trafficgeo.video.detectors.backends import (
    OPENVINO,
    OPENVINO_INT8,
    ORT_CPU,
    ORT_CUDA,
    ORT_INT8,
    ORT_OPENVINO,
    Backend,
    BackendChoice,
    OpenVinoBackend,
    OrtBackend,
    check_backend,
    choose_backend,
    int8_saturation,
    openvino_version,
)
from trafficgeo.video.detectors.names import DETECTOR_PARAMETERS, ONNX_HINT
from trafficgeo.video.detectors.onnx_formats import (
    IDENTITY,
    P5,
    P6,
    SUPPORTED,
    Decoding,
    Fit,
    Layout,
    ModelIO,
    Port,
    Preprocess,
    anchor_count,
    format_name,
    parse_literal,
    recognise,
    vehicle_classes,
)

ONNX_SHAPES = SUPPORTED  # the layouts decoded, for messages
PREFERRED_PROVIDERS = ("CUDAExecutionProvider", "OpenVINOExecutionProvider")
CPU = "CPUExecutionProvider"
EP_NAMES = {"CUDAExecutionProvider": ORT_CUDA, "OpenVINOExecutionProvider": ORT_OPENVINO}  # backend names
MAX_BATCH = 16  # images per run of a model with a dynamic batch dimension
MAX_CANDIDATES = 1000  # boxes per image going into the non-maximum suppression (the best scores)


def letterbox(image: np.ndarray, size: int, pad_value: int = 114) -> tuple[np.ndarray, float, tuple[int, int]]:
    """Resize ``image`` to fit a ``size`` x ``size`` square keeping its aspect, centred on a ``pad_value`` border
    (the ultralytics letterbox). Returns the square image, the scale and the (left, top) padding in pixels."""
    out, g = Preprocess(True, (0, 0, 0), (1, 1, 1), "letterbox", pad_value).canvas(image, (size, size))
    return out, g.scale[0], g.offset


def yolo_anchor_counts(input_size: int) -> tuple[int, int]:
    """Anchors of a YOLOv8/YOLO11 head on a square input of ``input_size`` px: strides 8, 16, 32 (P5 models) and
    8 to 64 (P6 models)."""
    return anchor_count((input_size, input_size), P5), anchor_count((input_size, input_size), P6)


def pick_providers(asked: str | Sequence[str] | None, available: Sequence[str]) -> list[str]:
    """onnxruntime execution providers to use, CPU last: those ``asked`` ("cuda", "openvino", "cpu" or full
    provider names; an InputError naming the installed ones when one is not installed), or with ``None`` CUDA and
    OpenVINO when installed."""
    avail = list(available)
    if asked is None:
        chosen = [p for p in PREFERRED_PROVIDERS if p in avail]
    else:
        short = {"cuda": "CUDAExecutionProvider", "openvino": "OpenVINOExecutionProvider", "cpu": CPU}
        chosen = [short.get(a.strip().lower(), a.strip()) for a in ([asked] if isinstance(asked, str) else asked)]
        missing = [a for a in chosen if a not in avail]
        if missing:
            raise InputError(f"execution provider {', '.join(missing)} is not installed (installed: "
                             f"{', '.join(avail)}); install onnxruntime-gpu or onnxruntime-openvino, or leave "
                             f"providers unset")
    return [*dict.fromkeys(p for p in chosen if p != CPU), CPU]


def suppress(boxes: np.ndarray, scores: np.ndarray, iou: float = 0.5, inside: float | None = 0.8) -> np.ndarray:
    """Greedy non-maximum suppression across classes: indices of the kept boxes (best score first). A box goes
    when its IoU with a kept one exceeds ``iou`` or their intersection covers at least ``inside`` of the smaller
    of the two (a box inside another)."""
    order = np.argsort(-np.asarray(scores), kind="stable")[:MAX_CANDIDATES]
    b = np.asarray(boxes, dtype=np.float64)[order]
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    iw = np.clip(np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0]), 0, None)
    ih = np.clip(np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 1], b[None, :, 1]), 0, None)
    inter = iw * ih
    over = inter > iou * (area[:, None] + area[None, :] - inter)
    if inside is not None:
        over |= inter >= inside * np.minimum(area[:, None], area[None, :])
    dead = np.zeros(len(order), dtype=bool)
    keep = []
    for i in range(len(order)):
        if not dead[i]:
            keep.append(i)
            dead |= over[i]
    return order[np.asarray(keep, dtype=np.int64)]


def _port(arg: object) -> Port:
    dims = tuple(d if isinstance(d, int) and not isinstance(d, bool) and d > 0 else None for d in arg.shape)
    return Port(arg.name, dims, arg.type)


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split())[:200]


def default_threads() -> int:
    """Intra-op threads of a detector not told otherwise: ``TRAFFICGEO_THREADS`` (set in batch workers) if it is a
    positive whole number, else 2."""
    text = os.environ.get("TRAFFICGEO_THREADS", "")
    return int(text) if text.isdigit() and int(text) > 0 else 2


class OnnxDetector:
    """An ONNX detector of any layout of :mod:`trafficgeo.video.detectors.onnx_formats`, run with onnxruntime.

    ``format``: the layout (a name or alias of :data:`~trafficgeo.video.detectors.onnx_formats.LAYOUTS`), or ``None``/
    ``"auto"`` to recognise it from the outputs' names and shapes and the model's metadata (an InputError naming
    the outputs found when no layout or several fit). Frames are pre-processed as the layout wants (colour order,
    scale, mean/std, letterbox or plain resize), decoded, kept when of a class in ``class_map`` (model class id ->
    trafficgeo name; default the vehicles of the metadata ``names``, else of COCO in the layout's numbering) and
    scoring at least ``conf`` (default: the layout's), then suppressed across classes (IoU above ``iou``, or
    intersection >= ``inside`` of the smaller box), mapped back to full-frame pixels (model corner-origin
    coordinates - 0.5 for the pixel-centre convention), clipped, and kept when their bottom centre is in ``roi``.
    A model with a dynamic input size gets its metadata ``imgsz``, else ``input_size`` (px, square).
    ``providers``: onnxruntime execution providers (:func:`pick_providers`; default CUDA or OpenVINO when
    installed, else the CPU); ``threads``: intra-op threads (default: the ``TRAFFICGEO_THREADS`` environment
    variable, which batch workers set to their share of the machine, else 2).
    ``backend``: what runs the network (:mod:`trafficgeo.video.detectors.backends`): ``None`` onnxruntime with
    ``providers``, untimed; ``"onnxruntime"`` or ``"openvino"`` that runtime, timed on a probe input (for the cost
    estimate); ``"auto"`` the fastest of the installed runtimes that agrees with onnxruntime CPU, by a probe cached
    per machine and model, ``"onnxruntime-int8"`` the INT8 version on onnxruntime. :attr:`backend_choice` says
    which and how fast (None with ``backend=None``). ``int8_model``: an INT8 version of the same network (same
    inputs and outputs; e.g. the built-in NanoDet's, Conv nodes quantized), which ``"auto"`` also times, on
    onnxruntime and OpenVINO, and takes where it is faster (checked against this model's outputs with a wider
    tolerance: its accuracy is the builder's to show, as ``tools/nanodet/quantize_int8.py`` does on real frames).
    """

    def __init__(self, model_path: str | Path, *, format: str | None = None, input_size: int | None = None,
                 conf: float | None = None, iou: float = 0.5, inside: float | None = 0.8,
                 class_map: Mapping[int, str] | None = None, roi: np.ndarray | None = None, threads: int | None = None,
                 providers: str | Sequence[str] | None = None, backend: str | None = None,
                 int8_model: str | Path | None = None) -> None:
        p = Path(model_path)
        asked = None if backend is None else check_backend(backend)
        self.int8_path = None if int8_model is None else Path(int8_model)
        if self.int8_path is not None and not self.int8_path.is_file():
            raise InputError(f"{self.int8_path}: INT8 model not found; give the INT8 version's .onnx file as "
                             "int8_model, or none", parameters=("int8_model",))
        if asked == ORT_INT8 and self.int8_path is None:
            raise InputError(f"backend {ORT_INT8}: {p.name} has no INT8 version (give one as int8_model; the "
                             "built-in nanodet has one); use backend auto or onnxruntime", parameters=("backend",))
        if not p.is_file():
            raise InputError(f"{p}: ONNX model not found; put the .onnx file there or pass its path with "
                             f"`detector` ({ONNX_HINT})", parameters=DETECTOR_PARAMETERS)
        fmt = format_name(format)
        if input_size is not None and (int(input_size) != input_size or input_size < 32):
            raise InputError(f"OnnxDetector: input_size {input_size!r} must be a whole number of pixels >= 32")
        for name, value in (("conf", conf), ("iou", iou), ("inside", inside)):
            if value is not None and not (np.isfinite(value) and 0 <= value <= 1):
                raise InputError(f"OnnxDetector: {name} {value!r} must be in [0, 1]")
        import onnxruntime as ort

        opts = ort.SessionOptions()
        self.threads = int(threads) if threads is not None else default_threads()
        opts.intra_op_num_threads = self.threads
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        self._opts = opts
        # auto: onnxruntime CPU is the reference the other runtimes are checked against
        chosen = [CPU] if asked == "auto" and providers is None else pick_providers(providers,
                                                                                     ort.get_available_providers())
        self._runner: Backend | None = None
        self.backend_choice: BackendChoice | None = None
        try:
            self._session = ort.InferenceSession(str(p), sess_options=opts, providers=chosen)
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            raise InputError(f"{p}: not a usable ONNX model ({_one_line(exc)}); {ONNX_HINT}",
                             parameters=DETECTOR_PARAMETERS) from None
        self.path = p
        self.providers = list(self._session.get_providers())
        io = self._describe(input_size)
        try:
            layout, fit = recognise(io, fmt)
        except InputError as exc:
            raise InputError(f"{p}: {exc}; {ONNX_HINT}", parameters=DETECTOR_PARAMETERS) from None
        self.layout, self.input_hw = layout, io.input_hw
        roles = list(fit.roles.items())
        self._roles = [r for r, _ in roles]
        self._out_names = [n for _, n in roles]
        self._sizes = io.extra[0] if layout.sizes_input else None
        for name in self._out_names:
            b = io.output(name).shape[0]
            if b is not None and b != (self._batch or 1):
                raise InputError(f"{p}: output {name} {list(io.output(name).shape)} has a batch of {b} for an "
                                 f"input batch of {self._batch or 1}; trafficgeo cannot decode it; {SUPPORTED}")
        if layout.settle is not None:
            grey = np.full((self.input_hw[0], self.input_hw[1], 3), 114, dtype=np.uint8)
            blob, _g = layout.pre.blob([grey], self.input_hw)
            try:
                fit = layout.settle(io, fit, self._infer(blob, (self.input_hw[1], self.input_hw[0]))[0],
                                    fmt is not None)
            except InputError as exc:
                raise InputError(f"{p}: {exc}") from None
        self.fit = fit
        self._runner = OrtBackend(self._session, self._out_names)
        if asked is not None:
            self._pick_backend(asked, providers)
        names = io.names if layout.names_index else None
        if class_map is not None:
            cmap = dict(class_map)
            if not cmap:
                raise InputError("OnnxDetector: class_map is empty; map at least one model class id to a vehicle "
                                 "name")
        else:
            cmap = vehicle_classes(names) if names else layout.default_classes
            if not cmap:
                raise InputError(f"{p}: none of the model's classes ({', '.join(names.values())[:120]}) is a road "
                                 "vehicle; give a class_map (model class id -> vehicle name)")
        self.class_map = {int(k): str(v) for k, v in cmap.items()}
        if fit.classes is not None and max(self.class_map) >= fit.classes:
            raise InputError(f"{p}: the model has {fit.classes} classes but class_map uses class id "
                             f"{max(self.class_map)}; give a class_map for this model")
        self.conf = float(layout.conf if conf is None else conf)
        self.iou, self.inside = float(iou), inside
        self.roi = None if roi is None else np.asarray(roi)
        self._decoding = Decoding(np.array(sorted(self.class_map), dtype=np.int64), self.conf, self.input_hw,
                                  fit.options)
        self._decodings = {self.input_hw: self._decoding}

    @property
    def format(self) -> str:
        """The name of the layout decoded."""
        return self.layout.name

    # ------------------------------------------------------------------------------------------------ model
    def _pick_backend(self, asked: str, providers: str | Sequence[str] | None) -> None:
        """Set the runtime (``asked``: a name of :data:`~trafficgeo.video.detectors.backends.BACKENDS`) and
        :attr:`backend_choice`, timed on a fixed synthetic frame (seed 0) at the model's input size."""
        import onnxruntime as ort

        def ort_with(provider: str) -> Callable[[], Backend]:
            def make() -> Backend:
                session = ort.InferenceSession(str(self.path), sess_options=self._opts, providers=[provider, CPU])
                return OrtBackend(session, self._out_names, EP_NAMES[provider])
            return make

        def openvino(path: Path) -> Callable[[], Backend]:
            return lambda: OpenVinoBackend(path, self._out_names, self.threads)

        def ort_int8() -> Backend:
            session = ort.InferenceSession(str(self.int8_path), sess_options=self._opts, providers=[CPU])
            return OrtBackend(session, self._out_names, ORT_INT8)

        reference = OrtBackend(self._session, self._out_names)
        candidates: dict[str, Callable[[], Backend]] = {}
        if asked in ("auto", "onnxruntime"):
            candidates[ORT_CPU] = lambda: reference
        if asked == "auto" and providers is None:
            avail = ort.get_available_providers()
            for provider in PREFERRED_PROVIDERS:
                if provider in avail:
                    candidates[EP_NAMES[provider]] = ort_with(provider)
            if openvino_version() is not None:
                candidates[OPENVINO] = openvino(self.path)
        if asked == "openvino":
            candidates[OPENVINO] = openvino(self.path)
        def unless_saturating(make: Callable[[], Backend]) -> Callable[[], Backend]:
            def checked() -> Backend:  # refused by the probe with this reason on a CPU without VNNI
                why = int8_saturation()
                if why is not None:
                    raise RuntimeError(why)
                return make()
            return checked

        if self.int8_path is not None and asked == ORT_INT8:  # asked for by name: runs on any CPU
            candidates[ORT_INT8] = ort_int8
        elif self.int8_path is not None and asked == "auto" and providers is None:
            candidates[ORT_INT8] = unless_saturating(ort_int8)
            if openvino_version() is not None:
                candidates[OPENVINO_INT8] = unless_saturating(openvino(self.int8_path))
        rng = np.random.default_rng(0)
        frame = rng.integers(0, 256, (self.input_hw[0], self.input_hw[1], 3), dtype=np.uint8)
        blob, _g = self.layout.pre.blob([frame] * (self._batch or 1), self.input_hw)
        feeds = self._feeds(blob, (self.input_hw[1], self.input_hw[0]))
        try:
            self.backend_choice, self._runner = choose_backend(candidates, feeds,
                                                               model_sha256=self._models_sha256(),
                                                               threads=self.threads, input_hw=self.input_hw)
        except InputError:
            raise
        except Exception as exc:  # the asked runtime failed to build or run
            raise InputError(f"{self.path}: backend {asked} failed on this model ({_one_line(exc)}); use backend "
                             "auto or onnxruntime", parameters=("backend",)) from None

    def _models_sha256(self) -> str:
        """The sha256 of the model file, or of the model's and its INT8 version's digests together."""
        digest = sha256_file(self.path)
        if self.int8_path is None:
            return digest
        return hashlib.sha256(f"{digest} {sha256_file(self.int8_path)}".encode()).hexdigest()

    def _describe(self, input_size: int | None) -> ModelIO:
        """The model's inputs, outputs (concrete shapes, from one run on a blank input if they are dynamic) and
        metadata; an InputError unless it has one float image input [B, 3, H, W]."""
        p = self.path
        inputs = [_port(a) for a in self._session.get_inputs()]
        images = [a for a in inputs if len(a.shape) == 4 and a.shape[1] in (3, None)]
        if len(images) != 1:
            raise InputError(f"{p}: expected one image input of shape [1, 3, H, W], found "
                             f"{[(a.name, list(a.shape)) for a in inputs]}; {ONNX_HINT}",
                             parameters=DETECTOR_PARAMETERS)
        image = images[0]
        if image.type not in ("tensor(float)", "tensor(float16)"):
            raise InputError(f"{p}: the model's input is {image.type}, not float32 or float16; {ONNX_HINT}",
                             parameters=DETECTOR_PARAMETERS)
        self._image, self._extra = image, [a for a in inputs if a is not image]
        self._in_dtype = np.float16 if image.type == "tensor(float16)" else np.float32
        self._batch = image.shape[0]
        meta = dict(self._session.get_modelmeta().custom_metadata_map or {})
        h, w = image.shape[2:]
        self.dynamic_hw = h is None and w is None and not self._extra  # runs at any input size (multiples of 32)
        imgsz = parse_literal(meta.get("imgsz"))
        imgsz = [imgsz, imgsz] if isinstance(imgsz, int) else imgsz
        if h is None or w is None:
            if input_size is None and isinstance(imgsz, list | tuple) and len(imgsz) == 2:
                h, w = h or int(imgsz[0]), w or int(imgsz[1])
            else:
                h, w = h or int(input_size or 640), w or int(input_size or 640)
        outputs = [_port(a) for a in self._session.get_outputs()]
        if not outputs:
            raise InputError(f"{p}: the model has no output; {SUPPORTED}; {ONNX_HINT}", parameters=DETECTOR_PARAMETERS)
        if any(None in o.shape for o in outputs):
            self._out_names = [o.name for o in outputs]
            self._roles = self._out_names
            self._sizes = next((a for a in self._extra if a.shape[-1:] in ((2,), (None,))), None)
            blob = np.zeros((self._batch or 1, 3, h, w), dtype=np.float32)
            found = self._run(blob, (w, h))
            outputs = [Port(o.name, tuple(int(d) for d in a.shape), o.type) for o, a in zip(outputs, found,
                                                                                            strict=True)]
        return ModelIO(image, tuple(self._extra), tuple(outputs), meta, (int(h), int(w)))

    def _feeds(self, blob: np.ndarray, frame_wh: tuple[int, int]) -> dict[str, np.ndarray]:
        """The model's inputs for ``blob`` [B, 3, h, w] of frames of ``frame_wh`` (w, h) px."""
        feeds = {self._image.name: blob.astype(self._in_dtype, copy=False)}
        for extra in self._extra:
            if extra is self._sizes:
                dtype = np.int64 if "int64" in extra.type else np.int32 if "int32" in extra.type else np.float32
                feeds[extra.name] = np.tile(np.asarray([frame_wh], dtype=dtype), (blob.shape[0], 1))
            else:
                raise InputError(f"{self.path}: the model has an input {extra.name} {list(extra.shape)} that "
                                 f"trafficgeo does not know how to fill; {SUPPORTED}")
        return feeds

    def _run(self, blob: np.ndarray, frame_wh: tuple[int, int]) -> list[np.ndarray]:
        """One run on a batch that fits the model; the outputs of ``self._out_names``."""
        feeds = self._feeds(blob, frame_wh)
        try:
            if self._runner is not None:
                return self._runner.run(feeds)
            return self._session.run(self._out_names, feeds)
        except Exception as exc:  # onnxruntime's own exception types (shape mismatch inside the graph, ...)
            raise InputError(f"{self.path}: the model failed on a {frame_wh[0]}x{frame_wh[1]} frame fed as "
                             f"{blob.shape[3]}x{blob.shape[2]} ({_one_line(exc)}); {ONNX_HINT}",
                             parameters=DETECTOR_PARAMETERS) from None

    def _infer(self, blob: np.ndarray, frame_wh: tuple[int, int]) -> list[dict[str, np.ndarray]]:
        """Per image of ``blob`` [B, 3, h, w], its outputs by role (batch dimension removed, float32): runs of the
        model's fixed batch (the last one padded) or of up to :data:`MAX_BATCH` images."""
        step = self._batch or MAX_BATCH
        per_image = []
        for start in range(0, blob.shape[0], step):
            chunk = blob[start:start + step]
            n = chunk.shape[0]
            if self._batch is not None and n < self._batch:
                chunk = np.concatenate([chunk, np.zeros((self._batch - n, *chunk.shape[1:]), dtype=chunk.dtype)])
            outs = [np.asarray(o) for o in self._run(chunk, frame_wh)]
            outs = [o.astype(np.float32) if o.dtype == np.float16 else o for o in outs]
            per_image.extend({r: o[j] for r, o in zip(self._roles, outs, strict=True)} for j in range(n))
        return per_image

    # ------------------------------------------------------------------------------------------------ detect
    def detect(self, image: np.ndarray, time_s: float = 0.0) -> Detections:
        """Vehicles in ``image`` ((H, W, 3) uint8 BGR); ``time_s`` is not used."""
        return self.detect_batch([image])[0]

    def detect_batch(self, images: Sequence[np.ndarray], input_hw: tuple[int, int] | None = None
                     ) -> list[Detections]:
        """Vehicles in each of several equally sized images (e.g. the tiles of a frame), in as few model runs as
        the model's batch dimension allows. ``input_hw``: the model input (h, w) px to fit them into, for a model
        whose input size is free (:attr:`dynamic_hw`; multiples of its largest stride, 32); default
        :attr:`input_hw`."""
        images = [check_image(im, f"image {k}") for k, im in enumerate(images)]
        if not images:
            return []
        h, w = images[0].shape[:2]
        if any(im.shape[:2] != (h, w) for im in images):
            raise InputError(f"detect_batch: images of sizes {sorted({im.shape[:2] for im in images})}; give "
                             "equally sized images")
        hw = self.input_hw if input_hw is None else (int(input_hw[0]), int(input_hw[1]))
        if hw != self.input_hw and not self.dynamic_hw:
            raise InputError(f"{self.path}: the model's input is fixed at {self.input_hw[1]}x{self.input_hw[0]} "
                             f"px; it cannot run at {hw[1]}x{hw[0]}")
        if hw not in self._decodings:
            if min(hw) < 32 or hw[0] % 32 or hw[1] % 32:
                raise InputError(f"OnnxDetector: input size {hw[1]}x{hw[0]} px must be multiples of 32 px")
            self._decodings[hw] = replace(self._decoding, input_hw=hw)
        blob, geom = self.layout.pre.blob(images, hw)
        outs = self._infer(blob, (w, h))
        geom = IDENTITY if self.layout.sizes_input else geom
        found = []
        for out in outs:
            try:
                raw = self.layout.decode(out, self._decodings[hw])
            except (IndexError, ValueError) as exc:
                raise InputError(f"{self.path}: outputs of shapes {[list(o.shape) for o in out.values()]} do not "
                                 f"decode as {self.layout.title} ({_one_line(exc)}); {SUPPORTED}") from None
            found.append(self._finish(*raw, geom, h, w))
        return found

    def _finish(self, boxes: np.ndarray, scores: np.ndarray, cls: np.ndarray, geom, h: int, w: int) -> Detections:
        """Boxes in input px -> full-frame px, clipped, suppressed, named, inside the ROI."""
        if len(scores) == 0:
            return Detections.empty()
        b = geom.to_frame(boxes)
        b[:, [0, 2]] = np.clip(b[:, [0, 2]], -0.5, w - 0.5)
        b[:, [1, 3]] = np.clip(b[:, [1, 3]], -0.5, h - 0.5)
        ok = np.flatnonzero((b[:, 2] > b[:, 0]) & (b[:, 3] > b[:, 1]) & np.isfinite(b).all(axis=1))
        keep = ok[suppress(b[ok], scores[ok], self.iou, self.inside)]
        names = np.array([self.class_map[int(c)] for c in cls[keep]], dtype=object)
        det = Detections(b[keep], np.clip(scores[keep], 0.0, 1.0), names)
        if self.roi is not None and len(det):
            det = det.select(in_roi(self.roi, det.bottom_centres, (h, w)))
        return det


__all__ = ["MAX_BATCH", "ONNX_SHAPES", "Fit", "Layout", "OnnxDetector", "letterbox", "pick_providers", "suppress",
           "yolo_anchor_counts"]
