"""A tile plan (:class:`TilePlan`): the tiles a detector runs on besides the full frame, each with its zoom, and
what the detector then reaches on each lane (:class:`RegionReach`). Planned by
:func:`trafficgeo.video.detectors.tiling.plan_tiles` (square tiles) or
:func:`trafficgeo.video.detectors.tile_bands.plan_bands` (zoom bands); conventions as in
:mod:`trafficgeo.video.detectors.tiling` (a tile ``(x0, y0, x1, y1)`` is the crop ``image[y0:y1, x0:x1]``;
boxes in full-frame px, pixel-centre convention)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from trafficgeo.errors import InputError
from trafficgeo.video.detectors.tiled import CUT_MARGIN_PX

if TYPE_CHECKING:
    from trafficgeo.video.detectors.tiling import RoadSamples

__all__ = ["LINE_SHORT_SHARE", "REFERENCE_CAR_M", "LineReach", "RegionReach", "TilePlan", "box_size_px"]

REFERENCE_CAR_M = (4.4, 1.8, 1.5)  # length, width, height (m): the small vehicle that must be detectable


def box_size_px(boxes: ArrayLike) -> np.ndarray:
    """The size (px) of boxes (N, 4) ``x1, y1, x2, y2``: their shorter side (see the module docstring)."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    return np.minimum(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])



# ---------------------------------------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class RegionReach:
    """How well the detector sees one lane (or the ROI) with a plan.

    Attributes:
        name: lane name, or ``"ROI"``.
        in_view_m: road in view (not hidden, inside the frame): metres of lane, or m^2 for the ROI.
        full_frame_m: of it, where the reference car reaches the minimum size in the full frame.
        tiles_m: where it reaches it only in a tile.
        beyond_m: where it stays below the minimum size even at the maximum zoom.
        beyond_distance_m: (nearest, farthest) horizontal distance (m) from the camera of that part; None if none.
        in_view_distance_m: (nearest, farthest) distance (m) of the road in view; None if none.
        unit: ``"m"`` (metres of lane) or ``"m2"`` (ROI area).
    """

    name: str
    in_view_m: float
    full_frame_m: float
    tiles_m: float
    beyond_m: float
    beyond_distance_m: tuple[float, float] | None
    in_view_distance_m: tuple[float, float] | None
    unit: str = "m"


LINE_SHORT_SHARE = 0.1  # a line warns when more than this share of it (in view) is below the detector's reach


@dataclass(frozen=True)
class LineReach:
    """How well the detector sees vehicles crossing one counting line with a plan.

    Attributes:
        name: the counting line's name.
        in_view: share of the line's sample points in view.
        short: share of the points in view where the reference car, crossing the line, stays below the minimum size
            in the detector input over the full frame and the tiles.
        input_px: (smallest, largest) size (px, shorter side) of that car in the detector input over those short
            points (over all the points in view when none is short); None when no point is in view.
        distance_m: (nearest, farthest) horizontal distance (m) from the camera of the same points; None likewise.
    """

    name: str
    in_view: float
    short: float
    input_px: tuple[float, float] | None
    distance_m: tuple[float, float] | None


@dataclass(frozen=True, eq=False)
class TilePlan:
    """Tiles for one camera (see the module docstring).

    Attributes:
        frame_shape: (H, W) of the frames.
        input_size: the detector's square input (px).
        min_size_px: the size (px, shorter side) the reference car must reach in the detector input.
        max_upscale: the largest zoom of a tile (input_size / tile side).
        tiles: (K, 4) int ``x0, y0, x1, y1`` (crop ``image[y0:y1, x0:x1]``), from the farthest road to the nearest.
        regions: per lane (or the ROI), what the detector sees with the plan.
        samples: the road points the plan was made for.
        size_px: (N,) the reference car's size at each sample in full-frame px (NaN: not in view).
        best_input_px: (N,) its largest size in the detector input over the full frame and the tiles that hold it
            whole (NaN: not in view).
        source: what the road was taken from: ``"lanes"``, ``"roi"`` or ``"lines"`` (a band of road around each
            counting line, when neither lanes nor an ROI are given); ``""`` for a plan made otherwise.
        lines: per counting line, what the detector reaches there
            (:func:`~trafficgeo.video.detectors.tiling.line_reach`); empty when no lines were given.
    """

    frame_shape: tuple[int, int]
    input_size: int
    min_size_px: float
    max_upscale: float
    tiles: np.ndarray
    regions: tuple[RegionReach, ...] = ()
    samples: RoadSamples | None = None
    size_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    best_input_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    vehicle_m: tuple[float, float, float] = REFERENCE_CAR_M
    camera_xy: np.ndarray = field(default_factory=lambda: np.zeros(2), repr=False)  # camera (x, y), CRS units
    unit_m: float = 1.0  # metres per CRS unit
    cut_margin_px: float = CUT_MARGIN_PX  # see cut_by_tile
    tile_input_hw: np.ndarray | None = None  # (K, 2) model input (h, w) px per tile; None: input_size square
    full_input_hw: tuple[int, int] | None = None  # model input (h, w) px of the full frame; None: square
    source: str = ""
    lines: tuple[LineReach, ...] = ()

    def __post_init__(self) -> None:
        h, w = (int(v) for v in self.frame_shape)
        object.__setattr__(self, "frame_shape", (h, w))
        tiles = np.asarray(self.tiles, dtype=np.int64).reshape(-1, 4)
        bad = ((tiles[:, 0] < 0) | (tiles[:, 1] < 0) | (tiles[:, 2] > w) | (tiles[:, 3] > h)
               | (tiles[:, 2] - tiles[:, 0] < 2) | (tiles[:, 3] - tiles[:, 1] < 2))
        if bad.any():
            raise InputError(f"tile plan: tile {tiles[np.argmax(bad)].tolist()} is not inside the {w}x{h} frame; give "
                             "x0, y0, x1, y1 pixel indices with 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height")
        object.__setattr__(self, "tiles", tiles)
        if self.tile_input_hw is not None:
            hw = np.asarray(self.tile_input_hw, dtype=np.int64).reshape(-1, 2)
            if hw.shape[0] != tiles.shape[0] or (hw < 1).any():
                raise InputError(f"tile plan: {hw.shape[0]} tile input sizes for {tiles.shape[0]} tiles; give one "
                                 "positive (h, w) per tile")
            object.__setattr__(self, "tile_input_hw", hw)
        if self.full_input_hw is not None:
            object.__setattr__(self, "full_input_hw", tuple(int(v) for v in self.full_input_hw))

    @property
    def full_scale(self) -> float:
        """Scale of the full frame into the detector input (letterbox: the input's side / the frame's)."""
        ih, iw = self.full_input_hw or (self.input_size, self.input_size)
        return min(ih / self.frame_shape[0], iw / self.frame_shape[1])

    @property
    def tile_scales(self) -> np.ndarray:
        """(K,) scale of each tile into the detector input (letterbox)."""
        t = self.tiles.astype(np.float64)
        th, tw = t[:, 3] - t[:, 1], t[:, 2] - t[:, 0]
        if self.tile_input_hw is None:
            return self.input_size / np.maximum(tw, th)
        return np.minimum(self.tile_input_hw[:, 0] / th, self.tile_input_hw[:, 1] / tw)

    @property
    def tile_inputs_hw(self) -> np.ndarray:
        """(K, 2) model input (h, w) px of each tile."""
        if self.tile_input_hw is not None:
            return self.tile_input_hw
        return np.full((len(self.tiles), 2), self.input_size, dtype=np.int64)

    @property
    def added_input_pixels(self) -> int:
        """Detector-input pixels the tiles add per frame (besides :attr:`full_input_pixels`)."""
        return int(np.prod(self.tile_inputs_hw, axis=1).sum())

    @property
    def full_input_pixels(self) -> int:
        """Detector-input pixels of the full frame's pass."""
        ih, iw = self.full_input_hw or (self.input_size, self.input_size)
        return int(ih * iw)

    @property
    def added_frame_pixels(self) -> int:
        """Frame pixels the tiles crop per frame (overlaps counted once per tile)."""
        t = self.tiles.astype(np.int64)
        return int(np.sum((t[:, 2] - t[:, 0]) * (t[:, 3] - t[:, 1])))

    def input_size_px(self, boxes: ArrayLike) -> np.ndarray:
        """The largest size (shorter side, px) boxes (N, 4) (full-frame px) have in the detector input over the full
        frame and the tiles holding them whole (the part of a box inside the frame)."""
        raw = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        b = clip_boxes(raw, self.frame_shape)
        size = box_size_px(raw)
        best = size * self.full_scale
        if len(self.tiles):
            inside = tiles_holding(self.tiles, b, self.frame_shape, self.cut_margin_px)  # (K, N)
            scaled = np.where(inside, size[None, :] * self.tile_scales[:, None], -np.inf)
            best = np.maximum(best, scaled.max(axis=0))
        return best

    def summary_lines(self) -> list[str]:
        """The plan in words, for the terminal: the tiles, then a warning per lane with road beyond reach."""
        s = self.input_size
        car = f"a car {self.vehicle_m[0]:g} m long"
        lines = []
        in_view = np.isfinite(self.size_px)
        if not in_view.any():
            lines.append("tiling: no part of the counted road is in view; check the "
                         + ("counting lines" if self.source == "lines" else "lanes or the ROI"))
        elif not len(self.tiles):
            smallest = float(np.nanmin(self.best_input_px))
            lines.append(f"tiling: not needed - {car} is at least {smallest:.0f} px across in the detector's {s} px "
                         "input everywhere on the road in view")
        else:
            sides = np.maximum(self.tiles[:, 2] - self.tiles[:, 0], self.tiles[:, 3] - self.tiles[:, 1])
            tiled = self._tiled_distance_m()
            where = f" over the road {tiled[0]:.0f}-{tiled[1]:.0f} m from the camera" if tiled else ""
            zoom = self.tile_scales
            n = len(self.tiles)
            total = self.full_input_pixels + self.added_input_pixels
            lines.append(f"tiling: {n} tile{'s' if n > 1 else ''} of {sides.min()}-{sides.max()} px (zoom "
                         f"{zoom.min():.2f}-{zoom.max():.2f}x){where} besides the full frame: the detector runs "
                         f"{n + 1} times per frame on {total / 1e6:.2f} Mpx of input "
                         f"({total / self.full_input_pixels:.1f}x the full frame's)")
        if self.source == "lines" and in_view.any():
            lines[0] += ("; planned around the counting lines (a band of road across each), as neither lanes nor "
                         "an ROI were given")
        lines.extend(self.warnings())
        return lines

    def warnings(self) -> list[str]:
        """One warning per lane (or the ROI) with road where the reference car stays below the minimum size."""
        out = []
        car = f"a car {self.vehicle_m[0]:g} m long"
        for r in self.regions if self.source != "lines" else ():  # a line band: the line's own warning says it
            if r.beyond_m <= 0 or r.beyond_distance_m is None:
                continue
            what = f"lane {r.name}" if r.unit == "m" else "the ROI"
            share = r.beyond_m / max(r.in_view_m, 1e-9)
            amount = f"{r.beyond_m:.0f} m of it" if r.unit == "m" else f"{share:.0%} of it"
            lo, hi = r.beyond_distance_m
            out.append(f"{what}: {amount}, {lo:.0f}-{hi:.0f} m from the camera, is too far for the detector: {car} "
                       f"stays below {self.min_size_px:g} px across in its {self.input_size} px input even at "
                       f"{self.max_upscale:g}x zoom, so vehicles there may go undetected and uncounted; count nearer "
                       "the camera, or film with a longer lens or a higher resolution")
        return out + self.line_warnings()

    def line_warnings(self) -> list[str]:
        """One warning per counting line where, on more than :data:`LINE_SHORT_SHARE` of it in view, the reference
        car crossing it stays below the minimum size in the detector input (with the tiles of this plan)."""
        out = []
        car = f"a car {self.vehicle_m[0]:g} m long"
        for r in self.lines:
            if r.short <= LINE_SHORT_SHARE or r.input_px is None or r.distance_m is None:
                continue
            (lo, hi), (d0, d1) = r.input_px, r.distance_m
            size = f"{lo:.0f} px" if round(lo) == round(hi) else f"{lo:.0f}-{hi:.0f} px"
            where = f"{d0:.0f} m" if round(d0) == round(d1) else f"{d0:.0f}-{d1:.0f} m"
            if len(self.tiles):  # tiles are planned over the line already: they zoom as far as they may
                fix = (f"the tiles there already zoom {self.max_upscale:g}x, as far as they may; count nearer the "
                       "camera, or film with a longer lens or a higher resolution")
            else:
                fix = ("plan tiles there (they are planned over the counting lines, lanes or an ROI when tiling is "
                       "on), count nearer the camera, or film with a longer lens or a higher resolution")
            out.append(f"counting line {r.name}: {car} crossing it ({where} from the camera) is only {size} across in "
                       f"the detector's input on {r.short:.0%} of the line, below the {self.min_size_px:g} px the "
                       f"detector needs, so vehicles there may go undetected and uncounted; {fix}")
        return out

    def _tiled_distance_m(self) -> tuple[float, float] | None:
        full = self.size_px * self.full_scale >= self.min_size_px
        tiled = np.isfinite(self.size_px) & ~full & (self.best_input_px > self.size_px * self.full_scale)
        if self.samples is None or not tiled.any():
            return None
        d = horizontal_distance_m(self.samples.xyz[tiled], self.camera_xy, self.unit_m)
        return float(d.min()), float(d.max())

    def to_dict(self) -> dict[str, object]:
        """The plan for the report / JSON (plain Python types)."""
        return {
            "input_size": self.input_size, "min_size_px": self.min_size_px, "max_upscale": self.max_upscale,
            "vehicle_m": list(self.vehicle_m), "frame_shape": list(self.frame_shape),
            "tiles": self.tiles.astype(int).tolist(), "passes_per_frame": len(self.tiles) + 1,
            "tile_input_hw": self.tile_inputs_hw.astype(int).tolist(),
            "full_input_hw": list(self.full_input_hw or (self.input_size, self.input_size)),
            "full_input_pixels": self.full_input_pixels,
            "added_input_pixels": self.added_input_pixels, "added_frame_pixels": self.added_frame_pixels,
            "regions": [{"name": r.name, "unit": r.unit, "in_view": round(r.in_view_m, 1),
                         "full_frame": round(r.full_frame_m, 1), "tiles_only": round(r.tiles_m, 1),
                         "beyond_reach": round(r.beyond_m, 1),
                         "beyond_distance_m": None if r.beyond_distance_m is None else
                         [round(v, 1) for v in r.beyond_distance_m],
                         "in_view_distance_m": None if r.in_view_distance_m is None else
                         [round(v, 1) for v in r.in_view_distance_m]} for r in self.regions],
            "source": self.source,
            "lines": [{"name": r.name, "in_view": round(r.in_view, 3), "below_reach": round(r.short, 3),
                       "input_px": None if r.input_px is None else [round(v, 1) for v in r.input_px],
                       "distance_m": None if r.distance_m is None else [round(v, 1) for v in r.distance_m]}
                      for r in self.lines],
            "line_warnings": self.line_warnings(),
            "warnings": self.warnings(),
        }


def horizontal_distance_m(xyz: np.ndarray, camera_xy: np.ndarray, mpu: float) -> np.ndarray:
    return np.hypot(xyz[:, 0] - camera_xy[0], xyz[:, 1] - camera_xy[1]) * mpu


def clip_boxes(boxes: np.ndarray, frame_shape: tuple[int, int]) -> np.ndarray:
    h, w = frame_shape
    out = boxes.copy()
    out[:, [0, 2]] = np.clip(out[:, [0, 2]], -0.5, w - 0.5)
    out[:, [1, 3]] = np.clip(out[:, [1, 3]], -0.5, h - 0.5)
    return out


def tiles_holding(tiles: np.ndarray, boxes: np.ndarray, frame_shape: tuple[int, int], margin_px: float = CUT_MARGIN_PX
              ) -> np.ndarray:
    """(K, N) whether tile k (x0, y0, x1, y1 pixel indices) holds box n (pixel-centre convention, clipped to the
    frame) whole: inside it, and more than ``margin_px`` from every tile edge that is not a frame edge (what
    :func:`cut_by_tile` would take for a cut vehicle)."""
    h, w = frame_shape
    t = tiles.astype(np.float64)[:, None, :]
    b = boxes[None, :, :]
    edge = t - 0.5
    inner = np.stack([t[..., 0] > 0, t[..., 1] > 0, t[..., 2] < w, t[..., 3] < h], axis=-1)
    lo_pad = np.where(inner[..., :2], margin_px, -1e-6)
    hi_pad = np.where(inner[..., 2:], margin_px, -1e-6)
    with np.errstate(invalid="ignore"):
        return (np.all(b[..., :2] > edge[..., :2] + lo_pad, axis=-1)
                & np.all(b[..., 2:] < edge[..., 2:] - hi_pad, axis=-1))


def region_reaches(samples: RoadSamples, seen: np.ndarray, full_ok: np.ndarray, reached: np.ndarray, dist_m: np.ndarray,
             unit: str) -> tuple[RegionReach, ...]:
    out = []
    for name in dict.fromkeys(samples.region.tolist()):
        mine = samples.region == name
        per = samples.area_m2 / (samples.widths_m.get(name, 1.0) if unit == "m" else 1.0)
        v = mine & seen
        full = v & full_ok
        tiles = v & ~full_ok & reached
        beyond = v & ~reached
        out.append(RegionReach(
            name=str(name), in_view_m=float(per[v].sum()), full_frame_m=float(per[full].sum()),
            tiles_m=float(per[tiles].sum()), beyond_m=float(per[beyond].sum()),
            beyond_distance_m=(float(dist_m[beyond].min()), float(dist_m[beyond].max())) if beyond.any() else None,
            in_view_distance_m=(float(dist_m[v].min()), float(dist_m[v].max())) if v.any() else None, unit=unit))
    return tuple(out)
