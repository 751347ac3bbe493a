"""Quality check of the NanoDet-g 416 ONNX model on real frames (dev tool; the product decoder lives elsewhere).

Decodes the six outputs into vehicle boxes, prints counts and writes PNG overlays::

    python tools/nanodet/check_decode.py IMAGE [IMAGE ...] [--model PATH] [--fit letterbox|stretch] [--out DIR]

Decoding: anchors row-major per stride s (8, 16, 32) with centre ((col + 0.5) s, (row + 0.5) s) in network
input px; each side (left, top, right, bottom) is the softmax expectation over its 11 bins times s (44 values =
side-major, 11 consecutive bins per side); score = max sigmoid over the vehicle classes; threshold, then greedy
NMS across vehicle classes (IoU >= 0.5) that also drops a box mostly inside a kept one (intersection / smaller
area >= 0.8). Boxes are returned in full-frame px, pixel-centre convention (model corner-origin minus 0.5).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from build_onnx import DEFAULT_OUT, INPUT_SIZE, MEAN_BGR, STD_BGR, session

STRIDES = (8, 16, 32)
BINS = 11
VEHICLES = {2: "car", 3: "motorcycle", 5: "bus", 7: "truck"}


def fit_image(image_bgr: np.ndarray, fit: str) -> tuple[np.ndarray, tuple[float, float]]:
    """Network input [1, 3, 416, 416] and the (sx, sy) network px per image px; letterbox pads right/bottom."""
    import cv2

    h, w = image_bgr.shape[:2]
    if fit == "stretch":
        sx, sy = INPUT_SIZE / w, INPUT_SIZE / h
        canvas = cv2.resize(image_bgr, (INPUT_SIZE, INPUT_SIZE), interpolation=cv2.INTER_AREA)
    else:
        s = min(INPUT_SIZE / w, INPUT_SIZE / h)
        sx = sy = s
        nw, nh = round(w * s), round(h * s)
        canvas = np.empty((INPUT_SIZE, INPUT_SIZE, 3), np.uint8)
        canvas[:] = np.round(MEAN_BGR).astype(np.uint8)
        canvas[:nh, :nw] = cv2.resize(image_bgr, (nw, nh), interpolation=cv2.INTER_AREA)
    x = (canvas.astype(np.float32) - np.float32(MEAN_BGR)) / np.float32(STD_BGR)
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None]), (sx, sy)


def decode(outputs: list[np.ndarray], side_major: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Six model outputs -> (boxes [N, 4] x1 y1 x2 y2 in network px, corner origin; class scores [N, 80])."""
    boxes, scores = [], []
    for stride, cls, reg in zip(STRIDES, outputs[:3], outputs[3:], strict=True):
        n = INPUT_SIZE // stride
        idx = np.arange(n * n)
        cx, cy = (idx % n + 0.5) * stride, (idx // n + 0.5) * stride
        logits = reg[0].reshape(-1, 4, BINS) if side_major else reg[0].reshape(-1, BINS, 4).transpose(0, 2, 1)
        prob = np.exp(logits - logits.max(axis=2, keepdims=True))
        prob /= prob.sum(axis=2, keepdims=True)
        dist = (prob * np.arange(BINS)).sum(axis=2) * stride
        boxes.append(np.stack([cx - dist[:, 0], cy - dist[:, 1], cx + dist[:, 2], cy + dist[:, 3]], axis=1))
        scores.append(cls[0])
    return np.concatenate(boxes), np.concatenate(scores)


def suppress(boxes: np.ndarray, scores: np.ndarray, iou_max: float = 0.5, inside_max: float = 0.8) -> np.ndarray:
    """Indices kept by greedy NMS with IoU and intersection-over-smaller limits, best score first."""
    order = np.argsort(-scores, kind="stable")
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    keep: list[int] = []
    while order.size:
        i, rest = order[0], order[1:]
        keep.append(int(i))
        ix = np.clip(np.minimum(boxes[i, 2], boxes[rest, 2]) - np.maximum(boxes[i, 0], boxes[rest, 0]), 0, None)
        iy = np.clip(np.minimum(boxes[i, 3], boxes[rest, 3]) - np.maximum(boxes[i, 1], boxes[rest, 1]), 0, None)
        inter = ix * iy
        iou = inter / (area[i] + area[rest] - inter)
        inside = inter / np.minimum(area[i], area[rest])
        order = rest[(iou < iou_max) & (inside < inside_max)]
    return np.array(keep, dtype=np.int64)


def detect(sess, image_bgr: np.ndarray, fit: str = "letterbox", threshold: float = 0.25, side_major: bool = True):
    """Vehicle boxes (full-frame px, pixel-centre convention), scores and COCO class ids for one BGR image."""
    x, (sx, sy) = fit_image(image_bgr, fit)
    boxes, cls = decode(sess.run(None, {"input": x}), side_major)
    ids = np.array(sorted(VEHICLES))
    best = cls[:, ids].argmax(axis=1)
    score = cls[np.arange(len(cls)), ids[best]]
    sel = np.flatnonzero(score >= threshold)
    keep = sel[suppress(boxes[sel], score[sel])]
    full = boxes[keep] / np.array([sx, sy, sx, sy]) - 0.5
    return full, score[keep], ids[best[keep]]


def main(argv: list[str] | None = None) -> int:
    import cv2

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("images", type=Path, nargs="+")
    parser.add_argument("--model", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--fit", choices=("letterbox", "stretch"), default="letterbox")
    parser.add_argument("--threshold", type=float, default=0.25)
    parser.add_argument("--bin-major", action="store_true", help="decode with the other bin ordering (to compare)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/nanodet_check"))
    args = parser.parse_args(argv)
    sess = session(args.model.read_bytes())
    args.out.mkdir(parents=True, exist_ok=True)
    for path in args.images:
        img = cv2.imread(str(path))
        boxes, scores, classes = detect(sess, img, args.fit, args.threshold, not args.bin_major)
        names = [VEHICLES[int(c)] for c in classes]
        wh = boxes[:, 2:] - boxes[:, :2]
        counts = {n: names.count(n) for n in sorted(set(names))}
        med = np.median(wh, axis=0) if len(wh) else (0, 0)
        print(f"{path}: {len(boxes)} vehicles {counts}, median box {med[0]:.0f}x{med[1]:.0f} px, "
              f"scores {scores.min() if len(scores) else 0:.2f}..{scores.max() if len(scores) else 0:.2f}")
        vis = img.copy()
        for (x1, y1, x2, y2), s, n in zip(boxes, scores, names, strict=True):
            cv2.rectangle(vis, (round(x1), round(y1)), (round(x2), round(y2)), (0, 255, 0), 1)
            cv2.putText(vis, f"{n[:3]} {s:.2f}", (round(x1), round(y1) - 2), cv2.FONT_HERSHEY_PLAIN, 0.7,
                        (0, 255, 255), 1)
        tag = f"{path.parent.name}_{path.stem}_{args.fit}{'_binmajor' if args.bin_major else ''}"
        out = args.out / f"{tag}.png"
        cv2.imwrite(str(out), cv2.resize(vis, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST))
        print(f"  overlay {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
