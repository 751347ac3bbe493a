"""Camera orientation for people: heading, tilt and roll, and their link to the rotation matrix ``R``.

Conventions (the only place they are defined; tested in tests/test_camera.py):

* World frame: the CRS's projected axes, X east, Y north, Z up (right-handed).
* Camera frame: OpenCV axes, x right in the image, y down in the image, z forward along the optical axis.
* ``R`` maps world to camera: ``Xc = R (Xw - position)``. Its rows are the camera axes expressed in world
  coordinates: ``R[0]`` = image right, ``R[1]`` = image down, ``R[2]`` = optical axis.
* ``heading_deg``: azimuth of the optical axis, clockwise from grid north (0 = north, 90 = east), in [0, 360).
* ``tilt_deg``: depression of the optical axis below the horizontal plane (0 = level, 90 = straight down).
* ``roll_deg``: rotation about the optical axis; positive when the image's right edge dips below the horizon
  (the camera is turned clockwise as seen from behind it, so the scene looks turned anticlockwise in the image).

For a camera looking straight down (tilt = 90) the heading is taken from the image's up direction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trafficgeo.io.records import Num


@dataclass(frozen=True)
class Orientation:
    """Heading (deg, clockwise from grid north), tilt (deg below horizon) and roll (deg) of a camera."""

    heading_deg: Num
    tilt_deg: Num
    roll_deg: Num

    def to_dict(self) -> dict[str, float]:
        return {"heading_deg": self.heading_deg, "tilt_deg": self.tilt_deg, "roll_deg": self.roll_deg}


def rotation_from_orientation(heading_deg: float, tilt_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """World->camera rotation ``R`` (3x3) for the given heading, tilt and roll in degrees."""
    h, t, p = np.radians([heading_deg, tilt_deg, roll_deg])
    forward = np.array([np.sin(h) * np.cos(t), np.cos(h) * np.cos(t), -np.sin(t)])
    right0 = np.array([np.cos(h), -np.sin(h), 0.0])
    down0 = np.cross(forward, right0)
    right = np.cos(p) * right0 + np.sin(p) * down0
    down = -np.sin(p) * right0 + np.cos(p) * down0
    return np.vstack([right, down, forward])


def orientation_from_rotation(R: np.ndarray) -> Orientation:
    """Heading, tilt and roll (degrees) of a world->camera rotation matrix ``R``."""
    R = np.asarray(R, dtype=np.float64)
    forward = R[2]
    tilt = np.degrees(np.arcsin(np.clip(-forward[2], -1.0, 1.0)))
    horiz = np.hypot(forward[0], forward[1])
    if horiz < 1e-9:
        # Looking straight down (or up): heading of the image's up direction, roll folded into it.
        up = -R[1]
        heading = np.degrees(np.arctan2(up[0], up[1])) % 360.0
        return Orientation(float(heading), float(tilt), 0.0)
    heading = np.degrees(np.arctan2(forward[0], forward[1])) % 360.0
    h = np.radians(heading)
    right0 = np.array([np.cos(h), -np.sin(h), 0.0])
    down0 = np.cross(forward, right0)
    roll = np.degrees(np.arctan2(R[0] @ down0, R[0] @ right0))
    return Orientation(float(heading), float(tilt), float(roll))
