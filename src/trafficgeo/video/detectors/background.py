"""The weight-free detector for a **fixed** camera (:class:`BackgroundDetector`): background subtraction (OpenCV
MOG2 or KNN with shadow detection) on a downscaled frame, then morphology, connected components, an optional region
of interest, the merging of a vehicle's parts and the splitting of blobs of touching vehicles, and, given a calibrated
camera and a road surface, a size filter and a size-based class in metres on the ground (:mod:`.sizes`). It finds
what moves: vehicles that touch in the image often stay one blob."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np

from trafficgeo.errors import InputError
from trafficgeo.groups import group_pairs
from trafficgeo.video.detections import Detections, check_image, check_roi
from trafficgeo.video.detectors.blobs import (
    Blobs,
    merge_candidates,
    split_mask,
    tight_part,
    union_boxes,
)
from trafficgeo.video.detectors.sizes import SizeRules, blob_ground_size, classify_sizes

if TYPE_CHECKING:
    from trafficgeo.camera.model import Camera
    from trafficgeo.geo.mapping import Surface

WARMUP_FRAMES = 20  # warm-up frames kept for the initial background (their per-pixel mode)
# s of video the background detector learns on before it reports anything; below the 4 s that `process` primes
# it on (pipeline.PRIME_S). On the demo world's bench 3 s counted 90.0 % per lane, 2 s 77.3 %, 1.67 s 84.5 %.
WARMUP_S = 3.0
GAIN_STEP = 8  # grid step (detection-scale px) of the pixels that measure a frame's brightness


# ---------------------------------------------------------------------------------------------------- background
def temporal_mode(frames: Sequence[np.ndarray], tol: int = 10) -> np.ndarray:
    """The most frequent colour of each pixel over ``frames`` (K images (H, W, 3) uint8): per pixel, the frame
    whose colour is within ``tol`` grey levels (every channel) of the most other frames. In dense traffic the road
    is visible less than half of the time far from the camera, so a median shows vehicles; the passing vehicles'
    colours differ from each other, the road's does not. O(K^2) image comparisons, done once."""
    k = len(frames)
    if k < 3:
        return frames[-1].copy()
    support = np.zeros((k, *frames[0].shape[:2]), dtype=np.uint8)
    lo, hi = (0, 0, 0), (tol, tol, tol)
    for i in range(k):
        for j in range(i + 1, k):
            close = cv2.inRange(cv2.absdiff(frames[i], frames[j]), lo, hi) // 255
            support[i] += close
            support[j] += close
    best = np.argmax(support, axis=0)
    stack = np.stack(frames)
    return np.take_along_axis(stack, best[None, :, :, None], axis=0)[0]


class BackgroundDetector:
    """Moving-vehicle detector for a fixed camera by background subtraction; needs no weights.

    Per frame (``detect``):

    1. The frame is downscaled by ``scale`` (INTER_AREA; default 0.5 for speed). During the first ``warmup_s``
       seconds of video (frame times, whatever the frame rate) nothing is reported: up to 20 of their frames,
       evenly spaced in time, are kept, and their per-pixel temporal mode
       (:func:`temporal_mode`: the colour seen most often, which in traffic is the road's even where vehicles cover
       it more than half of the time) initialises OpenCV's MOG2 (or KNN) model (``detectShadows=True``). From
       then on every frame updates the model with ``learning_rate`` per frame, by default ``1 / history``, a fixed
       slow rate (OpenCV's automatic rate, ``1 / min(2 * frames, history)``, is fast for the first hundreds of
       frames and absorbs uniformly coloured vehicles into the background); with MOG2 a vehicle that stops becomes
       background after about ``0.1 / learning_rate`` frames (2 s at 25 fps by default), and so does a ghost left
       where a vehicle stood during the warm-up. Before the update, with ``compensate_gain``, the frame is scaled
       to the brightness of the initial background (the median brightness ratio over a sparse pixel grid): a slow
       learning rate cannot follow auto-exposure or clouds.
    2. Foreground = pixels marked 255; shadows (marked 127: darker than the background by a factor between
       ``shadow_threshold`` and 1 with the same colour) are dropped. Dark grey vehicle faces on a grey road can
       pass for shadows: their blobs lose those faces. The ROI mask (bool (H, W), full resolution), if any, is
       applied here: nothing outside it is foreground.
    3. Morphology: opening with an ``open_px`` ellipse removes speckle noise (and the flicker of edges of a
       shaking camera), closing with a ``close_px`` ellipse joins a vehicle's parts (sizes in full-frame pixels,
       odd and at least 3 px at detection scale; by default no closing, which joins vehicles close in the image).
    4. Connected components (8-connectivity) of at least ``min_area_px`` full-frame pixels become blobs.
    5. **Merging** (``merge=True``): two blobs whose column ranges overlap by at least half the narrower one's
       width and whose vertical gap is at most a quarter of the smaller one's height (:func:`merge_candidates`)
       may be one vehicle broken in two (a windshield and a body whose colour is close to the road's). With a
       camera they are merged when the union is a plausible vehicle and at least one part is not; without, when
       the smaller part has at most half the pixels of the larger (vehicles one behind the other in a lane are
       stacked the same way, and are similar in size).
    6. **Splitting** (``split=True``, single-component blobs not touching the left or right frame border, at most
       3 levels, :func:`split_mask`): vehicles that touch in the image (side by side, or one partly hiding
       another) make one blob whose outline has a notch, a vehicle's own outline is nearly convex. The blob is
       cut through its deepest notches (convexity defects) when they are deeper than ``rules.defect_ratio`` (0.15)
       times the blob's smaller side. With a camera only blobs that are not plausible as one vehicle or whose
       bottom edge is wider on the ground than ``rules.split_lanes`` lane widths (1.6 x 3.5 m) are cut; the
       latter also, without a notch, at the column of minimum foreground density if it is a valley (below
       ``rules.valley_ratio`` of the densest column on each side). Without a camera notches must be twice as
       deep. Vehicles exactly one behind the other in one lane stay one blob.
    7. With a ``camera`` and a road ``surface`` (both or neither), the **class and size filter**
       (:func:`blob_ground_size`, :func:`classify_sizes`): the blob's ground length follows from its box for an
       assumed vehicle height (the bottom edge is on the road, the top edge is the far end of the roof); the class
       is the one of ``rules.classes`` (car 3-5.3 m long and 1.2-1.8 m high, van 4.6-7.5 m / 1.8-2.9 m, truck 7.5-25
       m / 2.6-4.3 m) whose heights give lengths within its length range, or nearest to it. "truck" covers trucks
       and buses: both are long and high, a blob cannot tell them apart. A "car" shorter than 3 m and narrower than
       1.4 m is a "motorcycle". The blob is kept when its class fits within a factor 1.65, its length is within
       1.2-25 m and its bottom edge is 0.5-6 m wide on the ground, and, with ``keep_merged``, also when it is longer
       than a car (the shortest class) or wider than 6 m but could not be split (vehicles hiding each other:
       dropping the blob would lose them all, keeping it makes at least one track). Blobs too small for a vehicle
       are dropped. A blob cut by the frame border (its ground contact or its extent is not seen) is kept without
       the size check. A blob no single vehicle explains (kept by ``keep_merged``, or cut by the border and not
       plausible) and a "truck" whose foreground fills less than ``rules.truck_min_fill`` of its box (vehicles
       merged into one blob leave empty corners, a truck's body does not) have class ``""`` (unknown). Without a
       camera every blob is kept and its class is ``""``.
    8. Score: the blob's fill ratio, foreground pixels / box area (in (0, 1]): compact vehicles score high, sparse
       noise or merged clutter low.

    Not thread-safe (the background model is state); use one detector per video. ``detect`` needs the frames'
    times (s, increasing): the warm-up is counted in them.
    """

    learns_background = True  # it learns the scene from every frame (process then detects on every frame)

    def fresh(self) -> BackgroundDetector:
        """A detector with the same options that has learnt nothing yet: ``process`` gives each segment of video
        its own, learnt on the video before it, so that a resumed run detects as an uninterrupted one."""
        return BackgroundDetector(**self._settings)

    def __init__(self, *, method: str = "mog2", scale: float = 0.5, warmup_s: float = WARMUP_S,
                 learning_rate: float | None = None, history: int = 500, threshold: float | None = None,
                 shadow_threshold: float = 0.5, camera: Camera | None = None,
                 surface: Surface | None = None, roi: np.ndarray | None = None, min_area_px: float | None = None,
                 open_px: float | None = None, close_px: float | None = None, merge: bool = True,
                 split: bool = True, rules: SizeRules | None = None, compensate_gain: bool = True,
                 keep_merged: bool = True) -> None:
        """Options (pixels are full-frame pixels; :meth:`fresh` gives an untrained detector with the same ones):

        Args:
            method: "mog2" or "knn" (OpenCV background subtractors).
            scale: downscale factor of the frame the model runs on (0 < scale <= 1).
            warmup_s: seconds of video (from the first frame's time) whose frames' temporal mode initialises the
                background; nothing is reported for them (longer in dense traffic). The first frame at or after
                ``warmup_s`` is detected in. With 0 the first frame initialises it (nothing is reported for it).
            learning_rate: background learning rate per frame in [0, 1] (default ``1 / history``), or -1 for
                OpenCV's automatic rate.
            history: frames of history of the model.
            shadow_threshold: a pixel darker than the background by a factor in [shadow_threshold, 1] with the same
                colour is a shadow and ignored (OpenCV's ``tau``; raise it if dark grey vehicles go undetected,
                lower it if dark shadows are detected).
            threshold: MOG2 ``varThreshold`` (squared Mahalanobis distance, default 16) or KNN ``dist2Threshold``
                (squared distance, default 400).
            camera, surface: calibrated camera and road surface for the metric size filter, class and splitting.
            roi: bool (H, W) region of interest at full resolution (True = watched).
            min_area_px: smallest blob area (px^2); default 5e-5 of the frame area (104 px^2 at 1920x1080: a car
                about 15 px tall).
            open_px, close_px: sizes of the opening and closing ellipses; default frame width / 400 and 0 (no
                closing: it joins neighbouring vehicles into one blob; 0 disables either).
            merge, split: merge the parts of a vehicle; split blobs of several vehicles.
            rules: metric size rules (:class:`SizeRules`).
            compensate_gain: scale each frame to the brightness of the initial background (camera auto-exposure,
                passing clouds) before the model sees it.
            keep_merged: keep blobs too long or too wide for one vehicle that could not be split (step 7): fewer
                boxes match one vehicle, more vehicles are counted.
        """
        self._settings = dict(method=method, scale=scale, warmup_s=warmup_s, learning_rate=learning_rate,
                              history=history, threshold=threshold, shadow_threshold=shadow_threshold, camera=camera,
                              surface=surface, roi=roi, min_area_px=min_area_px, open_px=open_px, close_px=close_px,
                              merge=merge, split=split, rules=rules, compensate_gain=compensate_gain,
                              keep_merged=keep_merged)
        method = method.lower().strip()
        if method not in ("mog2", "knn"):
            raise InputError(f"BackgroundDetector: unknown method {method!r}; use 'mog2' or 'knn'")
        if not (np.isfinite(scale) and 0 < scale <= 1):
            raise InputError(f"BackgroundDetector: scale {scale!r} must be in (0, 1], e.g. 0.5")
        if not (np.isfinite(warmup_s) and warmup_s >= 0):
            raise InputError(f"BackgroundDetector: warmup_s {warmup_s!r} must be a number of seconds >= 0, e.g. 3")
        if learning_rate is None:
            learning_rate = 1.0 / history if history >= 1 else -1.0
        if not (learning_rate == -1 or (np.isfinite(learning_rate) and 0 <= learning_rate <= 1)):
            raise InputError(f"BackgroundDetector: learning_rate {learning_rate!r} must be in [0, 1] or -1 (auto)")
        if int(history) != history or history < 1:
            raise InputError(f"BackgroundDetector: history {history!r} must be a whole number of frames >= 1")
        if threshold is not None and not (np.isfinite(threshold) and threshold > 0):
            raise InputError(f"BackgroundDetector: threshold {threshold!r} must be positive")
        if not (np.isfinite(shadow_threshold) and 0 < shadow_threshold < 1):
            raise InputError(f"BackgroundDetector: shadow_threshold {shadow_threshold!r} must be in (0, 1), e.g. 0.5")
        if (camera is None) != (surface is None):
            raise InputError("BackgroundDetector: the metric size filter needs both a camera and a road surface; "
                             "give both or neither")
        for name, value in (("min_area_px", min_area_px), ("open_px", open_px), ("close_px", close_px)):
            if value is not None and not (np.isfinite(value) and value >= 0):
                raise InputError(f"BackgroundDetector: {name} {value!r} must be >= 0")
        self.method = method
        self.scale = float(scale)
        self.warmup_s = float(warmup_s)
        self.learning_rate = float(learning_rate)
        self.camera = camera
        self.surface = surface
        self.roi = None if roi is None else np.asarray(roi)
        self.min_area_px = min_area_px
        self.open_px = open_px
        self.close_px = close_px
        self.merge = merge
        self.split = split
        self.rules = rules or SizeRules()
        self.frames_seen = 0
        if method == "mog2":
            self._model = cv2.createBackgroundSubtractorMOG2(history=int(history), varThreshold=threshold or 16.0,
                                                             detectShadows=True)
        else:
            self._model = cv2.createBackgroundSubtractorKNN(history=int(history), dist2Threshold=threshold or 400.0,
                                                            detectShadows=True)
        self._model.setShadowThreshold(float(shadow_threshold))
        self._buffer: list[np.ndarray] = []
        self._t_first: float | None = None  # time (s) of the first frame
        self._t_kept = -np.inf  # time (s) of the last warm-up frame kept in the buffer
        self._ready = False  # the background model is initialised
        self._shape: tuple[int, int] | None = None
        self._memo: dict[tuple[float, ...], tuple[str, float, bool, float]] = {}
        self._m = 1.0
        if camera is not None:
            from trafficgeo.crs import metres_per_unit
            from trafficgeo.geo.mapping import camera_crs

            crs = camera_crs(camera)
            self._m = metres_per_unit(crs) if crs is not None else 1.0
        self._small: tuple[int, int] = (0, 0)
        self._roi_small: np.ndarray | None = None
        self._open: np.ndarray | None = None
        self._close: np.ndarray | None = None
        self._min_area = 0.0
        self.last_mask: np.ndarray | None = None  # the last cleaned foreground mask (small image), for inspection
        self.background: np.ndarray | None = None  # the initial background (small image) once warmed up
        self.compensate_gain = bool(compensate_gain)
        self.keep_merged = bool(keep_merged)
        self.gain = 1.0  # brightness of the last frame relative to the initial background
        self._ref: np.ndarray | None = None
        self._ref_ok: np.ndarray | None = None

    # ---------------------------------------------------------------- set-up on the first frame
    def _setup(self, shape: tuple[int, int]) -> None:
        h, w = shape
        if self.camera is not None and tuple(self.camera.image_size) != (w, h):
            cw, ch = self.camera.image_size
            raise InputError(f"BackgroundDetector: frames are {w}x{h} px but the camera is calibrated for {cw}x{ch}; "
                             "use the camera of this video (or rescale it)")
        sw, sh = max(1, round(w * self.scale)), max(1, round(h * self.scale))
        self._small = (sw, sh)
        self._sx, self._sy = w / sw, h / sh
        if self.roi is not None:
            roi = check_roi(self.roi, (h, w))
            small = cv2.resize(roi.astype(np.uint8) * 255, (sw, sh), interpolation=cv2.INTER_AREA)
            self._roi_small = np.where(small >= 128, 255, 0).astype(np.uint8)
        open_px = w / 400.0 if self.open_px is None else self.open_px
        # No closing by default: it joins vehicles that are close in the image (far away, or one behind the other)
        # into one blob far more often than it mends a vehicle (its parts are merged by step 5 instead).
        close_px = 0.0 if self.close_px is None else self.close_px
        # Odd sizes: an even kernel has no centre pixel and shifts the mask by a pixel.
        ko = max(3, 2 * round(0.5 * (open_px / self._sx - 1)) + 1) if open_px > 0 else 1
        kc = max(3, 2 * round(0.5 * (close_px / self._sx - 1)) + 1) if close_px > 0 else 1
        self._open = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (ko, ko)) if ko > 1 else None
        self._close = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (kc, kc)) if kc > 1 else None
        min_area = 5e-5 * w * h if self.min_area_px is None else self.min_area_px
        self._min_area = max(1.0, min_area / (self._sx * self._sy))
        self._shape = (h, w)

    def _in_warmup(self, time_s: float) -> bool:
        """Is a frame at ``time_s`` (s) a warm-up frame (the first frame always is)?"""
        if not np.isfinite(time_s):
            raise InputError(f"BackgroundDetector: frame time {time_s!r} is not a number of seconds")
        if self._ready:
            return False
        if self._t_first is None:
            return True
        return time_s - self._t_first < self.warmup_s - 1e-9

    # ---------------------------------------------------------------- per frame
    def foreground(self, image: np.ndarray, time_s: float) -> np.ndarray:
        """Update the model with ``image`` taken at ``time_s`` (s) and return the cleaned foreground mask (uint8
        0/255) at detection scale (steps 1-3 of the class docstring); all zero for warm-up frames."""
        image = check_image(image)
        time_s = float(time_s)
        if self._shape is None:
            self._setup(image.shape[:2])
        elif image.shape[:2] != self._shape:
            raise InputError(f"BackgroundDetector: frame size changed from {self._shape[1]}x{self._shape[0]} to "
                             f"{image.shape[1]}x{image.shape[0]} px; use one detector per video")
        small = image if self._small == (image.shape[1], image.shape[0]) else \
            cv2.resize(image, self._small, interpolation=cv2.INTER_AREA)
        self.frames_seen += 1
        if self._in_warmup(time_s):
            if self._t_first is None:
                self._t_first = time_s
            # Up to WARMUP_FRAMES frames evenly spaced in time over the warm-up, whatever the frame rate.
            if time_s - self._t_kept >= self.warmup_s / WARMUP_FRAMES - 1e-9 and len(self._buffer) < WARMUP_FRAMES:
                self._buffer.append(small.copy() if small is image else small)
                self._t_kept = time_s
            self.last_mask = np.zeros(small.shape[:2], dtype=np.uint8)
            return self.last_mask
        if not self._ready:
            self._initialise()
        if self.compensate_gain and self._ref is not None:
            small = self._compensate(small)
        fg = self._model.apply(small, learningRate=self.learning_rate)
        _, mask = cv2.threshold(fg, 200, 255, cv2.THRESH_BINARY)  # 255 = foreground, 127 = shadow, 0 = background
        if self._roi_small is not None:
            mask = cv2.bitwise_and(mask, self._roi_small)
        if self._open is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._open)
        if self._close is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._close)
        self.last_mask = mask
        return mask

    def _initialise(self) -> None:
        """Initialise the model with the per-pixel temporal mode of the buffered warm-up frames."""
        background = temporal_mode(self._buffer)
        self._buffer = []
        self._ready = True
        self._model.apply(background, learningRate=1.0)  # 1 = re-initialise the model from this image
        if self.method == "knn":  # KNN fills its sample memories only over several updates
            for _ in range(5):
                self._model.apply(background, learningRate=0.5)
        self.background = background
        ref = background[::GAIN_STEP, ::GAIN_STEP].mean(axis=2)
        self._ref_ok = (ref > 16) & (ref < 240)
        self._ref = ref[self._ref_ok]
        if self._ref.size < 16:
            self._ref = None

    def _compensate(self, small: np.ndarray) -> np.ndarray:
        """``small`` scaled to the brightness of the initial background (the median ratio over a sparse grid)."""
        cur = small[::GAIN_STEP, ::GAIN_STEP].mean(axis=2)[self._ref_ok]
        gain = float(np.median(cur / self._ref))
        self.gain = gain
        if gain > 0 and abs(gain - 1.0) > 0.005:
            return cv2.convertScaleAbs(small, alpha=1.0 / gain)
        return small

    @property
    def warming_up(self) -> bool:
        """True until the background model is initialised (by the first frame after the warm-up)."""
        return not self._ready

    def detect(self, image: np.ndarray, time_s: float) -> Detections:
        """Vehicles moving in ``image`` ((H, W, 3) uint8 BGR) taken at ``time_s`` (s); empty during the warm-up
        (the first ``warmup_s`` seconds)."""
        learning = self._in_warmup(float(time_s))
        mask = self.foreground(image, time_s)
        if learning:
            return Detections.empty()
        self._memo.clear()
        # BBDT: several times faster than the default algorithm on sparse masks in OpenCV 4.x/5.x.
        _, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_BBDT)
        keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= self._min_area) + 1
        if keep.size == 0:
            return Detections.empty()
        s = stats[keep]
        boxes = np.column_stack([s[:, 0], s[:, 1], s[:, 0] + s[:, 2] - 1, s[:, 1] + s[:, 3] - 1]).astype(np.float64)
        blobs = Blobs(boxes, s[:, cv2.CC_STAT_AREA].astype(np.float64), [[int(k)] for k in keep])
        if self.merge and len(keep) > 1:
            blobs = self._merge(blobs)
        if self.split:
            blobs = self._split(blobs, labels)
        classes = np.full(len(blobs.areas), "", dtype=object)
        if self.camera is not None and self.surface is not None and len(blobs.areas):
            blobs, classes = self._metric(blobs)
        full = self._to_full(blobs.boxes)
        box_area = (blobs.boxes[:, 2] - blobs.boxes[:, 0] + 1) * (blobs.boxes[:, 3] - blobs.boxes[:, 1] + 1)
        scores = np.clip(blobs.areas / np.maximum(box_area, 1.0), 0.0, 1.0)
        return Detections(full, scores, classes)

    def _to_full(self, boxes: np.ndarray) -> np.ndarray:
        """Inclusive small-image pixel boxes -> full-frame boxes (pixel-centre convention: the blob's outer edges)."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        out = np.empty_like(b)
        out[:, 0] = b[:, 0] * self._sx - 0.5
        out[:, 2] = (b[:, 2] + 1) * self._sx - 0.5
        out[:, 1] = b[:, 1] * self._sy - 0.5
        out[:, 3] = (b[:, 3] + 1) * self._sy - 0.5
        return out

    def _measure(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(classes, length_m, plausible, width_m) of small-image boxes (memoised within a frame)."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        keys = [tuple(row) for row in b.tolist()]
        new = [k for k in dict.fromkeys(keys) if k not in self._memo]
        if new:
            sizes = blob_ground_size(self.camera, self.surface, self._to_full(np.array(new)),
                                     metres_per_unit=self._m)
            classes, length, plausible = classify_sizes(sizes, self.rules)
            for k, row in enumerate(new):
                self._memo[row] = (classes[k], length[k], plausible[k], sizes.width_m[k])
        out = [self._memo[k] for k in keys]
        return (np.array([o[0] for o in out], dtype=object), np.array([o[1] for o in out], dtype=np.float64),
                np.array([o[2] for o in out], dtype=bool), np.array([o[3] for o in out], dtype=np.float64))

    def _merge(self, blobs: Blobs) -> Blobs:
        """Merge the parts of one vehicle (step 5 of the class docstring)."""
        pairs = merge_candidates(blobs.boxes)
        if pairs.size == 0:
            return blobs
        i, j = pairs[:, 0], pairs[:, 1]
        if self.camera is not None and self.surface is not None:
            single = self._measure(blobs.boxes)[2]
            union = np.column_stack([np.minimum(blobs.boxes[i, :2], blobs.boxes[j, :2]),
                                     np.maximum(blobs.boxes[i, 2:], blobs.boxes[j, 2:])])
            ok = self._measure(union)[2] & ~(single[i] & single[j])
        else:
            a, b = blobs.areas[i], blobs.areas[j]
            ok = np.minimum(a, b) <= 0.5 * np.maximum(a, b)
        groups = group_pairs(len(blobs.areas), pairs[ok])
        if len(groups) == len(blobs.areas):
            return blobs
        return Blobs(union_boxes(blobs.boxes, groups), np.array([blobs.areas[g].sum() for g in groups]),
                      [[lab for k in g for lab in blobs.labels[k]] for g in groups])

    def _split(self, blobs: Blobs, labels: np.ndarray) -> Blobs:
        """Split blobs of merged vehicles (:func:`split_mask`, at most 3 levels): any single-component blob with a
        deep notch; with a camera, also at a density valley when wider on the ground than ``rules.split_lanes``
        lanes. Blobs touching the left or right frame border and blobs made by merging are left whole."""
        rules = self.rules
        sw, _sh = self._small
        metric = self.camera is not None and self.surface is not None
        boxes, areas, ids = list(blobs.boxes), list(blobs.areas), list(blobs.labels)
        masks: list[np.ndarray | None] = [None] * len(boxes)  # the crop of a part made by a split
        todo = [i for i in range(len(boxes)) if len(ids[i]) == 1]
        for _level in range(3):
            if not todo:
                break
            wide = np.zeros(len(todo), dtype=bool)
            suspect = np.ones(len(todo), dtype=bool)
            if metric:
                _cls, _len, plausible, width = self._measure(np.array([boxes[i] for i in todo]))
                with np.errstate(invalid="ignore"):
                    wide = width > rules.split_lanes * rules.lane_width_m
                suspect = wide | ~plausible
            ratio = rules.defect_ratio if metric else 2.0 * rules.defect_ratio
            nxt = []
            for i, is_wide, is_suspect in zip(todo, wide, suspect, strict=True):
                x1, y1, x2, y2 = (int(v) for v in boxes[i])
                if not is_suspect or x1 <= 0 or x2 >= sw - 1:
                    continue
                crop = masks[i] if masks[i] is not None else labels[y1:y2 + 1, x1:x2 + 1] == ids[i][0]
                parts = split_mask(crop, defect_ratio=ratio, valley_ratio=rules.valley_ratio if is_wide else None)
                if parts is None:
                    continue
                new = [tight_part(p, x1, y1) for p in parts]
                boxes[i], areas[i], masks[i] = new[0]
                boxes.append(new[1][0])
                areas.append(new[1][1])
                masks.append(new[1][2])
                ids.append(ids[i])
                nxt += [i, len(boxes) - 1]
            todo = nxt
        keep = [i for i in range(len(boxes)) if areas[i] >= self._min_area]
        return Blobs(np.array([boxes[i] for i in keep], dtype=np.float64).reshape(-1, 4),
                      np.array([areas[i] for i in keep], dtype=np.float64), [ids[i] for i in keep])

    def _metric(self, blobs: Blobs) -> tuple[Blobs, np.ndarray]:
        """The size filter and the classes (step 6 of the class docstring)."""
        sw, sh = self._small
        classes, length, single, width = self._measure(blobs.boxes)
        classes = classes.copy()
        b = blobs.boxes
        # keep_merged: longer than the shortest class allows (a car), or too wide, yet not split: vehicles that hide
        # each other (seen along the road from a low camera). Dropped, all of them would be lost.
        shortest = min(spec[1] for spec in self.rules.classes.values())
        with np.errstate(invalid="ignore"):
            merged = self.keep_merged & ~single & ((length > shortest) | (width > self.rules.max_width_m))
        # Cut by the frame border, a blob's ground size is not measurable: it is kept without the size check.
        cut = (b[:, 0] <= 0) | (b[:, 1] <= 0) | (b[:, 2] >= sw - 1) | (b[:, 3] >= sh - 1)
        # A blob that no single vehicle explains (vehicles merged into one blob) has no class: "" (unknown). Nor
        # has a truck-sized blob that fills little of its box: a truck's box-shaped body fills it, vehicles one
        # behind the other or side by side leave empty corners.
        box_area = (b[:, 2] - b[:, 0] + 1) * (b[:, 3] - b[:, 1] + 1)
        sparse = (classes == "truck") & (blobs.areas < self.rules.truck_min_fill * box_area)
        classes[~single | sparse] = ""
        keep = np.flatnonzero(single | merged | cut)
        return Blobs(blobs.boxes[keep], blobs.areas[keep], [blobs.labels[i] for i in keep]), classes[keep]


