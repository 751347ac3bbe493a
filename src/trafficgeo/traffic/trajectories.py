"""World trajectories from image tracks: ground points through the camera, smoothing, per-point and per-vehicle
kinematics.

For each track point the ground contact pixel is mapped to the road surface (:func:`pixels_to_world`). Its
uncertainty is the pixel noise ``pixel_sigma`` (with ``box_sigma_share`` of the box's height added in quadrature:
a detector's boxes scatter in proportion to their size) carried through the local image-to-ground Jacobian, so far
points are trusted less, and mostly along the viewing ray. Each track is then smoothed in metres by a Kalman filter +
RTS smoother (:mod:`trafficgeo.traffic.smoothing`) that rejects outlier points. A run of ``split_outliers`` rejected
points in a row means the track jumped to another vehicle (an ID switch): the track is split there, as it is at
gaps longer than ``max_gap_s`` and at gaps over ``check_gap_s`` that the motion on both sides does not bridge (an ID
switch while the vehicle was lost: :func:`_gap_cuts`); the parts are named ``<track>.1``, ``<track>.2``, ...
A box cut off by the left, right or bottom edge of the frame does not show where the vehicle meets the road: such
points are not used (``box_clipped``), but for boxes cut off by the bottom only (``top_edge_clipped``): those are
fitted by their top edge (:func:`trafficgeo.traffic.measurements.fit_top_edges`), with the fit's shift under the
vehicle's unknown length and height in their covariance, and join the part of their track nearest in time. Nor
are points within two pixel sigmas of the end of the surface (a DEM's edge, the horizon: ``surface_edge``), whose
errors are no longer symmetric, nor points so far away that one pixel spans more than ``max_metres_per_px`` of
road (``too_far``): their noise is no longer small against the curvature of the image-to-ground map, so it biases
positions and speeds.

With boxes, the bottom centre of a box is not the footprint centre (the lowest point of a vehicle is its nearest
bottom corner). A second pass fits a level cuboid of the class's typical size, heading along the smoothed track,
to each box (:mod:`trafficgeo.traffic.box_points`) and smooths again; it also estimates each vehicle's length where the
view allows.

Speeds are along each point's direction of travel, the smoothed velocity's trend over ~+-2 s
(:func:`trafficgeo.traffic.smoothing.along_track`): a smoothed path still wiggles sideways under position noise,
and its arc length, or the magnitude of its velocity, includes that wiggle and reads high. A vehicle's headline
``speed_kmh`` is the distance travelled along that direction over a window of the time seen where the calibration
knows the ground scale best, over the window's time (:mod:`trafficgeo.traffic.speed`: a real calibration's scale
is a few per cent off beyond its control points, and a speed over the whole path averages that in); its
``speed_std_kmh`` includes the calibration's scale uncertainty there. ``travel_speed_kmh`` is the former headline,
the distance travelled along the direction of travel over the whole time seen (``travel_m`` / ``duration_s``);
``mean_speed_kmh`` is the smoothed path's arc length (``path_length_m``) over that time, which reads high under
noise, and ``median_speed_kmh`` the median of the point speeds.

Units: positions in the camera CRS's units (columns ``x, y, z``), distances in metres, speeds in km/h, headings in
degrees clockwise from north, accelerations in m/s^2, times in seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

import numpy as np
import pandas as pd

from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import GroundPoints, Surface, camera_crs, lonlat_of, pixels_to_world
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.traffic.measurements import (
    blocks,
    fit_boxes,
    fit_top_edges,
    ground_covariance,
    majority,
    track_slices,
    vehicle_length,
)
from trafficgeo.traffic.smoothing import CHI2_2DOF_999, SmoothedTrack, along_track, smooth_track, travel_direction
from trafficgeo.traffic.speed import ScaleKnowledge, SpeedOptions, cumulative_travel_m, scale_terms, window_speed

MIN_MOVING_SPEED = 1.0  # m/s: below this a smoothed heading is noise
MIN_SPEED_DURATION_S = 1.0  # a vehicle seen for less than this gets no speeds at all (a glimpse tells too little)
EDGE_SIGMAS = 2.0  # points within this many pixel sigmas of the end of the surface are not used


MAX_COAST_HIDDEN_S = 30.0  # s, the longest a vehicle hidden behind another is carried on
# At a junction (a site with gates) the tracks are smoothed with more pixel noise by default: queued vehicles hide
# one another, and the boxes of the half-hidden ones jitter more than on an open road (benchmarks/README.md,
# junction benchmark, fourth pass)
JUNCTION_PIXEL_SIGMA = 3.0
# ... and with noise that grows with the box: the built-in detector's box edges scatter by 5-10 % of the box's height
# about the true box at every size (junction worlds; a car 100 px tall: ~9 px), so a fixed few pixels make the
# near vehicles' points outliers and cut their tracks (benchmarks/README.md, junction benchmark, sixth pass)
JUNCTION_BOX_SIGMA_SHARE = 0.05


@dataclass(frozen=True)
class TrajectoryOptions:
    """How image tracks become world trajectories (see the module docstring)."""

    pixel_sigma: float = 2.0  # px, 1-sigma noise of a ground contact point in the image
    box_sigma_share: float = 0.0  # px of ground-point noise per px of box height, added to pixel_sigma in quadrature
    accel_sigma: float = 1.5  # m/s^2, spectral density^(1/2) of the white-noise acceleration
    gate: float = CHI2_2DOF_999  # chi-square (2 dof) gate for outlier points
    split_outliers: int = 5  # this many rejected points in a row split a track
    max_gap_s: float = 5.0  # a longer gap in time splits a track
    check_gap_s: float = 0.5  # a gap this long splits a track unless the motion on both sides bridges it
    rejoin_gap_s: float = 2.0  # parts of a track split apart this long or less are joined again if motion bridges
    min_points: int = 5  # vehicles with fewer points (after their fragments are joined) are dropped
    min_fragment_points: int = 2  # shorter pieces of track (after splitting) are dropped before joining
    box_correction: bool = True  # fit a cuboid to each box (tracks with boxes only)
    estimate_length: bool = True  # estimate each vehicle's length from its boxes (where the view allows)
    frame_margin_px: float = 2.0  # boxes this close to the frame's edge are cut off by it: not used
    top_edge_clipped: bool = True  # boxes cut off by the bottom of the frame are fitted to their top edge instead
    max_metres_per_px: float = 1.5  # farther points, where one pixel spans more of the road (m), are not used
    coast_hidden_s: float = 3.0  # s a track that vanishes behind a nearer vehicle is carried on to count lines; 0: off

    @classmethod
    def at_junction(cls, **changes: object) -> TrajectoryOptions:
        """The defaults for a junction's turning movements (``pixel_sigma`` :data:`JUNCTION_PIXEL_SIGMA`,
        ``box_sigma_share`` :data:`JUNCTION_BOX_SIGMA_SHARE`), with ``changes``."""
        return cls(**{"pixel_sigma": JUNCTION_PIXEL_SIGMA, "box_sigma_share": JUNCTION_BOX_SIGMA_SHARE, **changes})

    def __post_init__(self) -> None:
        numbers = {k: v for k, v in asdict(self).items() if isinstance(v, float | int) and not isinstance(v, bool)}
        for name, value in numbers.items():
            if not np.isfinite(value):
                raise InputError(f"trajectory option {name}={float(value):g} must be a finite number",
                                 parameters=(name,))
        if self.coast_hidden_s > MAX_COAST_HIDDEN_S:
            raise InputError(f"trajectory option coast_hidden_s={self.coast_hidden_s:g} is more than "
                             f"{MAX_COAST_HIDDEN_S:g} s: nobody stays hidden that long; give e.g. 3 (0: off)",
                             parameters=("coast_hidden_s",))
        checks = {"pixel_sigma": self.pixel_sigma > 0, "box_sigma_share": self.box_sigma_share >= 0,
                  "accel_sigma": self.accel_sigma > 0, "gate": self.gate > 0,
                  "split_outliers": self.split_outliers >= 1, "max_gap_s": self.max_gap_s > 0,
                  "check_gap_s": self.check_gap_s > 0, "rejoin_gap_s": self.rejoin_gap_s > 0,
                  "max_metres_per_px": self.max_metres_per_px > 0, "coast_hidden_s": self.coast_hidden_s >= 0,
                  "min_points": self.min_points >= 2, "min_fragment_points": self.min_fragment_points >= 1}
        for name, ok in checks.items():
            if not ok:
                need = {"min_points": "at least 2", "min_fragment_points": "at least 1",
                        "coast_hidden_s": "0 (off) or more", "box_sigma_share": "0 (off) or more"}.get(name, "positive")
                raise InputError(f"trajectory option {name}={getattr(self, name)!r} is out of range; it must be "
                                 f"{need}", parameters=(name,))


@dataclass(frozen=True)
class WorldTracks:
    """``points``: one row per kept track point; ``vehicles``: one row per (split) track; ``dropped``: input
    points not used, by reason (e.g. ``{"above_horizon": 3, "short_track": 12}``)."""

    points: pd.DataFrame
    vehicles: pd.DataFrame
    dropped: dict[str, int]


# ------------------------------------------------------------------------------------------------ ground points
def point_sigma_px(box: np.ndarray, opts: TrajectoryOptions) -> np.ndarray:
    """(N,) image noise (px, 1 sigma) of each track point's ground contact: ``pixel_sigma``, and with
    ``box_sigma_share`` that share of the box's height added in quadrature (a detector's box edges scatter in
    proportion to the box's size; points without a box get ``pixel_sigma``)."""
    height = np.nan_to_num(box[:, 3] - box[:, 1], nan=0.0) if len(box) else np.zeros(0)
    return np.hypot(opts.pixel_sigma, opts.box_sigma_share * np.maximum(height, 0.0))


def clipped_boxes(camera: Camera, box: np.ndarray, margin_px: float) -> np.ndarray:
    """Boxes (N, 4) that touch the left, right or bottom edge of the frame: the vehicle is cut off there, so the
    box's bottom centre is not its ground point. NaN boxes are not clipped."""
    w, h = camera.image_size
    with np.errstate(invalid="ignore"):
        return (box[:, 0] <= margin_px) | (box[:, 2] >= w - 1 - margin_px) | (box[:, 3] >= h - 1 - margin_px)


def near_surface_edge(camera: Camera, surface: Surface, uv: np.ndarray, shift_px: float) -> np.ndarray:
    """Pixels whose ray meets the surface but would not ``shift_px`` higher in the image (farther away): the
    surface ends (a DEM's edge, the horizon) within their noise. Such points are biased towards the camera,
    because their farther noisy neighbours are lost, so they are not used."""
    far = pixels_to_world(camera, uv - [0.0, shift_px], surface, with_lonlat=False, frame_margin_px=1e6)
    return ~far.ok


def ground_points(camera: Camera, surface: Surface, uv: np.ndarray, **kwargs) -> GroundPoints:
    """:func:`pixels_to_world` (without lon/lat) over pixels (N, 2) block by block
    (:data:`trafficgeo.traffic.measurements.BLOCK_POINTS`)."""
    parts = [pixels_to_world(camera, uv[sl], surface, with_lonlat=False, **kwargs) for sl in blocks(uv.shape[0])]
    if not parts:
        return pixels_to_world(camera, uv, surface, with_lonlat=False, **kwargs)
    return GroundPoints(xyz=np.concatenate([g.xyz for g in parts]), status=np.concatenate([g.status for g in parts]),
                        distance_m=np.concatenate([g.distance_m for g in parts]),
                        incidence_deg=np.concatenate([g.incidence_deg for g in parts]), lon=None, lat=None)


# ------------------------------------------------------------------------------------------------ splitting
def _runs(mask: np.ndarray, min_len: int) -> list[int]:
    """Start indices of runs of True at least ``min_len`` long."""
    starts = []
    k = 0
    while k < mask.size:
        if mask[k]:
            e = k
            while e < mask.size and mask[e]:
                e += 1
            if e - k >= min_len:
                starts.append(k)
            k = e
        else:
            k += 1
    return starts


def _gap_cuts(t: np.ndarray, xy_m: np.ndarray, cov: np.ndarray, opts: TrajectoryOptions) -> np.ndarray:
    """Indices where a track is cut at a gap in time: gaps longer than ``max_gap_s``, and gaps longer than
    ``check_gap_s`` that the motion on their two sides does not bridge.

    A tracker that lost a vehicle may give its id to another one when it finds a box where it predicts the lost
    one (an ID switch across a gap). A gap is bridged when each side has at least 3 points within 1 s of it and
    the straight-line motions fitted to the two sides reach the middle of the gap within
    ``2 m + 3 sigma`` of each other (sigma from the points' covariance and ``accel_sigma`` over the gap).
    """
    dt = np.diff(t)
    cuts = set(np.flatnonzero(dt > opts.max_gap_s) + 1)
    for k in np.flatnonzero((dt > opts.check_gap_s) & (dt <= opts.max_gap_s)):
        before = np.flatnonzero((t <= t[k]) & (t >= t[k] - 1.0))
        after = np.flatnonzero((t >= t[k + 1]) & (t <= t[k + 1] + 1.0))
        mid = 0.5 * (t[k] + t[k + 1])
        ends = []
        for side in (before, after):
            if side.size < 3 or np.ptp(t[side]) <= 0:
                break
            coef = np.polyfit(t[side] - mid, xy_m[side], 1)  # (2, 2): slope row, intercept row
            ends.append(coef[1])
        if len(ends) < 2:
            cuts.add(k + 1)
            continue
        pos_var = float(np.trace(cov[k]) + np.trace(cov[k + 1]))
        half = 0.5 * dt[k]
        acc_var = 2.0 * (opts.accel_sigma ** 2) * half ** 3 / 3.0  # white-noise acceleration, per axis
        tol = 2.0 + 3.0 * np.sqrt(pos_var + 4.0 * acc_var)
        if np.hypot(*(ends[0] - ends[1])) > tol:
            cuts.add(k + 1)
    return np.array(sorted(cuts), dtype=np.int64)


def _smooth_segments(t: np.ndarray, xy_m: np.ndarray, cov: np.ndarray, opts: TrajectoryOptions,
                     segments: list[np.ndarray] | None = None) -> list[tuple[np.ndarray, SmoothedTrack]]:
    """Smooth one track's points (indices into t), starting from ``segments`` or from the track split at long
    gaps, and split again wherever ``split_outliers`` points in a row are rejected (an ID switch, or a wrong start
    that the filter then refuses to leave). Returns (indices, smoothed) per part of at least
    ``min_fragment_points`` (shorter vehicles are dropped after their fragments are joined:
    :mod:`trafficgeo.traffic.journeys`)."""
    if segments is None:
        pending = list(np.split(np.arange(t.size), _gap_cuts(t, xy_m, cov, opts)))
    else:
        pending = list(segments)
    done = []
    while pending:
        idx = pending.pop(0)
        if idx.size < opts.min_fragment_points:
            continue
        sm = smooth_track(t[idx], xy_m[idx], cov[idx], accel_sigma=opts.accel_sigma, gate=opts.gate)
        starts = _runs(sm.outlier, opts.split_outliers)
        if starts:
            pending[:0] = [idx[: starts[0]], idx[starts[0]:]]
            continue
        done.append((idx, sm))
    return _rejoin(t, xy_m, cov, opts, done)


def _bridges(a: SmoothedTrack, b: SmoothedTrack, opts: TrajectoryOptions) -> bool:
    """Whether part ``b`` (starting after ``a`` ends) continues ``a``: ``a``'s last smoothed state carried over the
    gap at constant velocity meets ``b``'s first within ``2 m + 3 sigma`` and the velocities differ by less than
    ``3 m/s + 3 sigma`` (sigma from both states and ``accel_sigma`` over the gap)."""
    gap = b.time[0] - a.time[-1]
    pred = np.array([a.x[-1] + a.vx[-1] * gap, a.y[-1] + a.vy[-1] * gap])
    pos_var = 2.0 * (a.position_std[-1] ** 2 + b.position_std[0] ** 2) + 2.0 * opts.accel_sigma ** 2 * gap ** 3 / 3.0
    vel_var = a.speed_std[-1] ** 2 + b.speed_std[0] ** 2 + opts.accel_sigma ** 2 * gap
    with np.errstate(invalid="ignore"):
        near = np.hypot(*(pred - [b.x[0], b.y[0]])) <= 2.0 + 3.0 * np.sqrt(pos_var)
        same_velocity = np.hypot(a.vx[-1] - b.vx[0], a.vy[-1] - b.vy[0]) <= 3.0 + 3.0 * np.sqrt(vel_var)
    return bool(near and same_velocity)


def _rejoin(t: np.ndarray, xy_m: np.ndarray, cov: np.ndarray, opts: TrajectoryOptions,
            parts: list[tuple[np.ndarray, SmoothedTrack]]) -> list[tuple[np.ndarray, SmoothedTrack]]:
    """Join parts of one track that belong together again: a stretch of bad points (the box of a merged blob, a
    moment on another vehicle) is cut out by the splitting, and the vehicle's own points on both sides of it are
    one vehicle when the motion bridges the gap (:func:`_bridges`, gaps up to ``rejoin_gap_s``). The stretch
    stays a part of its own. A join that the filter then rejects in a run of ``split_outliers`` points is undone."""
    if len(parts) < 2:
        return parts
    todo = sorted(parts, key=lambda p: t[p[0][0]])
    out = []
    while todo:
        idx, sm = todo.pop(0)
        joined = True
        while joined:
            joined = False
            for k, (idx2, sm2) in enumerate(todo):
                gap = t[idx2[0]] - t[idx[-1]]
                if gap <= 0 or gap > opts.rejoin_gap_s or not _bridges(sm, sm2, opts):
                    continue
                both = np.concatenate([idx, idx2])
                sm_both = smooth_track(t[both], xy_m[both], cov[both], accel_sigma=opts.accel_sigma, gate=opts.gate)
                if _runs(sm_both.outlier, opts.split_outliers):
                    continue
                idx, sm = both, sm_both
                del todo[k]
                joined = True
                break
        out.append((idx, sm))
    return out


# ------------------------------------------------------------------------------------------------ main
def _vehicle_class(values: np.ndarray) -> str:
    """A vehicle's class from its points': the most frequent one, or "" (unknown) when more of its points are of
    unknown class (e.g. blobs of vehicles merged in the image) than of that class."""
    best = majority(values)
    names = np.asarray([str(v) for v in values], dtype=object)
    return best if np.sum(names == best) >= np.sum(names == "") else ""


def _fill_heading(sm: SmoothedTrack) -> np.ndarray:
    """Smoothed heading (deg) where the vehicle moves; the heading of the nearest moving point elsewhere; NaN for a
    vehicle that never moves."""
    moving = sm.speed > MIN_MOVING_SPEED
    if not moving.any():
        return np.full(sm.time.size, np.nan)
    idx = np.flatnonzero(moving)
    nearest = idx[np.clip(np.searchsorted(idx, np.arange(sm.time.size)), 0, idx.size - 1)]
    return np.where(moving, sm.heading_deg, sm.heading_deg[nearest])


def world_trajectories(camera: Camera, surface: Surface, tracks: ImageTracks,
                       options: TrajectoryOptions | None = None,
                       progress: Callable[[int, int], None] | None = None, *,
                       knowledge: ScaleKnowledge | None = None,
                       speed_options: SpeedOptions | None = None) -> WorldTracks:
    """Map, smooth and describe every track (see the module docstring). ``progress(done, total)`` is called per
    track and pass. ``knowledge`` (what the calibration knows of its ground scale) and ``speed_options`` choose
    where each vehicle's headline speed is measured (:mod:`trafficgeo.traffic.speed`)."""
    opts = options or TrajectoryOptions()
    crs = camera_crs(camera)
    m = metres_per_unit(crs) if crs is not None else 1.0
    uv = np.column_stack([tracks.u, tracks.v])
    ground = ground_points(camera, surface, uv)
    status = ground.status.copy()
    clipped = ground.ok & clipped_boxes(camera, tracks.box, opts.frame_margin_px)
    status[clipped] = "box_clipped"
    ok = status == "ok"
    cov = np.full((len(tracks), 2, 2), np.nan)
    use = np.flatnonzero(ok)
    sigma_px = point_sigma_px(tracks.box, opts)
    for sl in blocks(use.size):
        cov[use[sl]] = ground_covariance(camera, surface, uv[use[sl]], ground.xyz[use[sl]], sigma_px[use[sl]], m)
    origin = camera.position[:2]
    slices = track_slices(tracks.track_id)
    n_steps = 2 * len(slices)

    def tick(k: int) -> None:
        if progress is not None:
            progress(k, n_steps)

    # Pass 1: the ground points as given (or the boxes' bottom centres), smoothed per track; split at ID switches
    # and long gaps.
    pass1, smoothed = [], np.full((len(tracks), 2), np.nan)
    for k, (tid, rows) in enumerate(slices, start=1):
        rows = rows[ok[rows]]
        segs = _smooth_segments(tracks.time[rows], (ground.xyz[rows, :2] - origin) * m, cov[rows], opts) \
            if rows.size else []
        for idx, sm in segs:
            smoothed[rows[idx]] = origin + np.column_stack([sm.x, sm.y]) / m
        pass1.append((tid, rows, segs))
        tick(k)
    # Which points to use is judged at the smoothed positions, not at the noisy points themselves: a cut on the
    # noisy points would keep those whose noise pulls them towards the camera and bias the rest.
    have = ok & np.isfinite(smoothed[:, 0])
    status[ok & ~have] = "short_track"
    have_idx = np.flatnonzero(have)
    for sl in blocks(have_idx.size):
        status[have_idx[sl]] = usable_positions(camera, surface, smoothed[have_idx[sl]], opts)
    ok = status == "ok"
    # Pass 2: the measurements (cuboid-fitted footprint centres with boxes), smoothed again on the same parts.
    measured = ground.xyz[:, :2].copy()  # the ground point each smoothed position was fitted to (CRS units)
    use_boxes = opts.box_correction and bool(np.any(ok & np.all(np.isfinite(tracks.box), axis=1)))
    heading = np.full(len(tracks), np.nan)
    good, dims = np.ones(len(tracks), dtype=bool), np.full((len(tracks), 3), np.nan)
    attached: list[list[np.ndarray]] = [[np.zeros(0, dtype=np.int64) for _ in segs] for _t, _r, segs in pass1]
    if use_boxes:
        for _tid, rows, segs in pass1:
            for idx, sm in segs:
                heading[rows[idx]] = _fill_heading(sm)
        good, dims = fit_boxes(camera, surface, tracks, heading, ok, measured)
        if opts.top_edge_clipped:
            attached = _attach_clipped(tracks, slices, pass1, status == "box_clipped", heading, opts)
            top = np.concatenate([a for per_track in attached for a in per_track] + [np.zeros(0, dtype=np.int64)])
            fitted, top_cov = fit_top_edges(camera, surface, tracks, heading, top, dims, measured,
                                             opts.pixel_sigma, m)
            cov[fitted] = top_cov
            good[fitted], status[fitted], ok[fitted] = True, "ok", True
            attached = [[a[ok[a]] for a in per_track] for per_track in attached]
    cov2 = np.where(good[:, None, None], cov, (100.0**2) * np.eye(2))
    xy2_m = (measured - origin) * m
    named = []
    no_size = (float("nan"), float("nan"))
    for k, ((tid, rows, segs), extra) in enumerate(zip(pass1, attached, strict=True), start=len(slices) + 1):
        parts = [idx[ok[rows[idx]]] for idx, _ in segs]
        if any(a.size for a in extra):  # the part's rows and the top-edge rows attached to it, in time order
            kept_rows = [rows[p] for p in parts]
            rows = np.unique(np.concatenate([rows, *extra]))
            parts = [np.searchsorted(rows, np.union1d(r, a)) for r, a in zip(kept_rows, extra, strict=True)]
        segs = _smooth_segments(tracks.time[rows], xy2_m[rows], cov2[rows], opts, segments=parts)
        # points fitted by their top edge only extend a track: a part made of them alone (they did not fit the
        # rest of their track) is dropped
        segs = [(idx, sm) for idx, sm in segs if not clipped[rows[idx]].all()]
        used = np.zeros(len(tracks), dtype=bool)
        for j, (idx, sm) in enumerate(segs, start=1):
            whole = good[rows[idx]] & ~clipped[rows[idx]]  # boxes the frame does not cut off
            size = vehicle_length(camera, surface, heading[rows[idx]], tracks.box[rows[idx]], dims[rows[idx]],
                                   whole, opts.pixel_sigma) if use_boxes and opts.estimate_length else no_size
            named.append((tid if len(segs) == 1 else f"{tid}.{j}", tid, rows[idx], sm, size))
            used[rows[idx]] = True
        short = rows[ok[rows] & ~used[rows]]
        status[short] = np.where(clipped[short], "box_clipped", "short_track")
        tick(k)
    kept = np.zeros(len(tracks), dtype=bool)
    for _name, _tid, rows, _sm, _size in named:
        kept[rows] = True
    dropped = {str(k): int(c) for k, c in zip(*np.unique(status[~kept].astype(str), return_counts=True),
                                               strict=True)}
    if clipped.any():  # the distance of a point fitted to its top edge is that of its footprint centre
        top = np.flatnonzero(clipped & kept)
        xyz = np.column_stack([measured[top], surface.elevation(measured[top, 0], measured[top, 1])])
        distance = ground.distance_m.copy()
        distance[top] = np.linalg.norm((xyz - camera.position) * m, axis=1)
        ground = replace(ground, distance_m=distance)
    return _assemble(camera, surface, tracks, ground, measured, named, m, dropped, knowledge,
                     speed_options or SpeedOptions(), clipped)


def _attach_clipped(tracks: ImageTracks, slices: list[tuple[str, np.ndarray]], pass1: list,
                    clipped: np.ndarray, heading: np.ndarray, opts: TrajectoryOptions) -> list[list[np.ndarray]]:
    """Per track and part of pass 1, the rows of that track whose box the frame's bottom cuts off and that lie
    within ``max_gap_s`` of that part (the nearest part in time); ``heading`` (deg) of each such row is set (in
    place) to that of the part's nearest point."""
    out = []
    for (_tid, all_rows), (_t, rows, segs) in zip(slices, pass1, strict=True):
        cand = all_rows[clipped[all_rows]]
        per_seg = [np.zeros(0, dtype=np.int64) for _ in segs]
        if cand.size and segs:
            t = tracks.time[cand]
            spans = np.array([[tracks.time[rows[idx[0]]], tracks.time[rows[idx[-1]]]] for idx, _ in segs])
            dist = np.maximum(spans[None, :, 0] - t[:, None], 0.0) + np.maximum(t[:, None] - spans[None, :, 1], 0.0)
            best = np.argmin(dist, axis=1)
            near = dist[np.arange(cand.size), best] <= opts.max_gap_s
            for j, (idx, _sm) in enumerate(segs):
                mine = cand[near & (best == j)]
                if mine.size:
                    seg_rows = rows[idx]
                    nearest = np.abs(tracks.time[seg_rows][None, :] - tracks.time[mine][:, None]).argmin(axis=1)
                    heading[mine] = heading[seg_rows[nearest]]
                    per_seg[j] = mine[np.isfinite(heading[mine])]
        out.append(per_seg)
    return out


def usable_positions(camera: Camera, surface: Surface, xy: np.ndarray, opts: TrajectoryOptions) -> np.ndarray:
    """``ok``, ``too_far`` or ``surface_edge`` for ground positions (N, 2) (CRS units): too far where one pixel
    spans more than ``max_metres_per_px`` of road, at the edge where the surface ends within two pixel sigmas."""
    crs = camera_crs(camera)
    m = metres_per_unit(crs) if crs is not None else 1.0
    xyz = np.column_stack([xy, surface.elevation(xy[:, 0], xy[:, 1])])
    uv = camera.project(xyz)
    out = np.full(xy.shape[0], "ok", dtype=object)
    edge = near_surface_edge(camera, surface, uv, EDGE_SIGMAS * opts.pixel_sigma)
    g = pixels_to_world(camera, uv, surface, with_lonlat=False, frame_margin_px=1e6)
    edge |= ~g.ok
    cov = ground_covariance(camera, surface, uv[~edge], g.xyz[~edge], 1.0, m)
    far = np.zeros(xy.shape[0], dtype=bool)
    far[~edge] = np.sqrt(np.linalg.eigvalsh(cov)[:, 1]) > opts.max_metres_per_px
    out[edge] = "surface_edge"
    out[far] = "too_far"
    return out


def _assemble(camera: Camera, surface: Surface, tracks: ImageTracks, ground, measured: np.ndarray, parts: list,
              m: float, dropped: dict[str, int], knowledge: ScaleKnowledge | None,
              speed_opts: SpeedOptions, clipped: np.ndarray) -> WorldTracks:
    """The tables of :class:`WorldTracks` from the smoothed ``parts``; a vehicle's class is voted by its points
    whose box the frame does not cut off (``clipped`` (N,)) where it has any: a cut-off box hides its size."""
    crs = camera_crs(camera)
    origin = camera.position[:2]
    point_tables, vehicle_rows = [], []
    directions = [travel_direction(sm) for _n, _s, _r, sm, _l in parts]
    if knowledge is not None and parts:
        xy_all = np.concatenate([origin + np.column_stack([sm.x, sm.y]) / m for _n, _s, _r, sm, _l in parts])
        terms = scale_terms(camera, surface, knowledge, xy_all, np.concatenate(directions))
        bounds = np.cumsum([0] + [sm.time.size for _n, _s, _r, sm, _l in parts])
        known = [terms.part(slice(bounds[k], bounds[k + 1])) for k in range(len(parts))]
    else:
        known = [None] * len(parts)
    for (name, source, rows, sm, (length, length_std)), d, part_terms in zip(parts, directions, known, strict=True):
        x = origin[0] + sm.x / m
        y = origin[1] + sm.y / m
        whole = rows[~clipped[rows]]
        vclass = _vehicle_class(tracks.vclass[whole if whole.size else rows])
        step = np.hypot(np.diff(sm.x), np.diff(sm.y))
        duration = float(sm.time[-1] - sm.time[0])
        glimpse_ok = duration >= MIN_SPEED_DURATION_S
        path = float(step.sum())
        along, travel = along_track(sm)
        head = window_speed(sm.time, cumulative_travel_m(sm.x, sm.y, d), sm.position_std, part_terms,
                            speed_opts) if glimpse_ok else None
        point_tables.append(pd.DataFrame({
            "track_id": name, "source_track": source, "frame": tracks.frame[rows], "time": sm.time,
            "u": tracks.u[rows], "v": tracks.v[rows], "x_obs": measured[rows, 0], "y_obs": measured[rows, 1],
            "x": x, "y": y, "speed_kmh": 3.6 * along if glimpse_ok else np.nan,
            "speed_std_kmh": 3.6 * sm.speed_std if glimpse_ok else np.nan,
            "heading_deg": sm.heading_deg, "accel_mps2": sm.accel, "position_std_m": sm.position_std,
            "outlier": sm.outlier, "distance_m": ground.distance_m[rows], "class": vclass,
        }))
        vehicle_rows.append({
            "track_id": name, "source_track": source, "class": vclass, "first_time": float(sm.time[0]),
            "last_time": float(sm.time[-1]), "duration_s": duration, "points": int(rows.size),
            "outliers": int(sm.outlier.sum()), "path_length_m": path, "travel_m": travel,
            "speed_kmh": 3.6 * head.speed_mps if head is not None else np.nan,
            "speed_std_kmh": 3.6 * head.std_mps if head is not None else np.nan,
            "speed_start_time": head.start_s if head is not None else np.nan,
            "speed_end_time": head.end_s if head is not None else np.nan,
            "travel_speed_kmh": 3.6 * travel / duration if glimpse_ok else np.nan,
            "mean_speed_kmh": 3.6 * path / duration if glimpse_ok else np.nan,
            "median_speed_kmh": float(np.median(3.6 * along)) if glimpse_ok else np.nan,
            "point_speed_std_kmh": float(np.sqrt(np.mean(sm.speed_std**2))) * 3.6,
            "min_distance_m": float(np.nanmin(ground.distance_m[rows])),
            "length_m": length, "length_std_m": length_std,
        })
    points = pd.concat(point_tables, ignore_index=True) if point_tables else _empty_points()
    if len(points):
        points["z"] = surface.elevation(points["x"].to_numpy(), points["y"].to_numpy())
        lon, lat = lonlat_of(points["x"].to_numpy(), points["y"].to_numpy(), crs)
        if lon is not None:
            points["lon"], points["lat"] = lon, lat
    vehicles = pd.DataFrame(vehicle_rows, columns=VEHICLE_COLUMNS)
    return WorldTracks(points=points, vehicles=vehicles, dropped=dropped)


POINT_COLUMNS = ["track_id", "source_track", "frame", "time", "u", "v", "x_obs", "y_obs", "x", "y", "speed_kmh",
                 "speed_std_kmh", "heading_deg", "accel_mps2", "position_std_m", "outlier", "distance_m", "class"]
VEHICLE_COLUMNS = ["track_id", "source_track", "class", "first_time", "last_time", "duration_s", "points",
                   "outliers", "path_length_m", "travel_m", "speed_kmh", "speed_std_kmh", "speed_start_time",
                   "speed_end_time", "travel_speed_kmh",
                   "mean_speed_kmh", "median_speed_kmh", "point_speed_std_kmh", "min_distance_m", "length_m",
                   "length_std_m"]


def _empty_points() -> pd.DataFrame:
    return pd.DataFrame({c: pd.Series(dtype=float) for c in POINT_COLUMNS})
