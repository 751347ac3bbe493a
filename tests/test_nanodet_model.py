"""The shipped NanoDet-g 416 ONNX model, its registry entry, and the TF.js -> ONNX converter that built it.

The converter, its numpy reference executor and the decode check live in tools/nanodet/ (dev tools, not part of
the package); they are imported here by putting that folder on sys.path. Nothing here needs the npm tarball.
"""

from __future__ import annotations

import base64
import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from trafficgeo.errors import InputError
from trafficgeo.video.detections import COCO_VEHICLES, box_iou
from trafficgeo.video.detectors import builtin
from trafficgeo.video.detectors.builtin import NANODET_G_416, builtin_model, builtin_model_path
from trafficgeo.video.reader import read_frame_at

TOOLS = Path(__file__).resolve().parents[1] / "tools" / "nanodet"
sys.path.insert(0, str(TOOLS))
import check_decode  # noqa: E402
from tfjs_graph import load_tfjs_graph, run_reference  # noqa: E402
from tfjs_onnx import convert_graph, make_spatial_dynamic  # noqa: E402

VIDEO = Path(__file__).parent / "data" / "intel-sample-video" / "car-detection.mp4"


# ------------------------------------------------------------------------------------------------ shipped model
@pytest.fixture(scope="module")
def session() -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 2
    return ort.InferenceSession(str(builtin_model_path("nanodet")), opts, providers=["CPUExecutionProvider"])


def test_shipped_file_matches_registry():
    path = builtin_model_path("nanodet", verify=True)
    data = path.read_bytes()
    assert path.name == "nanodet-g-416.onnx"
    assert len(data) == NANODET_G_416.size_bytes
    assert hashlib.sha256(data).hexdigest() == NANODET_G_416.sha256
    assert (path.parent / "NOTICE").is_file()
    notice = builtin.builtin_models_notice()
    assert "Copyright 2020-2021 RangiLyu" in notice and "Copyright (c) 2021 Vladimir Mandic" in notice
    assert NANODET_G_416.sha256 in notice
    source = (path.parent / "SOURCE.txt").read_text()  # provenance beside the file, as tests/data has it
    assert NANODET_G_416.sha256 in source and "Apache-2.0 AND MIT" in source
    int8 = builtin_model_path("nanodet", verify=True, int8=True)  # its INT8 version, with its provenance too
    assert int8.name == "nanodet-g-416-int8.onnx" and int8.stat().st_size == NANODET_G_416.int8.size_bytes
    assert NANODET_G_416.int8.sha256 in notice and NANODET_G_416.int8.sha256 in source


def test_registry_entry():
    m = builtin_model(" NanoDet ")
    assert m is NANODET_G_416
    assert (m.input_size_px, m.layout, m.color_order, m.score_threshold, m.reg_bins) == (416, "nanodet", "BGR",
                                                                                        0.25, 11)
    assert m.vehicle_class_names == COCO_VEHICLES
    assert m.mean == (103.53, 116.28, 123.675) and m.std == (57.375, 57.12, 58.395)
    with pytest.raises(InputError, match=r"unknown built-in model 'yolo'.*nanodet"):
        builtin_model("yolo")


def test_missing_or_corrupt_file_is_an_input_error(monkeypatch):
    monkeypatch.setattr(builtin, "MODELS_PACKAGE_DIR", ("data", "no-such-dir"))
    with pytest.raises(InputError, match="missing: reinstall trafficgeo; the file is shipped in the package"):
        builtin_model_path("nanodet")
    monkeypatch.undo()
    wrong = builtin.BuiltinModel(**{**NANODET_G_416.__dict__, "sha256": "0" * 64})
    monkeypatch.setitem(builtin.BUILTIN_MODELS, "nanodet", wrong)
    assert builtin_model_path("nanodet").is_file()  # no check without verify
    with pytest.raises(InputError, match="corrupt"):
        builtin_model_path("nanodet", verify=True)


def test_io_names_and_shapes(session):
    (inp,) = session.get_inputs()
    assert (inp.name, inp.shape, inp.type) == ("input", [1, 3, "height", "width"], "tensor(float)")
    assert session.get_modelmeta().custom_metadata_map["imgsz"] == "[416, 416]"
    names = [o.name for o in session.get_outputs()]
    assert tuple(names) == NANODET_G_416.output_names
    for h, w in ((416, 416), (256, 416), (96, 640)):  # any multiples of 32: anchors (h/s)(w/s) per stride s
        got = session.run(None, {"input": np.zeros((1, 3, h, w), np.float32)})
        cells = [(h // s) * (w // s) for s in NANODET_G_416.strides_px]
        assert [g.shape for g in got] == [(1, n, 80) for n in cells] + [(1, n, 44) for n in cells]
    model = onnx.load(str(builtin_model_path("nanodet")), load_external_data=False)
    weights = [t for t in model.graph.initializer if t.data_type == onnx.TensorProto.FLOAT16]
    assert sum(int(np.prod(t.dims)) for t in weights) == pytest.approx(3.79e6, rel=0.01)  # NanoDet-g: 3.79 M


def _frame(index: int) -> np.ndarray:
    """Frame ``index`` of the Intel sample video (12.5 fps: frame k at k x 80 ms)."""
    frame = read_frame_at(VIDEO, index * 0.08)
    assert frame.index == index
    return frame.image


def test_detects_the_two_cars_of_a_real_frame(session):
    # Intel sample video frame 212 (768x432): a red car fully in view and a silver car cut by the bottom edge;
    # boxes read by eye off a 50 px grid overlay (x1, y1, x2, y2, full-frame px).
    truth = np.array([[312.0, 78.0, 468.0, 335.0], [66.0, 140.0, 248.0, 431.0]])
    boxes, scores, classes = check_decode.detect(session, _frame(212), "letterbox", NANODET_G_416.score_threshold)
    assert len(boxes) == 2
    iou = box_iou(truth[:, None], boxes[None, :])
    assert iou.max(axis=1).min() >= 0.85
    assert set(classes.tolist()) <= set(COCO_VEHICLES)
    assert np.all(scores >= 0.25) and np.all(scores <= 1)


def test_empty_road_frame_has_no_vehicle(session):
    boxes, _, _ = check_decode.detect(session, _frame(10), "letterbox", NANODET_G_416.score_threshold)
    assert len(boxes) == 0


# ------------------------------------------------------------------------------------ converter on tiny graphs
def _attr_s(text: str) -> dict:
    return {"s": base64.b64encode(text.encode()).decode()}


def _ints(*values: int) -> dict:
    return {"list": {"i": [str(v) for v in values]}}


def _tfjs(nodes: list[dict], consts: dict[str, np.ndarray], inputs: dict[str, list[int]]) -> tuple[bytes, dict]:
    """A TF.js graph-model (JSON bytes, shards): float consts stored as float16, int consts as int32."""
    entries, chunks, all_nodes = [], [], []
    for name, shape in inputs.items():
        dims = [{"size": str(d)} for d in shape]
        all_nodes.append({"name": name, "op": "Placeholder", "attr": {"shape": {"shape": {"dim": dims}},
                                                                       "dtype": {"type": "DT_FLOAT"}}})
    for name, value in consts.items():
        value = np.asarray(value)
        if value.dtype.kind == "f":
            entries.append({"name": name, "shape": list(value.shape), "dtype": "float32",
                            "quantization": {"dtype": "float16", "original_dtype": "float32"}})
            chunks.append(value.astype("<f2").tobytes())
            tf_type = "DT_FLOAT"
        else:
            entries.append({"name": name, "shape": list(value.shape), "dtype": "int32"})
            chunks.append(value.astype("<i4").tobytes())
            tf_type = "DT_INT32"
        all_nodes.append({"name": name, "op": "Const", "attr": {"dtype": {"type": tf_type}}})
    doc = {"format": "graph-model", "modelTopology": {"node": all_nodes + nodes},
           "weightsManifest": [{"paths": ["w.bin"], "weights": entries}]}
    return json.dumps(doc).encode(), {"w.bin": b"".join(chunks)}


def _node(name: str, op: str, *inputs: str, **attrs) -> dict:
    return {"name": name, "op": op, "input": list(inputs), "attr": attrs}


def _run_onnx(model: onnx.ModelProto, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, feeds)


def _onnx_tf_style_graph():
    """NCHW input wrapped in transposes around NHWC ops, like the NanoDet TF.js graph (onnx-tf export)."""
    rng = np.random.default_rng(3)
    nhwc, nchw = np.array([0, 2, 3, 1]), np.array([0, 3, 1, 2])
    consts = {
        "pads": np.array([[0, 0], [0, 0], [1, 1], [1, 1]]), "to_nhwc": nhwc, "to_nchw": nchw,
        "w": rng.normal(size=(3, 3, 3, 4)), "b": rng.normal(size=4), "ninf": np.array(-np.inf),
        "size": np.array([5, 5]), "axis1": np.array(1), "crop_sizes": np.array([1, 3]), "sizes": np.array([3, 4]),
        "shape_base": np.array([1, 3, -1]), "where": np.zeros((0, 1), np.int64), "dense_shape": np.array([3]),
        "gather": np.zeros(0, np.int64), "zero": np.array(0), "perm021": np.array([0, 2, 1]),
    }
    nodes = [
        _node("pad0", "Pad", "x", "pads"),
        _node("t1", "Transpose", "pad0", "to_nhwc"),
        _node("conv", "Conv2D", "t1", "w", strides=_ints(1, 2, 2, 1), padding=_attr_s("VALID"),
              data_format=_attr_s("NHWC"), dilations=_ints(1, 1, 1, 1)),
        _node("add", "Add", "conv", "b"),
        _node("t2", "Transpose", "add", "to_nchw"),
        _node("lrelu", "LeakyRelu", "t2", alpha={"f": 0.1}),
        _node("padv2", "PadV2", "lrelu", "pads", "ninf"),
        _node("t3", "Transpose", "padv2", "to_nhwc"),
        _node("pool", "MaxPool", "t3", ksize=_ints(1, 3, 3, 1), strides=_ints(1, 2, 2, 1), padding=_attr_s("VALID")),
        _node("resize", "ResizeBilinear", "pool", "size", half_pixel_centers={"b": True}, align_corners={"b": False}),
        _node("t4", "Transpose", "resize", "to_nchw"),
        _node("t5", "Transpose", "lrelu", "to_nhwc"),
        _node("t6", "Transpose", "t5", "to_nchw"),
        _node("crop", "SplitV", "t6", "crop_sizes", "axis1"),
        _node("cat", "ConcatV2", "t4", "crop:1", "axis1"),
        _node("split", "SplitV", "cat", "sizes", "axis1"),
        _node("sig", "Sigmoid", "split"),
        _node("s2d", "SparseToDense", "where", "dense_shape", "gather", "zero"),
        _node("shape", "AddV2", "shape_base", "s2d"),
        _node("reshape", "Reshape", "sig", "shape"),
        _node("out0", "Transpose", "reshape", "perm021"),
        _node("Identity", "Identity", "out0"),
        _node("Identity_1", "Identity", "split:1"),
    ]
    return _tfjs(nodes, consts, {"x": [1, 3, 9, 9]})


def test_converter_matches_reference_and_removes_layout_transposes():
    graph = load_tfjs_graph(*_onnx_tf_style_graph())
    model = convert_graph(graph, {"x": "x"}, {"Identity:0": "scores", "Identity_1:0": "rest"})
    ops = [n.op_type for n in model.graph.node]
    assert ops.count("Transpose") == 1  # only the one after Reshape; NHWC<->NCHW pairs cancel or fold into ops
    assert ops.count("Conv") == 1 and ops.count("Cast") == 2  # float16 filter and bias -> float32
    assert [t.data_type for t in model.graph.initializer if t.name.startswith(("w/", "b/"))] == [10, 10]
    x = np.random.default_rng(4).normal(size=(1, 3, 9, 9)).astype(np.float32)
    got = _run_onnx(model, {"x": x})
    ref = run_reference(graph, {"x": x}, ["Identity:0", "Identity_1:0"])
    assert got[0].shape == ref["Identity:0"].shape == (1, 25, 3)
    assert got[1].shape == ref["Identity_1:0"].shape == (1, 4, 5, 5)
    np.testing.assert_allclose(got[0], ref["Identity:0"], atol=1e-5)
    np.testing.assert_allclose(got[1], ref["Identity_1:0"], atol=1e-5)
    again = convert_graph(load_tfjs_graph(*_onnx_tf_style_graph()), {"x": "x"},
                          {"Identity:0": "scores", "Identity_1:0": "rest"})
    assert again.SerializeToString(deterministic=True) == model.SerializeToString(deterministic=True)


def _upsampling_graph(h: int, w: int) -> tuple[bytes, dict]:
    """conv stride 2 (SAME) -> bilinear resize back to h x w -> concat with the input -> reshape [1, 7, -1], built
    for an h x w input (the resize size is a constant of the graph, as in the NanoDet TF.js graph)."""
    rng = np.random.default_rng(5)
    consts = {"w": rng.normal(size=(3, 3, 3, 4)), "b": rng.normal(size=4), "size": np.array([h, w]),
              "axis3": np.array(3), "shape": np.array([1, 7, -1]), "perm": np.array([0, 3, 1, 2])}
    nodes = [
        _node("conv", "Conv2D", "x", "w", strides=_ints(1, 2, 2, 1), padding=_attr_s("SAME"),
              data_format=_attr_s("NHWC"), dilations=_ints(1, 1, 1, 1)),
        _node("add", "Add", "conv", "b"),
        _node("up", "ResizeBilinear", "add", "size", half_pixel_centers={"b": True}, align_corners={"b": False}),
        _node("cat", "ConcatV2", "x", "up", "axis3"),
        _node("nchw", "Transpose", "cat", "perm"),
        _node("reshape", "Reshape", "nchw", "shape"),
        _node("Identity", "Identity", "reshape"),
    ]
    return _tfjs(nodes, consts, {"x": [1, h, w, 3]})


def test_spatially_dynamic_model_equals_a_graph_built_for_each_size():
    # Truth for another input size: the same network built for that size (its resize constant changed).
    static = convert_graph(load_tfjs_graph(*_upsampling_graph(8, 8)), {"x": "x"}, {"Identity:0": "y"})
    dynamic = make_spatial_dynamic(static, axes=(1, 2))  # an NHWC input
    assert [d.dim_param for d in dynamic.graph.input[0].type.tensor_type.shape.dim[1:3]] == ["height", "width"]
    rng = np.random.default_rng(6)
    for h, w in ((8, 8), (16, 24), (6, 10)):
        x = rng.normal(size=(1, h, w, 3)).astype(np.float32)
        truth = run_reference(load_tfjs_graph(*_upsampling_graph(h, w)), {"x": x}, ["Identity:0"])["Identity:0"]
        got = _run_onnx(dynamic, {"x": x})[0]
        assert got.shape == truth.shape == (1, 7, h * w)
        np.testing.assert_allclose(got, truth, atol=1e-5)
    same = rng.normal(size=(1, 8, 8, 3)).astype(np.float32)
    np.testing.assert_array_equal(_run_onnx(static, {"x": same})[0], _run_onnx(dynamic, {"x": same})[0])
    odd = convert_graph(load_tfjs_graph(*_onnx_tf_style_graph()), {"x": "x"}, {"Identity:0": "y"})
    with pytest.raises(NotImplementedError, match="not a whole factor"):  # 3 -> 5 px: no scale fits every size
        make_spatial_dynamic(odd, axes=(2, 3))


def _both(nodes, consts, inputs, feeds, fetch):
    """(reference, onnxruntime) values of TF tensor ``fetch`` for a tiny graph."""
    graph = load_tfjs_graph(*_tfjs(nodes, consts, inputs))
    ref = run_reference(graph, feeds, [fetch])[fetch]
    got = _run_onnx(convert_graph(graph, {k: k for k in inputs}, {fetch: "y"}), feeds)[0]
    return ref, got


def test_resize_bilinear_half_pixel_hand_values():
    x = np.array([[0.0, 1.0], [2.0, 3.0]], np.float32).reshape(1, 2, 2, 1)
    nodes = [_node("r", "ResizeBilinear", "x", "size", half_pixel_centers={"b": True}, align_corners={"b": False})]
    ref, got = _both(nodes, {"size": np.array([4, 4])}, {"x": [1, 2, 2, 1]}, {"x": x}, "r")
    expected = np.array([[0, 0.25, 0.75, 1], [0.5, 0.75, 1.25, 1.5], [1.5, 1.75, 2.25, 2.5], [2, 2.25, 2.75, 3]])
    np.testing.assert_allclose(ref[0, :, :, 0], expected, atol=1e-6)
    np.testing.assert_allclose(got[0, :, :, 0], expected, atol=1e-6)


def test_conv_same_padding_and_max_pool_hand_values():
    ones = np.ones((1, 4, 4, 1), np.float32)
    nodes = [_node("c", "Conv2D", "x", "w", strides=_ints(1, 2, 2, 1), padding=_attr_s("SAME"))]
    ref, got = _both(nodes, {"w": np.ones((3, 3, 1, 1))}, {"x": [1, 4, 4, 1]}, {"x": ones}, "c")
    for y in (ref, got):  # TF SAME with stride 2 on 4 px pads 0 before, 1 after
        np.testing.assert_allclose(y[0, :, :, 0], [[9, 6], [6, 4]])
    ramp = np.arange(1, 17, dtype=np.float32).reshape(1, 4, 4, 1)
    nodes = [_node("p", "MaxPool", "x", ksize=_ints(1, 2, 2, 1), strides=_ints(1, 2, 2, 1), padding=_attr_s("VALID"))]
    ref, got = _both(nodes, {}, {"x": [1, 4, 4, 1]}, {"x": ramp}, "p")
    for y in (ref, got):
        np.testing.assert_allclose(y[0, :, :, 0], [[6, 8], [14, 16]])


def test_leaky_relu_pad_concat_hand_values():
    x = np.array([[-2.0, 3.0]], np.float32)
    nodes = [_node("l", "LeakyRelu", "x", alpha={"f": 0.1}), _node("p", "PadV2", "l", "pads", "value"),
             _node("c", "ConcatV2", "p", "x", "axis")]
    consts = {"pads": np.array([[0, 0], [1, 0]]), "value": np.array(7.0), "axis": np.array(-1)}
    ref, got = _both(nodes, consts, {"x": [1, 2]}, {"x": x}, "c")
    for y in (ref, got):
        np.testing.assert_allclose(y, [[7, -0.2, 3, -2, 3]], atol=1e-6)


def test_float16_weights_are_decoded_exactly():
    w = np.array([0.1, -2.5, 65504.0, 1e-4])
    graph = load_tfjs_graph(*_tfjs([], {"w": w, "i": np.array([3, -1])}, {}))
    assert graph.consts["w"].dtype == np.float16
    np.testing.assert_array_equal(graph.consts["w"], w.astype(np.float16))
    np.testing.assert_array_equal(graph.consts["i"], [3, -1])
    model_json, shards = _tfjs([], {"w": w}, {})
    with pytest.raises(ValueError, match="too short"):
        load_tfjs_graph(model_json, {"w.bin": shards["w.bin"][:-2]})


def test_unsupported_op_is_named():
    graph = load_tfjs_graph(*_tfjs([_node("r", "Relu6", "x")], {}, {"x": [1, 2]}))
    with pytest.raises(NotImplementedError, match="Relu6"):
        convert_graph(graph, {"x": "x"}, {"r": "y"})
    with pytest.raises(NotImplementedError, match="Relu6"):
        run_reference(graph, {"x": np.zeros((1, 2), np.float32)}, ["r"])


def test_decode_check_tool_on_a_synthetic_anchor():
    # stride-16 anchor at row 3, col 5 (centre 88, 56) with sides 2, 1, 3, 4 bins -> 32, 16, 48, 64 px.
    outputs = [np.zeros((1, n, 80), np.float32) for n in (2704, 676, 169)]
    outputs += [np.full((1, n, 44), -30.0, np.float32) for n in (2704, 676, 169)]
    k = 3 * 26 + 5
    outputs[1][0, k, 2] = 0.9
    for side, bin_index in enumerate((2, 1, 3, 4)):
        outputs[4][0, k, side * 11 + bin_index] = 30.0
    boxes, scores = check_decode.decode(outputs)
    best = int(np.argmax(scores[:, 2]))
    assert best == 2704 + k
    np.testing.assert_allclose(boxes[best], [88 - 32, 56 - 16, 88 + 48, 56 + 64], atol=1e-3)
