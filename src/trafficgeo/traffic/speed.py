"""A vehicle's headline speed where the calibration knows the ground scale, and the warning when it does not.

A real calibration's ground scale is a few per cent wrong, differently across the view: right among its control
points, off beyond them (towards the camera and far away). At constant true speed the apparent speed then drifts
along a track, and "distance travelled / time seen" averages the drift over the whole path, edges included.

The headline ``speed_kmh`` (:func:`window_speed`) is therefore the distance travelled along the direction of
travel (the smoothed path's steps projected on it) over one window of the time seen, divided by the window's
time: a chord of the smoothed path, whose position noise only enters through the window's two ends. Without
anything known of the calibration (a camera made by hand) the window is the middle ``core_fraction`` of the time
seen. With what the calibration knows (:class:`ScaleKnowledge`, from the camera JSON) the window, of that length
or 1/2 or 3/4 of it, minimizes the speed's expected squared error from:

* the position noise at its two ends (the smoothed positions' 1-sigma);
* the covariance's relative scale sigma along the direction of travel over it (the camera JSON's ``covariance``
  block; :func:`trafficgeo.geo.uncertainty.along_scale_sigma`);
* a scale-bias risk of ``hull_scale_pct`` % per hull radius (sqrt(area / pi) of the convex hull of the control
  points) of its mean distance outside that hull and of its mean position's distance from the hull's centroid:
  the calibration model is only checked among the control points, and a scale error growing away from them
  cancels to first order over a window centred on them.

``speed_std_kmh`` combines the position noise at the window's ends and the covariance's scale sigma over the
window (not the hull's assumed one). :func:`scale_drift_warning` looks for the symptom: vehicles as a whole
reading faster or slower at the same distance from the camera than where their speed is measured.

Units: times in s, distances in m, speeds in m/s inside and km/h in tables, scale errors as fractions (0.01 = 1 %)
inside and per cent in messages.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd
import shapely

from trafficgeo.camera.calibrated import CalibratedCamera, CameraCovariance
from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs
from trafficgeo.geo.uncertainty import along_scale_sigma

BLOCK_POINTS = 8192  # points per block of the covariance propagation
SHORTER_WINDOWS = (0.5, 0.75, 1.0)  # window lengths tried with knowledge, as fractions of the core


@dataclass(frozen=True)
class SpeedOptions:
    """How the headline speed and the scale-drift warning are computed (see the module docstring)."""

    core_fraction: float = 0.5  # share of the time seen that the speed's window spans
    min_core_s: float = 1.0  # s, the window spans at least this (or all the time seen, when shorter)
    hull_scale_pct: float = 3.0  # %, assumed scale error per hull radius outside the control points' hull
    drift_min_pct: float = 1.5  # %, smallest scale drift the warning reports
    drift_min_vehicles: int = 8  # vehicles needed in a distance band to judge it
    drift_bands: int = 6  # distance bands (equal numbers of points) the warning compares
    drift_end_s: float = 0.3  # s at each end of a track whose point speeds the warning leaves out: there the
    # smoother's speeds lean on one side only, and where tracks start or end in the same part of the image (near the
    # camera) that read 2 % fast on the demo world with its true camera (0: keep them)

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not np.isfinite(value):
                raise InputError(f"speed option {name}={value!r} must be a finite number", parameters=(name,))
        checks = {"core_fraction": 0 < self.core_fraction <= 1, "min_core_s": self.min_core_s >= 0,
                  "hull_scale_pct": self.hull_scale_pct >= 0, "drift_min_pct": self.drift_min_pct > 0,
                  "drift_min_vehicles": self.drift_min_vehicles >= 2, "drift_bands": self.drift_bands >= 2,
                  "drift_end_s": self.drift_end_s >= 0}
        for name, ok in checks.items():
            if not ok:
                raise InputError(f"speed option {name}={getattr(self, name)!r} is out of range (core_fraction: "
                                 "0 < f <= 1; drift_min_vehicles, drift_bands: >= 2; others positive)",
                                 parameters=(name,))


@dataclass(frozen=True, eq=False)
class ScaleKnowledge:
    """What the calibration knows about its ground scale: its parameter ``covariance`` and the ground positions
    of its control points ``control_xy`` (K, 2; camera CRS units). Either may be None."""

    covariance: CameraCovariance | None = None
    control_xy: np.ndarray | None = None

    @classmethod
    def from_camera(cls, camera: CalibratedCamera) -> ScaleKnowledge | None:
        """From what a calibrated camera knows (its covariance; its inlier control GCPs); None when it knows
        neither (a camera made by hand)."""
        xy = camera.control_xyz()[:, :2]
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if camera.covariance is None and len(xy) < 3:
            return None
        return cls(covariance=camera.covariance, control_xy=xy if len(xy) >= 3 else None)

    def describe(self) -> str:
        """``covariance+gcps``, ``covariance``, ``gcps`` (what the headline speed's window is chosen by)."""
        parts = [n for n, v in (("covariance", self.covariance), ("gcps", self.control_xy)) if v is not None]
        return "+".join(parts) or "none"


def _hull(camera: Camera, control_xy: np.ndarray | None) -> tuple[Any, float] | None:
    """The control points' convex hull and its radius sqrt(area / pi) (CRS units), or None when degenerate."""
    if control_xy is None or len(control_xy) < 3:
        return None
    hull = shapely.convex_hull(shapely.multipoints(control_xy))
    if hull.geom_type != "Polygon" or hull.area <= 0:
        return None
    return hull, float(np.sqrt(hull.area / np.pi))


@dataclass(frozen=True)
class ScaleTerms:
    """Per point, what the window is chosen by: ``cal`` the covariance's relative 1-sigma scale error along the
    direction of travel (fraction; 0 without a covariance, NaN where it cannot be propagated); ``outside`` the
    distance outside the control points' hull and ``offset`` (N, 2) the position relative to the hull's centroid,
    both in hull radii (0 without a hull)."""

    cal: np.ndarray
    outside: np.ndarray
    offset: np.ndarray

    def part(self, sl: slice) -> ScaleTerms:
        return ScaleTerms(self.cal[sl], self.outside[sl], self.offset[sl])


def scale_terms(camera: Camera, surface: Surface, knowledge: ScaleKnowledge, xy: np.ndarray,
                direction_xy: np.ndarray) -> ScaleTerms:
    """:class:`ScaleTerms` of ground positions ``xy`` (N, 2; CRS units) moving along ``direction_xy`` (N, 2)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = xy.shape[0]
    cal, outside, offset = np.zeros(n), np.zeros(n), np.zeros((n, 2))
    if knowledge.covariance is not None and n:
        z = np.asarray(surface.elevation(xy[:, 0], xy[:, 1]), dtype=np.float64).reshape(-1)
        xyz = np.column_stack([xy, z])
        for k in range(0, n, BLOCK_POINTS):
            sl = slice(k, min(k + BLOCK_POINTS, n))
            cal[sl] = along_scale_sigma(camera, xyz[sl], direction_xy[sl], surface, knowledge.covariance)
    hull = _hull(camera, knowledge.control_xy)
    if hull is not None and n:
        with np.errstate(invalid="ignore"):
            outside = np.nan_to_num(shapely.distance(hull[0], shapely.points(xy)) / hull[1], nan=1e3)
        centre = np.asarray(hull[0].centroid.coords[0])
        offset = (xy - centre) / hull[1]
    return ScaleTerms(cal, outside, offset)


def cumulative_travel_m(x_m: np.ndarray, y_m: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distance travelled (m, (N,), 0 at the first point) along the direction of travel ``direction`` (N, 2 unit
    vectors): each step of the path projected on the mean direction at its two ends."""
    mid = direction[1:] + direction[:-1]
    norm = np.hypot(mid[:, 0], mid[:, 1])
    mid = np.where(norm[:, None] > 1e-9, mid / np.where(norm > 1e-9, norm, 1.0)[:, None], direction[1:])
    return np.concatenate([[0.0], np.cumsum(np.diff(x_m) * mid[:, 0] + np.diff(y_m) * mid[:, 1])])


@dataclass(frozen=True)
class WindowSpeed:
    """A vehicle's headline speed (m/s), its 1-sigma (m/s) and the window it was measured over (s)."""

    speed_mps: float
    std_mps: float
    start_s: float
    end_s: float


def window_speed(time_s: np.ndarray, travel_m: np.ndarray, position_std_m: np.ndarray,
                 terms: ScaleTerms | None = None, options: SpeedOptions | None = None) -> WindowSpeed:
    """The headline speed of one vehicle: ``travel_m`` is :func:`cumulative_travel_m`, ``position_std_m`` the
    smoothed positions' 1-sigma (m), ``terms`` its points' :class:`ScaleTerms` (None: nothing known, the window
    is the middle ``core_fraction`` of the time seen).

    The speed is the chord of the smoothed path along the direction of travel over the window: a least-squares
    slope over the window's points reads 15-20 % noisier on smoothed tracks (their errors are correlated).
    With ``terms`` the window (``core_fraction`` of the time seen, or 1/2 or 3/4 of that) minimizes the speed's
    expected squared error: the position noise at its ends, the covariance's scale variance over it, and a scale
    bias risk of ``hull_scale_pct`` % per hull radius of (a) its mean distance outside the control points' hull and
    (b) how far its mean position lies from the hull's centroid: an error that grows with the distance from the
    control points cancels to first order over a window centred on them."""
    opts = options or SpeedOptions()
    t = np.asarray(time_s, dtype=np.float64)
    duration = float(t[-1] - t[0])
    if duration <= 0:
        return WindowSpeed(float("nan"), float("nan"), float(t[0]), float(t[-1]))
    fractions = (1.0,) if terms is None else SHORTER_WINDOWS
    spans = sorted({min(duration, max(f * opts.core_fraction * duration, opts.min_core_s)) for f in fractions})
    starts_l, ends_l = [], []
    for span in spans:
        st = np.flatnonzero(t <= t[-1] - span + 1e-9)
        starts_l.append(st)
        ends_l.append(np.clip(np.searchsorted(t, t[st] + span - 1e-9), 0, t.size - 1))
    starts, ends = np.concatenate(starts_l), np.concatenate(ends_l)
    dt = t[ends] - t[starts]
    good = dt > 0
    starts, ends, dt = starts[good], ends[good], dt[good]
    speed = (travel_m[ends] - travel_m[starts]) / dt
    noise_var = (position_std_m[starts] ** 2 + position_std_m[ends] ** 2) / dt**2
    centre = 0.5 * (t[starts] + t[ends]) - 0.5 * (t[0] + t[-1])
    if terms is None:
        k = int(np.argmin(np.abs(centre)))
        cal_var = np.zeros_like(speed)
    else:
        def window_mean(values: np.ndarray) -> np.ndarray:
            c = np.concatenate([[0.0], np.cumsum(values)])
            return (c[ends + 1] - c[starts]) / (ends - starts + 1)

        cal = np.asarray(terms.cal, dtype=np.float64)
        cal = np.where(np.isfinite(cal), cal, np.nanmax(np.r_[cal, 0.05]))
        v2 = float(np.median(speed)) ** 2
        cal_var = window_mean(cal**2) * v2
        off = np.hypot(window_mean(terms.offset[:, 0]), window_mean(terms.offset[:, 1]))
        bias = 0.01 * opts.hull_scale_pct * (window_mean(terms.outside) + off)
        cost = cal_var + bias**2 * v2 + noise_var
        best = float(np.min(cost))
        near = np.flatnonzero(cost <= best * (1.0 + 1e-6) + 1e-12)
        k = int(near[np.argmin(np.abs(centre[near]))])
    return WindowSpeed(float(speed[k]), float(np.sqrt(noise_var[k] + cal_var[k])), float(t[starts[k]]),
                       float(t[ends[k]]))


# ------------------------------------------------------------------------------------------------ the symptom
def _band_text(band: pd.DataFrame, dev: float) -> str:
    lo, hi = band["distance_m"].quantile([0.05, 0.95])
    v_lo, v_hi = band["v"].quantile([0.05, 0.95])
    x, y = band["x"].median(), band["y"].median()
    return (f"{dev:+.1f} % at {lo:.0f}-{hi:.0f} m from the camera (image rows {v_lo:.0f}-{v_hi:.0f}, around "
            f"x {x:.1f}, y {y:.1f})")


def scale_drift_warning(camera: Camera, points: pd.DataFrame, vehicles: pd.DataFrame,
                        options: SpeedOptions | None = None) -> str | None:
    """A warning when vehicles as a whole read faster or slower at some distance from the camera than their own
    headline speed (measured where the scale is best known): the camera's ground scale is off there.

    Each point's speed over its vehicle's ``speed_kmh`` (vehicles of steady speed only: that ratio, divided by its
    distance band's median over all vehicles, within +-15 % of 1 for 80 % of the time; the first and last
    ``drift_end_s`` of each track left out) is grouped into
    ``drift_bands`` bands of distance from the camera; per band, the median over vehicles of each vehicle's median
    ratio. A band is reported when it has ``drift_min_vehicles`` vehicles and its median differs from 1 by at least
    ``drift_min_pct`` % and four standard errors (from the spread over vehicles)."""
    opts = options or SpeedOptions()
    need = {"track_id", "time", "speed_kmh", "x", "y", "v"}
    if not len(points) or not len(vehicles) or not need <= set(points.columns):
        return None
    crs = camera_crs(camera)
    m = metres_per_unit(crs) if crs is not None else 1.0
    head = vehicles.set_index("track_id")["speed_kmh"]
    pts = points[list(need)].copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        pts["ratio"] = pts["speed_kmh"].to_numpy() / pts["track_id"].map(head).to_numpy()
    pts["distance_m"] = np.hypot(pts["x"] - camera.position[0], pts["y"] - camera.position[1]) * m
    grp = pts.groupby("track_id", sort=False)["time"]
    inner = (pts["time"] >= grp.transform("min") + opts.drift_end_s) & \
            (pts["time"] <= grp.transform("max") - opts.drift_end_s)
    pts = pts[inner & np.isfinite(pts["ratio"]) & (pts["track_id"].map(head).to_numpy() > 10.0)]
    if not len(pts):
        return None
    # steady: judged on what is left once each distance band's shared ratio is divided out, so that a large drift
    # (which every vehicle there shares) does not make all vehicles look unsteady and silence the warning
    pre = np.quantile(pts["distance_m"], np.linspace(0.0, 1.0, opts.drift_bands + 1))
    pre_band = np.clip(np.searchsorted(pre, pts["distance_m"], side="right") - 1, 0, opts.drift_bands - 1)
    shared = pts.groupby(pre_band)["ratio"].transform("median")
    own = (pts["ratio"] / shared).groupby(pts["track_id"])
    steady = own.agg(lambda r: np.mean(np.abs(r - 1.0) <= 0.15) >= 0.8)
    pts = pts[pts["track_id"].map(steady).to_numpy(dtype=bool)]
    if pts["track_id"].nunique() < opts.drift_min_vehicles:
        return None
    edges = np.quantile(pts["distance_m"], np.linspace(0.0, 1.0, opts.drift_bands + 1))
    pts = pts.assign(band=np.clip(np.searchsorted(edges, pts["distance_m"], side="right") - 1, 0,
                                  opts.drift_bands - 1))
    per_vehicle = pts.groupby(["band", "track_id"])["ratio"].median().rename("r").reset_index()
    found = []
    for band, g in per_vehicle.groupby("band"):
        r = g["r"].to_numpy()
        if r.size < opts.drift_min_vehicles:
            continue
        med = float(np.median(r))
        se = 1.4826 * float(np.median(np.abs(r - med))) / np.sqrt(r.size) * 1.253
        dev = 100.0 * (med - 1.0)
        if abs(dev) >= opts.drift_min_pct and abs(med - 1.0) >= 4.0 * se:
            found.append((abs(dev), _band_text(pts[pts["band"] == band], dev)))
    if not found:
        return None
    found.sort(reverse=True)
    where = "; ".join(text for _, text in found)
    return (f"vehicles as a whole read faster or slower at the same place than where their speed is measured: "
            f"{where}. At steady speeds this is the camera's ground scale being off there by about that much "
            "(a calibration fitted to control points elsewhere, e.g. a pitch or focal error); the headline speeds "
            "are measured where the calibration knows the scale best, but positions and spot speeds there are off: "
            "add control points in that range and calibrate again (ignore this if traffic really speeds up or "
            "slows down there)")
