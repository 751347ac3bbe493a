"""The GIS picture of a calibrated site: camera position, GCPs with their residuals, and the camera footprint."""

from __future__ import annotations

from typing import Any

import numpy as np

from trafficgeo.camera.calibrated import CalibratedCamera
from trafficgeo.camera.model import Camera
from trafficgeo.io.gis import Layer, points_layer

_GCP_COLUMNS = ("id", "role", "u", "v", "u_proj", "v_proj", "error_px", "inlier", "loo_error_px")


def gcp_layer(camera: CalibratedCamera) -> Layer | None:
    """The calibration's GCPs as 3-D points with their residuals (px); None when there are none.

    ``du``/``dv`` are projected minus clicked pixels, so an arrow from (u, v) along (du, dv) points to where the
    camera model puts the surveyed point.
    """
    rows = camera.gcps or ()
    if not rows:
        return None
    attrs: dict[str, Any] = {k: [getattr(g, k) for g in rows] for k in _GCP_COLUMNS}
    attrs["du"] = np.asarray(attrs["u_proj"], dtype=float) - np.asarray(attrs["u"], dtype=float)
    attrs["dv"] = np.asarray(attrs["v_proj"], dtype=float) - np.asarray(attrs["v"], dtype=float)
    return points_layer("gcps", [g.x for g in rows], [g.y for g in rows], [g.z for g in rows], attributes=attrs,
                        crs=camera.camera.crs)


def camera_layer(calibrated: CalibratedCamera) -> Layer:
    """The camera as a 3-D point with its orientation (deg), focal length (px), position sigma (m), the fit's RMS
    (px) and inliers (NaN where the calibration does not say)."""
    camera, o = calibrated.camera, calibrated.camera.orientation
    unc = calibrated.uncertainty
    sigma = unc.position_std_m if unc is not None and unc.position_std_m is not None else (np.nan,) * 3
    stats = calibrated.stats
    rmse = stats.rmse_px if stats is not None and stats.rmse_px is not None else np.nan
    inliers = stats.n_inliers if stats is not None and stats.n_inliers is not None else np.nan
    attrs = {
        "heading_deg": [o.heading_deg], "tilt_deg": [o.tilt_deg], "roll_deg": [o.roll_deg],
        "focal_px": [camera.focal_px], "width_px": [camera.width], "height_px": [camera.height],
        "sigma_x_m": [sigma[0]], "sigma_y_m": [sigma[1]], "sigma_z_m": [sigma[2]],
        "rmse_px": [rmse], "n_inliers": [inliers],
    }
    p = camera.position
    return points_layer("camera", [p[0]], [p[1]], [p[2]], attributes=attrs, crs=camera.crs)


def footprint_layer(footprint: Any, area_m2: float | None = None) -> Layer:
    """The visible ground as one (Multi)Polygon feature."""
    return Layer("footprint", [footprint], {"area_m2": [np.nan if area_m2 is None else area_m2]})


def site_layers(camera: CalibratedCamera, footprint: Any | None = None) -> list[Layer]:
    """Camera, GCP and (when given) footprint layers for :func:`trafficgeo.io.gis.write_gis`."""
    from trafficgeo.crs import metres_per_unit

    layers = [camera_layer(camera)]
    gcps = gcp_layer(camera)
    if gcps is not None:
        layers.append(gcps)
    if footprint is not None and not footprint.is_empty:
        m = metres_per_unit(camera.camera.crs)
        layers.append(footprint_layer(footprint, footprint.area * m * m))
    return layers



def visible_footprint(camera: Camera, surface: Any, max_distance_m: float = 250.0, cells: int = 200) -> Any:
    """The ground the camera sees within ``max_distance_m`` on ``surface`` (a coarse ``cells``-wide grid)."""
    from trafficgeo.geo.uncertainty import accuracy_grid, footprint_polygon

    grid = accuracy_grid(camera, surface, None, max_distance_m=max_distance_m, max_cells=cells * cells)
    return footprint_polygon(grid)
