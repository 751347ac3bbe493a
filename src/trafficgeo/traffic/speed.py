"""A vehicle's headline speed where the calibration knows the ground scale, and the warning when it does not.

A real calibration's ground scale is a few per cent wrong, differently across the view: right among its control
points, off beyond them (towards the camera and far away). At constant true speed the apparent speed then drifts
along a track, and "distance travelled / time seen" averages the drift over the whole path, edges included.

The headline ``speed_kmh`` (:func:`window_speed`) is therefore the distance travelled along the direction of
travel (the smoothed path's steps projected on it) over one window of the time seen, divided by the window's
time: a chord of the smoothed path, whose position noise only enters through the window's two ends. The window
spans ``core_fraction`` of the time seen (at least ``min_core_s``) and sits where the calibration knows the scale
best (:class:`ScaleKnowledge`):

* with the camera JSON's ``covariance`` block, each point's 1-sigma relative scale error along its direction of
  travel (:func:`trafficgeo.geo.uncertainty.along_scale_sigma`);
* with its GCPs, a scale error assumed to grow by ``hull_scale_pct`` % per hull radius outside the convex hull of
  the control points (the calibration model is only checked where they are);
* the window minimizes the speed's variance from both and from the smoothed positions' noise at its ends. Without
  either (a camera made by hand) it is the middle of the time seen.

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

from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs
from trafficgeo.geo.uncertainty import CameraCovariance, along_scale_sigma

BLOCK_POINTS = 8192  # points per block of the covariance propagation


@dataclass(frozen=True)
class SpeedOptions:
    """How the headline speed and the scale-drift warning are computed (see the module docstring)."""

    core_fraction: float = 0.5  # share of the time seen that the speed's window spans
    min_core_s: float = 1.0  # s, the window spans at least this (or all the time seen, when shorter)
    hull_scale_pct: float = 1.0  # %, assumed scale error per hull radius outside the control points' hull
    drift_min_pct: float = 2.0  # %, smallest scale drift the warning reports
    drift_min_vehicles: int = 8  # vehicles needed in a distance band to judge it
    drift_bands: int = 6  # distance bands (equal numbers of points) the warning compares
    drift_end_s: float = 0.5  # s at each end of a track whose point speeds the warning leaves out

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
    def from_document(cls, doc: dict[str, Any] | None, camera: Camera,
                      where: str = "camera JSON") -> ScaleKnowledge | None:
        """From a camera JSON document (``covariance`` block; ``gcps`` list: inlier control points); None for
        no document or one with neither."""
        if doc is None:
            return None
        cov = CameraCovariance.from_document(doc, camera, where)
        rows = [r for r in doc.get("gcps") or [] if isinstance(r, dict) and r.get("role", "control") == "control"
                and r.get("inlier", True)]
        try:
            xy = np.array([[float(r["x"]), float(r["y"])] for r in rows], dtype=np.float64).reshape(-1, 2)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: its gcps list is damaged ({exc}); re-run 'trafficgeo calibrate'") from None
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if cov is None and len(xy) < 3:
            return None
        return cls(covariance=cov, control_xy=xy if len(xy) >= 3 else None)

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


def scale_sigma(camera: Camera, surface: Surface, knowledge: ScaleKnowledge | None, xy: np.ndarray,
                direction_xy: np.ndarray, options: SpeedOptions | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per ground position ``xy`` (N, 2; CRS units) moving along ``direction_xy`` (N, 2): the relative 1-sigma
    scale error the window is chosen by (covariance and hull, combined in quadrature) and the covariance's part
    alone (0 without a covariance). Fractions (0.01 = 1 %); NaN where the covariance cannot be propagated."""
    opts = options or SpeedOptions()
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = xy.shape[0]
    cal = np.zeros(n)
    if knowledge is None:
        return cal.copy(), cal
    if knowledge.covariance is not None and n:
        z = np.asarray(surface.elevation(xy[:, 0], xy[:, 1]), dtype=np.float64).reshape(-1)
        xyz = np.column_stack([xy, z])
        for k in range(0, n, BLOCK_POINTS):
            sl = slice(k, min(k + BLOCK_POINTS, n))
            cal[sl] = along_scale_sigma(camera, xyz[sl], direction_xy[sl], surface, knowledge.covariance)
    total = cal.copy()
    hull = _hull(camera, knowledge.control_xy)
    if hull is not None and n:
        outside = shapely.distance(hull[0], shapely.points(xy)) / hull[1]
        total = np.hypot(total, 0.01 * opts.hull_scale_pct * outside)
    return total, cal


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
                 sigma_total: np.ndarray | None = None, sigma_cal: np.ndarray | None = None,
                 options: SpeedOptions | None = None) -> WindowSpeed:
    """The headline speed of one vehicle (module docstring): ``travel_m`` is :func:`cumulative_travel_m`,
    ``position_std_m`` the smoothed positions' 1-sigma (m), ``sigma_total``/``sigma_cal`` the relative scale errors
    of :func:`scale_sigma` (None: unknown, the window is the middle of the time seen)."""
    opts = options or SpeedOptions()
    t = np.asarray(time_s, dtype=np.float64)
    duration = float(t[-1] - t[0])
    span = min(duration, max(opts.core_fraction * duration, opts.min_core_s))
    starts = np.flatnonzero(t <= t[-1] - span + 1e-9)
    ends = np.clip(np.searchsorted(t, t[starts] + span - 1e-9), 0, t.size - 1)
    if starts.size == 0 or duration <= 0:
        return WindowSpeed(float("nan"), float("nan"), float(t[0]), float(t[-1]))
    dt = t[ends] - t[starts]
    good = dt > 0
    starts, ends, dt = starts[good], ends[good], dt[good]
    speed = (travel_m[ends] - travel_m[starts]) / dt
    noise_var = (position_std_m[starts] ** 2 + position_std_m[ends] ** 2) / dt**2
    centre = 0.5 * (t[starts] + t[ends]) - 0.5 * (t[0] + t[-1])
    if sigma_total is None:
        k = int(np.argmin(np.abs(centre)))
        cal_var = np.zeros_like(speed)
    else:
        total = np.where(np.isfinite(sigma_total), sigma_total, np.nanmax(np.r_[sigma_total, 1.0]))
        cal = np.nan_to_num(np.asarray(sigma_cal if sigma_cal is not None else np.zeros_like(total)), nan=0.0)
        csum, ccal = np.concatenate([[0.0], np.cumsum(total**2)]), np.concatenate([[0.0], np.cumsum(cal**2)])
        count = ends - starts + 1
        mean_total = (csum[ends + 1] - csum[starts]) / count
        cal_var = (ccal[ends + 1] - ccal[starts]) / count * np.median(speed) ** 2
        cost = mean_total * np.median(speed) ** 2 + noise_var
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

    Each point's speed over its vehicle's ``speed_kmh`` (vehicles of steady speed only: their point speeds within
    +-15 % of it for 80 % of the time; the first and last ``drift_end_s`` of each track left out) is grouped into
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
    pts["ratio"] = pts["speed_kmh"].to_numpy() / pts["track_id"].map(head).to_numpy()
    pts["distance_m"] = np.hypot(pts["x"] - camera.position[0], pts["y"] - camera.position[1]) * m
    grp = pts.groupby("track_id", sort=False)["time"]
    inner = (pts["time"] >= grp.transform("min") + opts.drift_end_s) & \
            (pts["time"] <= grp.transform("max") - opts.drift_end_s)
    pts = pts[inner & np.isfinite(pts["ratio"]) & (pts["track_id"].map(head).to_numpy() > 10.0)]
    if not len(pts):
        return None
    steady = pts.groupby("track_id")["ratio"].agg(lambda r: np.mean(np.abs(r - 1.0) <= 0.15) >= 0.8)
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
