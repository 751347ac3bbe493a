"""The tiled detector of :mod:`trafficgeo.video.detectors.tiling`: a base detector run on the full frame and on
each tile of a :class:`~trafficgeo.video.detectors.tile_plan.TilePlan`, its tile boxes shifted to the frame, those cut
by a tile's inner edge dropped, and everything merged. Pixels follow :mod:`trafficgeo.video.detections`: a tile
``(x0, y0, x1, y1)`` is the crop ``image[y0:y1, x0:x1]``, a box at ``x`` in the crop is at ``x + x0`` in the frame."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.video.detections import Detections, check_image, check_roi, in_roi

if TYPE_CHECKING:
    from trafficgeo.video.detectors.schedule import TileSchedule
    from trafficgeo.video.detectors.tile_plan import TilePlan

CUT_MARGIN_PX = 2.0  # a tile box this near (px) to a tile edge inside the frame is of a vehicle the tile cuts


def merge_boxes(boxes: np.ndarray, scores: np.ndarray, source: np.ndarray, *, iou: float = 0.5,
                containment: float = 0.8) -> np.ndarray:
    """Indices of the boxes kept, best score first: class-agnostic non-maximum suppression at ``iou``, and a box
    whose intersection with a kept box from *another* source (the full frame, a tile) covers ``containment`` of the
    smaller one is dropped too (a vehicle's part seen in a tile). Within one source the base detector's own choice
    stands: a car mostly hidden behind a truck is a vehicle of its own."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    n = b.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")
    b = b[order]
    src = np.asarray(source)[order]
    iw = np.clip(np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0]), 0, None)
    ih = np.clip(np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 1], b[None, :, 1]), 0, None)
    inter = iw * ih
    area = np.clip(b[:, 2] - b[:, 0], 0, None) * np.clip(b[:, 3] - b[:, 1], 0, None)
    union = area[:, None] + area[None, :] - inter
    smaller = np.minimum(area[:, None], area[None, :])
    suppress = (inter >= iou * np.maximum(union, 1e-9)) | (
        (inter >= containment * np.maximum(smaller, 1e-9)) & (src[:, None] != src[None, :]))
    np.fill_diagonal(suppress, False)
    dead = np.zeros(n, dtype=bool)
    keep = []
    for i in range(n):  # greedy over the score order; each step is one vectorised row
        if dead[i]:
            continue
        keep.append(i)
        dead |= suppress[i]
    return order[np.asarray(keep, dtype=np.int64)]


def cut_by_tile(boxes: np.ndarray, tile: Sequence[int], frame_shape: tuple[int, int],
                margin_px: float = CUT_MARGIN_PX) -> np.ndarray:
    """(N,) whether boxes (N, 4) (frame px) touch an edge of ``tile`` that is not an edge of the frame (within
    ``margin_px``): a vehicle cut by the tile, seen only in part."""
    h, w = frame_shape
    x0, y0, x1, y1 = (float(v) for v in tile)
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    cut = np.zeros(b.shape[0], dtype=bool)
    if x0 > 0:
        cut |= b[:, 0] <= x0 - 0.5 + margin_px
    if y0 > 0:
        cut |= b[:, 1] <= y0 - 0.5 + margin_px
    if x1 < w:
        cut |= b[:, 2] >= x1 - 0.5 - margin_px
    if y1 < h:
        cut |= b[:, 3] >= y1 - 0.5 - margin_px
    return cut


class TiledDetector:
    """A :class:`~trafficgeo.video.detections.Detector` running ``base`` on the full frame and on each tile of
    ``plan`` (the base letterboxes every crop to its own input size; ``base.detect_batch(crops)`` is used for the
    tiles of each size when it exists; with a plan giving input sizes (``tile_input_hw``, ``full_input_hw``) it is
    called with ``input_hw=`` per size), then shifting the tile boxes to the frame, dropping those cut by a tile's
    inner edge (:func:`cut_by_tile`) and merging all with :func:`merge_boxes`.

    ``base`` must not filter by an ROI of its own (its frames are crops): give ``roi`` (bool (H, W)) here instead;
    boxes whose bottom centre lies outside it are dropped after the merge.

    With a ``schedule`` (:class:`~trafficgeo.video.detectors.schedule.TileSchedule`, set as an attribute), each
    frame runs only the tiles it chooses; a still tile gives its last detections again, the others none.
    """

    def __init__(self, base: object, plan: TilePlan, *, iou: float = 0.5, containment: float = 0.8,
                 roi: np.ndarray | None = None) -> None:
        if getattr(base, "roi", None) is not None and len(plan.tiles):
            raise ValueError("TiledDetector: the base detector has an ROI; it would see crops, not frames - build it "
                             "without one and give the ROI to TiledDetector")
        if (plan.tile_input_hw is not None or plan.full_input_hw is not None) and not hasattr(base, "detect_batch"):
            raise InputError("tiled detector: the plan gives each tile its own input size, but the detector has no "
                             "detect_batch(images, input_hw=...); plan square tiles for it (plan_tiles)")
        self.base, self.plan = base, plan
        self.iou, self.containment = float(iou), float(containment)
        self.roi = None if roi is None else check_roi(roi, plan.frame_shape, "TiledDetector roi")
        self.schedule: TileSchedule | None = None  # None: every tile on every frame
        self._last: list[Detections] = [Detections.empty() for _ in range(len(plan.tiles))]

    def last_state(self) -> dict[str, np.ndarray]:
        """Each tile's last detections (those a still tile gives again), as arrays for a checkpoint."""
        tiles = np.concatenate([np.full(len(d), t, dtype=np.int64) for t, d in enumerate(self._last)]
                               or [np.zeros(0, dtype=np.int64)])
        last = Detections.concatenate(self._last) if self._last else Detections.empty()
        return {"last_tile": tiles, "last_box": last.boxes.astype(np.float64),
                "last_score": last.scores.astype(np.float64), "last_class": np.asarray(last.classes, dtype=str)}

    def restore_last(self, arrays: dict[str, np.ndarray]) -> None:
        """Put back a :meth:`last_state`; :class:`ValueError` if it is not one of these tiles."""
        try:
            tiles = np.asarray(arrays["last_tile"], dtype=np.int64)
            boxes = np.asarray(arrays["last_box"], dtype=np.float64).reshape(-1, 4)
            scores = np.asarray(arrays["last_score"], dtype=np.float64)
            classes = np.asarray(arrays["last_class"]).astype(object)
        except (KeyError, ValueError, TypeError) as exc:
            raise ValueError(f"the tiles' last detections are damaged ({exc})") from None
        n = tiles.size
        if boxes.shape[0] != n or scores.size != n or classes.size != n or (n and not (
                0 <= tiles.min() and tiles.max() < len(self._last))):
            raise ValueError("the tiles' last detections are not of these tiles")
        self._last = [Detections(boxes[tiles == t], scores[tiles == t], classes[tiles == t])
                      for t in range(len(self._last))]

    def detect(self, image: np.ndarray, time_s: float = 0.0) -> Detections:
        """Vehicles in ``image`` ((H, W, 3) uint8 BGR) at ``time_s`` s, boxes in full-frame px."""
        image = check_image(image)
        shape = image.shape[:2]
        if shape != self.plan.frame_shape:
            raise InputError(f"tiled detector: a {shape[1]}x{shape[0]} frame, but the tiles were planned for "
                             f"{self.plan.frame_shape[1]}x{self.plan.frame_shape[0]} frames; plan them for this video")
        plan = self.plan
        if plan.full_input_hw is None:
            full = self.base.detect(image, time_s)
        else:
            full = self.base.detect_batch([image], input_hw=plan.full_input_hw)[0]
        k_all = len(plan.tiles)
        if self.schedule is not None and k_all:
            run, reuse = self.schedule.choose(image)
        else:
            run, reuse = np.ones(k_all, dtype=bool), np.zeros(k_all, dtype=bool)
        chosen = np.flatnonzero(run)
        crops = [image[y0:y1, x0:x1] for x0, y0, x1, y1 in plan.tiles[chosen]]
        sized = plan.tile_input_hw is not None
        if not crops:
            parts = [full]
        elif hasattr(self.base, "detect_batch"):  # one call per crop and input size (a batch holds one size)
            found: list[Detections | None] = [None] * len(crops)
            keys = [(c.shape, tuple(plan.tile_input_hw[t]) if sized else None) for t, c in zip(chosen, crops,
                                                                                               strict=True)]
            for key in dict.fromkeys(keys):
                idx = [k for k, kk in enumerate(keys) if kk == key]
                batch = [crops[k] for k in idx]
                dets = self.base.detect_batch(batch, input_hw=key[1]) if sized else self.base.detect_batch(batch)
                for k, det in zip(idx, dets, strict=True):
                    found[k] = det
            parts = [full, *found]
        else:
            parts = [full, *(self.base.detect(c, time_s) for c in crops)]
        for t, det in zip(chosen, parts[1:], strict=True):
            tile = plan.tiles[t]
            boxes = det.boxes + np.array([tile[0], tile[1], tile[0], tile[1]], dtype=np.float64)
            whole = ~cut_by_tile(boxes, tile, shape, self.plan.cut_margin_px)
            self._last[t] = Detections(boxes[whole], det.scores[whole], det.classes[whole])
        kept = [full]
        sources = [np.zeros(len(full), dtype=np.int64)]
        for t in np.flatnonzero(run | reuse):
            if len(self._last[t]):
                kept.append(self._last[t])
                sources.append(np.full(len(self._last[t]), t + 1, dtype=np.int64))
        merged = Detections.concatenate(kept)
        pick = merge_boxes(merged.boxes, merged.scores, np.concatenate(sources), iou=self.iou,
                           containment=self.containment)
        out = merged.select(pick)
        if self.roi is not None and len(out):
            out = out.select(in_roi(self.roi, out.bottom_centres, shape))
        return out
