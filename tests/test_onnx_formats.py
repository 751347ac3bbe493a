"""Every ONNX detector layout decodes to the right full-frame boxes.

Each test model is a tiny ONNX graph with no weights: its outputs are constants holding known boxes in the
layout's own encoding (plus 0 x the mean of the input, so that onnxruntime runs the input through), and the
detector must return exactly the known boxes, in full-frame pixels, on a 960 x 540 frame fed to a 320 x 320 input.
The expected input coordinates are worked out by hand below for each resize (centred letterbox: scale 1/3, 70 px
of grey above and below; top-left letterbox: scale 1/3, grey below only; plain resize: 1/3 across, 320/540 down),
and the model's corner-origin pixels come back 0.5 px lower (the pixel-centre convention).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from trafficgeo.errors import InputError
from trafficgeo.video.detectors.onnx import OnnxDetector, pick_providers, suppress
from trafficgeo.video.detectors.onnx_formats import LAYOUTS, format_name, looks_decoded

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

W, H, S = 960, 540, 320  # frame width, height (px); model input side (px)
CAR, TRUCK = [299.5, 239.5, 419.5, 329.5], [599.5, 89.5, 779.5, 209.5]  # the truth, full-frame px
# (frame box, COCO-80 class id, score, objectness): what every test model holds
ENTRIES = [
    (CAR, 2, 0.9, 1.0),
    ([301.5, 240.5, 421.5, 330.5], 2, 0.8, 1.0),  # the same car again: IoU 0.94, suppressed
    (TRUCK, 7, 0.85, 1.0),
    ([639.5, 119.5, 719.5, 189.5], 2, 0.6, 1.0),  # a "car" inside the truck: IoU 0.26, but all inside it
    ([99.5, 99.5, 139.5, 199.5], 0, 0.95, 1.0),  # a person: not a vehicle
    ([499.5, 399.5, 559.5, 439.5], 2, 0.5, 0.2),  # a car at 0.5 x objectness 0.2 = 0.1 (0.5 without one)
]
COCO91 = {0: 1, 2: 3, 7: 8}  # COCO-80 index -> COCO category id (person, car, truck)
ANCHORS = {8: 1600, 16: 400, 32: 100}  # cells per stride on a 320 px input


def to_input(box: list[float], resize: str) -> np.ndarray:
    """A full-frame box (pixel centres) in model-input px (corner origin), worked out by hand per resize."""
    x1, y1, x2, y2 = np.asarray(box) + 0.5
    if resize == "letterbox":  # 960x540 -> 320x180 centred in 320x320: 70 px above
        return np.array([x1 / 3, y1 / 3 + 70, x2 / 3, y2 / 3 + 70])
    if resize == "topleft":  # 960x540 -> 320x180 at the top-left corner
        return np.array([x1 / 3, y1 / 3, x2 / 3, y2 / 3])
    return np.array([x1 / 3, y1 * S / H, x2 / 3, y2 * S / H])  # plain resize


def cxcywh(b: np.ndarray) -> np.ndarray:
    return np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2, b[2] - b[0], b[3] - b[1]])


def frame(value: int = 90) -> np.ndarray:
    return np.full((H, W, 3), value, dtype=np.uint8)


def model(path: Path, outputs: dict[str, np.ndarray], *, image: str = "images", batch: object = 1,
          metadata: dict[str, str] | None = None, sizes_input: bool = False, dynamic: bool = False,
          per_image_score: str | None = None, half: bool = False) -> Path:
    """An ONNX model with a [batch, 3, S, S] input whose outputs are the constants ``outputs`` (float, or int64
    passed through). ``sizes_input``: a second input orig_target_sizes [1, 2] (int64) multiplies output "boxes"
    (x1, y1, x2, y2 normalised) by (w, h, w, h). ``dynamic``: outputs declared with dynamic dimensions.
    ``per_image_score``: that output's rows 4.. are multiplied by each image's mean input value. ``half``: a
    float16 input."""
    zero = numpy_helper.from_array(np.zeros((), dtype=np.float32), name="zero")
    inits = [zero]
    nodes = [helper.make_node("Cast", [image], ["image32"], to=TensorProto.FLOAT)] if half else []
    source = "image32" if half else image
    nodes += [helper.make_node("ReduceMean", [source], ["mean"], keepdims=0),
              helper.make_node("Mul", ["mean", "zero"], ["nothing"])]
    inputs = [helper.make_tensor_value_info(image, TensorProto.FLOAT16 if half else TensorProto.FLOAT,
                                            [batch, 3, S, S])]
    outs = []
    for name, value in outputs.items():
        inits.append(numpy_helper.from_array(value, name=f"{name}_const"))
        if value.dtype == np.int64:
            nodes.append(helper.make_node("Identity", [f"{name}_const"], [name]))
        elif name == per_image_score:
            split = np.zeros_like(value)
            split[:, 4:] = 1.0
            inits += [numpy_helper.from_array((value * split).astype(np.float32), name="score_part"),
                      numpy_helper.from_array((value * (1 - split)).astype(np.float32), name="box_part"),
                      numpy_helper.from_array(np.array([-1, 1, 1], dtype=np.int64), name="b11")]
            nodes += [helper.make_node("ReduceMean", [source], ["img_mean"], axes=[1, 2, 3], keepdims=1),
                      helper.make_node("Reshape", ["img_mean", "b11"], ["img_mean3"]),
                      helper.make_node("Mul", ["score_part", "img_mean3"], ["scaled"]),
                      helper.make_node("Add", ["scaled", "box_part"], [name])]
        elif name == "boxes" and sizes_input:
            inits.append(numpy_helper.from_array(np.array([1, 1, 4], dtype=np.int64), name="s114"))
            nodes += [helper.make_node("Cast", ["orig_target_sizes"], ["sizes_f"], to=TensorProto.FLOAT),
                      helper.make_node("Concat", ["sizes_f", "sizes_f"], ["sizes4"], axis=1),
                      helper.make_node("Reshape", ["sizes4", "s114"], ["sizes114"]),
                      helper.make_node("Mul", [f"{name}_const", "sizes114"], ["boxes_px"]),
                      helper.make_node("Add", ["boxes_px", "nothing"], [name])]
        else:
            nodes.append(helper.make_node("Add", [f"{name}_const", "nothing"], [name]))
        shape = [f"d{k}_{name}" for k in range(value.ndim)] if dynamic else list(value.shape)
        if per_image_score == name:
            shape[0] = batch
        kind = TensorProto.INT64 if value.dtype == np.int64 else TensorProto.FLOAT
        outs.append(helper.make_tensor_value_info(name, kind, shape))
    if sizes_input:
        inputs.append(helper.make_tensor_value_info("orig_target_sizes", TensorProto.INT64, [1, 2]))
    graph = helper.make_graph(nodes, "const_detector", inputs, outs, initializer=inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    m.ir_version = 8
    if metadata:
        helper.set_model_props(m, metadata)
    onnx.checker.check_model(m)
    onnx.save(m, str(path))
    return path


# ---------------------------------------------------------------------------------------------------- encoders
def enc_yolov8(transposed: bool = False) -> np.ndarray:
    a = np.zeros((1, 84, 2100), dtype=np.float32)
    for k, (box, cls, score, obj) in enumerate(ENTRIES):
        a[0, :4, k] = cxcywh(to_input(box, "letterbox"))
        a[0, 4 + cls, k] = score * obj
    return a.transpose(0, 2, 1).copy() if transposed else a


def enc_end2end() -> np.ndarray:
    a = np.zeros((1, 300, 6), dtype=np.float32)
    for k, (box, cls, score, obj) in enumerate(ENTRIES):
        a[0, k] = [*to_input(box, "letterbox"), score * obj, cls]
    a[0, len(ENTRIES):, 5] = 2  # the unused rows: class car at score 0
    return a


def enc_objectness(anchors: int, resize: str) -> np.ndarray:
    a = np.zeros((1, anchors, 85), dtype=np.float32)
    for k, (box, cls, score, obj) in enumerate(ENTRIES):
        a[0, 40 * k, :4] = cxcywh(to_input(box, resize))
        a[0, 40 * k, 4] = obj
        a[0, 40 * k, 5 + cls] = score
    return a


def _cell(box: np.ndarray, stride: int) -> tuple[int, int, int]:
    """The anchor (index over all strides 8/16/32, row-major), column and row holding the centre of ``box``."""
    cx, cy = cxcywh(box)[:2]
    col, row = int(cx // stride), int(cy // stride)
    level = {8: 0, 16: 1600, 32: 2000}[stride]
    return level + row * (S // stride) + col, col, row


def enc_yolox_raw() -> np.ndarray:
    a = np.zeros((1, 2100, 85), dtype=np.float32)
    for (box, cls, score, obj), stride in zip(ENTRIES, (8, 16, 32, 8, 16, 32), strict=True):
        b = to_input(box, "topleft")
        k, col, row = _cell(b, stride)
        cx, cy, bw, bh = cxcywh(b)
        a[0, k, :4] = [cx / stride - col, cy / stride - row, math.log(bw / stride), math.log(bh / stride)]
        a[0, k, 4], a[0, k, 5 + cls] = obj, score
    return a


def grid_xy() -> np.ndarray:
    """Centres (px) of every cell of strides 8/16/32 at 320 px, as a decoded YOLOX head puts them."""
    parts = []
    for s in (8, 16, 32):
        n = S // s
        rows, cols = np.divmod(np.arange(n * n), n)
        parts.append(np.column_stack([(cols + 0.5) * s, (rows + 0.5) * s]))
    return np.concatenate(parts)


def enc_yolox_decoded(resize: str = "topleft") -> np.ndarray:
    a = np.zeros((1, 2100, 85), dtype=np.float32)
    a[0, :, :2] = grid_xy() + 0.3  # every cell predicts a box near its centre, with no score
    a[0, :, 2:4] = 20.0
    for (box, cls, score, obj), stride in zip(ENTRIES, (8, 16, 32, 8, 16, 32), strict=True):
        b = to_input(box, resize)
        k, _col, _row = _cell(b, stride)
        a[0, k, :4] = cxcywh(b)
        a[0, k, 4], a[0, k, 5 + cls] = obj, score
    return a


def enc_rtdetr() -> dict[str, np.ndarray]:
    q = 300
    labels, boxes, scores = np.zeros((1, q), np.int64), np.zeros((1, q, 4), np.float32), np.zeros((1, q), np.float32)
    for k, (box, cls, score, obj) in enumerate(ENTRIES):
        labels[0, k], scores[0, k] = cls, score * obj
        boxes[0, k] = (np.asarray(box) + 0.5) / [W, H, W, H]  # normalised; the graph multiplies by (w, h, w, h)
    return {"labels": labels, "boxes": boxes, "scores": scores}


def enc_rtdetr_ultra() -> np.ndarray:
    a = np.zeros((1, 300, 84), dtype=np.float32)
    for k, (box, cls, score, obj) in enumerate(ENTRIES):
        a[0, k, :4] = cxcywh(to_input(box, "stretch")) / S
        a[0, k, 4 + cls] = score * obj
    return a


def enc_rfdetr() -> dict[str, np.ndarray]:
    dets, logits = np.zeros((1, 300, 4), np.float32), np.full((1, 300, 91), -12.0, np.float32)
    for k, (box, cls, score, obj) in enumerate(ENTRIES):
        dets[0, k] = cxcywh(to_input(box, "stretch")) / S
        p = score * obj
        logits[0, k, COCO91[cls]] = math.log(p / (1 - p))
    return {"dets": dets, "labels": logits}


def _distribution(d: float) -> np.ndarray:
    """Logits over 11 bins whose softmax expectation is ``d`` (0..10)."""
    p = np.full(11, 1e-12)
    k = min(int(d), 9)
    p[k], p[k + 1] = max(1 - (d - k), 1e-12), max(d - k, 1e-12)
    return np.log(p)


def enc_nanodet() -> dict[str, np.ndarray]:
    out = {}
    for s in (8, 16, 32):
        out[f"cls_s{s}"] = np.zeros((1, ANCHORS[s], 80), np.float32)
        out[f"reg_s{s}"] = np.tile(_distribution(0.0), (1, ANCHORS[s], 4)).astype(np.float32)
    for (box, cls, score, obj), s in zip(ENTRIES, (8, 16, 32, 8, 8, 8), strict=True):
        b = to_input(box, "letterbox")
        k, col, row = _cell(b, s)
        k -= {8: 0, 16: 1600, 32: 2000}[s]
        cx, cy = (col + 0.5) * s, (row + 0.5) * s
        sides = np.array([cx - b[0], cy - b[1], b[2] - cx, b[3] - cy]) / s
        out[f"reg_s{s}"][0, k] = np.concatenate([_distribution(d) for d in sides])
        out[f"cls_s{s}"][0, k, cls] = score * obj
    return {k: out[k] for k in ("cls_s8", "cls_s16", "cls_s32", "reg_s8", "reg_s16", "reg_s32")}


ULTRA = {"author": "Ultralytics", "task": "detect", "stride": "32", "imgsz": "[320, 320]",
         "names": str({k: f"class{k}" for k in range(80)} | {0: "person", 2: "car", 7: "truck"})}


def case(name: str, path: Path) -> Path:
    """The test model of one layout, by name."""
    if name == "yolov8":
        return model(path, {"output0": enc_yolov8()})
    if name == "yolov8-transposed":
        return model(path, {"output0": enc_yolov8(transposed=True)})
    if name == "yolov8-metadata-dynamic":
        return model(path, {"output0": enc_yolov8()}, metadata=ULTRA, dynamic=True)
    if name == "end2end":
        return model(path, {"output0": enc_end2end()})
    if name == "end2end-metadata":
        return model(path, {"output0": enc_end2end()}, metadata={**ULTRA, "end2end": "True"})
    if name == "yolov5":
        return model(path, {"output0": enc_objectness(6300, "letterbox")})
    if name == "yolov5-names":  # YOLOv5's own metadata: stride and names, at an anchor-free count of rows
        return model(path, {"output0": enc_objectness(2100, "letterbox")},
                     metadata={"stride": "32", "names": ULTRA["names"]})
    if name == "yolox":
        return model(path, {"output": enc_yolox_raw()})
    if name == "rtdetr":
        return model(path, enc_rtdetr(), sizes_input=True)
    if name == "rtdetr-ultra":
        return model(path, {"output0": enc_rtdetr_ultra()},
                     metadata={**ULTRA, "description": "Ultralytics rtdetr-l model trained on coco.yaml"})
    if name == "rfdetr":
        return model(path, enc_rfdetr(), image="input")
    if name == "nanodet":
        return model(path, enc_nanodet(), image="input")
    raise KeyError(name)


CASES = {"yolov8": "yolov8", "yolov8-transposed": "yolov8", "yolov8-metadata-dynamic": "yolov8",
         "end2end": "end2end", "end2end-metadata": "end2end", "yolov5": "yolov5", "yolov5-names": "yolov5",
         "yolox": "yolox", "rtdetr": "rtdetr", "rtdetr-ultra": "rtdetr-ultra", "rfdetr": "rfdetr",
         "nanodet": "nanodet"}


def assert_truth(det: OnnxDetector, image: np.ndarray | None = None) -> None:
    d = det.detect(frame() if image is None else image, 0.0)
    assert list(d.classes) == ["car", "truck"], (list(d.classes), d.boxes)
    np.testing.assert_allclose(d.boxes, [CAR, TRUCK], atol=2e-3)
    np.testing.assert_allclose(d.scores, [0.9, 0.85], atol=1e-4)


# ---------------------------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("name", list(CASES))
def test_every_layout_decodes_to_the_known_boxes(tmp_path: Path, name: str) -> None:
    """Recognised without being told, and the known boxes come back in full-frame px: the right resize and padding
    side, the -0.5 shift, the class map of the layout, the score (objectness x class), NMS across classes and the
    suppression of a box inside another."""
    path = case(name, tmp_path / f"{name}.onnx")
    det = OnnxDetector(path)
    assert det.format == CASES[name]
    assert_truth(det)
    named = OnnxDetector(path, format=CASES[name])  # and when named
    assert named.format == CASES[name]
    assert_truth(named)


def test_every_layout_has_a_test_model() -> None:
    assert set(CASES.values()) == set(LAYOUTS)


def test_pre_processing_of_a_batch_is_the_whole_array_formula() -> None:
    """The channel-by-channel input equals (letterboxed image [RGB] - mean) / std transposed to [B, 3, h, w], for a
    batch of random images at a square and a frame-shaped input."""
    rng = np.random.default_rng(5)
    for name, layout in LAYOUTS.items():
        pre = layout.pre
        for shape, hw in (((60, 90, 3), (64, 64)), ((45, 80, 3), (32, 64))):
            images = [rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(3)]
            blob, _g = pre.blob(images, hw)
            x = np.stack([pre.canvas(im, hw)[0] for im in images]).astype(np.float64)
            x = x[..., ::-1] if pre.rgb else x
            want = ((x - np.asarray(pre.mean)) / np.asarray(pre.std)).transpose(0, 3, 1, 2)
            assert blob.dtype == np.float32 and blob.flags.c_contiguous and blob.shape == (3, 3, *hw)
            np.testing.assert_allclose(blob, want, rtol=1e-6, atol=1e-6, err_msg=name)


def test_pre_processing_colour_order_and_normalisation() -> None:
    """One BGR pixel (B 10, G 100, R 200) as each layout feeds it."""
    img = np.zeros((4, 6, 3), dtype=np.uint8)
    img[:] = (10, 100, 200)
    cases = {"yolov8": [200 / 255, 100 / 255, 10 / 255], "yolox": [10, 100, 200],
             "rtdetr": [200 / 255, 100 / 255, 10 / 255],
             "rfdetr": [(200 / 255 - 0.485) / 0.229, (100 / 255 - 0.456) / 0.224, (10 / 255 - 0.406) / 0.225],
             "nanodet": [(10 - 103.53) / 57.375, (100 - 116.28) / 57.12, (200 - 123.675) / 58.395]}
    for name, want in cases.items():
        blob, _g = LAYOUTS[name].pre.blob([img], (12, 12))
        assert blob.shape == (1, 3, 12, 12) and blob.dtype == np.float32
        np.testing.assert_allclose(blob[0, :, 5, 5], want, rtol=1e-5, err_msg=name)  # the image's middle
    # padding: centred (yolov8: rows 0..2 grey), top-left (yolox: rows 8.. grey), none (plain resize)
    blob, g = LAYOUTS["yolov8"].pre.blob([img], (12, 12))
    assert g.offset == (0, 2) and np.allclose(blob[0, :, 0, 0], 114 / 255) and np.allclose(blob[0, 0, 2, 0], 200 / 255)
    blob, g = LAYOUTS["yolox"].pre.blob([img], (12, 12))
    assert g.offset == (0, 0) and np.allclose(blob[0, :, 11, 0], 114) and np.allclose(blob[0, 0, 0, 0], 10)
    blob, g = LAYOUTS["rtdetr"].pre.blob([img], (12, 12))
    assert g.scale == (2.0, 3.0) and np.allclose(blob[0, 0], 200 / 255)


def test_shapes_that_used_to_decode_into_garbage(tmp_path: Path) -> None:
    """[1, 300, 6] is end-to-end, [1, 8400, 85] YOLOX, [1, 300, 84] an ultralytics RT-DETR when its metadata says
    so and refused otherwise."""
    e2e = np.zeros((1, 300, 6), np.float32)
    e2e[0, 0] = [*to_input(CAR, "letterbox"), 0.9, 2]
    det = OnnxDetector(model(tmp_path / "e2e.onnx", {"output0": e2e}))
    assert det.format == "end2end"
    d = det.detect(frame())
    assert list(d.classes) == ["car"] and np.allclose(d.boxes, [CAR], atol=2e-3)
    x = np.zeros((1, 2100, 85), np.float32)
    assert OnnxDetector(model(tmp_path / "x.onnx", {"output": x})).format == "yolox"
    r = np.zeros((1, 300, 84), np.float32)
    with pytest.raises(InputError, match="cannot decode") as err:
        OnnxDetector(model(tmp_path / "r.onnx", {"output0": r}))
    assert "output0 [1, 300, 84]" in str(err.value) and "\n" not in str(err.value)
    assert OnnxDetector(model(tmp_path / "r.onnx", {"output0": r}), format="rtdetr-ultra").format == "rtdetr-ultra"


def test_a_half_precision_input(tmp_path: Path) -> None:
    det = OnnxDetector(model(tmp_path / "half.onnx", {"output0": enc_yolov8()}, half=True))
    assert det.format == "yolov8"
    assert_truth(det)


def test_yolox_raw_or_decoded(tmp_path: Path) -> None:
    """Decoded YOLOX outputs look like a YOLOv5/v6 export with another colour order and padding: auto refuses
    them in one line, and the named format decides (and decodes with its own padding)."""
    assert looks_decoded(enc_yolox_decoded()[0], (S, S)) and not looks_decoded(enc_yolox_raw()[0], (S, S))
    path = model(tmp_path / "xd.onnx", {"output": enc_yolox_decoded()})
    with pytest.raises(InputError, match="detector_format yolox") as err:
        OnnxDetector(path)
    assert "\n" not in str(err.value) and "[1, 2100, 85]" in str(err.value)
    det = OnnxDetector(path, format="yolox")
    assert det.fit.options["decoded"] is True
    assert_truth(det)
    as_v5 = OnnxDetector(model(tmp_path / "v6.onnx", {"output": enc_yolox_decoded("letterbox")}), format="yolov5")
    assert_truth(as_v5)


@pytest.mark.slow
def test_recognition_from_metadata(tmp_path: Path) -> None:
    """Names map classes (a custom model's 'van'), tasks other than detection are refused, a model that fits no
    layout or the named one gives one line naming its outputs."""
    a = np.zeros((1, 7, 2100), np.float32)  # 3 classes: person, van, bus
    a[0, :4, 0] = cxcywh(to_input(CAR, "letterbox"))
    a[0, 4 + 1, 0] = 0.7
    meta = {**ULTRA, "names": "{0: 'person', 1: 'van', 2: 'Bus'}"}
    det = OnnxDetector(model(tmp_path / "van.onnx", {"output0": a}, metadata=meta))
    assert det.class_map == {1: "van", 2: "bus"}
    d = det.detect(frame())
    assert list(d.classes) == ["van"] and np.allclose(d.boxes, [CAR], atol=2e-3)
    with pytest.raises(InputError, match="class_map is empty"):
        OnnxDetector(tmp_path / "van.onnx", class_map={})
    with pytest.raises(InputError, match="'pose' model"):
        OnnxDetector(model(tmp_path / "pose.onnx", {"output0": a}, metadata={**meta, "task": "pose"}))
    with pytest.raises(InputError, match="road vehicle"):
        OnnxDetector(model(tmp_path / "p.onnx", {"output0": a}, metadata={**meta, "names": "{0: 'a', 1: 'b', 2: 'c'}"}))
    for shape in ((1, 84, 300), (1, 300, 5), (1, 300, 84)):
        with pytest.raises(InputError, match="cannot decode") as err:
            OnnxDetector(model(tmp_path / "bad.onnx", {"output0": np.zeros(shape, np.float32)}))
        msg = str(err.value)
        assert "\n" not in msg and str(list(shape)) in msg and "detector_format" in msg, msg
    with pytest.raises(InputError, match=r"fit several layouts \(end2end, yolox\)") as err:  # 1 class, or 2100 boxes?
        OnnxDetector(model(tmp_path / "six.onnx", {"output0": np.zeros((1, 2100, 6), np.float32)}))
    assert "output0 [1, 2100, 6]" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(InputError, match="do not fit detector_format nanodet") as err:
        OnnxDetector(case("yolov8", tmp_path / "v8.onnx"), format="nanodet")
    assert "output0 [1, 84, 2100]" in str(err.value)
    with pytest.raises(InputError, match="not known"):
        OnnxDetector(tmp_path / "v8.onnx", format="yolo-9000")
    assert format_name("auto") is None and format_name("YOLO11") == "yolov8" and format_name("d-fine") == "rtdetr"


def test_detect_batch_runs_dynamic_batches_at_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Scores scale with each image's brightness: a white image finds the cars, a black one nothing; a dynamic
    batch runs once for both, a fixed batch of 1 once per image."""
    for batch, runs in (("N", 1), (1, 2)):
        path = model(tmp_path / f"b{batch}.onnx", {"output0": enc_yolov8()}, batch=batch, per_image_score="output0")
        det = OnnxDetector(path)
        calls: list[int] = []
        run = det._run
        monkeypatch.setattr(det, "_run",
                            lambda blob, wh, run=run, calls=calls: calls.append(blob.shape[0]) or run(blob, wh))
        white, black = det.detect_batch([frame(255), frame(0)])
        assert len(calls) == runs and sum(calls) == 2
        assert len(black) == 0
        np.testing.assert_allclose(white.boxes, [CAR, TRUCK], atol=2e-3)
    with pytest.raises(InputError, match="equally sized"):
        det.detect_batch([frame(), np.zeros((10, 10, 3), np.uint8)])
    assert det.detect_batch([]) == []


def test_execution_providers_and_threads(tmp_path: Path) -> None:
    cpu, cuda, ov = "CPUExecutionProvider", "CUDAExecutionProvider", "OpenVINOExecutionProvider"
    assert pick_providers(None, ["AzureExecutionProvider", cpu]) == [cpu]
    assert pick_providers(None, [cuda, ov, cpu]) == [cuda, ov, cpu]
    assert pick_providers("openvino", [ov, cpu]) == [ov, cpu]
    assert pick_providers(["cpu"], [cuda, cpu]) == [cpu]
    with pytest.raises(InputError, match="not installed") as err:
        pick_providers("cuda", [cpu])
    assert cpu in str(err.value)
    det = OnnxDetector(case("yolov8", tmp_path / "v8.onnx"), threads=1)
    assert det.providers[-1] == cpu
    assert det._session.get_session_options().intra_op_num_threads == 1


def test_suppression_across_classes_and_inside() -> None:
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [2, 2, 5, 5], [20, 20, 30, 30], [0, 0, 40, 40.0]])
    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.5])
    assert list(suppress(boxes, scores, 0.5, 0.8)) == [0, 3]  # 1: IoU 0.82; 2: inside 0; 4: holds 0 (and 3)
    assert list(suppress(boxes, scores, 0.5, None)) == [0, 2, 3, 4]
    assert len(suppress(np.zeros((0, 4)), np.zeros(0))) == 0


@pytest.mark.slow
def test_detector_format_reaches_the_run(tmp_path: Path) -> None:
    """--detector-format goes from the command line through ProcessOptions (checked before anything is written,
    part of the run key) to the detector: a decoded YOLOX model that auto refuses runs as named."""
    from dataclasses import asdict

    from cli_support import invoke
    from trafficgeo.camera.io import write_camera_json
    from trafficgeo.camera.model import Camera
    from trafficgeo.video.checkpoint import run_key
    from trafficgeo.video.detectors.factory import make_detector
    from trafficgeo.video.pipeline import ProcessOptions, detect_and_track
    from video_support import H as VH
    from video_support import W as VW
    from video_support import write_two_car_video

    path = model(tmp_path / "xd.onnx", {"output": enc_yolox_decoded()})
    with pytest.raises(InputError, match="detector_format yolox"):
        ProcessOptions(detector=str(path))
    with pytest.raises(InputError, match="applies to an ONNX model"):
        ProcessOptions(detector="bg", detector_format="yolox")
    assert make_detector(str(path), detector_format="yolox").format == "yolox"
    opts = ProcessOptions(detector=str(path), detector_format="yolox", checkpoint_s=1.0)
    video = write_two_car_video(tmp_path / "cars.mp4", 3, 2.0, rows=(60, 120), seed=1)

    def key(o: ProcessOptions) -> str:
        return run_key(video, camera=None, surface=None, roi=None, options=asdict(o), detector_file=path)

    assert key(opts) != key(ProcessOptions(detector=str(path), detector_format="yolov5", checkpoint_s=1.0))
    dets = detect_and_track(video, None, None, tmp_path / "out", opts)[0].to_table()
    # a 320x180 frame fills the top-left of the 320 px input at scale 1: input px - 0.5
    car, truck = np.array(CAR) + 0.5, np.array(TRUCK) + 0.5
    want = np.array([car / 3 - 0.5, truck / 3 - 0.5])
    assert dets["frame"].nunique() == 6 and len(dets) == 12
    for _f, g in dets.groupby("frame"):
        np.testing.assert_allclose(g[["x1", "y1", "x2", "y2"]].to_numpy(), want, atol=2e-3)
    cam = Camera.from_orientation((VW, VH), 300.0, [0.0, -20.0, 8.0], 0.0, 20.0, crs="EPSG:32633")
    write_camera_json(tmp_path / "camera.json", cam)
    for fmt, said in (("yolox", "applies to an ONNX model"), ("nonsense", "not known")):
        out = tmp_path / f"cli_{fmt}"
        code, _stdout, stderr = invoke("process", video, "--camera", tmp_path / "camera.json", "--surface", "0",
                                       "--out", out, "--detector", "bg", "--detector-format", fmt)
        assert code == 2 and len(stderr.strip().splitlines()) == 1 and said in stderr, stderr
        assert not out.exists()


def test_the_packaged_nanodet_is_recognised() -> None:
    """The built-in NanoDet (shipped in the package once converted) is read as NanoDet without being told."""
    import trafficgeo

    path = Path(trafficgeo.__file__).parent / "data" / "models" / "nanodet-g-416.onnx"
    if not path.is_file():
        pytest.skip("the NanoDet model is not in this checkout")
    det = OnnxDetector(path, threads=1)
    assert det.format == "nanodet" and det.input_hw == (416, 416) and det.conf == 0.25
    assert det.fit.options == {"strides": (8, 16, 32), "bins": 11} and det.fit.classes == 80
    assert det.class_map == {1: "bicycle", 2: "car", 3: "motorcycle", 5: "bus", 7: "truck"}
    assert len(det.detect(frame(114))) == 0
