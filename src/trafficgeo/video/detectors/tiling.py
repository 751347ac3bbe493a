"""Camera-aware tiling for a learned detector: run it on the full frame plus zoomed tiles over the far road.

A detector with a small square input (NanoDet at 416 px) sees a 1920 px frame shrunk 4.6 times: a car 150 m away,
~15 px across in the frame, becomes ~3 px in its input, far below the ~16-24 px it needs. The calibration tells how
big a vehicle is at each point of the road, so the tiles can be planned once per camera:

* :func:`vehicle_size_px` - the **size** of a reference vehicle in the image: the *shorter side* of the axis-aligned
  box of its projected cuboid (full-frame px). The shorter side, not ``sqrt(area)``: a detector's feature cells
  must span the object both ways, and a car seen side-on far away (40 x 12 px) is as hard to find as its 12 px
  suggest; for a car seen end-on (the usual view along a road) both measures nearly agree.
* :func:`plan_tiles` -> :class:`TilePlan` - square tiles (full-frame px), each run at the detector's input size (a
  tile of side ``T`` is scaled by ``input_size / T``, at most ``max_upscale``), chosen greedily from the farthest
  road (smallest vehicles, smallest tiles) to the nearest so that the reference car reaches ``min_size_px`` in the
  detector input everywhere on the counted road, and so that a *large* vehicle (a truck) at any road point lies whole
  in the tile that serves that point (the tiles overlap by that vehicle's extent). No tiles when the full frame
  suffices. The plan reports, per lane (or for the ROI), the road that stays too small even at the maximum zoom.
* The counted road is the lanes (:func:`lane_samples`), else the ROI (:func:`roi_samples`), else a band of road
  around each counting line (:func:`line_samples`: :data:`LINE_BAND_ALONG_M` beyond each end of the line and
  :data:`LINE_BAND_ACROSS_M` to each side, so vehicles are tracked before and after it), so that the simplest run
  (counting lines only) still tiles the far lines. :func:`line_reach` tells, per counting line, how large a car
  crossing it is in the detector input with a plan (the plan's line warnings).
* :class:`~trafficgeo.video.detectors.tile_plan.TilePlan` holds a plan and what it reaches per lane.
* :class:`~trafficgeo.video.detectors.tiled.TiledDetector` - a
  :class:`~trafficgeo.video.detections.Detector` running a base detector on the full frame and on every tile crop,
  dropping tile boxes cut by a tile's inner edge and merging everything.

World coordinates are in the camera's CRS and its units; vehicle dimensions and distances are metres; pixels
follow :mod:`trafficgeo.video.detections` (pixel-centre convention). A tile ``(x0, y0, x1, y1)`` is the crop
``image[y0:y1, x0:x1]`` (integer pixel indices, ends excluded): a box at ``x`` in the crop is at ``x + x0`` in the
frame, and the tile spans ``x0 - 0.5 .. x1 - 0.5`` in box coordinates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import shapely
from numpy.typing import ArrayLike

from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.cuboids import VEHICLE_DIMENSIONS, cuboid_boxes
from trafficgeo.geo.mapping import Surface, camera_crs, pixels_to_world, world_to_pixels
from trafficgeo.site.lanes import Lanes
from trafficgeo.site.lines import CountLine
from trafficgeo.video.detections import check_roi
from trafficgeo.video.detectors.tile_plan import (
    REFERENCE_CAR_M,
    LineReach,
    TilePlan,
    box_size_px,
    clip_boxes,
    horizontal_distance_m,
    region_reaches,
    tiles_holding,
)
from trafficgeo.video.detectors.tiled import CUT_MARGIN_PX

__all__ = ["LARGE_VEHICLE_M", "LINE_BAND_ACROSS_M", "LINE_BAND_ALONG_M", "RoadSamples", "RoadView", "finish_plan",
           "lane_samples", "line_reach", "line_samples", "plan_tiles", "road_view", "roi_samples", "vehicle_boxes",
           "vehicle_size_px"]

LARGE_VEHICLE_M = VEHICLE_DIMENSIONS["truck"]  # the vehicle that must lie whole in a tile (its extent = overlap)
UNKNOWN_HEADINGS_DEG = (0.0, 45.0, 90.0, 135.0)  # tried where the direction of travel is unknown (ROI)
Road = Lanes | np.ndarray | Sequence[CountLine]  # the counted road: lanes, an ROI mask (H, W) or counting lines
LINE_BAND_ALONG_M = 3.0  # m of road planned beyond each end of a counting line (no lanes or ROI given)
LINE_BAND_ACROSS_M = 30.0  # m of road planned to each side of a counting line: ~2 s of travel at 50 km/h


# ---------------------------------------------------------------------------------------------------- sizes
def _mpu(camera: Camera) -> float:
    crs = camera_crs(camera)
    return metres_per_unit(crs) if crs is not None else 1.0



def _boxes_per_heading(camera: Camera, xyz: ArrayLike, heading_deg: ArrayLike, dims_m: Sequence[float]) -> np.ndarray:
    """(N, K, 4) image boxes of the cuboids at K headings each: the given one, or :data:`UNKNOWN_HEADINGS_DEG`
    where it is NaN (K = 1 when no heading is unknown)."""
    pts = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    n = pts.shape[0]
    heading = np.broadcast_to(np.asarray(heading_deg, dtype=np.float64), (n,))
    grid = heading[:, None]
    if np.isnan(heading).any():
        grid = np.where(np.isnan(heading)[:, None], np.asarray(UNKNOWN_HEADINGS_DEG)[None, :], grid)
    k = grid.shape[1]
    length, width, height = (float(v) / _mpu(camera) for v in dims_m)
    return cuboid_boxes(camera, np.repeat(pts, k, axis=0), grid.reshape(-1), length, width, height).reshape(n, k, 4)


def vehicle_boxes(camera: Camera, xyz: ArrayLike, heading_deg: ArrayLike, dims_m: Sequence[float] = REFERENCE_CAR_M,
                  ) -> np.ndarray:
    """Image boxes (N, 4) (full-frame px, unclipped) of level cuboids ``dims_m`` = (length, width, height) in
    metres standing with their footprint centre at ground points ``xyz`` (N, 3; CRS units), heading
    ``heading_deg`` (N,) clockwise from grid north. Where the heading is NaN (unknown), the union of the boxes over
    :data:`UNKNOWN_HEADINGS_DEG`. NaN rows where a corner is behind the camera."""
    boxes = _boxes_per_heading(camera, xyz, heading_deg, dims_m)
    return np.concatenate([boxes[:, :, :2].min(axis=1), boxes[:, :, 2:].max(axis=1)], axis=1)


def vehicle_size_px(camera: Camera, xyz: ArrayLike, heading_deg: ArrayLike,
                    dims_m: Sequence[float] = REFERENCE_CAR_M) -> np.ndarray:
    """Size (px, the shorter side of the projected box; see the module docstring) of a vehicle ``dims_m`` (m) at
    ground points ``xyz`` (N, 3; CRS units) heading ``heading_deg`` (N,) (deg clockwise from grid north). Where the
    heading is NaN, the smallest size over :data:`UNKNOWN_HEADINGS_DEG`. NaN behind the camera."""
    boxes = _boxes_per_heading(camera, xyz, heading_deg, dims_m)
    return box_size_px(boxes.reshape(-1, 4)).reshape(boxes.shape[:2]).min(axis=1)


# ---------------------------------------------------------------------------------------------------- road samples
@dataclass(frozen=True, eq=False)
class RoadSamples:
    """Points of the counted road where vehicles may stand.

    Attributes:
        xyz: (N, 3) ground points (CRS units, on the surface).
        heading_deg: (N,) direction of travel (deg clockwise from grid north, modulo 180; NaN = unknown).
        region: (N,) object array, the lane name (or ``"ROI"``).
        area_m2: (N,) road area each point stands for (m^2).
        widths_m: lane width (m) per region name, to turn areas into lengths of lane (absent for the ROI).
    """

    xyz: np.ndarray
    heading_deg: np.ndarray
    region: np.ndarray
    area_m2: np.ndarray
    widths_m: dict[str, float] = field(default_factory=dict)


def _local_heading_deg(poly: shapely.Geometry, x: np.ndarray, y: np.ndarray, radius: float) -> np.ndarray:
    """Direction (deg clockwise from grid north, modulo 180) of a lane strip at points (x, y): the long axis of the
    smallest rotated rectangle around the part of the lane within ``radius`` of each point (``radius`` about twice
    the lane width, so the part is longer along the lane than across it, at its ends too)."""
    pieces = shapely.intersection(poly, shapely.buffer(shapely.points(x, y), radius, quad_segs=4))
    env = shapely.oriented_envelope(pieces)
    out = np.full(x.shape[0], np.nan)
    rect = shapely.get_type_id(env) == 3  # a polygon (degenerate pieces give points or lines)
    if rect.any():
        corners = np.stack([np.asarray(g.exterior.coords)[:3, :2] for g in env[rect]])  # (N, 3, 2)
        a, b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 1]
        longer = np.where((np.hypot(*a.T) >= np.hypot(*b.T))[:, None], a, b)
        out[rect] = np.degrees(np.arctan2(longer[:, 0], longer[:, 1])) % 180.0
    return out


def lane_samples(lanes: Lanes, surface: Surface, *, step_m: float = 1.0, metres_per_unit_: float = 1.0
                 ) -> RoadSamples:
    """Points on a square grid of ``step_m`` metres inside every lane polygon, at the surface's height, heading
    along their lane (:func:`_local_heading_deg`; a lane is a long strip)."""
    if not (np.isfinite(step_m) and step_m > 0):
        raise InputError(f"tiling: the road sampling step {step_m!r} m must be a positive number of metres")
    step = step_m / metres_per_unit_
    out_xy, out_h, out_r, widths = [], [], [], {}
    for name, poly in zip(lanes.names, lanes.polygons, strict=True):
        x0, y0, x1, y1 = poly.bounds
        gx = np.arange(x0 + 0.5 * step, x1, step)
        gy = np.arange(y0 + 0.5 * step, y1, step)
        X, Y = (a.reshape(-1) for a in np.meshgrid(gx, gy))
        inside = shapely.contains_xy(poly, X, Y)
        X, Y = X[inside], Y[inside]
        widths[name] = 2.0 * poly.area / max(poly.length, 1e-12) * metres_per_unit_
        if X.size == 0:
            continue
        heading = _local_heading_deg(poly, X, Y, 2.0 * widths[name] / metres_per_unit_)
        out_xy.append(np.column_stack([X, Y]))
        out_h.append(heading)
        out_r.append(np.full(X.size, name, dtype=object))
    if not out_xy:
        raise InputError(f"tiling: the lanes ({', '.join(lanes.names)}) are narrower than the {step_m:g} m "
                         "sampling step; give lane polygons of real lanes")
    xy = np.concatenate(out_xy)
    z = np.asarray(surface.elevation(xy[:, 0], xy[:, 1]), dtype=np.float64).reshape(-1)
    return RoadSamples(np.column_stack([xy, z]), np.concatenate(out_h), np.concatenate(out_r),
                       np.full(xy.shape[0], step_m * step_m), widths)


def _line_crossing_heading_deg(line: shapely.LineString) -> float:
    """Direction of travel across a counting line (deg clockwise from grid north, modulo 180): square to its chord
    (first to last vertex)."""
    xy = np.asarray(line.coords, dtype=np.float64)[:, :2]
    d = xy[-1] - xy[0]
    return float((np.degrees(np.arctan2(d[0], d[1])) + 90.0) % 180.0)


def _line_band(line: shapely.LineString, along: float, across: float) -> shapely.Polygon:
    """The band of ground around ``line``: the line stretched by ``along`` beyond each end (along its end
    segments), widened by ``across`` to each side (flat ends); CRS units."""
    xy = np.asarray(line.coords, dtype=np.float64)[:, :2]
    ends = []
    for a, b in ((xy[0], xy[1]), (xy[-1], xy[-2])):
        d = a - b
        ends.append(a + along * d / max(float(np.hypot(*d)), 1e-12))
    stretched = shapely.LineString(np.vstack([ends[0], xy[1:-1], ends[1]]))
    return shapely.buffer(stretched, across, cap_style="flat", join_style="mitre")


def line_samples(lines: Sequence[CountLine], surface: Surface, *, step_m: float = 1.0, metres_per_unit_: float = 1.0,
                 along_m: float = LINE_BAND_ALONG_M, across_m: float = LINE_BAND_ACROSS_M) -> RoadSamples:
    """Points on a square grid of ``step_m`` metres in a band of road around every counting line (``along_m`` m
    beyond its ends, ``across_m`` m to each side; :func:`_line_band`), at the surface's height, heading across the
    line (:func:`_line_crossing_heading_deg`). The region of a point is its line's name, its "lane width" the
    band's length along the line (so the plan's lengths are metres of travel across it)."""
    if not (np.isfinite(step_m) and step_m > 0):
        raise InputError(f"tiling: the road sampling step {step_m!r} m must be a positive number of metres")
    if not lines:
        raise InputError("tiling: no counting lines to plan tiles around; give lanes, an ROI or counting lines")
    step = step_m / metres_per_unit_
    out_xy, out_h, out_r, widths = [], [], [], {}
    for line in lines:
        band = _line_band(line.geometry, along_m / metres_per_unit_, across_m / metres_per_unit_)
        x0, y0, x1, y1 = band.bounds
        X, Y = (a.reshape(-1) for a in np.meshgrid(np.arange(x0 + 0.5 * step, x1, step),
                                                   np.arange(y0 + 0.5 * step, y1, step)))
        inside = shapely.contains_xy(band, X, Y)
        widths[line.name] = line.geometry.length * metres_per_unit_ + 2.0 * along_m
        out_xy.append(np.column_stack([X[inside], Y[inside]]))
        out_h.append(np.full(int(inside.sum()), _line_crossing_heading_deg(line.geometry)))
        out_r.append(np.full(int(inside.sum()), line.name, dtype=object))
    xy = np.concatenate(out_xy)
    z = np.asarray(surface.elevation(xy[:, 0], xy[:, 1]), dtype=np.float64).reshape(-1)
    return RoadSamples(np.column_stack([xy, z]), np.concatenate(out_h), np.concatenate(out_r),
                       np.full(xy.shape[0], step_m * step_m), widths)


def line_reach(plan: TilePlan, camera: Camera, surface: Surface, lines: Sequence[CountLine], *, samples: int = 21
               ) -> tuple[LineReach, ...]:
    """Per counting line, how large the plan's reference car crossing it (heading square to the line, standing at
    ``samples`` points evenly along it) is in the detector input over the full frame and the plan's tiles
    (:meth:`TilePlan.input_size_px`), against the plan's minimum size."""
    mpu = _mpu(camera)
    out = []
    for line in lines:
        at = shapely.line_interpolate_point(line.geometry, np.linspace(0.0, 1.0, samples), normalized=True)
        xy = shapely.get_coordinates(at)[:, :2]
        xyz = np.column_stack([xy, np.asarray(surface.elevation(xy[:, 0], xy[:, 1]), dtype=np.float64).reshape(-1)])
        seen = world_to_pixels(camera, xyz, surface).ok
        best = np.full(samples, np.nan)
        if seen.any():
            boxes = vehicle_boxes(camera, xyz[seen], _line_crossing_heading_deg(line.geometry), plan.vehicle_m)
            best[seen] = plan.input_size_px(boxes)
        seen &= np.isfinite(best)
        if not seen.any():
            out.append(LineReach(line.name, 0.0, 0.0, None, None))
            continue
        short = seen & (best < plan.min_size_px)
        pick = short if short.any() else seen
        dist = horizontal_distance_m(xyz[pick], camera.position[:2], mpu)
        out.append(LineReach(line.name, float(seen.mean()), float(short.sum() / seen.sum()),
                             (float(best[pick].min()), float(best[pick].max())),
                             (float(dist.min()), float(dist.max()))))
    return tuple(out)


def _roi_heading_deg(xy: np.ndarray, radius: float, min_ratio: float = 2.0) -> np.ndarray:
    """Direction (deg clockwise from grid north, modulo 180) of the road at ground points (N, 2) spread evenly over
    it: the major axis of the points within ``radius`` of each, where that neighbourhood is at least ``min_ratio``
    times longer than wide (a road strip); NaN where it is not (a square or a junction: direction unknown)."""
    from scipy.spatial import cKDTree

    n = xy.shape[0]
    out = np.full(n, np.nan)
    if n < 3:
        return out
    tree = cKDTree(xy)
    pairs = tree.query_pairs(radius, output_type="ndarray")  # (P, 2), i < j
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(n)])
    d = xy[cols] - xy[rows]
    count = np.bincount(rows, minlength=n).astype(np.float64)
    mean = np.column_stack([np.bincount(rows, d[:, k], n) for k in (0, 1)]) / count[:, None]
    sxx, syy, sxy = (np.bincount(rows, a * b, n) / count - ma * mb for a, b, ma, mb in
                     ((d[:, 0], d[:, 0], mean[:, 0], mean[:, 0]), (d[:, 1], d[:, 1], mean[:, 1], mean[:, 1]),
                      (d[:, 0], d[:, 1], mean[:, 0], mean[:, 1])))
    half_gap = np.sqrt(0.25 * (sxx - syy) ** 2 + sxy ** 2)
    major, minor = 0.5 * (sxx + syy) + half_gap, 0.5 * (sxx + syy) - half_gap
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # of the major axis, from +x (east) counter-clockwise
    ok = (count >= 3) & (major >= min_ratio ** 2 * np.maximum(minor, 1e-12))
    out[ok] = (90.0 - np.degrees(angle[ok])) % 180.0
    return out


def roi_samples(camera: Camera, surface: Surface, roi: np.ndarray, *, step_px: int = 8,
                heading_radius_m: float = 30.0) -> RoadSamples:
    """The ground points of the ROI mask's pixels on a ``step_px`` grid, each standing for the ground area of its
    ``step_px`` x ``step_px`` cell, heading along the road where the ROI is a strip on the ground
    (:func:`_roi_heading_deg` over ground points about 1 m apart), unknown (NaN) elsewhere."""
    mask = check_roi(roi, (camera.height, camera.width), "tiling ROI")
    s = int(step_px)
    vv, uu = np.mgrid[s // 2:camera.height:s, s // 2:camera.width:s]
    keep = mask[vv, uu]
    uv = np.column_stack([uu[keep], vv[keep]]).astype(np.float64)
    ground = pixels_to_world(camera, np.vstack([uv, uv + [s, 0.0], uv + [0.0, s]]), surface, with_lonlat=False)
    n = uv.shape[0]
    xyz = ground.xyz.reshape(3, n, 3)
    du, dv = xyz[1] - xyz[0], xyz[2] - xyz[0]
    mpu = _mpu(camera)
    area = np.abs(du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0]) * mpu ** 2
    ok = np.all(np.isfinite(xyz[0]), axis=1) & np.isfinite(area)
    pts, area = xyz[0][ok], area[ok]
    # Image samples crowd far away on the ground: thin them to ~1 m for the direction, then spread it back.
    cell = np.floor(pts[:, :2] * mpu)
    _, first, back = np.unique(cell, axis=0, return_index=True, return_inverse=True)
    heading = _roi_heading_deg(pts[first, :2] * mpu, heading_radius_m)[back.reshape(-1)]
    return RoadSamples(pts, heading, np.full(pts.shape[0], "ROI", dtype=object), area)


def _tile_origins(box: np.ndarray, others: np.ndarray, side: int, frame_shape: tuple[int, int], candidates: int,
                  margin_px: float = CUT_MARGIN_PX) -> tuple[np.ndarray, np.ndarray]:
    """Candidate origins (x0s, y0s) of a tile of ``side`` px inside the frame holding ``box`` whole (as
    :func:`tiles_holding` has it): evenly spread over the feasible range, the frame's edges, and those putting a tile
    edge just beyond an edge of one of the ``others`` boxes (M, 4) (at most ``candidates`` of those, by quantile).
    A box that fits nowhere gets the tile centred on it."""
    h, w = frame_shape
    m = margin_px
    out = []
    for k, size in ((0, w), (1, h)):
        lo_edge, hi_edge = box[k], box[k + 2]
        lo = max(0, int(np.ceil(hi_edge + 0.5 + m - side + 1e-9)))
        hi = min(size - side, int(np.floor(lo_edge + 0.5 - m - 1e-9)))
        aligned = np.concatenate([np.floor(others[:, k] + 0.5 - m - 1e-9),
                                  np.ceil(others[:, k + 2] + 0.5 + m - side + 1e-9)])
        aligned = np.unique(aligned[(aligned >= lo) & (aligned <= hi)])
        if aligned.size > candidates:
            aligned = np.unique(np.quantile(aligned, np.linspace(0.0, 1.0, candidates), method="nearest"))
        c = np.concatenate([np.round(np.linspace(lo, hi, candidates)) if hi >= lo else [], aligned,
                            [0, size - side]]).astype(np.int64)
        # the exact test: more than m px inside every tile edge that is not a frame edge
        holds = (((c == 0) | (lo_edge > c - 0.5 + m)) & ((c + side == size) | (hi_edge < c + side - 0.5 - m))
                 & (c >= 0) & (c <= size - side))
        if not holds.any():
            mid = round(0.5 * (lo_edge + hi_edge) + 0.5 - 0.5 * side)
            out.append(np.array([int(np.clip(mid, 0, size - side))]))
        else:
            out.append(np.unique(c[holds]))
    return out[0], out[1]


def grid_plan(frame_shape: tuple[int, int], n: int = 2, *, overlap: float = 0.2, input_size: int = 416) -> TilePlan:
    """A plan without a calibrated camera: the full frame plus an ``n`` x ``n`` grid of equal tiles that overlap by
    ``overlap`` of a tile's side (so a vehicle cut by one tile's edge is whole in its neighbour if it is smaller than
    the overlap)."""
    if not (isinstance(n, int) and n >= 1) or not 0.0 <= overlap < 1.0:
        raise InputError(f"grid tiles: n {n!r} must be a whole number >= 1 and overlap {overlap!r} in [0, 1)")
    h, w = (int(v) for v in frame_shape[:2])
    tw, th = (min(size, math.ceil(size / (n - (n - 1) * overlap))) for size in (w, h))
    xs = np.linspace(0, w - tw, n).round().astype(np.int64)
    ys = np.linspace(0, h - th, n).round().astype(np.int64)
    tiles = np.array([[x, y, x + tw, y + th] for y in ys for x in xs], dtype=np.int64) if n > 1 else np.zeros((0, 4))
    return TilePlan((h, w), int(input_size), 0.0, max(input_size / min(tw, th), 1.0), tiles)


def plan_tiles(camera: Camera, surface: Surface, road: Road, frame_shape: tuple[int, int] | None = None,
               *, input_size: int = 416, min_size_px: float = 24.0, max_upscale: float = 2.0,
               min_tiled_size_px: float = 16.0, vehicle_m: Sequence[float] = REFERENCE_CAR_M,
               large_vehicle_m: Sequence[float] = LARGE_VEHICLE_M, max_distance_m: float | None = None,
               step_m: float = 1.0, roi_step_px: int = 8, candidates: int = 17) -> TilePlan:
    """Tiles so that the reference car ``vehicle_m`` (length, width, height; m) reaches ``min_size_px`` (shorter
    side) in the detector's ``input_size`` px input at every point of the counted road ``road`` (lanes, a bool
    ROI mask (H, W), or counting lines: a band of road around each, :func:`line_samples`) within
    ``max_distance_m`` (m; None = all) of the camera.

    A tile of side ``T`` px is scaled by ``input_size / T``; the smallest tile is ``input_size / max_upscale`` px and
    the largest the frame's shorter side. Greedy, from the farthest road to the nearest: the point with the smallest
    vehicles not yet served sets the tile side (the largest side that brings its car to ``min_size_px``); among up
    to ``2 candidates`` squared positions (:func:`_tile_origins`) holding that point's large vehicle
    ``large_vehicle_m`` whole (its car where the large vehicle does not fit), the tile serves the most road (each
    point weighted by its area over its own tile side squared, so the far road comes first). A point is served by a
    tile that holds its large vehicle (else car) whole at a zoom bringing its car to the minimum size. Points that
    even the maximum zoom cannot bring to ``min_tiled_size_px`` get no tile. Returns the plan with, per lane, the
    road beyond reach.
    """
    view = road_view(camera, surface, road, frame_shape, input_size=input_size, min_size_px=min_size_px,
                     max_upscale=max_upscale, min_tiled_size_px=min_tiled_size_px, vehicle_m=vehicle_m,
                     max_distance_m=max_distance_m, step_m=step_m, roi_step_px=roi_step_px)
    h, w = view.frame_shape
    s_in = int(input_size)
    t_max = min(h, w)
    t_min = min(t_max, int(np.ceil(s_in / max_upscale)))
    samples, size, car_box = view.samples, view.size_px, view.car_box
    with np.errstate(invalid="ignore"):
        need = view.seen & (size * s_in / max(h, w) < min_size_px) & (size * s_in / t_min >= min_tiled_size_px)
    idx = np.flatnonzero(need)
    tiles: list[tuple[int, int, int, int]] = []
    if idx.size:
        side_req = np.clip(size[idx] * s_in / min_size_px, t_min, t_max)  # largest tile side serving each point
        big = clip_boxes(vehicle_boxes(camera, samples.xyz[idx], samples.heading_deg[idx], large_vehicle_m), (h, w))
        room = np.floor(side_req) - 2.0 * CUT_MARGIN_PX - 1.0
        fits = (big[:, 2] - big[:, 0] <= room) & (big[:, 3] - big[:, 1] <= room)
        hold = np.where(fits[:, None], big, clip_boxes(car_box[idx], (h, w)))  # what a serving tile must hold whole
        # A point needing a tile of side T "costs" about area / T^2 tiles: serving the far, costly points first
        # keeps the small tiles few (plain area favours tiles that only graze the far road).
        weight = samples.area_m2[idx] / side_req ** 2
        open_ = np.ones(idx.size, dtype=bool)
        while open_.any():
            rest = np.flatnonzero(open_)
            seed = rest[np.lexsort((hold[rest, 1], side_req[rest]))[0]]  # smallest tile side, then topmost
            side = int(np.floor(side_req[seed] + 1e-9))
            xs, ys = _tile_origins(hold[seed], hold[rest], side, (h, w), candidates)
            X0, Y0 = (a.reshape(-1) for a in np.meshgrid(xs, ys))
            cand = np.column_stack([X0, Y0, X0 + side, Y0 + side])
            ok = tiles_holding(cand, hold[rest], (h, w)) & (side <= side_req[rest] + 1e-9)[None, :]
            best = int(np.argmax(ok.astype(np.float64) @ weight[rest]))
            served = rest[ok[best]]
            open_[served] = False
            open_[seed] = False  # always: even a tile that could not hold it whole is its best effort
            tiles.append(tuple(int(v) for v in cand[best]))
    return finish_plan(camera, view, np.asarray(tiles, dtype=np.int64).reshape(-1, 4), input_size=s_in,
                       min_size_px=min_size_px, max_upscale=max_upscale, vehicle_m=vehicle_m)


@dataclass(frozen=True, eq=False)
class RoadView:
    """The counted road as the camera sees it, for a tile planner: the ``samples``, their horizontal distance
    ``dist_m`` (m) from the camera, whether each is in view (``seen``), the reference car's size ``size_px``
    (full-frame px, NaN out of view) and box ``car_box`` (N, 4) there; ``unit`` ``"m"`` (lanes, line bands) or
    ``"m2"`` (ROI); ``source`` what the road was taken from (:attr:`TilePlan.source`)."""

    frame_shape: tuple[int, int]
    samples: RoadSamples
    unit: str
    dist_m: np.ndarray
    seen: np.ndarray
    size_px: np.ndarray
    car_box: np.ndarray
    metres_per_unit: float
    source: str = ""  # "lanes", "roi" or "lines"


def road_view(camera: Camera, surface: Surface, road: Road, frame_shape: tuple[int, int] | None = None,
              *, input_size: float = 416, min_size_px: float = 24.0, max_upscale: float = 2.0,
              min_tiled_size_px: float = 16.0, vehicle_m: Sequence[float] = REFERENCE_CAR_M,
              max_distance_m: float | None = None, step_m: float = 1.0, roi_step_px: int = 8) -> RoadView:
    """The :class:`RoadView` of ``road`` (lanes, a bool ROI mask (H, W), or counting lines) within
    ``max_distance_m`` (m; None = all) of the camera; InputError for frames of another size than the calibration
    or a non-positive setting."""
    h, w = camera.height, camera.width
    if frame_shape is not None and tuple(int(v) for v in frame_shape[:2]) != (h, w):
        raise InputError(f"tiling: frames of {frame_shape[1]}x{frame_shape[0]} px do not match the camera's "
                         f"{w}x{h} px calibration; calibrate at the video's resolution")
    for name, value in (("input_size", input_size), ("min_size_px", min_size_px), ("max_upscale", max_upscale),
                        ("min_tiled_size_px", min_tiled_size_px)):
        if not (np.isfinite(value) and value > 0):
            raise InputError(f"tiling: {name} {value!r} must be a positive number")
    mpu = _mpu(camera)
    if isinstance(road, Lanes):
        samples, unit, source = lane_samples(road, surface, step_m=step_m, metres_per_unit_=mpu), "m", "lanes"
    elif isinstance(road, np.ndarray):
        samples, unit, source = roi_samples(camera, surface, road, step_px=roi_step_px), "m2", "roi"
    else:
        samples, unit, source = line_samples(list(road), surface, step_m=step_m, metres_per_unit_=mpu), "m", "lines"
    dist_m = horizontal_distance_m(samples.xyz, camera.position[:2], mpu)
    seen = world_to_pixels(camera, samples.xyz, surface).ok
    if max_distance_m is not None:
        seen &= dist_m <= float(max_distance_m)
    size = np.full(len(dist_m), np.nan)
    size[seen] = vehicle_size_px(camera, samples.xyz[seen], samples.heading_deg[seen], vehicle_m)
    seen &= np.isfinite(size)
    size[~seen] = np.nan
    car_box = np.full((len(dist_m), 4), np.nan)
    car_box[seen] = vehicle_boxes(camera, samples.xyz[seen], samples.heading_deg[seen], vehicle_m)
    return RoadView((h, w), samples, unit, dist_m, seen, size, car_box, mpu, source)


def finish_plan(camera: Camera, view: RoadView, tiles: np.ndarray, *, input_size: int, min_size_px: float,
                max_upscale: float, vehicle_m: Sequence[float], tile_input_hw: np.ndarray | None = None,
                full_input_hw: tuple[int, int] | None = None) -> TilePlan:
    """The :class:`TilePlan` of ``tiles`` over ``view``, with what the detector reaches on each lane."""
    plan = TilePlan(frame_shape=view.frame_shape, input_size=int(input_size), min_size_px=float(min_size_px),
                    max_upscale=float(max_upscale), tiles=tiles, regions=(), samples=view.samples,
                    size_px=view.size_px, best_input_px=np.full(len(view.size_px), np.nan),
                    vehicle_m=tuple(float(v) for v in vehicle_m), camera_xy=camera.position[:2].copy(),
                    unit_m=view.metres_per_unit, tile_input_hw=tile_input_hw, full_input_hw=full_input_hw,
                    source=view.source)
    best = np.full(len(view.size_px), np.nan)
    if view.seen.any():
        best[view.seen] = plan.input_size_px(view.car_box[view.seen])
    object.__setattr__(plan, "best_input_px", best)
    object.__setattr__(plan, "regions", region_reaches(view.samples, view.seen,
                                                 view.size_px * plan.full_scale >= min_size_px,
                                                 best >= min_size_px, view.dist_m, view.unit))
    return plan
