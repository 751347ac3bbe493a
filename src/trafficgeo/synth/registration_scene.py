"""Generated scenes with known truth for orthophoto registration (:mod:`trafficgeo.registration`).

A scene is a road (crowned, on a grade) with its lane markings and textured verges, seen by a roadside camera:

* the **world's ground texture** is an orthophoto at ``ortho_resolution`` (:func:`~.orthophoto.render_orthophoto`);
* the **frame** is that texture draped through the true camera (:func:`trafficgeo.geo.drape.drape_orthophoto`, via
  :func:`~.render.drape_orthophoto`, lens distortion included, at ``supersample`` x the resolution averaged over
  each pixel as a sensor integrates it), with vehicles and their shadows
  (:func:`~.render.render_frame`), a change of brightness and colour, a little blur and sensor noise;
* the **user's orthophoto** is the same ground "flown at another time": other gain, offset and gamma per channel,
  a blur of ``ortho_blur_px`` cells, its own grain; with ``wrong_place`` a road elsewhere (another azimuth, other
  markings and texture) under the same coordinates;
* the **user's GCPs**: ``n_control`` lane-marking corners and pole bases clicked with ``click_sigma_px`` noise (per
  axis), ``n_check`` more as check points; **perfect GCPs**: ``n_perfect`` points with exact world coordinates,
  clicked at the nearest whole pixel (the best a click can do);
* **another day** (issue 40, all off by default): the orthophoto's grass in another season (``ortho_season``),
  shadows of trees and buildings (``ortho_shadows``), cars of its own (``ortho_vehicles``), or winter
  (``ortho_snow``: verges white, markings under slush: a ground no matcher should claim to know);
* **truth points** on the ground 20-110 m along the road from the camera to score a camera by its ground error.

Deterministic for a seed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from affine import Affine

from trafficgeo.calibration.gcp_table import GCPTable
from trafficgeo.camera.model import Camera
from trafficgeo.crs import parse_crs
from trafficgeo.geo.raster import GeoRaster
from trafficgeo.geo.surface import DEMSurface
from trafficgeo.synth.gcp_scene import RoadSurface
from trafficgeo.synth.orthophoto import RoadMarkings, dash_corners, render_orthophoto
from trafficgeo.synth.render import Boxes, drape_orthophoto, render_frame
from trafficgeo.synth.world import WorldOptions, world_camera


@dataclass(frozen=True)
class RegistrationSceneOptions:
    """Parameters of a registration scene (metres, pixels, degrees)."""

    seed: int = 0
    image_size: tuple[int, int] = (1280, 720)
    camera_height: float = 8.0
    azimuth_deg: float = 30.0
    grade: float = 0.01
    dist: tuple[float, float, float, float, float] = (-0.06, 0.012, 0.0, 0.0, 0.0)
    ortho_resolution: float = 0.05
    half_size: float = 85.0  # the orthophoto and DEM cover this far around the road at station 30
    n_control: int = 8
    n_check: int = 3
    click_sigma_px: float = 3.0
    n_perfect: int = 20
    vehicles: int = 10
    frame_gain: float = 0.85  # brightness of the frame against the world's texture
    ortho_gain: tuple[float, float, float] = (1.15, 1.05, 0.9)  # the user's orthophoto, per RGB channel
    ortho_offset: float = 12.0
    ortho_gamma: float = 0.9
    ortho_blur_px: float = 0.7
    sensor_noise: float = 2.0
    supersample: int = 3  # the frame's ground is rendered at 3x and averaged over each pixel
    wrong_place: bool = False
    ortho_season: float = 0.0  # 0: the frame's season; 1: grass dried to straw, its pattern faded and partly new
    ortho_shadows: int = 0  # soft shadows of trees and buildings cast on the orthophoto only
    ortho_vehicles: int = 0  # cars parked or driving in the orthophoto (not the frame's)
    ortho_snow: bool = False  # the orthophoto flown in winter: snow on the verges, slush over the markings


@dataclass(frozen=True)
class RegistrationScene:
    """A generated scene: the true camera, the frame (H, W, 3) BGR uint8, the user's orthophoto, the surface, the
    user's GCPs (rough), the perfect GCPs, and truth points on the ground (M, 3)."""

    camera: Camera
    frame: np.ndarray
    ortho: GeoRaster
    surface: DEMSurface
    gcps: GCPTable
    perfect_gcps: GCPTable
    truth_points: np.ndarray


def _table(ids: list[str], world: np.ndarray, pixels: np.ndarray, roles: list[str], sigma: float,
           crs: object) -> GCPTable:
    return GCPTable(ids=tuple(ids), world=world, pixels=pixels, roles=tuple(roles),
                    sigma_px=np.full(len(ids), float(sigma)), crs=parse_crs(crs), source="registration scene",
                    lines=(0,) * len(ids))


def _spread(uv: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """k indices spread over the image by farthest-point sampling from a random first point."""
    chosen = [int(rng.integers(len(uv)))]
    d2 = np.full(len(uv), np.inf)
    while len(chosen) < min(k, len(uv)):
        d2 = np.minimum(d2, np.sum((uv - uv[chosen[-1]]) ** 2, axis=1))
        chosen.append(int(np.argmax(d2)))
    return np.asarray(chosen)


def _candidates(camera: Camera, road: RoadSurface, markings: RoadMarkings) -> tuple[np.ndarray, np.ndarray]:
    """World points a user would click (dash corners, pole bases and tops) in the frame within 100 m."""
    corners = dash_corners(road, markings, (-30.0, 110.0))
    poles_s = np.arange(-20.0, 110.0, 20.0)
    bases = road.points(poles_s, np.full(poles_s.shape, markings.left_edge - markings.shoulder - 1.0))
    world = np.vstack([corners, bases, bases + [0.0, 0.0, 4.0]])
    uv = camera.project(world)
    ok = camera.in_image(uv, margin=15) & (np.linalg.norm(world - camera.position, axis=1) < 100.0)
    return world[ok], uv[ok]


def _vehicles(road: RoadSurface, markings: RoadMarkings, n: int, rng: np.random.Generator) -> Boxes:
    lanes = np.array([markings.lane_width * (k + 0.5) for k in range(markings.lanes_right)]
                     + [-markings.lane_width * (k + 0.5) for k in range(markings.lanes_left)])
    s = rng.uniform(0.0, 100.0, n)
    o = rng.choice(lanes, n)
    centre = road.points(s, o)
    heading = (road.azimuth_deg + np.where(o > 0, 0.0, 180.0)) % 360.0
    length = rng.uniform(4.0, 5.0, n)
    colour = rng.uniform(20, 235, (n, 3))
    return Boxes(centre=centre, heading_deg=heading, length=length, width=np.full(n, 1.8),
                 height=np.full(n, 1.5), colour=colour, kind=np.full(n, "car", dtype=object))


def _flown_again(ortho: GeoRaster, opts: RegistrationSceneOptions, rng: np.random.Generator) -> GeoRaster:
    """The same ground at another time: per-channel gain, offset and gamma, a blur, its own grain."""
    img = ortho.data.transpose(1, 2, 0).astype(np.float32) / 255.0
    img = np.power(np.clip(img, 0.0, 1.0), opts.ortho_gamma) * 255.0
    img = img * np.asarray(opts.ortho_gain, dtype=np.float32) + opts.ortho_offset
    if opts.ortho_blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), opts.ortho_blur_px)
    img = img + rng.normal(0.0, 2.0, img.shape).astype(np.float32)
    data = np.clip(np.rint(img), 0, 255).astype(np.uint8).transpose(2, 0, 1)
    return GeoRaster(data=data, transform=ortho.transform, crs=ortho.crs, descriptions=ortho.descriptions)


def _another_day(texture: GeoRaster, road: RoadSurface, markings: RoadMarkings, opts: RegistrationSceneOptions
                 ) -> GeoRaster:
    """The world's texture on the day the orthophoto was flown (see ``ortho_season``, ``ortho_shadows``,
    ``ortho_vehicles``, ``ortho_snow``); its own random stream, so scenes without these are unchanged."""
    if not (opts.ortho_season > 0 or opts.ortho_shadows or opts.ortho_vehicles or opts.ortho_snow):
        return texture
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(opts.seed + 4000)
    img = texture.data.transpose(1, 2, 0).astype(np.float32)
    rows, cols = img.shape[:2]
    res = float(texture.transform.a)
    X, Y = texture.pixel_to_map(*np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5))
    s, o = road.station_offset(X, Y)
    verge = (o < markings.left_edge - markings.shoulder) | (o > markings.right_edge + markings.shoulder)
    if opts.ortho_season > 0:  # the grass turns to straw: its patches stay where they were, a third is new
        blotch = gaussian_filter(rng.normal(0.0, 1.0, (rows, cols)), 10.0)
        blotch = (blotch / max(float(blotch.std()), 1e-9))[..., None]
        w = np.float32(opts.ortho_season)
        pattern = img - np.float32(img[verge].mean(axis=0))
        straw = np.array([150.0, 132.0, 82.0], dtype=np.float32) + 0.8 * pattern + 4.0 * blotch
        img[verge] = (1 - w) * img[verge] + w * straw[verge]
    if opts.ortho_snow:
        slush = gaussian_filter(rng.normal(0.0, 1.0, (rows, cols)), 3.0)
        slush = (slush / max(float(slush.std()), 1e-9))[..., None]
        snow = np.float32(236.0) + 6.0 * slush
        road_slush = np.float32(112.0) + 10.0 * slush
        img = np.broadcast_to(np.where(verge[..., None], snow, road_slush), img.shape).astype(np.float32)
    if opts.ortho_vehicles:
        length, width = 4.6, 1.8
        lanes = np.array([markings.lane_width * (k + 0.5) for k in range(markings.lanes_right)]
                         + [-markings.lane_width * (k + 0.5) for k in range(markings.lanes_left)])
        for st, lo, colour in zip(rng.uniform(-40.0, 130.0, opts.ortho_vehicles),
                                  rng.choice(lanes, opts.ortho_vehicles),
                                  rng.uniform(20, 235, (opts.ortho_vehicles, 3)), strict=True):
            car = (np.abs(s - st) < length / 2) & (np.abs(o - lo) < width / 2)
            img[car] = colour.astype(np.float32)
            shade = (np.abs(s - st) < length / 2) & (o - lo >= width / 2) & (o - lo < width / 2 + 1.0)
            img[shade] *= 0.55
    if opts.ortho_shadows:
        dark = np.zeros((rows, cols), dtype=np.float32)
        for _ in range(opts.ortho_shadows):
            cs, co = rng.uniform(-20.0, 120.0), rng.uniform(-25.0, 25.0)
            a, b = rng.uniform(3.0, 9.0), rng.uniform(2.0, 6.0)
            dark = np.maximum(dark, (((s - cs) / a) ** 2 + ((o - co) / b) ** 2 < 1.0).astype(np.float32))
        dark = gaussian_filter(dark, 0.4 / res)
        img *= (1.0 - 0.5 * dark)[..., None]
    data = np.clip(np.rint(img), 0, 255).astype(np.uint8).transpose(2, 0, 1)
    return GeoRaster(data=data, transform=texture.transform, crs=texture.crs, descriptions=texture.descriptions)


def _elsewhere(opts: RegistrationSceneOptions, origin: np.ndarray, bounds: tuple[float, float, float, float],
               crs: str, rng: np.random.Generator) -> GeoRaster:
    """The ground texture of another place under the same coordinates: another road (35 deg off, 3 + 1 lanes,
    shifted), other markings and grain."""
    other_road = RoadSurface(origin=origin + [35.0, -20.0, 0.0], azimuth_deg=opts.azimuth_deg + 35.0,
                             grade=opts.grade, crossfall=0.02)
    other = RoadMarkings(lanes_right=3, lanes_left=1, dash_phase=float(rng.uniform(0.0, 9.0)))
    return render_orthophoto(other_road, other, bounds, resolution=opts.ortho_resolution, seed=opts.seed + 1000,
                             crs=crs)


def _integrated_background(camera: Camera, surface: DEMSurface, texture: GeoRaster, k: int) -> np.ndarray:
    """The draped texture as a sensor sees it: rendered at k x the resolution and averaged over each pixel (a
    point-sampled far field would alias the texture into patterns no real camera records)."""
    if k <= 1:
        return drape_orthophoto(camera, surface, texture)
    w, h = camera.image_size
    K = camera.K.copy()
    K[0, 0] *= k
    K[1, 1] *= k
    K[0, 2] = (K[0, 2] + 0.5) * k - 0.5  # pixel-centre convention: pixel u spans u +- 0.5
    K[1, 2] = (K[1, 2] + 0.5) * k - 0.5
    fine = camera.replace(image_size=(w * k, h * k), K=K)
    return cv2.resize(drape_orthophoto(fine, surface, texture), (w, h), interpolation=cv2.INTER_AREA)


def make_registration_scene(opts: RegistrationSceneOptions | None = None) -> RegistrationScene:
    """Build a scene (see the module docstring)."""
    opts = opts or RegistrationSceneOptions()
    rng = np.random.default_rng(opts.seed)
    world_opts = WorldOptions(image_size=opts.image_size, camera_height=opts.camera_height,
                              azimuth_deg=opts.azimuth_deg, dist=opts.dist)
    origin = np.array(world_opts.origin)
    road = RoadSurface(origin=origin, azimuth_deg=opts.azimuth_deg, grade=opts.grade, crossfall=0.02)
    markings = RoadMarkings(dash_phase=float(rng.uniform(0.0, 9.0)))
    camera = world_camera(road, markings, world_opts)
    centre = road.points([30.0], [0.0])[0]
    h = opts.half_size
    bounds = (centre[0] - h, centre[1] - h, centre[0] + h, centre[1] + h)
    texture = render_orthophoto(road, markings, bounds, resolution=opts.ortho_resolution, seed=opts.seed,
                                crs=world_opts.crs)
    surface = road.sampled_dem(centre[:2], h, 0.25)
    background = _integrated_background(camera, surface, texture, opts.supersample)
    frame, _ = render_frame(camera, np.clip(background * opts.frame_gain, 0, 255).astype(np.float32),
                            _vehicles(road, markings, opts.vehicles, rng))
    frame = cv2.GaussianBlur(frame, (0, 0), 0.6) + rng.normal(0.0, opts.sensor_noise, frame.shape).astype(np.float32)
    frame_bgr = np.clip(np.rint(frame), 0, 255).astype(np.uint8)[..., ::-1].copy()
    if opts.wrong_place:
        texture = _elsewhere(opts, origin, bounds, world_opts.crs, rng)
    else:
        texture = _another_day(texture, road, markings, opts)
    ortho = _flown_again(texture, opts, rng)

    world, uv = _candidates(camera, road, markings)
    pick = _spread(uv, opts.n_control + opts.n_check, rng)
    rough_uv = uv[pick] + rng.normal(0.0, opts.click_sigma_px, (len(pick), 2))
    roles = ["control"] * opts.n_control + ["check"] * opts.n_check
    gcps = _table([f"G{k + 1:02d}" for k in range(len(pick))], world[pick], rough_uv, roles[:len(pick)],
                  opts.click_sigma_px, world_opts.crs)
    best = _spread(uv, opts.n_perfect, rng)
    perfect = _table([f"P{k + 1:02d}" for k in range(len(best))], world[best], np.rint(uv[best]),
                     ["control"] * len(best), 0.5, world_opts.crs)
    s = np.repeat(world_opts.camera_station + np.arange(20.0, 111.0, 10.0), 5)
    o = np.tile(np.linspace(-7.0, 7.0, 5), len(s) // 5)
    truth = road.points(s, o)
    dist = np.linalg.norm(truth[:, :2] - camera.position[:2], axis=1)
    truth = truth[(dist > 15.0) & camera.in_image(camera.project(truth), margin=5)]
    return RegistrationScene(camera=camera, frame=frame_bgr, ortho=ortho, surface=surface, gcps=gcps,
                             perfect_gcps=perfect, truth_points=truth)


def ground_errors_m(camera: Camera, truth_camera: Camera, points: np.ndarray) -> np.ndarray:
    """Ground error (m) of ``camera`` at world points: each point's true pixel (through ``truth_camera``) mapped by
    ``camera`` onto the horizontal plane at the point's height, distance to the true X, Y."""
    uv = truth_camera.project(points)
    g = camera.intersect_horizontal_plane(uv, points[:, 2])
    return np.hypot(g[:, 0] - points[:, 0], g[:, 1] - points[:, 1])


def write_registration_scene(folder: str | Path, opts: RegistrationSceneOptions | None = None) -> RegistrationScene:
    """Write a scene as a user would have it, into ``folder``: ``frame.png`` (BGR still), ``ortho.tif`` (the user's
    orthophoto), ``ortho_elsewhere.tif`` (an orthophoto of another place, same extent and lighting change),
    ``dem.tif``, ``gcps.csv`` (the rough clicks: control and check), ``camera.json`` + ``report.json`` (their
    calibration by ``trafficgeo calibrate``), and the truth: ``camera_truth.json``, ``perfect_gcps.csv``,
    ``truth_points.csv`` (x, y, z). Returns the scene (with ``wrong_place`` False)."""
    from trafficgeo.calibration.run import run_calibration
    from trafficgeo.camera.io import write_camera_json
    from trafficgeo.geo.raster import write_geotiff
    from trafficgeo.io.atomic import atomic_path, write_csv_atomic

    opts = dataclasses.replace(opts or RegistrationSceneOptions(), wrong_place=False)
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    scene = make_registration_scene(opts)
    with atomic_path(out / "frame.png") as tmp:
        cv2.imwrite(str(tmp), scene.frame)
    crs = scene.ortho.crs
    write_geotiff(out / "ortho.tif", scene.ortho.data, scene.ortho.transform, crs)
    rng = np.random.default_rng(opts.seed + 7)
    left, bottom, right, top = scene.ortho.bounds
    elsewhere = _flown_again(_elsewhere(opts, np.array(WorldOptions().origin), (left, bottom, right, top),
                                        WorldOptions().crs, rng), opts, rng)
    write_geotiff(out / "ortho_elsewhere.tif", elsewhere.data, elsewhere.transform, crs)
    s = scene.surface
    write_geotiff(out / "dem.tif", s.values[None], Affine(s.xres, 0.0, s.left, 0.0, -s.yres, s.top), crs,
                  nodata=float("nan"))
    scene.gcps.to_csv(out / "gcps.csv")
    scene.perfect_gcps.to_csv(out / "perfect_gcps.csv")
    run_calibration(scene.gcps, opts.image_size, camera_path=out / "camera.json", report_path=out / "report.json")
    write_camera_json(out / "camera_truth.json", scene.camera)
    import pandas as pd

    write_csv_atomic(out / "truth_points.csv", pd.DataFrame(scene.truth_points, columns=["x", "y", "z"]))
    return scene
