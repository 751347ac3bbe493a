"""Checks of a site before any work: the ground under and in front of the camera must be below it.

A surface whose heights are in another unit (a DEM in feet read as metres) or vertical datum than the camera's puts
the ground above the camera, and no pixel reaches it; the check names the likely cause.
"""

from __future__ import annotations

import numpy as np

from trafficgeo.camera.model import Camera
from trafficgeo.crs import metres_per_unit
from trafficgeo.errors import InputError
from trafficgeo.geo.mapping import Surface, camera_crs

AHEAD_M = (0.0, 5.0, 10.0, 20.0, 40.0, 80.0)  # m along the camera's viewing direction where the ground is sampled
FEET_PER_METRE = 1.0 / 0.3048
MAX_MOUNT_M = 60.0  # m: the highest a fixed traffic camera is usually mounted above the road


def camera_metres_per_unit(camera: Camera) -> float:
    """Metres per unit of the camera's CRS (1 without a CRS)."""
    crs = camera_crs(camera)
    return metres_per_unit(crs) if crs is not None else 1.0


def ground_ahead_z(camera: Camera, surface: Surface) -> np.ndarray:
    """Surface elevations (CRS units; NaN where it has none) under the camera and at :data:`AHEAD_M` m in front of
    it along its horizontal viewing direction."""
    c = np.asarray(camera.position, dtype=np.float64)
    axis = np.asarray(camera.optical_axis, dtype=np.float64)[:2]
    norm = float(np.hypot(*axis))
    direction = axis / norm if norm > 1e-6 else np.zeros(2)
    d = np.asarray(AHEAD_M) / camera_metres_per_unit(camera)
    x, y = c[0] + d * direction[0], c[1] + d * direction[1]
    return np.asarray(surface.elevation(x, y), dtype=np.float64).reshape(-1)


def check_camera_above_surface(camera: Camera, surface: Surface) -> None:
    """Raise :class:`InputError` when the surface under and in front of the camera is all above it (no pixel can
    reach the ground), naming the likely cause: heights in another unit (feet read as metres) or datum."""
    z = ground_ahead_z(camera, surface)
    z = z[np.isfinite(z)]
    cam_z = float(camera.position[2])
    if not z.size or not np.all(z >= cam_z):
        return
    mpu = camera_metres_per_unit(camera)
    ground = float(np.median(z))
    above_m = (ground - cam_z) * mpu
    hint = ""
    if 0 < (cam_z - ground / FEET_PER_METRE) * mpu <= MAX_MOUNT_M:  # read as feet, the camera would stand on it
        hint = (f" read as feet, {ground:.1f} would be {ground / FEET_PER_METRE:.1f}, "
                f"{(cam_z - ground / FEET_PER_METRE) * mpu:.1f} m below the camera, so its heights are probably in "
                "feet;")
    raise InputError(f"surface {surface.describe()}: the ground under and in front of the camera is at {ground:.1f} "
                     f"(CRS units), {above_m:.1f} m above the camera ({cam_z:.1f}), so no pixel can reach it;{hint} "
                     "its heights are in another unit or vertical datum than the camera's; give the surface in the "
                     "camera CRS's units and vertical datum (or calibrate the camera against it)")
