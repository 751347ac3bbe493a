"""TF.js graph-model loading and an independent numpy reference executor (dev tool, not part of the package).

A TF.js graph model is a ``model.json`` (a TensorFlow ``GraphDef`` as JSON plus a weights manifest) and one or
more binary weight shards. :func:`load_tfjs_graph` reads both into a :class:`TfGraph`; :func:`run_reference`
executes it with plain numpy following TensorFlow's op semantics (NHWC by default, TF padding and resize
rules), so that a converted ONNX model can be checked against something written independently of it.

Only the ops in :data:`REFERENCE_OPS` are supported; anything else raises ``NotImplementedError`` naming the op.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

_TF_DTYPES = {"DT_FLOAT": np.float32, "DT_INT32": np.int32, "DT_INT64": np.int64, "DT_BOOL": np.bool_}


@dataclass(frozen=True)
class TfNode:
    """One GraphDef node: ``inputs`` are tensor references ``"node"`` or ``"node:k"`` (control inputs dropped)."""

    name: str
    op: str
    inputs: tuple[str, ...]
    attrs: Mapping[str, dict] = field(default_factory=dict)

    def attr_int(self, key: str, default: int | None = None) -> int:
        if key not in self.attrs:
            if default is None:
                raise KeyError(f"{self.name}: missing attribute {key}")
            return default
        return int(self.attrs[key]["i"])

    def attr_float(self, key: str, default: float) -> float:
        return float(self.attrs[key]["f"]) if key in self.attrs else default

    def attr_bool(self, key: str, default: bool = False) -> bool:
        return bool(self.attrs[key].get("b", False)) if key in self.attrs else default

    def attr_str(self, key: str, default: str = "") -> str:
        return base64.b64decode(self.attrs[key]["s"]).decode() if key in self.attrs else default

    def attr_ints(self, key: str, default: Sequence[int] = ()) -> tuple[int, ...]:
        if key not in self.attrs:
            return tuple(default)
        return tuple(int(v) for v in self.attrs[key].get("list", {}).get("i", []))


@dataclass(frozen=True)
class TfGraph:
    """Nodes in topological order and the constant tensors by node name.

    Float constants keep their stored precision (float16 when the manifest quantised them to float16); use
    :func:`const_f32` for computing.
    """

    nodes: tuple[TfNode, ...]
    consts: Mapping[str, np.ndarray]
    outputs: tuple[str, ...]


def split_ref(ref: str) -> tuple[str, int]:
    """``"node:k"`` -> (``"node"``, k); ``"node"`` -> (``"node"``, 0)."""
    name, sep, index = ref.rpartition(":")
    if sep and index.isdigit():
        return name, int(index)
    return ref, 0


def const_f32(value: np.ndarray) -> np.ndarray:
    """A stored constant as TF computes with it: float16 storage widened to float32, others unchanged."""
    return value.astype(np.float32) if value.dtype == np.float16 else value


def _decode_weights(manifest: Sequence[dict], shards: Mapping[str, bytes]) -> dict[str, np.ndarray]:
    """Weights manifest + shard bytes -> arrays (float16-quantised entries stay float16)."""
    out: dict[str, np.ndarray] = {}
    for group in manifest:
        buffer = b"".join(shards[path] for path in group["paths"])
        offset = 0
        for entry in group["weights"]:
            shape = [int(d) for d in entry["shape"]]
            count = int(np.prod(shape, dtype=np.int64))
            quant = entry.get("quantization")
            if quant is None:
                dtype = np.dtype({"float32": "<f4", "int32": "<i4", "bool": "?"}[entry["dtype"]])
            else:
                dtype = np.dtype({"float16": "<f2", "uint8": "u1", "uint16": "<u2"}[quant["dtype"]])
            nbytes = count * dtype.itemsize
            if offset + nbytes > len(buffer):
                raise ValueError(f"weights shard too short for {entry['name']}")
            raw = np.frombuffer(buffer, dtype=dtype, count=count, offset=offset).reshape(shape)
            offset += nbytes
            if quant is not None and quant["dtype"] != "float16":
                raw = (raw.astype(np.float32) * np.float32(quant["scale"]) + np.float32(quant["min"]))
            out[entry["name"]] = raw.astype(raw.dtype.newbyteorder("="))
        if offset != len(buffer):
            raise ValueError(f"weights shard has {len(buffer) - offset} unused bytes")
    return out


def _topological(nodes: Sequence[TfNode]) -> list[TfNode]:
    """Nodes ordered so every input comes first (stable: keeps file order where it can)."""
    by_name = {n.name: n for n in nodes}
    order: list[TfNode] = []
    state: dict[str, int] = {}
    for root in nodes:
        stack = [(root.name, False)]
        while stack:
            name, done = stack.pop()
            if done:
                state[name] = 2
                order.append(by_name[name])
                continue
            if state.get(name):
                continue
            state[name] = 1
            stack.append((name, True))
            for ref in reversed(by_name[name].inputs):
                src = split_ref(ref)[0]
                if src not in by_name:
                    raise ValueError(f"node {name} reads unknown node {src}")
                if not state.get(src):
                    stack.append((src, False))
    return order


def load_tfjs_graph(model_json: bytes, shards: Mapping[str, bytes]) -> TfGraph:
    """Parse a TF.js graph-model JSON and its weight shards (file name -> bytes)."""
    doc = json.loads(model_json)
    if doc.get("format") != "graph-model":
        raise ValueError(f"not a TF.js graph model (format={doc.get('format')!r})")
    raw_nodes = doc["modelTopology"]["node"]
    nodes = [
        TfNode(n["name"], n["op"], tuple(i for i in n.get("input", []) if not i.startswith("^")), n.get("attr", {}))
        for n in raw_nodes
    ]
    weights = _decode_weights(doc["weightsManifest"], shards)
    consts: dict[str, np.ndarray] = {}
    for node in nodes:
        if node.op == "Const":
            if node.name not in weights:
                raise ValueError(f"constant {node.name} is not in the weights manifest")
            value = weights[node.name]
            tf_type = node.attrs.get("dtype", {}).get("type", "DT_FLOAT")
            if value.dtype != np.float16 and tf_type in _TF_DTYPES:
                value = value.astype(_TF_DTYPES[tf_type])
            consts[node.name] = value
    outputs = tuple(sorted(doc.get("signature", {}).get("outputs", {})))
    return TfGraph(tuple(_topological(nodes)), consts, outputs)


# ----------------------------------------------------------------------------------------------------------------
# Reference op implementations (TensorFlow semantics). Each takes the node and its input values, returns outputs.


def _same_pads(size: int, kernel: int, stride: int, dilation: int = 1) -> tuple[int, int]:
    """TF 'SAME' padding (before, after) along one axis."""
    effective = (kernel - 1) * dilation + 1
    out = -(-size // stride)
    total = max((out - 1) * stride + effective - size, 0)
    return total // 2, total - total // 2


def _spatial_pads(node: TfNode, x_nhwc: np.ndarray, kh: int, kw: int, sh: int, sw: int) -> list[tuple[int, int]]:
    padding = node.attr_str("padding")
    if padding == "VALID":
        return [(0, 0), (0, 0)]
    if padding == "SAME":
        return [_same_pads(x_nhwc.shape[1], kh, sh), _same_pads(x_nhwc.shape[2], kw, sw)]
    if padding == "EXPLICIT":
        e = node.attr_ints("explicit_paddings")
        pairs = [(e[2 * i], e[2 * i + 1]) for i in range(4)]
        return [pairs[2], pairs[3]] if node.attr_str("data_format", "NHWC") == "NCHW" else [pairs[1], pairs[2]]
    raise NotImplementedError(f"{node.name}: padding {padding!r}")


def _nhwc_attr(node: TfNode, key: str) -> tuple[int, int]:
    """(h, w) of a 4-element NHWC/NCHW attribute list."""
    values = node.attr_ints(key, (1, 1, 1, 1))
    return (values[2], values[3]) if node.attr_str("data_format", "NHWC") == "NCHW" else (values[1], values[2])


def _windows(x: np.ndarray, kh: int, kw: int, sh: int, sw: int) -> np.ndarray:
    """Sliding (kh, kw) windows of an NHWC array with strides -> [N, OH, OW, C, kh, kw] view."""
    view = np.lib.stride_tricks.sliding_window_view(x, (kh, kw), axis=(1, 2))
    return view[:, ::sh, ::sw]


def _conv2d(node: TfNode, x: np.ndarray, w: np.ndarray) -> list[np.ndarray]:
    nchw = node.attr_str("data_format", "NHWC") == "NCHW"
    if nchw:
        x = x.transpose(0, 2, 3, 1)
    if _nhwc_attr(node, "dilations") != (1, 1):
        raise NotImplementedError(f"{node.name}: dilated Conv2D")
    kh, kw, cin, _ = w.shape
    if x.shape[3] != cin:
        raise NotImplementedError(f"{node.name}: grouped Conv2D ({x.shape[3]} input channels, filter has {cin})")
    sh, sw = _nhwc_attr(node, "strides")
    pads = _spatial_pads(node, x, kh, kw, sh, sw)
    x = np.pad(x, [(0, 0), *pads, (0, 0)])
    cols = _windows(x, kh, kw, sh, sw)
    y = np.tensordot(cols, w.transpose(2, 0, 1, 3), axes=([3, 4, 5], [0, 1, 2])).astype(np.float32)
    return [y.transpose(0, 3, 1, 2) if nchw else y]


def _max_pool(node: TfNode, x: np.ndarray) -> list[np.ndarray]:
    nchw = node.attr_str("data_format", "NHWC") == "NCHW"
    if nchw:
        x = x.transpose(0, 2, 3, 1)
    kh, kw = _nhwc_attr(node, "ksize")
    sh, sw = _nhwc_attr(node, "strides")
    pads = _spatial_pads(node, x, kh, kw, sh, sw)
    x = np.pad(x, [(0, 0), *pads, (0, 0)], constant_values=-np.inf)
    y = _windows(x, kh, kw, sh, sw).max(axis=(4, 5))
    return [y.transpose(0, 3, 1, 2) if nchw else y]


def _pad(node: TfNode, x: np.ndarray, paddings: np.ndarray, value: np.ndarray | None = None) -> list[np.ndarray]:
    fill = 0 if value is None else np.asarray(value).astype(x.dtype).item()
    return [np.pad(x, [(int(a), int(b)) for a, b in np.asarray(paddings)], constant_values=fill)]


def _resize_axis(in_size: int, out_size: int, align_corners: bool, half_pixel: bool):
    """TF bilinear source indices (lower, upper) and weights along one axis."""
    if align_corners and out_size > 1:
        scale = (in_size - 1) / (out_size - 1)
    else:
        scale = in_size / out_size
    out = np.arange(out_size, dtype=np.float64)
    src = (out + 0.5) * scale - 0.5 if half_pixel else out * scale
    floor = np.floor(src)
    lower = np.maximum(floor, 0).astype(np.int64)
    upper = np.minimum(np.ceil(src), in_size - 1).astype(np.int64)
    return lower, upper, (src - floor).astype(np.float32)


def _resize_bilinear(node: TfNode, x: np.ndarray, size: np.ndarray) -> list[np.ndarray]:
    out_h, out_w = (int(v) for v in np.asarray(size))
    corners, half = node.attr_bool("align_corners"), node.attr_bool("half_pixel_centers")
    y0, y1, fy = _resize_axis(x.shape[1], out_h, corners, half)
    x0, x1, fx = _resize_axis(x.shape[2], out_w, corners, half)
    fx = fx[None, None, :, None]
    top = x[:, y0][:, :, x0] + (x[:, y0][:, :, x1] - x[:, y0][:, :, x0]) * fx
    bottom = x[:, y1][:, :, x0] + (x[:, y1][:, :, x1] - x[:, y1][:, :, x0]) * fx
    return [(top + (bottom - top) * fy[None, :, None, None]).astype(np.float32)]


def _split_v(node: TfNode, x: np.ndarray, sizes: np.ndarray, axis: np.ndarray) -> list[np.ndarray]:
    ax = int(axis) % x.ndim
    sizes = [int(s) for s in np.asarray(sizes)]
    if sizes.count(-1) == 1:
        sizes[sizes.index(-1)] = x.shape[ax] - (sum(sizes) + 1)
    if sum(sizes) != x.shape[ax]:
        raise ValueError(f"{node.name}: split sizes {sizes} do not add up to {x.shape[ax]}")
    return np.split(x, np.cumsum(sizes)[:-1], axis=ax)


def _sparse_to_dense(node: TfNode, indices, shape, values, default) -> list[np.ndarray]:
    dense = np.full([int(v) for v in np.asarray(shape).reshape(-1)], np.asarray(default).item(),
                    dtype=np.asarray(values).dtype)
    idx = np.asarray(indices)
    idx = idx.reshape(1, 1) if idx.ndim == 0 else idx.reshape(-1, 1) if idx.ndim == 1 else idx
    if idx.shape[0]:
        dense[tuple(idx.T)] = values
    return [dense]


def _sigmoid(node: TfNode, x: np.ndarray) -> list[np.ndarray]:
    with np.errstate(over="ignore"):
        return [(1.0 / (1.0 + np.exp(-x))).astype(x.dtype)]


def _leaky_relu(node: TfNode, x: np.ndarray) -> list[np.ndarray]:
    return [np.where(x > 0, x, x * np.float32(node.attr_float("alpha", 0.2))).astype(x.dtype)]


def _add(node: TfNode, a: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    return [np.add(a, b, dtype=np.result_type(a, b))]


REFERENCE_OPS: dict[str, Callable[..., list[np.ndarray]]] = {
    "Add": _add,
    "AddV2": _add,
    "ConcatV2": lambda node, *xs: [np.concatenate(xs[:-1], axis=int(xs[-1]))],
    "Conv2D": _conv2d,
    "Identity": lambda node, x: [x],
    "LeakyRelu": _leaky_relu,
    "MaxPool": _max_pool,
    "Pad": _pad,
    "PadV2": _pad,
    "Reshape": lambda node, x, shape: [x.reshape([int(v) for v in np.asarray(shape)])],
    "ResizeBilinear": _resize_bilinear,
    "Sigmoid": _sigmoid,
    "SparseToDense": _sparse_to_dense,
    "SplitV": _split_v,
    "Transpose": lambda node, x, perm: [x.transpose([int(v) for v in np.asarray(perm)])],
}


def eval_node(node: TfNode, values: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Evaluate one node with the reference implementation of its op."""
    if node.op not in REFERENCE_OPS:
        raise NotImplementedError(f"TF op {node.op} (node {node.name}) is not supported")
    return REFERENCE_OPS[node.op](node, *values)


def run_reference(graph: TfGraph, feeds: Mapping[str, np.ndarray], fetches: Sequence[str]) -> dict[str, np.ndarray]:
    """Execute ``graph`` with numpy; ``feeds`` by Placeholder name, ``fetches`` as tensor refs (``"node[:k]"``)."""
    values: dict[tuple[str, int], np.ndarray] = {}
    needed = _needed_nodes(graph, [split_ref(f)[0] for f in fetches])
    for node in graph.nodes:
        if node.name not in needed:
            continue
        if node.op == "Const":
            outs = [const_f32(graph.consts[node.name])]
        elif node.op == "Placeholder":
            if node.name not in feeds:
                raise KeyError(f"no feed for placeholder {node.name}")
            outs = [np.asarray(feeds[node.name], dtype=np.float32)]
        else:
            outs = eval_node(node, [values[split_ref(r)] for r in node.inputs])
        for k, out in enumerate(outs):
            values[(node.name, k)] = out
    return {f: values[split_ref(f)] for f in fetches}


def _needed_nodes(graph: TfGraph, roots: Sequence[str]) -> set[str]:
    by_name = {n.name: n for n in graph.nodes}
    needed: set[str] = set()
    stack = list(roots)
    while stack:
        name = stack.pop()
        if name in needed:
            continue
        needed.add(name)
        stack.extend(split_ref(r)[0] for r in by_name[name].inputs)
    return needed
