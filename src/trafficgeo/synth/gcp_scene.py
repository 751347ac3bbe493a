"""Synthetic calibration scenes with known truth: a road seen by a roadside camera, with GCPs and planted outliers.

A scene is what a user of trafficgeo would produce when calibrating a camera from ground control points: a camera
(smartphone on a tripod or a traffic camera on a pole) standing beside a straight road, GCPs at lane-marking corners
whose world coordinates were read off an orthophoto (X, Y) and a point cloud / DEM (Z), and the pixels where the
user clicked them. Everything is generated from a seed, so tests and the benchmark can compare a calibration with the
truth (:attr:`GCPScene.camera`, :attr:`GCPScene.true_world`, :attr:`GCPScene.true_pixels`).

Geometry
--------
* The road is straight with azimuth ``a`` (clockwise from north); its surface (:class:`RoadSurface`) has a grade
  along the axis, a crowned crossfall (falling both ways from the centre line) and optionally a parabolic crest,
  so it is not a plane: a calibration that assumes a flat ground is visibly wrong on it.
* The camera stands beside the road, 3-10 m beyond the edge, ``camera_height`` above the nearest road edge,
  looking along the road and turned towards it by 5-75 deg (from "along" to "nearly across"), so that the road
  fills the lower part of the frame.
* Candidate features are lane-marking corners on a grid of stations every 3 m (multiples of 3 m from the road
  origin) at the lane boundaries (both edge lines included), 10-120 m in front of the camera (camera-frame depth)
  and inside the image with a 2 % margin on each side. Elevated features are the tops of poles and signs standing
  0.5-3 m beyond either road edge, 0.5-6 m above the road surface. A spread-out subset is kept by farthest-point
  sampling in the image (random start), which covers near and far.

Noise and outliers
------------------
* Survey noise: independent Gaussian, ``survey_sigma`` on X, Y (orthophoto) and on Z (point cloud).
* Pixel noise: Gaussian ``pixel_sigma`` on u and v; observed pixels are rounded to 0.01 px.
* Planted outliers (``n_outliers``, among the *control* points only), kinds cycling ``pixel``, ``elevation``,
  ``ortho``:

  - ``pixel``: a wrong click, offset by 15-60 px in a random direction;
  - ``elevation``: Z too high by 3-10 m (the point cloud hit a tree or a vehicle);
  - ``ortho``: X, Y off by 1.5-5 m in a random direction (the neighbouring marking was picked on the orthophoto).

  **Outlier rule** (this defines what the benchmark calls an outlier): a planted error must be a gross error *in
  the image*. Its image displacement -- ``|observed pixel - true pixel|`` for a wrong click, or
  ``|camera.project(observed world point) - true pixel|`` for a wrong world coordinate (survey noise included) --
  must be at least ``12 * pixel_sigma``, at least 8 px, and at least 8 times the point's own noise in the image,
  ``sigma_eff = sqrt(pixel_sigma^2 + (f * survey_sigma / depth)^2)`` (survey noise matters near the camera: 3 cm at
  10 m is 8 px at f = 2800 px; an error inside a few sigma_eff is noise, not a detectable blunder), and the
  displaced point must still lie inside the image
  (in front of the camera, within the lens model's monotonic radius). The error is redrawn up to 50 times until it
  satisfies this; a point for which it never does is swapped for another control point.

Coordinates are large on purpose (EPSG:2949 around (245000, 5182600, 90)): code under test must keep float64
precision, e.g. by subtracting a local origin before squaring anything.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from trafficgeo.calibration.gcp_table import GCPTable
from trafficgeo.camera.distortion import as_dist, max_monotonic_radius
from trafficgeo.camera.model import Camera
from trafficgeo.crs import is_geographic, metres_per_unit, parse_crs
from trafficgeo.geo.surface import DEMSurface

__all__ = ["GCPScene", "RoadSurface", "make_gcp_scene"]

OUTLIER_KINDS = ("pixel", "elevation", "ortho")

_STATION_STEP = 3.0  # m between candidate stations (dash ends of lane markings)
_MIN_DEPTH = 10.0  # m, nearest candidate in front of the camera
_MAX_DEPTH = 120.0  # m, farthest candidate
_IMAGE_MARGIN = 0.02  # fraction of width / height kept free at each side
_MAX_GEOMETRY_ATTEMPTS = 40
_MAX_OUTLIER_DRAWS = 50
_PIXEL_ROUNDING = 0.01  # px, observed pixels are rounded to this step


@dataclass(frozen=True, eq=False)
class RoadSurface:
    """Road surface Z(x, y) in world units about a local origin: grade along the road axis, crowned crossfall
    (falling both ways from the centre line), a vertical crest (parabolic), on a straight road axis with a given
    azimuth.

    With ``s`` the station along the axis and ``o`` the lateral offset (right of the axis positive) of a point
    relative to ``origin``::

        Z = origin_z + grade * s - crossfall * |o| - s^2 / (2 crest_radius)

    (the last term only when ``crest_radius > 0``). The formula is defined everywhere, so the verges continue the
    crossfall of the carriageway.

    The axis is straight, or with ``curve_radius`` a circular arc through ``origin`` that leaves it along
    ``azimuth_deg`` and turns right (``curve_radius > 0``) or left (``< 0``): station is arc length along the axis
    and offset is measured along the radius (valid for ``|o| < |curve_radius|``).
    """

    origin: np.ndarray  # (3,) world point on the road centre line at the scene centre
    azimuth_deg: float  # road axis direction, clockwise from north
    grade: float = 0.0  # dZ/ds along the axis (0.03 = 3 %)
    crossfall: float = 0.0  # fall from the crown per unit offset (0.02 = 2 % each way); 0 = flat section
    crest_radius: float = 0.0  # vertical curve radius (m); 0 = none; Z -= s^2 / (2 R)
    curve_radius: float = 0.0  # horizontal curve radius (m): > 0 turns right, < 0 left, 0 = straight

    def __post_init__(self) -> None:
        origin = np.array(self.origin, dtype=np.float64).reshape(-1)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f"RoadSurface.origin must be 3 finite numbers, got {self.origin!r}")
        object.__setattr__(self, "origin", origin)
        for name in ("azimuth_deg", "grade", "crossfall", "crest_radius", "curve_radius"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise ValueError(f"RoadSurface.{name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        if self.crest_radius < 0:
            raise ValueError(f"RoadSurface.crest_radius must be >= 0 (0 = no crest), got {self.crest_radius}")

    @property
    def axis(self) -> np.ndarray:
        """Unit (east, north) vector of the road axis."""
        a = np.radians(self.azimuth_deg)
        return np.array([np.sin(a), np.cos(a)])

    @property
    def right(self) -> np.ndarray:
        """Unit (east, north) vector pointing right of the axis (azimuth + 90 deg)."""
        a = np.radians(self.azimuth_deg)
        return np.array([np.cos(a), -np.sin(a)])

    def station_offset(self, x: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Station along the axis and lateral offset (right positive) of world points, relative to ``origin``."""
        dx = np.asarray(x, dtype=np.float64) - self.origin[0]
        dy = np.asarray(y, dtype=np.float64) - self.origin[1]
        t, n = self.axis, self.right
        if self.curve_radius == 0.0:
            return dx * t[0] + dy * t[1], dx * n[0] + dy * n[1]
        R = self.curve_radius
        # Relative to the circle's centre C = origin + R * right; u0 = -right points from C to the origin.
        cx, cy = dx - R * n[0], dy - R * n[1]
        dist = np.hypot(cx, cy)
        u0x, u0y = -n[0], -n[1]
        sgn = np.sign(R)
        ux, uy = sgn * cx, sgn * cy
        theta = -np.arctan2(u0x * uy - u0y * ux, u0x * ux + u0y * uy)  # clockwise angle from u0 to u
        return R * theta, R - sgn * dist

    def _z_local(self, s: np.ndarray, offset: np.ndarray) -> np.ndarray:
        dz = self.grade * s - self.crossfall * np.abs(offset)
        if self.crest_radius > 0:
            dz = dz - s * s / (2.0 * self.crest_radius)
        return self.origin[2] + dz

    def z(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Road surface height at world ``(x, y)`` (arrays broadcast together)."""
        s, o = self.station_offset(x, y)
        return self._z_local(s, o)

    def sampled_dem(self, centre_xy: ArrayLike, half_width: float, cell: float) -> DEMSurface:
        """The road surface sampled at the centres of a square grid of ``cell``-sized cells reaching
        ``half_width`` (world units) either side of ``centre_xy``: a reference DEM with the exact heights."""
        n = round(2 * half_width / cell)
        left, top = float(centre_xy[0]) - half_width, float(centre_xy[1]) + half_width
        x = left + (np.arange(n) + 0.5) * cell
        y = top - (np.arange(n) + 0.5) * cell
        X, Y = np.meshgrid(x, y)
        return DEMSurface(self.z(X, Y), left, top, cell, cell)

    def points(self, s: ArrayLike, offset: ArrayLike) -> np.ndarray:
        """World points (N, 3) on the surface at stations ``s`` and lateral offsets ``offset`` (right positive)."""
        ss, oo = np.broadcast_arrays(np.asarray(s, dtype=np.float64), np.asarray(offset, dtype=np.float64))
        ss, oo = ss.reshape(-1), oo.reshape(-1)
        t, n = self.axis, self.right
        if self.curve_radius == 0.0:
            x = self.origin[0] + ss * t[0] + oo * n[0]
            y = self.origin[1] + ss * t[1] + oo * n[1]
        else:
            R = self.curve_radius
            theta = ss / R
            # u(theta): u0 = -right rotated clockwise by theta; P = C + (R - o) u(theta).
            u0x, u0y = -n[0], -n[1]
            ux = u0x * np.cos(theta) + u0y * np.sin(theta)
            uy = -u0x * np.sin(theta) + u0y * np.cos(theta)
            x = self.origin[0] + R * n[0] + (R - oo) * ux
            y = self.origin[1] + R * n[1] + (R - oo) * uy
        return np.stack([x, y, self._z_local(ss, oo)], axis=-1)

    def heading_at(self, s: ArrayLike) -> np.ndarray:
        """Azimuth (deg clockwise from north) of the axis at stations ``s``."""
        ss = np.asarray(s, dtype=np.float64)
        turn = np.degrees(ss / self.curve_radius) if self.curve_radius else np.zeros_like(ss)
        return (self.azimuth_deg + turn) % 360.0


@dataclass(frozen=True, eq=False)
class GCPScene:
    """A synthetic calibration problem with its truth (see the module docstring for how it is built)."""

    camera: Camera  # the true camera
    gcps: GCPTable  # what a user would measure: noisy world coords and noisy pixels, roles set
    true_world: np.ndarray  # (N,3) true positions of the features
    true_pixels: np.ndarray  # (N,2) true projections (camera.project(true_world))
    outlier: np.ndarray  # (N,) bool, planted gross errors
    outlier_kind: tuple[str, ...]  # "" | "pixel" | "elevation" | "ortho"
    road: RoadSurface
    pixel_sigma: float
    survey_sigma: float


# ---------------------------------------------------------------------------------------------------------- helpers
def _visible(camera: Camera, world: np.ndarray, r_max: float, margin: float = _IMAGE_MARGIN) -> np.ndarray:
    """Boolean (N,): in front of the camera (depth 10-120 m), within the lens model's monotonic radius and inside
    the image shrunk by ``margin`` (fraction of width/height) on each side."""
    xc = camera.world_to_camera(world)
    depth = xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.hypot(xc[:, 0], xc[:, 1]) / depth
    uv = camera.project(world)
    w, h = camera.image_size
    mu, mv = margin * w, margin * h
    return ((depth >= _MIN_DEPTH) & (depth <= _MAX_DEPTH) & (r < r_max)
            & (uv[:, 0] >= -0.5 + mu) & (uv[:, 0] <= w - 0.5 - mu)
            & (uv[:, 1] >= -0.5 + mv) & (uv[:, 1] <= h - 0.5 - mv))


def _in_frame(camera: Camera, world: np.ndarray | None, uv: np.ndarray, r_max: float) -> bool:
    """Whether a (displaced) point is inside the image; for world points also in front and within ``r_max``."""
    if not np.all(np.isfinite(uv)) or not bool(camera.in_image(uv)[0]):
        return False
    if world is not None:
        xc = camera.world_to_camera(world)[0]
        if not xc[2] > 0 or np.hypot(xc[0], xc[1]) / xc[2] >= r_max:
            return False
    return True


def _farthest_points(uv: np.ndarray, k: int, rng: np.random.Generator, seeds: np.ndarray | None = None) -> list[int]:
    """Indices of ``k`` rows of ``uv`` chosen by farthest-point sampling; starts from the rows ``seeds`` (already
    chosen elsewhere, not returned) or, without seeds, from a random row."""
    n = uv.shape[0]
    if k <= 0 or n == 0:
        return []
    chosen: list[int] = []
    if seeds is not None and len(seeds):
        d = np.min(np.linalg.norm(uv[:, None, :] - seeds[None, :, :], axis=-1), axis=1)
    else:
        first = int(rng.integers(n))
        chosen.append(first)
        d = np.linalg.norm(uv - uv[first], axis=1)
    d[chosen] = -1.0
    while len(chosen) < min(k, n):
        nxt = int(np.argmax(d))
        chosen.append(nxt)
        d = np.minimum(d, np.linalg.norm(uv - uv[nxt], axis=1))
        d[chosen] = -1.0
    return chosen


def _unit_vector_2d(rng: np.random.Generator) -> np.ndarray:
    ang = rng.uniform(0.0, 2.0 * np.pi)
    return np.array([np.cos(ang), np.sin(ang)])


def _check_count(name: str, value: int, minimum: int = 0) -> int:
    if int(value) != value or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


# ---------------------------------------------------------------------------------------------------------- scene
def make_gcp_scene(
    seed: int,
    *,
    image_size: tuple[int, int] = (1920, 1080),
    n_control: int = 12,
    n_check: int = 0,
    n_outliers: int = 0,
    n_elevated: int = 2,
    pixel_sigma: float = 1.0,
    survey_sigma: float = 0.025,
    grade: float = 0.02,
    crossfall: float = 0.02,
    crest_radius: float = 0.0,
    camera_height: float = 8.0,
    focal_px: float | None = None,
    dist: ArrayLike | None = None,
    heading_deg: float | None = None,
    tilt_deg: float | None = None,
    roll_deg: float | None = None,
    lanes: int = 3,
    lane_width: float = 3.5,
    origin: tuple[float, float, float] = (245000.0, 5182600.0, 90.0),
    crs: str | None = "EPSG:2949",
) -> GCPScene:
    """A synthetic road scene with ``n_control`` control and ``n_check`` check GCPs (see the module docstring).

    Deterministic for a ``seed`` (``numpy.random.default_rng(seed)``). Parameters left at None are drawn at random
    in realistic ranges:

    * ``focal_px``: uniform 0.7-1.3 x image width (a phone's main lens is ~0.8 W, traffic cameras zoom in more);
    * ``dist``: mild phone distortion, k1 uniform in [-0.15, 0.05], k2 in [-0.05, 0.05], p1 = p2 = k3 = 0;
    * ``heading_deg``: any (the road azimuth is uniform, the camera looks along the road turned 5-75 deg towards
      it); when given, the road azimuth is drawn relative to it instead, so the camera still sees the road;
    * ``tilt_deg``: uniform 8-25 deg below the horizon; for low cameras the range is lowered so that the optical
      axis meets the road at least 12 m away: ``[min(8, 0.6 t12), min(25, t12)]`` with
      ``t12 = atan(camera_height / 12 m)`` (an 8 m pole keeps 8-25 deg, a 1.5 m tripod gets 4.3-7.1 deg);
    * ``roll_deg``: uniform within +-2 deg.

    Always random: road azimuth (or its angle to a given heading), the camera's side of the road, its distance
    beyond the road edge (3-10 m) and its station (20-50 m before the road origin, centre of the crest parabola when
    ``crest_radius > 0``). If a random draw leaves too few visible candidates the random parts are redrawn (up to
    40 times, still deterministic).

    ``n_elevated`` of the control points are tops of poles/signs 0.5-6 m above the road. The table's ``sigma_px``
    is ``pixel_sigma`` for every point (0.01 px, the rounding step, when ``pixel_sigma`` is 0, since a table's
    sigma must be positive); ``crs`` must be projected in metres, or None for local coordinates; ids are ``G01``,
    ``G02``, ... (control first, then check).

    Raises:
        ValueError: impossible options, or the requested points cannot be placed in view (e.g. the camera looks at
            the sky), or outliers cannot be planted as gross errors inside the image.
    """
    n_control = _check_count("n_control", n_control, 1)
    n_check = _check_count("n_check", n_check)
    n_outliers = _check_count("n_outliers", n_outliers)
    n_elevated = _check_count("n_elevated", n_elevated)
    lanes = _check_count("lanes", lanes, 1)
    if n_elevated > n_control:
        raise ValueError(f"n_elevated ({n_elevated}) cannot exceed n_control ({n_control})")
    if n_outliers > n_control:
        raise ValueError(f"n_outliers ({n_outliers}) cannot exceed n_control ({n_control}): outliers are planted "
                         "among control points only")
    w, h = (int(v) for v in image_size)
    if w <= 0 or h <= 0:
        raise ValueError(f"image_size must be positive (width, height), got {image_size!r}")
    for name, value in (("pixel_sigma", pixel_sigma), ("survey_sigma", survey_sigma)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    for name, value in (("camera_height", camera_height), ("lane_width", lane_width)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    if focal_px is not None and not (np.isfinite(focal_px) and focal_px > 0):
        raise ValueError(f"focal_px must be a positive number, got {focal_px!r}")
    origin_arr = np.array(origin, dtype=np.float64).reshape(-1)
    if origin_arr.shape != (3,) or not np.all(np.isfinite(origin_arr)):
        raise ValueError(f"origin must be 3 finite numbers (X, Y, Z), got {origin!r}")
    pixel_sigma = float(pixel_sigma)
    survey_sigma = float(survey_sigma)
    crs_obj = parse_crs(crs)
    if crs_obj is not None and (is_geographic(crs_obj) or abs(metres_per_unit(crs_obj) - 1.0) > 1e-9):
        raise ValueError(f"crs must be a projected CRS in metres (X east, Y north), got {crs!r}")
    crs_text = None if crs_obj is None else (crs if isinstance(crs, str) else crs_obj.to_string())

    rng = np.random.default_rng(seed)
    half_width = 0.5 * lanes * lane_width
    boundaries = -half_width + lane_width * np.arange(lanes + 1)  # lane lines, both edge lines included
    t12 = np.degrees(np.arctan(camera_height / 12.0))
    tilt_range = (min(8.0, 0.6 * t12), min(25.0, t12))
    n_road = n_control - n_elevated + n_check

    best = (-1, 0, 0)  # best failed attempt: (score, lane-marking candidates, elevated candidates)
    for _attempt in range(_MAX_GEOMETRY_ATTEMPTS):
        # --- random geometry (all draws happen on every attempt, in a fixed order)
        side = 1.0 if rng.random() < 0.5 else -1.0  # camera right (+1) or left (-1) of the axis
        look = 1.0 if rng.random() < 0.5 else -1.0  # looking towards increasing (+1) or decreasing stations
        beyond_edge = rng.uniform(3.0, 10.0)
        cam_station = -look * rng.uniform(20.0, 50.0)
        turn = rng.uniform(5.0, 75.0)  # deg from "along the road" towards the road
        az_draw = rng.uniform(0.0, 360.0)
        f_draw = rng.uniform(0.7, 1.3) * w
        k_draw = np.array([rng.uniform(-0.15, 0.05), rng.uniform(-0.05, 0.05), 0.0, 0.0, 0.0])
        tilt_draw = rng.uniform(*tilt_range)
        roll_draw = rng.uniform(-2.0, 2.0)

        # The view direction in road coordinates: along (look * axis) turned towards the road (-side * right).
        # Its azimuth relative to the road azimuth, clockwise:
        rel = np.degrees(np.arctan2(-side * np.sin(np.radians(turn)), look * np.cos(np.radians(turn))))
        if heading_deg is None:
            azimuth = az_draw
            heading = (azimuth + rel) % 360.0
        else:
            heading = float(heading_deg) % 360.0
            azimuth = (heading - rel) % 360.0
        road = RoadSurface(origin_arr, azimuth, grade, crossfall, crest_radius)
        focal = float(focal_px) if focal_px is not None else f_draw
        dist_arr = as_dist(dist) if dist is not None else k_draw
        tilt = float(tilt_deg) if tilt_deg is not None else tilt_draw
        roll = float(roll_deg) if roll_deg is not None else roll_draw

        edge = road.points(cam_station, side * half_width)[0]
        cam_xy = road.points(cam_station, side * (half_width + beyond_edge))[0, :2]
        position = np.array([cam_xy[0], cam_xy[1], edge[2] + camera_height])
        camera = Camera.from_orientation((w, h), focal, position, heading, tilt, roll, dist=dist_arr, crs=crs_text)
        r_max = 0.97 * max_monotonic_radius(camera.dist)

        # --- candidates: lane-marking corners on the road, pole/sign tops at the verges
        stations = _STATION_STEP * np.arange(np.floor((cam_station - 140.0) / _STATION_STEP),
                                             np.ceil((cam_station + 140.0) / _STATION_STEP) + 1)
        ss, oo = np.meshgrid(stations, boundaries, indexing="ij")
        road_world = road.points(ss.ravel(), oo.ravel())
        road_world = road_world[_visible(camera, road_world, r_max)]

        n_pole = stations.size * 2
        pole_side = np.tile([-1.0, 1.0], stations.size)
        pole_offset = pole_side * (half_width + rng.uniform(0.5, 3.0, n_pole))
        pole_height = rng.uniform(0.5, 6.0, n_pole)
        pole_world = road.points(np.repeat(stations, 2), pole_offset)
        pole_world[:, 2] += pole_height
        pole_world = pole_world[_visible(camera, pole_world, r_max)]

        if road_world.shape[0] >= n_road and pole_world.shape[0] >= n_elevated:
            break
        score = min(road_world.shape[0], n_road) + min(pole_world.shape[0], n_elevated)
        if score > best[0]:
            best = (score, road_world.shape[0], pole_world.shape[0])
    else:
        raise ValueError(
            f"cannot place {n_control} control + {n_check} check GCPs ({n_elevated} elevated) in view: at best "
            f"{best[1]} lane-marking and {best[2]} elevated candidates were visible 10-120 m in front of the camera "
            f"after {_MAX_GEOMETRY_ATTEMPTS} attempts (camera looking at the sky or away from the road? check "
            f"tilt_deg={tilt_deg}, heading_deg={heading_deg}, focal_px={focal_px}, image_size={image_size})")

    # --- spread-out subsets: elevated first, then road points continuing the farthest-point sampling
    pole_uv = camera.project(pole_world)
    road_uv = camera.project(road_world)
    pole_pick = _farthest_points(pole_uv, n_elevated, rng)
    road_pick = _farthest_points(road_uv, n_road, rng, seeds=pole_uv[pole_pick] if pole_pick else None)
    road_pick_arr = np.array(road_pick, dtype=int)
    is_check = np.zeros(len(road_pick), dtype=bool)
    is_check[rng.choice(len(road_pick), size=n_check, replace=False)] = True
    control_world = np.concatenate([pole_world[pole_pick], road_world[road_pick_arr[~is_check]]])
    control_world = control_world[rng.permutation(control_world.shape[0])]
    true_world = np.concatenate([control_world, road_world[road_pick_arr[is_check]]])
    n = true_world.shape[0]
    true_pixels = camera.project(true_world)

    # --- measurement noise
    world_obs = true_world + rng.normal(0.0, 1.0, (n, 3)) * survey_sigma
    pixel_noise = rng.normal(0.0, 1.0, (n, 2)) * pixel_sigma
    pixel_obs = true_pixels + pixel_noise

    # --- planted outliers among control points
    outlier = np.zeros(n, dtype=bool)
    kinds = [""] * n
    depth = camera.world_to_camera(true_world)[:, 2]
    sigma_eff = np.sqrt(pixel_sigma ** 2 + (camera.focal_px * survey_sigma / depth) ** 2)
    order = list(rng.permutation(n_control))
    threshold = max(12.0 * pixel_sigma, 8.0)
    for j in range(n_outliers):
        kind = OUTLIER_KINDS[j % len(OUTLIER_KINDS)]
        planted = False
        while order and not planted:
            i = int(order.pop(0))
            threshold = max(12.0 * pixel_sigma, 8.0, 8.0 * float(sigma_eff[i]))
            for _ in range(_MAX_OUTLIER_DRAWS):
                if kind == "pixel":
                    uv = true_pixels[i] + pixel_noise[i] + rng.uniform(15.0, 60.0) * _unit_vector_2d(rng)
                    ok = np.hypot(*(uv - true_pixels[i])) >= threshold and _in_frame(camera, None, uv[None], np.inf)
                    if ok:
                        pixel_obs[i] = uv
                else:
                    xyz = world_obs[i].copy()
                    if kind == "elevation":
                        xyz[2] += rng.uniform(3.0, 10.0)
                    else:
                        xyz[:2] += rng.uniform(1.5, 5.0) * _unit_vector_2d(rng)
                    uv = camera.project(xyz[None])
                    ok = (bool(np.all(np.isfinite(uv))) and np.hypot(*(uv[0] - true_pixels[i])) >= threshold
                          and _in_frame(camera, xyz[None], uv, r_max))
                    if ok:
                        world_obs[i] = xyz
                if ok:
                    outlier[i] = True
                    kinds[i] = kind
                    planted = True
                    break
        if not planted:
            raise ValueError(
                f"cannot plant {n_outliers} outliers as gross errors (>= {threshold:.1f} px in the image, still in "
                f"view): failed for outlier {j + 1} of kind {kind!r}; use fewer outliers or a smaller pixel_sigma")

    pixel_obs = np.round(pixel_obs, 2)  # _PIXEL_ROUNDING
    table = GCPTable(
        ids=tuple(f"G{i + 1:02d}" for i in range(n)),
        world=world_obs,
        pixels=pixel_obs,
        roles=("control",) * n_control + ("check",) * n_check,
        sigma_px=np.full(n, pixel_sigma if pixel_sigma > 0 else _PIXEL_ROUNDING),
        crs=crs_obj,
        source="synthetic",
        lines=tuple(range(2, n + 2)),
    )
    return GCPScene(camera=camera, gcps=table, true_world=true_world, true_pixels=true_pixels, outlier=outlier,
                    outlier_kind=tuple(kinds), road=road, pixel_sigma=pixel_sigma, survey_sigma=survey_sigma)
