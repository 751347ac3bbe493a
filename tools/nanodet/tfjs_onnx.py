"""A small TF.js graph -> ONNX converter (dev tool, not part of the package).

One function per TF op (:data:`CONVERTERS`). Layout handling: every dynamic TF tensor is held as an ONNX value
plus a permutation ``perm`` with ``tf_tensor == onnx_value.transpose(perm)``. TF ``Transpose`` only composes
permutations (no ONNX node); ops that need a given layout (``Conv2D``/``MaxPool``/``ResizeBilinear`` want NCHW,
``Reshape`` wants the TF layout) insert one ONNX ``Transpose`` only when the permutation differs; elementwise
ops, ``Pad``, ``ConcatV2`` and ``SplitV`` remap their axes instead. Graphs exported through onnx-tf (NCHW
tensors wrapped in transposes around every NHWC convolution) thus convert to a transpose-free ONNX graph.

Nodes whose inputs are all constants are folded with the numpy reference ops of :mod:`tfjs_graph`. Float
constants stored as float16 stay float16 initializers followed by a ``Cast`` to float32, so the file keeps the
TF.js size while all arithmetic is float32. The output is deterministic: names come from the TF graph, nodes
and initializers are emitted in graph order.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper
from tfjs_graph import TfGraph, TfNode, const_f32, eval_node, split_ref

OPSET = 18
IR_VERSION = 9


@dataclass(frozen=True)
class _Value:
    """A TF tensor: a constant (``const`` set) or an ONNX value ``name`` with ``tf == onnx.transpose(perm)``."""

    name: str = ""
    perm: tuple[int, ...] = ()
    const: np.ndarray | None = None


def _inverse(perm: Sequence[int]) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argsort(perm))


class _Builder:
    """Collects ONNX nodes and initializers with unique, graph-derived names."""

    def __init__(self) -> None:
        self.nodes: list[onnx.NodeProto] = []
        self.initializers: list[onnx.TensorProto] = []
        self.names: set[str] = set()
        self.cache: dict[tuple, str] = {}

    def unique(self, base: str) -> str:
        name, k = base, 1
        while name in self.names:
            name, k = f"{base}_{k}", k + 1
        self.names.add(name)
        return name

    def node(self, op: str, inputs: Sequence[str], name: str, n_out: int = 1, **attrs) -> list[str]:
        outs = [self.unique(name if k == 0 else f"{name}:{k}") for k in range(n_out)]
        self.nodes.append(helper.make_node(op, list(inputs), outs, name=outs[0], **attrs))
        return outs

    def const(self, array: np.ndarray, name: str) -> str:
        """An initializer for ``array``; float16 -> float16 initializer + Cast (float32 out); ints -> int64."""
        array = np.ascontiguousarray(array)
        key = (name, array.dtype.str, array.shape, array.tobytes())
        if key in self.cache:
            return self.cache[key]
        if array.dtype == np.float16:
            stored = self.unique(name)
            self.initializers.append(numpy_helper.from_array(array, stored))
            out = self.node("Cast", [stored], f"{stored}/f32", to=TensorProto.FLOAT)[0]
        else:
            cast = array.astype(np.int64) if np.issubdtype(array.dtype, np.integer) else array.astype(np.float32)
            out = self.unique(name)
            self.initializers.append(numpy_helper.from_array(cast, out))
        self.cache[key] = out
        return out

    def layout(self, value: _Value, perm: Sequence[int], hint: str) -> str:
        """ONNX value holding ``value`` such that ``tf == result.transpose(perm)`` (inserting a Transpose)."""
        perm = tuple(perm)
        if value.const is not None:
            return self.const(value.const.transpose(_inverse(perm)), f"{hint}/const")
        onnx_perm = tuple(value.perm[i] for i in _inverse(perm))
        if onnx_perm == tuple(range(len(onnx_perm))):
            return value.name
        key = ("transpose", value.name, onnx_perm)
        if key not in self.cache:
            suffix = "".join(str(i) for i in onnx_perm)
            name = f"{value.name}/perm{suffix}"
            self.cache[key] = self.node("Transpose", [value.name], name, perm=list(onnx_perm))[0]
        return self.cache[key]


_NHWC_AS_NCHW = (0, 2, 3, 1)  # tf NHWC == onnx NCHW .transpose(0, 2, 3, 1)


def _spatial_layout(node: TfNode) -> tuple[int, ...]:
    return (0, 1, 2, 3) if node.attr_str("data_format", "NHWC") == "NCHW" else _NHWC_AS_NCHW


def _hw(node: TfNode, key: str) -> list[int]:
    v = node.attr_ints(key, (1, 1, 1, 1))
    return [v[2], v[3]] if node.attr_str("data_format", "NHWC") == "NCHW" else [v[1], v[2]]


def _pool_conv_padding(node: TfNode) -> dict:
    padding = node.attr_str("padding")
    if padding == "VALID":
        return {"pads": [0, 0, 0, 0]}
    if padding == "SAME":
        return {"auto_pad": "SAME_UPPER"}
    if padding == "EXPLICIT":
        e = node.attr_ints("explicit_paddings")
        h, w = (2, 3) if node.attr_str("data_format", "NHWC") == "NCHW" else (1, 2)
        return {"pads": [e[2 * h], e[2 * w], e[2 * h + 1], e[2 * w + 1]]}
    raise NotImplementedError(f"{node.name}: padding {padding!r}")


def _conv2d(b: _Builder, node: TfNode, x: _Value, w: _Value) -> list[_Value]:
    if w.const is None:
        raise NotImplementedError(f"{node.name}: Conv2D with a non-constant filter")
    layout = _spatial_layout(node)
    kernel = w.const.transpose(3, 2, 0, 1)  # HWIO -> OIHW, exact in any precision
    attrs = {"kernel_shape": list(kernel.shape[2:]), "strides": _hw(node, "strides"),
             "dilations": _hw(node, "dilations"), **_pool_conv_padding(node)}
    inputs = [b.layout(x, layout, node.name), b.const(kernel, f"{node.inputs[1]}/oihw")]
    return [_Value(b.node("Conv", inputs, node.name, **attrs)[0], layout)]


def _max_pool(b: _Builder, node: TfNode, x: _Value) -> list[_Value]:
    layout = _spatial_layout(node)
    attrs = {"kernel_shape": _hw(node, "ksize"), "strides": _hw(node, "strides"), **_pool_conv_padding(node)}
    return [_Value(b.node("MaxPool", [b.layout(x, layout, node.name)], node.name, **attrs)[0], layout)]


def _resize_bilinear(b: _Builder, node: TfNode, x: _Value, size: _Value) -> list[_Value]:
    if size.const is None:
        raise NotImplementedError(f"{node.name}: ResizeBilinear with a non-constant size")
    if node.attr_bool("align_corners"):
        mode = "align_corners"
    elif node.attr_bool("half_pixel_centers"):
        mode = "half_pixel"
    else:
        mode = "asymmetric"
    x_nchw = b.layout(x, _NHWC_AS_NCHW, node.name)
    # Full-rank sizes = (N, C of the input) + (H, W): onnxruntime's layout optimiser mishandles Resize's `axes`.
    batch_channels = b.node("Shape", [x_nchw], f"{node.name}/nc", start=0, end=2)[0]
    hw = b.const(np.asarray(size.const, dtype=np.int64), f"{node.name}/hw")
    sizes = b.node("Concat", [batch_channels, hw], f"{node.name}/sizes", axis=0)[0]
    out = b.node("Resize", [x_nchw, "", "", sizes], node.name, mode="linear", coordinate_transformation_mode=mode)
    return [_Value(out[0], _NHWC_AS_NCHW)]


def _elementwise(op: str, **attrs):
    """Converter for an elementwise op: dynamic inputs share the first one's layout, constants are permuted."""

    def convert(b: _Builder, node: TfNode, *xs: _Value) -> list[_Value]:
        ref = next(x for x in xs if x.const is None)
        rank = len(ref.perm)
        names = []
        for k, x in enumerate(xs):
            if x.const is not None:
                c = x.const.reshape((1,) * (rank - x.const.ndim) + x.const.shape)
                names.append(b.layout(_Value(const=c), ref.perm, f"{node.inputs[k]}/{node.name}"))
            elif len(x.perm) != rank:
                raise NotImplementedError(f"{node.name}: {node.op} of tensors of different ranks")
            else:
                names.append(b.layout(x, ref.perm, node.name))
        return [_Value(b.node(op, names, node.name, **attrs)[0], ref.perm)]

    return convert


def _leaky_relu(b: _Builder, node: TfNode, x: _Value) -> list[_Value]:
    return _elementwise("LeakyRelu", alpha=node.attr_float("alpha", 0.2))(b, node, x)


def _pad(b: _Builder, node: TfNode, x: _Value, paddings: _Value, value: _Value | None = None) -> list[_Value]:
    if paddings.const is None:
        raise NotImplementedError(f"{node.name}: Pad with non-constant paddings")
    tf_pads = np.asarray(paddings.const, dtype=np.int64)
    onnx_pads = tf_pads[_inverse(x.perm), :]  # onnx axis j is tf axis inverse(perm)[j]
    inputs = [x.name, b.const(np.concatenate([onnx_pads[:, 0], onnx_pads[:, 1]]), f"{node.name}/pads")]
    if value is not None:
        inputs.append(b.const(const_f32(np.asarray(value.const)).astype(np.float32), f"{node.name}/value"))
    return [_Value(b.node("Pad", inputs, node.name, mode="constant")[0], x.perm)]


def _concat(b: _Builder, node: TfNode, *xs: _Value) -> list[_Value]:
    *parts, axis = xs
    ref = next(x for x in parts if x.const is None)
    tf_axis = int(axis.const) % len(ref.perm)
    names = [b.layout(x, ref.perm, f"{node.name}/in{k}") for k, x in enumerate(parts)]
    return [_Value(b.node("Concat", names, node.name, axis=ref.perm[tf_axis])[0], ref.perm)]


def _split_v(b: _Builder, node: TfNode, x: _Value, sizes: _Value, axis: _Value) -> list[_Value]:
    split = np.asarray(sizes.const, dtype=np.int64)
    if (split < 0).any():
        raise NotImplementedError(f"{node.name}: SplitV with an inferred (-1) size")
    onnx_axis = x.perm[int(axis.const) % len(x.perm)]
    outs = b.node("Split", [x.name, b.const(split, f"{node.name}/split")], node.name, n_out=len(split), axis=onnx_axis)
    return [_Value(o, x.perm) for o in outs]


def _reshape(b: _Builder, node: TfNode, x: _Value, shape: _Value) -> list[_Value]:
    if shape.const is None:
        raise NotImplementedError(f"{node.name}: Reshape with a non-constant shape")
    target = np.asarray(shape.const, dtype=np.int64)
    name = b.layout(x, tuple(range(len(x.perm))), node.name)
    out = b.node("Reshape", [name, b.const(target, f"{node.name}/shape")], node.name)
    return [_Value(out[0], tuple(range(len(target))))]


def _transpose(b: _Builder, node: TfNode, x: _Value, perm: _Value) -> list[_Value]:
    if perm.const is None:
        raise NotImplementedError(f"{node.name}: Transpose with a non-constant permutation")
    return [_Value(x.name, tuple(x.perm[int(i)] for i in np.asarray(perm.const)))]


CONVERTERS = {
    "Add": _elementwise("Add"),
    "AddV2": _elementwise("Add"),
    "ConcatV2": _concat,
    "Conv2D": _conv2d,
    "Identity": lambda b, node, x: [x],
    "LeakyRelu": _leaky_relu,
    "MaxPool": _max_pool,
    "Pad": _pad,
    "PadV2": _pad,
    "Reshape": _reshape,
    "ResizeBilinear": _resize_bilinear,
    "Sigmoid": _elementwise("Sigmoid"),
    "SplitV": _split_v,
    "Transpose": _transpose,
}


def _placeholder_shape(node: TfNode) -> list[int | str]:
    dims = node.attrs.get("shape", {}).get("shape", {}).get("dim", [])
    return [int(d.get("size", -1)) if int(d.get("size", -1)) >= 0 else f"{node.name}_d{k}" for k, d in enumerate(dims)]


def _prune(nodes: list[onnx.NodeProto], inits: list[onnx.TensorProto], outputs: Sequence[str]):
    """Drop nodes and initializers that no graph output depends on (keeps order)."""
    live = set(outputs)
    kept: list[onnx.NodeProto] = []
    for n in reversed(nodes):
        if any(o in live for o in n.output):
            kept.append(n)
            live.update(i for i in n.input if i)
    return kept[::-1], [t for t in inits if t.name in live]


def convert_graph(
    graph: TfGraph,
    inputs: Mapping[str, str],
    outputs: Mapping[str, str],
    graph_name: str = "tfjs_graph",
    doc: str = "",
    metadata: Mapping[str, str] | None = None,
) -> onnx.ModelProto:
    """Convert ``graph`` to an ONNX model.

    ``inputs`` maps Placeholder names to ONNX input names; ``outputs`` maps TF tensor refs (``"node[:k]"``) to
    ONNX output names, in output order. Output shapes come from ONNX shape inference.
    """
    b = _Builder()
    values: dict[tuple[str, int], _Value] = {}
    graph_inputs = []
    for node in graph.nodes:
        if node.op == "Const":
            values[(node.name, 0)] = _Value(const=graph.consts[node.name])
            continue
        if node.op == "Placeholder":
            if node.name not in inputs:
                raise KeyError(f"no ONNX name given for placeholder {node.name}")
            shape = _placeholder_shape(node)
            graph_inputs.append(helper.make_tensor_value_info(inputs[node.name], TensorProto.FLOAT, shape))
            b.names.add(inputs[node.name])
            values[(node.name, 0)] = _Value(inputs[node.name], tuple(range(len(shape))))
            continue
        args = [values[split_ref(r)] for r in node.inputs]
        if all(a.const is not None for a in args):
            outs = [_Value(const=v) for v in eval_node(node, [const_f32(a.const) for a in args])]
        elif node.op in CONVERTERS:
            outs = CONVERTERS[node.op](b, node, *args)
        else:
            raise NotImplementedError(f"TF op {node.op} (node {node.name}) has no ONNX converter")
        for k, out in enumerate(outs):
            values[(node.name, k)] = out

    graph_outputs = []
    renames: dict[str, str] = {}
    for ref, out_name in outputs.items():
        value = values[split_ref(ref)]
        if value.const is not None:
            raise NotImplementedError(f"output {ref} is a constant")
        src = b.layout(value, tuple(range(len(value.perm))), out_name)
        if src in renames or src in {i.name for i in graph_inputs}:
            b.nodes.append(helper.make_node("Identity", [src], [out_name], name=out_name))
        else:
            renames[src] = out_name
        graph_outputs.append(helper.make_tensor_value_info(out_name, TensorProto.FLOAT, None))
    for n in b.nodes:
        n.input[:] = [renames.get(i, i) for i in n.input]
        n.output[:] = [renames.get(o, o) for o in n.output]
        if n.name in renames:
            n.name = renames[n.name]
    nodes, inits = _prune(b.nodes, b.initializers, list(outputs.values()))
    onnx_graph = helper.make_graph(nodes, graph_name, graph_inputs, graph_outputs, inits)
    model = helper.make_model(onnx_graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="trafficgeo tools/nanodet", producer_version="1", doc_string=doc)
    model.ir_version = IR_VERSION
    for key, val in (metadata or {}).items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=key, value=val))
    inferred = onnx.shape_inference.infer_shapes(model, strict_mode=True)
    for out, inf in zip(model.graph.output, inferred.graph.output, strict=True):
        out.type.CopyFrom(inf.type)
    onnx.checker.check_model(model, full_check=True)
    return model


def make_spatial_dynamic(model: onnx.ModelProto, dims: tuple[str, str] = ("height", "width"),
                         axes: tuple[int, int] = (2, 3)) -> onnx.ModelProto:
    """A copy of a converted image model whose input's H and W (its ``axes``: 2, 3 for [1, C, H, W]) are symbolic
    (``dims``), so that it runs on any input whose sides are multiples of the network's largest stride.

    The TF.js graph fixes the output sizes of its bilinear resizes (``ResizeBilinear`` with a constant size, e.g.
    13 -> 26); each becomes a ``Resize`` by the same constant *scale* (output / input size of the static graph,
    which must be a whole factor or its inverse). ``Reshape`` targets must already leave the spatial size to ``-1``.
    On the static input size the copy computes exactly what the original does.
    """
    static = onnx.shape_inference.infer_shapes(model, strict_mode=True)
    shapes = {v.name: [d.dim_value for d in v.type.tensor_type.shape.dim]
              for v in [*static.graph.value_info, *static.graph.input]}
    out = onnx.ModelProto()
    out.CopyFrom(model)
    g = out.graph
    inits = {t.name: t for t in g.initializer}
    producer = {o: n for n in g.node for o in n.output}
    for n in g.node:
        if n.op_type == "Reshape":
            target = numpy_helper.to_array(inits[n.input[1]])
            if target.size and (target[-1] != -1 or (target[1:-1] < 0).any()):
                raise NotImplementedError(f"{n.name}: a Reshape to {target.tolist()} fixes the spatial size")
        if n.op_type != "Resize":
            continue
        concat = producer[n.input[3]]
        hw = numpy_helper.to_array(inits[concat.input[1]]).astype(np.float64)
        in_hw = np.asarray(shapes[n.input[0]][2:], dtype=np.float64)
        scale = hw / in_hw
        if not all(abs(s - round(s)) < 1e-9 or abs(1 / s - round(1 / s)) < 1e-9 for s in scale):
            raise NotImplementedError(f"{n.name}: resize by {scale.tolist()} is not a whole factor")
        name = f"{n.name}/scales"
        g.initializer.append(numpy_helper.from_array(np.array([1.0, 1.0, *scale], dtype=np.float32), name))
        n.input[:] = [n.input[0], "", name]
    dim = g.input[0].type.tensor_type.shape.dim
    for k, label in zip(axes, dims, strict=True):
        dim[k].Clear()
        dim[k].dim_param = label
    nodes, kept = _prune(list(g.node), list(g.initializer), [o.name for o in g.output])
    del g.node[:], g.initializer[:], g.value_info[:]
    g.node.extend(nodes)
    g.initializer.extend(kept)
    for o in g.output:
        o.type.tensor_type.ClearField("shape")
    inferred = onnx.shape_inference.infer_shapes(out, strict_mode=True)
    for o, inf in zip(g.output, inferred.graph.output, strict=True):
        o.type.CopyFrom(inf.type)
        for k, d in enumerate(o.type.tensor_type.shape.dim):
            if d.dim_param.startswith("unk__"):
                d.dim_param = f"{o.name}_d{k}"
    onnx.checker.check_model(out, full_check=True)
    return out
