"""Where positions can be trusted: calibration and pixel noise propagated to the ground, and the visible ground.

The ground position of a pixel depends on the camera parameters (uncertain after calibration: their covariance is
stored in the camera JSON by ``trafficgeo calibrate``) and on the pixel itself (detection or clicking noise). Both
are propagated to first order: the ground point is held on the surface's tangent plane at the nominal hit, and its
horizontal position is differentiated numerically along each principal direction of the parameter covariance and
along u and v. Results are 1-sigma ellipses in metres; azimuths are degrees clockwise from grid north.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pyproj
from numpy.typing import ArrayLike

from trafficgeo.camera.calibrated import CameraCovariance
from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs, pixels_to_world, world_to_pixels


@dataclass(frozen=True)
class GroundUncertainty:
    """1-sigma horizontal ground uncertainty of N pixels (metres), from calibration and pixel noise.

    ``cov_m2`` is (N, 2, 2) in m^2 (east, north); ``radial_m`` = sqrt(trace) (the RMS horizontal error);
    ``major_m``/``minor_m`` the ellipse semi-axes, ``azimuth_deg`` the major axis (clockwise from grid north,
    0..180); ``calibration_m`` and ``pixel_m`` the radial parts from each source. NaN where the pixel does not map
    to the ground.
    """

    xyz: np.ndarray
    status: np.ndarray
    cov_m2: np.ndarray
    radial_m: np.ndarray
    major_m: np.ndarray
    minor_m: np.ndarray
    azimuth_deg: np.ndarray
    calibration_m: np.ndarray
    pixel_m: np.ndarray


def _on_tangent_plane(camera: Camera, uv: np.ndarray, p0: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Where the rays of ``uv`` meet the planes through ``p0`` (N, 3) with ``normal`` (N, 3); (N, 2) x, y."""
    d = camera.rays(uv)
    c = camera.position
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", p0 - c, normal) / np.einsum("ij,ij->i", d, normal)
    return (c[:2] + t[:, None] * d[:, :2]) - p0[:, :2]


def ground_uncertainty(camera: Camera, uv: ArrayLike, surface: Surface, covariance: CameraCovariance | None,
                       pixel_sigma: float = 1.0, *, height: float = 0.0, step: float = 0.1) -> GroundUncertainty:
    """Propagate the calibration covariance and ``pixel_sigma`` (px, per axis) to the ground for pixels (N, 2).

    Without a covariance only the pixel noise is propagated (``calibration_m`` is NaN).
    """
    pts = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    ground = pixels_to_world(camera, pts, surface, height=height, with_lonlat=False)
    n = pts.shape[0]
    cov = np.full((n, 2, 2), np.nan)
    cal_part = np.full(n, np.nan)
    pix_part = np.full(n, np.nan)
    ok = ground.ok
    crs = camera_crs(camera)
    m = metres_per_unit(crs) if crs is not None else 1.0
    if ok.any():
        p0 = ground.xyz[ok]
        normal = surface.normal(p0[:, 0], p0[:, 1])
        if height:
            p0 = p0.copy()  # the lifted surface is parallel to the road's: same normal
        sub = pts[ok]
        c_pix = np.zeros((sub.shape[0], 2, 2))
        h = 0.5
        for axis in (0, 1):
            off = np.zeros(2)
            off[axis] = h
            J = (_on_tangent_plane(camera, sub + off, p0, normal) - _on_tangent_plane(camera, sub - off, p0, normal))
            J = J * (m / (2 * h))
            c_pix += pixel_sigma**2 * J[:, :, None] * J[:, None, :]
        c_cal = np.zeros_like(c_pix)
        if covariance is not None:
            for col in covariance.factor().T:
                plus = covariance.camera(covariance.values + step * col, camera)
                minus = covariance.camera(covariance.values - step * col, camera)
                J = (_on_tangent_plane(plus, sub, p0, normal) - _on_tangent_plane(minus, sub, p0, normal))
                J = J * (m / (2 * step))
                c_cal += J[:, :, None] * J[:, None, :]
            cal_part[ok] = np.sqrt(np.trace(c_cal, axis1=1, axis2=2))
        pix_part[ok] = np.sqrt(np.trace(c_pix, axis1=1, axis2=2))
        cov[ok] = c_pix + c_cal
    w, V = np.linalg.eigh(np.nan_to_num(cov))
    major = np.sqrt(np.clip(w[:, 1], 0, None))
    minor = np.sqrt(np.clip(w[:, 0], 0, None))
    azimuth = np.degrees(np.arctan2(V[:, 0, 1], V[:, 1, 1])) % 180.0
    bad = ~ok
    for a in (major, minor, azimuth):
        a[bad] = np.nan
    radial = np.sqrt(np.trace(cov, axis1=1, axis2=2))
    return GroundUncertainty(xyz=ground.xyz, status=ground.status, cov_m2=cov, radial_m=radial, major_m=major,
                             minor_m=minor, azimuth_deg=azimuth, calibration_m=cal_part, pixel_m=pix_part)


@dataclass(frozen=True)
class GroundGrid:
    """A north-up grid over the ground seen by a camera.

    ``transform`` is the rasterio/affine corner transform (CRS units); ``visible`` (rows, cols) marks cells whose
    centre the camera sees (in the frame, in front, not hidden by the surface, within ``max_distance_m``);
    ``bands`` holds the accuracy layers named in ``band_names`` (metres, NaN where not visible).
    """

    transform: Any
    crs: pyproj.CRS | None
    visible: np.ndarray
    bands: np.ndarray
    band_names: tuple[str, ...]
    resolution: float


def _coarse_footprint_bounds(camera: Camera, surface: Surface, max_distance: float) -> tuple[float, ...] | None:
    w, h = camera.image_size
    u, v = np.meshgrid(np.linspace(0, w - 1, 97), np.linspace(0, h - 1, 55))
    g = pixels_to_world(camera, np.column_stack([u.ravel(), v.ravel()]), surface, with_lonlat=False,
                        min_incidence_deg=0.0)
    ok = g.ok
    if not ok.any():
        return None
    xy = g.xyz[ok, :2]
    near = np.linalg.norm(xy - camera.position[:2], axis=1) <= max_distance
    if near.any():
        xy = xy[near]
    # Rays that run past max_distance still see ground up to it: include the circle's reach in their direction.
    far = g.xyz[ok, :2][~near] if (~near).any() else np.zeros((0, 2))
    if far.size:
        dirs = far - camera.position[:2]
        far = camera.position[:2] + dirs / np.linalg.norm(dirs, axis=1, keepdims=True) * max_distance
        xy = np.vstack([xy, far])
    return (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()), float(xy[:, 1].max()))


def accuracy_grid(camera: Camera, surface: Surface, covariance: CameraCovariance | None, *,
                  pixel_sigma: float = 1.0, resolution_m: float | None = None, max_distance_m: float = 250.0,
                  max_cells: int = 1_000_000) -> GroundGrid:
    """Expected 1-sigma ground error (metres) over the visible ground, on a north-up grid in the camera's CRS.

    Bands: ``radial_m`` (RMS horizontal error from calibration and pixel noise), ``major_m`` and ``minor_m``
    (ellipse semi-axes), ``calibration_m`` (the calibration's share alone), ``pixel_m`` (pixel noise alone) and
    ``gsd_m`` (ground size of one pixel along its worst direction). The grid covers the ground seen within
    ``max_distance_m`` of the camera; the default resolution gives about 500 cells along the longer side.
    """
    from affine import Affine

    crs = camera_crs(camera)
    m = metres_per_unit(crs) if crs is not None else 1.0
    max_distance = max_distance_m / m
    bounds = _coarse_footprint_bounds(camera, surface, max_distance)
    if bounds is None:
        raise InputError("the camera sees no ground on this surface (every ray misses it); check the surface "
                         "elevation and the camera pose")
    left, bottom, right, top = bounds
    sb = getattr(surface, "bounds", None)
    if sb is not None:
        left, bottom, right, top = max(left, sb[0]), max(bottom, sb[1]), min(right, sb[2]), min(top, sb[3])
    span = max(right - left, top - bottom)
    res = resolution_m / m if resolution_m else span / 500.0
    res = max(res, span / np.sqrt(max_cells))
    cols = max(int(np.ceil((right - left) / res)), 1)
    rows = max(int(np.ceil((top - bottom) / res)), 1)
    transform = Affine(res, 0.0, left, 0.0, -res, top)
    cc, rr = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
    x = left + cc.ravel() * res
    y = top - rr.ravel() * res
    z = surface.elevation(x, y)
    xyz = np.column_stack([x, y, z])
    visible = np.isfinite(z)
    visible &= np.hypot(x - camera.position[0], y - camera.position[1]) <= max_distance
    idx = np.flatnonzero(visible)
    img = world_to_pixels(camera, xyz[idx], surface, occlusion_tolerance_m=max(0.5, 0.75 * res * m))
    visible[idx[~img.ok]] = False
    idx = idx[img.ok]
    names = ("radial_m", "major_m", "minor_m", "calibration_m", "pixel_m", "gsd_m")
    bands = np.full((len(names), rows * cols), np.nan, dtype=np.float32)
    if idx.size:
        unc = ground_uncertainty(camera, img.uv[img.ok], surface, covariance, pixel_sigma)
        unit = ground_uncertainty(camera, img.uv[img.ok], surface, None, 1.0)
        for k, a in enumerate((unc.radial_m, unc.major_m, unc.minor_m, unc.calibration_m, unc.pixel_m,
                               unit.major_m)):
            bands[k, idx] = a
        lost = ~np.isfinite(unc.radial_m)
        visible[idx[lost]] = False
    return GroundGrid(transform=transform, crs=crs, visible=visible.reshape(rows, cols),
                      bands=bands.reshape(len(names), rows, cols), band_names=names, resolution=res)


def footprint_polygon(grid: GroundGrid, min_area_cells: int = 4) -> Any:
    """The visible ground of a :class:`GroundGrid` as a shapely (Multi)Polygon in the grid's CRS."""
    from rasterio import features
    from shapely.geometry import shape
    from shapely.ops import unary_union

    mask = grid.visible.astype(np.uint8)
    polys = [shape(geom) for geom, value in features.shapes(mask, mask=grid.visible, transform=grid.transform)
             if value == 1]
    polys = [p for p in polys if p.area >= min_area_cells * grid.resolution**2]
    if not polys:
        from shapely.geometry import Polygon

        return Polygon()
    merged = unary_union(polys)
    return merged.simplify(grid.resolution * 0.5, preserve_topology=True)


def along_scale_sigma(camera: Camera, xyz: np.ndarray, direction_xy: np.ndarray, surface: Surface,
                      covariance: CameraCovariance, *, length_m: float = 5.0, step: float = 0.1) -> np.ndarray:
    """Relative 1-sigma (dimensionless, 0.01 = 1 %) of the ground scale along ``direction_xy`` (N, 2; any length)
    at ground points ``xyz`` (N, 3; CRS units) from the calibration's ``covariance``: how much the ground distance
    between the point and the point ``length_m`` m further along the direction, seen through the camera, changes
    with the camera's parameters (first order, each principal direction of the covariance). NaN where either
    point is behind the camera."""
    p0 = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(direction_xy, dtype=np.float64).reshape(-1, 2)
    n = p0.shape[0]
    out = np.full(n, np.nan)
    if n == 0:
        return out
    crs = camera_crs(camera)
    m = metres_per_unit(crs) if crs is not None else 1.0
    norm = np.hypot(d[:, 0], d[:, 1])
    unit = d / np.where(norm > 1e-12, norm, 1.0)[:, None]
    q_xy = p0[:, :2] + unit * (length_m / m)
    p1 = np.column_stack([q_xy, surface.elevation(q_xy[:, 0], q_xy[:, 1])])
    p1[:, 2] = np.where(np.isfinite(p1[:, 2]), p1[:, 2], p0[:, 2])
    uv0, uv1 = camera.project(p0), camera.project(p1)
    ok = np.all(np.isfinite(uv0), axis=1) & np.all(np.isfinite(uv1), axis=1) & (norm > 1e-12)
    if not ok.any():
        return out
    n0 = surface.normal(p0[ok, 0], p0[ok, 1])
    n1 = surface.normal(p1[ok, 0], p1[ok, 1])
    var = np.zeros(int(ok.sum()))
    for col in covariance.factor().T:
        lengths = []
        for sign in (1.0, -1.0):
            cam = covariance.camera(covariance.values + sign * step * col, camera)
            a = _on_tangent_plane(cam, uv0[ok], p0[ok], n0) + p0[ok, :2]
            b = _on_tangent_plane(cam, uv1[ok], p1[ok], n1) + p1[ok, :2]
            lengths.append(np.einsum("ij,ij->i", b - a, unit[ok]) * m)
        var += ((lengths[0] - lengths[1]) / (2.0 * step) / length_m) ** 2
    out[ok] = np.sqrt(var)
    return out
