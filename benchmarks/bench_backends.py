"""Benchmark: the runtimes of the built-in learned detector (NanoDet-g, 416 x 416) on this machine, in one run.

For each backend (onnxruntime CPU, on the float model and on its INT8 version; the OpenVINO runtime at its default
precision, forced to f32, and on the INT8 version, when ``openvino`` imports - install it into a separate venv:
``pip install -e . openvino``):

* time per pass (ms, median of interleaved rounds on a real NGSIM frame, ``--threads`` threads, default 2) and the
  ratio to onnxruntime's;
* agreement with onnxruntime on the hand-labelled real frames (tests/data/*-labels): the largest absolute
  difference of the class scores (the network's outputs ``cls_s8/16/32``) and the F1 of its detections against
  onnxruntime's (IoU >= 0.5), full frame and 2 x 2 tiles;
* F1 against the hand labels (full frame);
* the probe's choice (:mod:`trafficgeo.video.detectors.backends`) with ``backend="auto"`` (a fresh cache);
* the tracker's time per frame (ByteTrack on onnxruntime's detections of NGSIM seq2, 2 x 2 tiles), the allowance
  :data:`trafficgeo.video.cost.TRACK_MS_PER_FRAME` is set from.

Run ``python benchmarks/bench_backends.py [--rounds N] [--threads T]``.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def cpu_flags() -> str:
    out = subprocess.run("grep -o 'avx[^ ]*\\|amx[^ ]*' /proc/cpuinfo | sort -u", shell=True, capture_output=True,
                         text=True, check=False).stdout.split()
    return " ".join(out) or "(none listed)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=30, help="timed rounds (each runs every backend once)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    import onnxruntime as ort

    from labelled_frames import INTEL_LABELS, NGSIM_LABELS, load_labels, score_frame
    from trafficgeo.video.detectors.backends import OpenVinoBackend, openvino_version
    from trafficgeo.video.detectors.builtin import builtin_model_path
    from trafficgeo.video.detectors.onnx import OnnxDetector
    from trafficgeo.video.detectors.tiled import TiledDetector
    from trafficgeo.video.detectors.tiling import grid_plan

    path = builtin_model_path("nanodet")
    print(f"CPU: {platform.processor() or platform.machine()}; flags: {cpu_flags()}")
    print(f"onnxruntime {ort.__version__}, openvino {openvino_version()}, threads {args.threads}")

    def detector() -> OnnxDetector:
        return OnnxDetector(path, format="nanodet", threads=args.threads)

    int8 = builtin_model_path("nanodet", int8=True)
    dets = {"onnxruntime": detector(), "onnxruntime, INT8 version": OnnxDetector(int8, format="nanodet",
                                                                               threads=args.threads)}
    if openvino_version() is not None:
        for name, model, config in (("openvino (default precision)", path, {}),
                                    ("openvino (f32)", path, {"INFERENCE_PRECISION_HINT": "f32"}),
                                    ("openvino, INT8 version", int8, {})):
            d = detector()
            d._runner = OpenVinoBackend(model, d._out_names, args.threads, config)
            dets[name] = d
            print(f"{name}: inference precision {d._runner.compiled.get_property('INFERENCE_PRECISION_HINT')}")
    labels = {**load_labels(NGSIM_LABELS), **{f"intel/{k}": v for k, v in load_labels(INTEL_LABELS).items()}}
    frame = next(iter(labels.values())).image
    ref = dets["onnxruntime"]
    blob, _g = ref.layout.pre.blob([frame], ref.input_hw)
    feeds = ref._feeds(blob, (frame.shape[1], frame.shape[0]))
    times: dict[str, list[float]] = {k: [] for k in dets}
    for d in dets.values():
        for _ in range(3):
            d._runner.run(feeds)
    for _ in range(args.rounds):
        for name, d in dets.items():
            t0 = time.perf_counter()
            d._runner.run(feeds)
            times[name].append(1e3 * (time.perf_counter() - t0))
    ms = {k: float(np.median(v)) for k, v in times.items()}

    cls = [k for k, r in enumerate(ref._roles) if str(r).startswith("cls")] or list(range(len(ref._roles)))
    rows = []
    for name, d in dets.items():
        diff, agree_full, agree_tiled, truth = 0.0, [0, 0, 0], [0, 0, 0], [0, 0, 0]
        for fr in labels.values():
            b, _ = ref.layout.pre.blob([fr.image], ref.input_hw)
            f = ref._feeds(b, (fr.image.shape[1], fr.image.shape[0]))
            a, o = ref._runner.run(f), d._runner.run(f)
            diff = max(diff, max(float(np.max(np.abs(np.asarray(a[k], np.float32) - np.asarray(o[k], np.float32))))
                                 for k in cls))
            plan = grid_plan(fr.image.shape[:2], 2)
            for acc, (mine, theirs) in ((agree_full, (d, ref)),
                                        (agree_tiled, (TiledDetector(d, plan), TiledDetector(ref, plan)))):
                s = score_frame(mine.detect(fr.image, 0.0).boxes, theirs.detect(fr.image, 0.0).boxes)
                acc[0] += s.tp
                acc[1] += s.fp
                acc[2] += s.fn
            s = score_frame(d.detect(fr.image, 0.0).boxes, fr.boxes)
            truth[0] += s.tp
            truth[1] += s.fp
            truth[2] += s.fn

        def f1(c: list[int]) -> float:
            return 2 * c[0] / max(1, 2 * c[0] + c[1] + c[2])

        rows.append((name, ms[name], ms[name] / ms["onnxruntime"], diff, f1(agree_full), f1(agree_tiled), f1(truth)))
    print(f"\n{len(labels)} hand-labelled frames; time per pass: median of {args.rounds} interleaved rounds\n")
    print("| backend | ms per pass | x onnxruntime | max abs score diff | F1 vs onnxruntime (full / 2x2 tiles) | "
          "F1 vs labels (full) |\n|---|---|---|---|---|---|")
    for name, t, ratio, diff, af, at, tr in rows:
        print(f"| {name} | {t:.1f} | {ratio:.2f} | {diff:.4f} | {af:.3f} / {at:.3f} | {tr:.3f} |")

    with tempfile.TemporaryDirectory() as cache:
        os.environ["TRAFFICGEO_CACHE_DIR"] = cache
        t0 = time.perf_counter()
        auto = OnnxDetector(path, format="nanodet", threads=args.threads, backend="auto", int8_model=int8)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        OnnxDetector(path, format="nanodet", threads=args.threads, backend="auto", int8_model=int8)
        again = time.perf_counter() - t0
    print(f"\nprobe (backend auto): {auto.backend_choice.summary()}; detector built in {first:.2f} s with the probe, "
          f"{again:.2f} s from the cache")

    from trafficgeo.video.pipeline import LEARNED_TRACKER
    from trafficgeo.video.track import VehicleTracker

    files = sorted((ROOT.parent / "shared" / "data" / "ngsim-us101-frames" / "seq2").glob("frame_*.jpg"))
    if files:
        images = [cv2.imread(str(f)) for f in files]
        tiled = TiledDetector(ref, grid_plan(images[0].shape[:2], 2))
        found = [tiled.detect(im, 0.0) for im in images]
        tracker = VehicleTracker(10.0, LEARNED_TRACKER)
        spent = []
        for det in found:
            t0 = time.perf_counter()
            tracker.update(det)
            spent.append(1e3 * (time.perf_counter() - t0))
        print(f"tracker: {np.mean(spent):.2f} ms per frame mean, {np.percentile(spent, 95):.2f} ms 95th percentile "
              f"({len(files)} NGSIM seq2 frames, {np.mean([len(d) for d in found]):.0f} detections a frame)")


if __name__ == "__main__":
    main()
