"""Build ``src/trafficgeo/data/models/nanodet-g-416-int8.onnx``: the shipped NanoDet with its Conv nodes in INT8.

Dev tool, not part of the package. onnxruntime's static quantization (QDQ format, Conv nodes only, weights int8
per output channel, activations uint8 per tensor, min-max calibration) of the float model, calibrated on real road
frames that are *not* among the hand-labelled test frames: the 19 NGSIM US-101 frames of
``tests/data/ngsim-us101-calibration`` (see its SOURCE.txt), each as the full frame letterboxed to 416 x 416 and as
its 2 x 2 tiles (the detector runs on both). Only Conv nodes: quantizing every op broke the model (the sigmoid and
softmax heads lose their range); the convolutions are where the time goes.

Then it scores the float and the INT8 model on the hand-labelled frames (``tests/data/*-labels``, full frame and
2 x 2 tiles, IoU 0.5) and refuses to write a model whose F1 is more than :data:`F1_TOLERANCE` below the float
model's on any of them.

    python tools/nanodet/quantize_int8.py            # build, score, write
    python tools/nanodet/quantize_int8.py --check    # build in memory, compare with the shipped file

The output is the same on every run of the same onnxruntime version on the same CPU (min-max calibration has no
randomness); a different CPU may move a calibrated range in its last bit, so ``--check`` compares the weights and
scales with a tolerance rather than bytes.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "src"))
FLOAT_MODEL = REPO / "src/trafficgeo/data/models/nanodet-g-416.onnx"
DEFAULT_OUT = REPO / "src/trafficgeo/data/models/nanodet-g-416-int8.onnx"
FRAMES = REPO / "tests/data/ngsim-us101-calibration"  # 19 NGSIM frames, none of them hand-labelled (SOURCE.txt)
F1_TOLERANCE = 0.01
INPUT_HW = (416, 416)


def calibration_blobs() -> list[np.ndarray]:
    """The calibration inputs [1, 3, 416, 416]: each calibration frame whole and as its 2 x 2 tiles."""
    from trafficgeo.video.detectors.onnx_formats import LAYOUTS
    from trafficgeo.video.detectors.tiling import grid_plan

    pre = LAYOUTS["nanodet"].pre
    blobs = []
    paths = sorted(FRAMES.glob("*.jpg"))
    if len(paths) != 19:
        raise SystemExit(f"{FRAMES}: expected the 19 calibration frames, found {len(paths)}")
    for path in paths:
        frame = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if frame is None:
            raise SystemExit(f"{path}: calibration frame not readable")
        crops = [frame] + [frame[y0:y1, x0:x1] for x0, y0, x1, y1 in grid_plan(frame.shape[:2], 2).tiles]
        blobs += [pre.blob([c], INPUT_HW)[0] for c in crops]
    return blobs


def quantize(float_model: Path, out: Path) -> None:
    """Write the INT8 (Conv nodes, QDQ) model of ``float_model`` to ``out``."""
    import onnx
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.items = iter([{"input": b} for b in calibration_blobs()])

        def get_next(self) -> dict | None:
            return next(self.items, None)

    with tempfile.TemporaryDirectory() as tmp:
        pre = Path(tmp) / "pre.onnx"
        quant_pre_process(str(float_model), str(pre), skip_symbolic_shape=True)
        quantize_static(str(pre), str(out), Reader(), quant_format=QuantFormat.QDQ, op_types_to_quantize=["Conv"],
                        per_channel=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)
    model = onnx.load(str(out))
    model.doc_string = (f"{onnx.load(str(float_model), load_external_data=False).doc_string} INT8 version by "
                        "trafficgeo tools/nanodet/quantize_int8.py: Conv nodes quantized (QDQ; weights int8 per output "
                        "channel, activations uint8 per tensor; min-max calibration on 19 NGSIM US-101 frames, whole "
                        "and as 2 x 2 tiles); every other op in float32.")
    meta = {p.key: p.value for p in model.metadata_props if not p.key.startswith("onnx.")}
    meta["quantization"] = "int8 Conv QDQ (tools/nanodet/quantize_int8.py)"
    del model.metadata_props[:]
    onnx.helper.set_model_props(model, dict(sorted(meta.items())))
    onnx.save(model, str(out))


def score(model: Path) -> dict[str, float]:
    """F1 of ``model`` on each hand-labelled set, full frame and 2 x 2 tiles (name -> F1)."""
    from labelled_frames import INTEL_LABELS, NGSIM_LABELS, load_labels, score_labels
    from trafficgeo.video.detectors.onnx import OnnxDetector
    from trafficgeo.video.detectors.tiled import TiledDetector
    from trafficgeo.video.detectors.tiling import grid_plan

    det = OnnxDetector(model, format="nanodet")
    out = {}
    for folder in (NGSIM_LABELS, INTEL_LABELS):
        labels = load_labels(folder)
        shape = next(iter(labels.values())).image.shape[:2]
        tiled = TiledDetector(det, grid_plan(shape, 2))
        out[f"{folder.name} full"] = score_labels(labels, lambda im: det.detect(im, 0.0).boxes)[0].f1
        out[f"{folder.name} 2x2"] = score_labels(labels, lambda im, t=tiled: t.detect(im, 0.0).boxes)[0].f1
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--check", action="store_true", help="build in memory and compare with the file at --out")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        built = Path(tmp) / "int8.onnx"
        quantize(FLOAT_MODEL, built)
        if args.check:
            sys.exit(compare(built, args.out))
        f32, i8 = score(FLOAT_MODEL), score(built)
        worst = 0.0
        for k in f32:
            print(f"{k:40s} F1 float {f32[k]:.4f}  int8 {i8[k]:.4f}  ({i8[k] - f32[k]:+.4f})")
            worst = min(worst, i8[k] - f32[k])
        if worst < -F1_TOLERANCE:
            raise SystemExit(f"INT8 model loses {-worst:.4f} F1 (> {F1_TOLERANCE}); not written")
        args.out.write_bytes(built.read_bytes())
        print(f"wrote {args.out} ({args.out.stat().st_size} bytes)")


def compare(built: Path, shipped: Path) -> int:
    """0 when every initializer of ``built`` equals ``shipped``'s within one quantization step / 1e-6 relative."""
    import onnx
    from onnx import numpy_helper

    a = {t.name: numpy_helper.to_array(t) for t in onnx.load(str(built)).graph.initializer}
    b = {t.name: numpy_helper.to_array(t) for t in onnx.load(str(shipped)).graph.initializer}
    if a.keys() != b.keys():
        print(f"initializers differ: {sorted(a.keys() ^ b.keys())[:5]}")
        return 1
    bad = [k for k in a if a[k].shape != b[k].shape or not np.allclose(a[k].astype(np.float64),
                                                                         b[k].astype(np.float64), rtol=1e-6, atol=1)]
    print(f"{len(a)} initializers, {len(bad)} differ{': ' + ', '.join(bad[:5]) if bad else ''}")
    return 1 if bad else 0


if __name__ == "__main__":
    main()
