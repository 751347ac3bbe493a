"""The GIS picture of a calibrated site: camera position, GCPs with their residuals, and the camera footprint."""

from __future__ import annotations

from typing import Any

import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.io.gis import Layer, points_layer

_GCP_COLUMNS = ("id", "role", "u", "v", "u_proj", "v_proj", "error_px", "inlier", "loo_error_px")


def gcp_layer(doc: dict[str, Any], crs: Any) -> Layer | None:
    """GCPs stored in a camera JSON as 3-D points with their residuals (px); None when there are none.

    ``du``/``dv`` are projected minus clicked pixels, so an arrow from (u, v) along (du, dv) points to where the
    camera model puts the surveyed point.
    """
    rows = [r for r in doc.get("gcps") or [] if isinstance(r, dict)]
    if not rows:
        return None

    def col(key: str, default: Any = np.nan) -> list[Any]:
        return [r.get(key, default) for r in rows]

    attrs: dict[str, Any] = {k: col(k, "" if k in ("id", "role") else np.nan) for k in _GCP_COLUMNS}
    attrs["id"] = [str(v) for v in attrs["id"]]
    attrs["inlier"] = [bool(v) if v is not None else None for v in col("inlier", None)]
    attrs["du"] = np.asarray(attrs["u_proj"], dtype=float) - np.asarray(attrs["u"], dtype=float)
    attrs["dv"] = np.asarray(attrs["v_proj"], dtype=float) - np.asarray(attrs["v"], dtype=float)
    return points_layer("gcps", col("x"), col("y"), col("z"), attributes=attrs, crs=crs)


def camera_layer(camera: Camera, doc: dict[str, Any]) -> Layer:
    """The camera as a 3-D point with its orientation (deg), focal length (px) and position sigma (m)."""
    o = camera.orientation
    unc = (doc.get("uncertainty") or {}).get("position_std_m") or [np.nan] * 3
    stats = doc.get("stats") or {}
    attrs = {
        "heading_deg": [o.heading_deg], "tilt_deg": [o.tilt_deg], "roll_deg": [o.roll_deg],
        "focal_px": [camera.focal_px], "width_px": [camera.width], "height_px": [camera.height],
        "sigma_x_m": [unc[0]], "sigma_y_m": [unc[1]], "sigma_z_m": [unc[2]],
        "rmse_px": [stats.get("rmse_px", np.nan)], "n_inliers": [stats.get("n_inliers", np.nan)],
    }
    p = camera.position
    return points_layer("camera", [p[0]], [p[1]], [p[2]], attributes=attrs, crs=camera.crs)


def footprint_layer(footprint: Any, area_m2: float | None = None) -> Layer:
    """The visible ground as one (Multi)Polygon feature."""
    return Layer("footprint", [footprint], {"area_m2": [np.nan if area_m2 is None else area_m2]})


def site_layers(camera: Camera, doc: dict[str, Any], footprint: Any | None = None) -> list[Layer]:
    """Camera, GCP and (when given) footprint layers for :func:`trafficgeo.io.gis.write_gis`."""
    from trafficgeo.crs import metres_per_unit

    layers = [camera_layer(camera, doc)]
    gcps = gcp_layer(doc, camera.crs)
    if gcps is not None:
        layers.append(gcps)
    if footprint is not None and not footprint.is_empty:
        m = metres_per_unit(camera.crs)
        layers.append(footprint_layer(footprint, footprint.area * m * m))
    return layers



def visible_footprint(camera: Camera, surface: Any, max_distance_m: float = 250.0, cells: int = 200) -> Any:
    """The ground the camera sees within ``max_distance_m`` on ``surface`` (a coarse ``cells``-wide grid)."""
    from trafficgeo.geo.uncertainty import accuracy_grid, footprint_polygon

    grid = accuracy_grid(camera, surface, None, max_distance_m=max_distance_m, max_cells=cells * cells)
    return footprint_polygon(grid)
