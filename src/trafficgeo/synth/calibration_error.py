"""Constant-speed vehicles seen by a roadside camera, analysed with cameras that are slightly wrong in the way real
calibrations are: for checking speed estimators against calibration error with an exact truth.

The scene: a straight two-way road running north from beside a camera :data:`HEIGHT_M` m up (1920 x 1080, focal
:data:`FOCAL_PX` px, looking north :data:`TILT_DEG` deg down), vehicles at constant speeds in both directions from
the bottom of the image (~14 m) to ``far_m`` (default 75 m) away. Control points (:func:`control_points`) lie on
the road between :data:`CONTROL_M` m from the camera, as a surveyor would put them in the middle of the view.

Wrong cameras (:func:`wrong_camera`), each still placing the control points where they are, as a calibration
would (re-fitted by least squares on the control points' ground positions from their true pixels, in metres):

* ``exact`` - the true camera;
* ``pitch`` - the tilt off by ``+0.4`` deg (the camera taken to look that much higher), position, heading, roll,
  focal length and k1 re-fitted (the control points' pixels then move by up to 3.5 px);
* ``focal`` - the focal length ``+2.5`` %, position, heading, tilt, roll and k1 re-fitted (up to 2.2 px);
* ``warp`` - the true camera, but the ground positions it gives are warped radially from the camera: the ground
  scale along the line of sight is ``+4`` % near the camera, right among the control points and ``-1`` % far
  (:func:`scale_warp`: a distortion-like error the camera model does not have).

:func:`tracks_through_true_camera` projects the vehicles through the TRUE camera (warped positions for ``warp``)
with pixel noise (white and correlated), so analysing them with the wrong camera shows its scale error.
:func:`control_covariance` is the parameter covariance a calibration from those control points would report.
Units: metres (a local CRS-less frame, z up), seconds, km/h, pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from trafficgeo.calibration.params import project_full
from trafficgeo.camera.calibrated import CameraCovariance
from trafficgeo.camera.model import Camera
from trafficgeo.camera.parameters import camera_to_full
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import pixels_to_world
from trafficgeo.geo.surface import ConstantSurface
from trafficgeo.run.tracks import ImageTracks
from trafficgeo.synth.noisy_paths import ar1_noise, point_tracks
from trafficgeo.traffic.speed import ScaleKnowledge

HEIGHT_M = 12.0
FOCAL_PX = 1400.0
TILT_DEG = 20.0
IMAGE_SIZE = (1920, 1080)
LANES_X_M = (3.0, 6.5)  # lane centres (m east of the camera): northbound, southbound
CONTROL_M = (25.0, 55.0)  # control points lie this far north of the camera (m)
ROAD_M = (5.0, 75.0)  # vehicles drive between these distances north of the camera (the near end out of view)
WRONG = ("exact", "pitch", "focal", "warp")


def true_camera() -> Camera:
    """The scene's true camera at the origin, :data:`HEIGHT_M` m up, looking north."""
    return Camera.from_orientation(IMAGE_SIZE, FOCAL_PX, [0.0, 0.0, HEIGHT_M], 0.0, TILT_DEG)


def control_points() -> np.ndarray:
    """(12, 3) ground control points (m) on the road between :data:`CONTROL_M` m north of the camera."""
    y = np.linspace(*CONTROL_M, 4)
    x = np.array([-2.0, 4.75, 11.5])
    xx, yy = np.meshgrid(x, y)
    return np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])


def scale_warp(xy: np.ndarray, camera: Camera) -> np.ndarray:
    """Ground positions (N, 2) moved radially from the camera so that the scale along the line of sight is
    ``1 + a(d)``: ``a`` = +4 % up to 18 m away, falling linearly to 0 at :data:`CONTROL_M`'s near end, 0 among the
    control points, falling to -1 % at 20 m beyond their far end and staying there."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    rel = xy - camera.position[:2]
    d = np.hypot(rel[:, 0], rel[:, 1])
    knots = np.array([0.0, 18.0, CONTROL_M[0], CONTROL_M[1], CONTROL_M[1] + 20.0, 1e4])
    a = np.array([0.04, 0.04, 0.0, 0.0, -0.01, -0.01])
    grid = np.linspace(0.0, 400.0, 40001)
    g = np.concatenate([[0.0], np.cumsum(1.0 + np.interp(0.5 * (grid[1:] + grid[:-1]), knots, a)) * 0.01])
    scale = np.where(d > 1e-9, np.interp(d, grid, g) / np.where(d > 1e-9, d, 1.0), 1.0)
    return camera.position[:2] + rel * scale[:, None]


def _pose_camera(p: np.ndarray, focal_px: float | None, tilt_deg: float | None) -> Camera:
    """A camera from the fitted values ``p`` (x, y, z, heading, roll, then tilt and/or focal where not held)."""
    x, y, z, heading, roll, k1, *rest = p
    tilt = rest.pop(0) if tilt_deg is None else tilt_deg
    focal = rest.pop(0) if focal_px is None else focal_px
    return Camera.from_orientation(IMAGE_SIZE, focal, [x, y, z], heading, tilt, roll, dist=[k1, 0, 0, 0, 0])


def wrong_camera(kind: str) -> Camera:
    """The camera a calibration of the kind ``kind`` (:data:`WRONG`) gives; see the module docstring."""
    cam = true_camera()
    if kind not in WRONG:
        raise InputError(f"wrong camera {kind!r}: give one of {', '.join(WRONG)}", parameters=("kind",))
    if kind in ("exact", "warp"):
        return cam
    gcp = control_points()
    target = cam.project(gcp)
    focal = FOCAL_PX * 1.025 if kind == "focal" else None
    tilt = TILT_DEG - 0.4 if kind == "pitch" else None  # tilt is the depression angle: 0.4 deg less looks higher
    p0 = [0.0, 0.0, HEIGHT_M, 0.0, 0.0, 0.0] + ([] if tilt is not None else [TILT_DEG]) + \
        ([] if focal is not None else [FOCAL_PX])
    surface = ConstantSurface(0.0)

    def ground_error_m(p: np.ndarray) -> np.ndarray:
        hit = pixels_to_world(_pose_camera(p, focal, tilt), target, surface, with_lonlat=False, frame_margin_px=1e6)
        return np.nan_to_num(hit.xyz[:, :2] - gcp[:, :2], nan=1e3).ravel()

    fit = least_squares(ground_error_m, p0, x_scale=1.0)
    return _pose_camera(fit.x, focal, tilt)


def control_covariance(camera: Camera, sigma_px: float = 1.0) -> CameraCovariance:
    """The covariance of the OpenCV parameter vector a calibration of ``camera`` from :func:`control_points`
    measured with ``sigma_px`` px of noise reports: ``sigma_px^2 (J^T J)^-1`` over rotation, translation and one
    focal length (square pixels; principal point and distortion held), about the camera's own position."""
    origin = np.asarray(camera.position, dtype=np.float64)
    values = camera_to_full(camera, origin)
    _uv, J = project_full(values, control_points() - origin)
    A = np.zeros((15, 7))  # the 7 fitted parameters -> the 15-vector (fx and fy are one focal length)
    A[np.arange(6), np.arange(6)] = 1.0
    A[6:8, 6] = 1.0
    Jf = J @ A
    matrix = A @ (sigma_px**2 * np.linalg.inv(Jf.T @ Jf)) @ A.T
    return CameraCovariance(origin=origin, values=values, matrix=matrix)


def knowledge_of(camera: Camera, sigma_px: float = 1.0) -> ScaleKnowledge:
    """What the calibration of ``camera`` knows of its ground scale: :func:`control_covariance` and the control
    points."""
    return ScaleKnowledge(covariance=control_covariance(camera, sigma_px), control_xy=control_points()[:, :2])


@dataclass(frozen=True)
class PixelNoise:
    """Noise of the ground contact pixel (1-sigma, px): white, plus a part correlated over ``correlation_s``."""

    white_px: float = 1.5
    correlated_px: float = 1.5
    correlation_s: float = 0.5


def tracks_through_true_camera(speeds_kmh: np.ndarray, noise: PixelNoise, *, warp: bool = False,
                               fps: float = 30.0, headway_s: float = 2.0, far_m: float = ROAD_M[1],
                               seed: int = 0) -> tuple[ImageTracks, dict[str, float]]:
    """Image tracks of vehicles at constant ``speeds_kmh`` (alternately northbound and southbound) between
    ``ROAD_M[0]`` and ``far_m`` m north of the camera, projected through :func:`true_camera` (of
    :func:`scale_warp`-ed positions with ``warp``) with pixel ``noise``; points in the image only. Returns the
    tracks (ids ``"v0", "v1", ...``) and each track's true speed (km/h)."""
    speeds = np.asarray(speeds_kmh, dtype=np.float64).reshape(-1)
    if not (np.all(np.isfinite(speeds)) and np.all(speeds > 0)):
        raise InputError("tracks_through_true_camera: speeds must be positive km/h", parameters=("speeds_kmh",))
    if not ROAD_M[0] + 20.0 <= far_m <= 200.0:
        raise InputError(f"tracks_through_true_camera: far_m {far_m:g} must be between {ROAD_M[0] + 20:g} and 200 m",
                         parameters=("far_m",))
    rng = np.random.default_rng(seed)
    cam = true_camera()
    paths = []
    for k, kmh in enumerate(speeds):
        v = kmh / 3.6
        start = round(k * headway_s * fps)
        t = np.arange(start, start + (far_m - ROAD_M[0]) / v * fps) / fps
        s = v * (t - t[0])
        north = k % 2 == 0
        y = ROAD_M[0] + s if north else far_m - s
        xy = np.column_stack([np.full(t.size, LANES_X_M[0 if north else 1]), y])
        if warp:
            xy = scale_warp(xy, cam)
        uv = cam.project(np.column_stack([xy, np.zeros(t.size)]))
        uv += rng.normal(0.0, noise.white_px, uv.shape)
        uv += np.column_stack([ar1_noise(rng, t.size, noise.correlated_px, noise.correlation_s, fps)
                               for _ in (0, 1)])
        paths.append((f"v{k}", start, t, uv))
    return point_tracks(cam, paths), {f"v{k}": float(s) for k, s in enumerate(speeds)}
