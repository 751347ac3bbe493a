"""Tiles for a detector whose input size is free (any multiple of 32 px, as the built-in NanoDet): rectangles over
the road, each zoomed just enough, instead of squares at one input size.

A square tile at a fixed 416 px input spends most of its pixels off the road or on road that needs less zoom (a
view along a road is a wedge; the far road needs zoom 1.7x, the middle 0.3-1x). :func:`plan_bands` works in
*bands of zoom* instead:

1. Each road point (:func:`~trafficgeo.video.detectors.tiling.road_view`) needs the zoom
   ``min_size_px / car size there`` (px in the model input per frame px), at most ``max_upscale``; points the full
   frame already serves need none.
2. Sorted from the largest zoom down, points are cut into bands whose zooms lie within a factor ``ratio`` of the
   band's largest; the band runs at that zoom.
3. A band's rectangle is the bounding box of the *large* vehicle (a truck, :data:`LARGE_VEHICLE_M`) standing at each
   of its points (so that every vehicle it serves lies whole in it), split in two along its longer side while the
   two halves' cost is lower (a road that curves or crosses the frame diagonally).
4. The model input of a rectangle is its size times the band's zoom rounded up to multiples of ``stride_px``; the
   rectangle then grows to fill that input's aspect (more context, no grey border), staying in the frame.
5. The cost of a plan is the model input pixels per frame plus ``pass_cost_px`` per run (onnxruntime's fixed cost
   per call); of the ``ratios`` tried, the cheapest plan wins.

Conventions (pixels, tiles, world units) follow :mod:`trafficgeo.video.detectors.tiling`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface
from trafficgeo.video.detectors.tile_plan import REFERENCE_CAR_M, TilePlan, clip_boxes
from trafficgeo.video.detectors.tiled import CUT_MARGIN_PX
from trafficgeo.video.detectors.tiling import LARGE_VEHICLE_M, Road, finish_plan, road_view, vehicle_boxes

__all__ = ["PASS_COST_PX", "input_hw_for", "plan_bands"]

PASS_COST_PX = 8192  # a model run's fixed cost in input pixels (NanoDet-g, onnxruntime, 2 threads: ~1/20 of 416^2)
ZOOM_RATIOS = (1.25, 1.5, 2.0, 3.0)


def input_hw_for(hw_px: tuple[float, float], zoom: float, stride_px: int = 32) -> tuple[int, int]:
    """Model input (h, w) px for a frame region of ``hw_px`` (h, w) px at ``zoom``: rounded up to ``stride_px``."""
    return tuple(max(stride_px, math.ceil(v * zoom / stride_px - 1e-9) * stride_px) for v in hw_px)


def _bbox(boxes: np.ndarray, frame_shape: tuple[int, int]) -> np.ndarray:
    """Integer tile ``x0, y0, x1, y1`` holding ``boxes`` (N, 4) whole (more than the cut margin inside every edge
    that is not a frame edge; see :func:`trafficgeo.video.detectors.tiling._contains`)."""
    h, w = frame_shape
    m = CUT_MARGIN_PX
    x0 = math.floor(boxes[:, 0].min() + 0.5 - m) - 1
    y0 = math.floor(boxes[:, 1].min() + 0.5 - m) - 1
    x1 = math.ceil(boxes[:, 2].max() + 0.5 + m) + 1
    y1 = math.ceil(boxes[:, 3].max() + 0.5 + m) + 1
    return np.array([max(0, x0), max(0, y0), min(w, x1), min(h, y1)], dtype=np.int64)


def _cost(rect: np.ndarray, zoom: float, stride_px: int, pass_cost_px: float) -> float:
    ih, iw = input_hw_for((rect[3] - rect[1], rect[2] - rect[0]), zoom, stride_px)
    return pass_cost_px + ih * iw


def _split(hold: np.ndarray, zoom: float, frame_shape: tuple[int, int], stride_px: int, pass_cost_px: float,
           depth: int = 0) -> list[np.ndarray]:
    """Rectangles holding the boxes ``hold`` (N, 4) at ``zoom``: their bounding box, split in two along its longer
    side (at the quartile or median of the box centres that costs least) while that is cheaper."""
    rect = _bbox(hold, frame_shape)
    whole = _cost(rect, zoom, stride_px, pass_cost_px)
    if len(hold) < 2 or depth >= 8:
        return [rect]
    axis = 0 if rect[2] - rect[0] >= rect[3] - rect[1] else 1
    centre = 0.5 * (hold[:, axis] + hold[:, axis + 2])
    best, best_cost = None, whole
    for q in (0.25, 0.5, 0.75):
        cut = np.quantile(centre, q)
        lo = centre <= cut
        if lo.all() or not lo.any():
            continue
        cost = sum(_cost(_bbox(hold[part], frame_shape), zoom, stride_px, pass_cost_px) for part in (lo, ~lo))
        if cost < best_cost:
            best, best_cost = lo, cost
    if best is None:
        return [rect]
    return [*_split(hold[best], zoom, frame_shape, stride_px, pass_cost_px, depth + 1),
            *_split(hold[~best], zoom, frame_shape, stride_px, pass_cost_px, depth + 1)]


def _grow(rect: np.ndarray, zoom: float, frame_shape: tuple[int, int], stride_px: int
          ) -> tuple[np.ndarray, tuple[int, int]]:
    """``rect`` grown about its centre to the frame region its model input covers at ``zoom`` (kept in the frame,
    still holding ``rect``), and that input (h, w) px."""
    h, w = frame_shape
    ih, iw = input_hw_for((rect[3] - rect[1], rect[2] - rect[0]), zoom, stride_px)
    out = rect.copy()
    for k, (size, span) in enumerate(((w, iw), (h, ih))):
        want = min(size, max(int(rect[k + 2] - rect[k]), math.floor(span / zoom)))
        start = round(0.5 * (rect[k] + rect[k + 2]) - 0.5 * want)
        start = min(max(start, 0), size - want)
        start = min(start, int(rect[k]))  # never lose a part of the rectangle to rounding
        out[k], out[k + 2] = start, max(start + want, int(rect[k + 2]))
    return out, (ih, iw)


def _bands(zoom: np.ndarray, ratio: float) -> list[np.ndarray]:
    """Indices of the points per band: sorted by zoom, largest first, each band within ``ratio`` of its first."""
    order = np.argsort(-zoom, kind="stable")
    z = zoom[order]
    out, i = [], 0
    while i < len(order):
        j = int(np.searchsorted(-z, -z[i] / ratio, side="right"))
        j = max(j, i + 1)
        out.append(order[i:j])
        i = j
    return out


def plan_bands(camera: Camera, surface: Surface, road: Road, frame_shape: tuple[int, int] | None = None,
               *, input_size: int = 416, min_size_px: float = 24.0, max_upscale: float = 2.0,
               min_tiled_size_px: float = 16.0, vehicle_m: Sequence[float] = REFERENCE_CAR_M,
               large_vehicle_m: Sequence[float] = LARGE_VEHICLE_M, max_distance_m: float | None = None,
               step_m: float = 1.0, roi_step_px: int = 8, stride_px: int = 32, pass_cost_px: float = PASS_COST_PX,
               ratios: Sequence[float] = ZOOM_RATIOS) -> TilePlan:
    """Rectangular tiles, each with its own model input size, so that the reference car ``vehicle_m`` reaches
    ``min_size_px`` (shorter side) in the model input everywhere on the counted road ``road`` (lanes, a bool ROI
    mask (H, W), or counting lines: a band of road around each) within ``max_distance_m`` (m), at the least input
    pixels per frame (see the module docstring). The full frame runs at ``input_size`` px on its longer side. Points
    that even ``max_upscale`` cannot bring to ``min_tiled_size_px`` get no tile (the plan's warnings name them)."""
    if not (isinstance(stride_px, int) and stride_px >= 1) or not (np.isfinite(pass_cost_px) and pass_cost_px >= 0):
        raise InputError(f"tiling: stride_px {stride_px!r} must be a whole number >= 1 and pass_cost_px "
                         f"{pass_cost_px!r} a number >= 0")
    if not ratios or any(not (np.isfinite(r) and r > 1.0) for r in ratios):
        raise InputError(f"tiling: zoom ratios {list(ratios)!r} must be numbers > 1")
    view = road_view(camera, surface, road, frame_shape, input_size=input_size, min_size_px=min_size_px,
                     max_upscale=max_upscale, min_tiled_size_px=min_tiled_size_px, vehicle_m=vehicle_m,
                     max_distance_m=max_distance_m, step_m=step_m, roi_step_px=roi_step_px)
    h, w = view.frame_shape
    full_zoom = input_size / max(h, w)
    full_hw = input_hw_for((h, w), full_zoom, stride_px)
    full_zoom = min(full_hw[0] / h, full_hw[1] / w)
    size = view.size_px
    with np.errstate(invalid="ignore"):
        need = view.seen & (size * full_zoom < min_size_px) & (size * max_upscale >= min_tiled_size_px)
    idx = np.flatnonzero(need)
    tiles, inputs = np.zeros((0, 4), dtype=np.int64), np.zeros((0, 2), dtype=np.int64)
    if idx.size:
        zoom = np.minimum(min_size_px / size[idx], max_upscale)
        samples = view.samples
        hold = clip_boxes(vehicle_boxes(camera, samples.xyz[idx], samples.heading_deg[idx], large_vehicle_m), (h, w))
        hold = np.where(np.isfinite(hold).all(axis=1)[:, None], hold, clip_boxes(view.car_box[idx], (h, w)))
        best_cost, best_rects = np.inf, []
        for ratio in ratios:
            rects = []
            for band in _bands(zoom, float(ratio)):
                z = float(zoom[band].max())
                rects.extend((r, z) for r in _split(hold[band], z, (h, w), stride_px, pass_cost_px))
            cost = sum(_cost(r, z, stride_px, pass_cost_px) for r, z in rects)
            if cost < best_cost:
                best_cost, best_rects = cost, rects
        grown = [_grow(r, z, (h, w), stride_px) for r, z in best_rects]
        tiles = np.array([g[0] for g in grown], dtype=np.int64).reshape(-1, 4)
        inputs = np.array([g[1] for g in grown], dtype=np.int64).reshape(-1, 2)
    return finish_plan(camera, view, tiles, input_size=input_size, min_size_px=min_size_px, max_upscale=max_upscale,
                       vehicle_m=vehicle_m, tile_input_hw=inputs, full_input_hw=full_hw)
