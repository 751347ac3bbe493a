"""The built-in learned detector as ``process`` runs it: NanoDet-g (shipped in the package, never downloaded) on the
full frame plus camera-aware tiles over the counted road (:mod:`trafficgeo.video.detectors.tiling`), with each
vehicle's class taken from its size on the ground.

A COCO detector's class labels are unreliable on traffic cameras (cars seen from above are often called trucks),
while a calibrated camera measures a vehicle's length on the road: :class:`SizeClasses` gives every box the class
its ground size fits (:func:`trafficgeo.video.detectors.sizes.classify_sizes`), ``""`` (unknown) where no class
fits, and keeps the box either way (whether a box is a vehicle is the detector's call, not the size rule's).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.video.detections import Detections, Detector
from trafficgeo.video.detectors.builtin import builtin_model, builtin_model_path
from trafficgeo.video.detectors.onnx import OnnxDetector
from trafficgeo.video.detectors.sizes import SizeRules, blob_ground_size, broadside_heavy, classify_sizes
from trafficgeo.video.detectors.tile_bands import plan_bands
from trafficgeo.video.detectors.tile_plan import TilePlan
from trafficgeo.video.detectors.tiled import TiledDetector
from trafficgeo.video.detectors.tiling import line_reach, plan_tiles

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.mapping import Surface
    from trafficgeo.site.lanes import Lanes
    from trafficgeo.site.lines import CountLine
    from trafficgeo.video.detectors.backends import BackendChoice

BUILTIN = "nanodet"
# How the tiles are planned: "squares" (plan_tiles: square tiles at the model's 416 px input) or "bands"
# (plan_bands: rectangles, each at its own input size, ~2.5x fewer input pixels on the demo camera). Demo world,
# every 3rd frame (bench_video): squares 96.4 % per-lane counts, bands 93.6 % (24 or 32 px), 95.5 % (48 px).
TILINGS = ("squares", "bands")
BANDS_MIN_SIZE_PX = 32.0  # the size (px, shorter side) bands bring a car to: NanoDet's recall is >= 0.96 above 32


class SizeClasses:
    """A :class:`~trafficgeo.video.detections.Detector` whose boxes get the class their size on the ground fits
    (``camera`` and ``surface``: the calibrated camera and the road), ``""`` where none fits, except that a box
    wider on the ground than any van is long is a truck or bus seen broadside (:func:`broadside_heavy`)."""

    def __init__(self, base: Detector, camera: Camera, surface: Surface, rules: SizeRules | None = None) -> None:
        self.base, self.camera, self.surface = base, camera, surface
        self.rules = rules or SizeRules()
        self.plan: TilePlan | None = getattr(base, "plan", None)

    def detect(self, image: np.ndarray, time_s: float = 0.0) -> Detections:
        """The base detector's boxes in ``image`` ((H, W, 3) uint8 BGR), classes from their ground size."""
        det = self.base.detect(image, time_s)
        if not len(det):
            return det
        sizes = blob_ground_size(self.camera, self.surface, det.boxes)
        classes, _length_m, plausible = classify_sizes(sizes, self.rules)
        named = np.where(plausible, classes, "").astype(object)
        named[~plausible & broadside_heavy(sizes, self.rules)] = "truck"
        return Detections(det.boxes, det.scores, named)


def make_learned_detector(*, camera: Camera | None = None, surface: Surface | None = None,
                          road: Lanes | np.ndarray | None = None, roi: np.ndarray | None = None, tiles: bool = True,
                          conf: float | None = None, iou: float = 0.5, threads: int | None = None,
                          tiling: str = "squares", lines: Sequence[CountLine] | None = None,
                          backend: str | None = None) -> Detector:
    """The built-in learned detector. With a calibrated ``camera`` and its ``surface`` and a counted ``road`` (lanes,
    else the ``roi`` mask, else a band of road around each counting line of ``lines``), tiles are planned so that
    vehicles on that road are large enough for it (``tiles``) and classes come from the ground size; the plan is the
    detector's ``plan`` (None without tiling), with what it reaches at each of the ``lines``
    (:func:`~trafficgeo.video.detectors.tiling.line_reach`: its line warnings). ``roi`` (bool (H, W)) keeps boxes
    whose bottom centre lies inside it. ``conf``: the score threshold (default the model's). ``tiling``: one of
    :data:`TILINGS`. ``backend``: the runtime
    (:class:`~trafficgeo.video.detectors.onnx.OnnxDetector`; ``"auto"`` probes for the fastest); its choice is
    :func:`detector_backend`'s."""
    if tiling not in TILINGS:
        raise InputError(f"tiling {tiling!r}: use one of {', '.join(TILINGS)}")
    model = builtin_model(BUILTIN)
    path = builtin_model_path(BUILTIN)
    area = road if road is not None else roi if roi is not None else (list(lines) if lines else None)
    plan = None
    if tiles and camera is not None and surface is not None and area is not None:
        if tiling == "bands":
            plan = plan_bands(camera, surface, area, input_size=model.input_size_px, min_size_px=BANDS_MIN_SIZE_PX)
        else:
            plan = plan_tiles(camera, surface, area, input_size=model.input_size_px)
        if lines:
            object.__setattr__(plan, "lines", line_reach(plan, camera, surface, lines))
    tiled = plan is not None and len(plan.tiles) > 0
    base: Detector = OnnxDetector(path, format=model.layout, conf=conf, iou=iou, roi=None if tiled else roi,
                                  threads=threads, backend=backend,
                                  int8_model=builtin_model_path(BUILTIN, int8=True) if model.int8 else None)
    if plan is not None:
        base = TiledDetector(base, plan, iou=iou, roi=roi if tiled else None)  # its plan, even with no tile
    if camera is not None and surface is not None:
        base = SizeClasses(base, camera, surface)
    return base


def detector_plan(detector: object) -> TilePlan | None:
    """The tile plan a detector runs with (:func:`make_learned_detector`), or None."""
    return getattr(detector, "plan", None)


def _layers(detector: object) -> Iterator[object]:
    """The detector, then the ``base`` of each wrapper inside it (size classes, tiles), outermost first."""
    seen = 0
    while detector is not None and seen < 8:
        yield detector
        detector, seen = getattr(detector, "base", None), seen + 1


def tiled_detector(detector: object) -> TiledDetector | None:
    """The :class:`~trafficgeo.video.detectors.tiled.TiledDetector` inside a detector (the size-class wrapper), or
    None."""
    return next((d for d in _layers(detector) if isinstance(d, TiledDetector)), None)


def detector_backend(detector: object) -> BackendChoice | None:
    """The runtime choice (:class:`~trafficgeo.video.detectors.backends.BackendChoice`) of an ONNX detector, also
    inside the tiled and size-class wrappers; None for other detectors or one built without ``backend``."""
    return next((c for d in _layers(detector) if (c := getattr(d, "backend_choice", None)) is not None), None)
