"""Vehicles at known constant speeds on a straight or curved road, with position noise sideways and along the
road, seen by a camera looking straight down: image tracks for checking speed estimators against an exact truth.

The road runs east through the point below the camera, straight or bending left on a circle of ``radius_m``. Each
vehicle drives it at its own constant speed; its ground position is disturbed by noise of ``sideways_m`` across
and ``along_m`` along the road (1-sigma, metres), white or correlated over ``correlation_s`` (a first-order
autoregressive process: a detector's box errors persist over a few frames), and optionally a sideways sway
(``sway_m`` at ``sway_hz``: a box edge that wanders across the vehicle as its view changes, which a smoother
follows as motion), then projected into the image. No
pixel noise is added, so the noise is exactly the stated one in metres. Units: metres (a local metric CRS-less
frame), seconds, km/h.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from trafficgeo.camera.model import Camera
from trafficgeo.errors import InputError
from trafficgeo.run.tracks import ImageTracks

HEIGHT_M = 300.0  # camera height above the road (m): 0.2 m per pixel, 384 m x 216 m in view
FOCAL_PX = 1500.0
ROAD_HALF_LENGTH_M = 210.0  # each vehicle drives from -this to +this along the road (beyond the view at both ends)


@dataclass(frozen=True)
class PathNoise:
    """Position noise of the simulated ground points (1-sigma, m) and its correlation time (s; 0: white)."""

    sideways_m: float = 0.3
    along_m: float = 0.3
    correlation_s: float = 0.0
    sway_m: float = 0.0  # amplitude (m) of a sideways sway of the ground point, at a random phase per vehicle
    sway_hz: float = 1.0

    def __post_init__(self) -> None:
        for name in ("sideways_m", "along_m", "correlation_s", "sway_m", "sway_hz"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise InputError(f"PathNoise.{name} = {value!r} must be a finite number >= 0")


def nadir_camera() -> Camera:
    """The camera: 1920 x 1080, looking straight down from :data:`HEIGHT_M` above the origin, image x east."""
    return Camera.from_orientation((1920, 1080), FOCAL_PX, [0.0, 0.0, HEIGHT_M], 0.0, 90.0)


def metres_per_px() -> float:
    """Ground size of one pixel (m) for :func:`nadir_camera`."""
    return HEIGHT_M / FOCAL_PX


def ar1_noise(rng: np.random.Generator, n: int, sigma: float, correlation_s: float, fps: float) -> np.ndarray:
    """(n,) noise of 1-sigma ``sigma`` sampled at ``fps``: first-order autoregressive with correlation time
    ``correlation_s`` (s; 0: white). Draws nothing from ``rng`` when ``sigma`` is 0."""
    if sigma == 0:
        return np.zeros(n)
    if correlation_s <= 0:
        return rng.normal(0.0, sigma, n)
    phi = float(np.exp(-1.0 / (fps * correlation_s)))
    shocks = rng.normal(0.0, sigma * np.sqrt(1.0 - phi**2), n)
    out = np.empty(n)
    out[0] = rng.normal(0.0, sigma)
    for k in range(1, n):
        out[k] = phi * out[k - 1] + shocks[k]
    return out


def road_point(s: np.ndarray, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions (N, 2) m and unit directions (N, 2) at arc lengths ``s`` (m) along the road."""
    s = np.asarray(s, dtype=np.float64)
    if not np.isfinite(radius_m):
        return np.column_stack([s, np.zeros_like(s)]), np.column_stack([np.ones_like(s), np.zeros_like(s)])
    a = s / radius_m
    pos = np.column_stack([radius_m * np.sin(a), radius_m * (1.0 - np.cos(a))])
    return pos, np.column_stack([np.cos(a), np.sin(a)])


def point_tracks(camera: Camera, paths: list[tuple[str, int, np.ndarray, np.ndarray]]) -> ImageTracks:
    """Image tracks of ground-contact points (no boxes, class car) from ``paths``: per vehicle its track id, its
    first frame index, its times (N,) s and its pixels (N, 2); the points outside ``camera``'s image are left out."""
    ids, frames, times, uv = [], [], [], []
    for track_id, start, t, px in paths:
        seen = camera.in_image(np.nan_to_num(px, nan=-1e9))
        ids += [track_id] * int(seen.sum())
        frames.append(start + np.arange(t.size)[seen])
        times.append(t[seen])
        uv.append(px[seen])
    n = len(ids)
    uv_all = np.concatenate(uv) if uv else np.zeros((0, 2))
    return ImageTracks(track_id=np.array(ids, dtype=object),
                       frame=np.concatenate(frames).astype(np.int64) if frames else np.zeros(0, dtype=np.int64),
                       time=np.concatenate(times) if times else np.zeros(0), u=uv_all[:, 0], v=uv_all[:, 1],
                       box=np.full((n, 4), np.nan), vclass=np.full(n, "car", dtype=object), score=np.full(n, np.nan))


def noisy_road_tracks(speeds_kmh: np.ndarray, noise: PathNoise, *, radius_m: float = np.inf, fps: float = 30.0,
                      headway_s: float = 3.0, seed: int = 0) -> tuple[Camera, ImageTracks, pd.Series]:
    """One image track per speed (km/h), the vehicles entering the road ``headway_s`` apart: the camera, the
    tracks (track ids ``"v0", "v1", ...``; points in view only) and each track's true speed (km/h, indexed by
    track id)."""
    speeds = np.asarray(speeds_kmh, dtype=np.float64).reshape(-1)
    if not (np.all(np.isfinite(speeds)) and np.all(speeds > 0)) or not fps > 0:
        raise InputError("noisy_road_tracks: speeds must be positive km/h and fps positive")
    if not radius_m > ROAD_HALF_LENGTH_M / np.pi:
        raise InputError(f"noisy_road_tracks: radius_m {radius_m} is too tight for a {2 * ROAD_HALF_LENGTH_M:g} m "
                         "road (at least its length / 2 pi)")
    rng = np.random.default_rng(seed)
    camera = nadir_camera()
    paths = []
    for k, kmh in enumerate(speeds):
        v = kmh / 3.6
        start = round(k * headway_s * fps)
        t = np.arange(start, start + 2.0 * ROAD_HALF_LENGTH_M / v * fps) / fps
        pos, d = road_point(-ROAD_HALF_LENGTH_M + v * (t - t[0]), radius_m)
        normal = np.column_stack([-d[:, 1], d[:, 0]])
        along = ar1_noise(rng, t.size, noise.along_m, noise.correlation_s, fps)
        side = ar1_noise(rng, t.size, noise.sideways_m, noise.correlation_s, fps)
        side += noise.sway_m * np.sin(2.0 * np.pi * noise.sway_hz * t + rng.uniform(0.0, 2.0 * np.pi))
        xy = pos + along[:, None] * d + side[:, None] * normal
        paths.append((f"v{k}", start, t, camera.project(np.column_stack([xy, np.zeros(t.size)]))))
    tracks = point_tracks(camera, paths)
    truth = pd.Series(speeds, index=[f"v{k}" for k in range(speeds.size)], name="speed_kmh")
    return camera, tracks, truth
