"""The one camera model of trafficgeo: pinhole + OpenCV 5-term distortion, posed in a projected CRS.

A world point ``Xw`` (CRS units, X east, Y north, Z up) projects to the pixel ``(u, v)`` by::

    Xc = R (Xw - position)                 # OpenCV camera axes: x right, y down, z forward
    x, y = Xc[0] / Xc[2], Xc[1] / Xc[2]    # normalized coordinates
    xd, yd = distort(x, y, dist)           # dist = [k1, k2, p1, p2, k3]
    u = fx xd + s yd + cx ;  v = fy yd + cy

Pixel ``(0, 0)`` is the centre of the top-left pixel (OpenCV's convention), so the image centre of a ``W x H``
frame is ``((W - 1) / 2, (H - 1) / 2)``. ``position`` is subtracted before anything else, so coordinates of 5e6 m
keep float64 precision (~1e-9 m). See :mod:`trafficgeo.camera.orientation` for heading/tilt/roll.

The world CRS: ``Camera(..., crs=...)`` and every constructor take text ("EPSG:2949", WKT, a PROJ string, the
OpenDroneMap forms of :func:`trafficgeo.crs.parse_crs`), a :class:`pyproj.CRS` or ``None`` (local coordinates).
It is parsed once, when the camera is made (an unknown CRS raises the one-line
:class:`~trafficgeo.errors.InputError` of ``parse_crs``), and ``camera.crs`` is that ``pyproj.CRS`` (or None).
``camera.crs_text`` is the text written to camera JSON: ``"AUTH:CODE"`` (e.g. "EPSG:2949") when that is the same
CRS, else the CRS's WKT (:func:`crs_to_text`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import pyproj
from numpy.typing import ArrayLike
from pyproj.exceptions import CRSError

from trafficgeo.camera.distortion import as_dist, distort_normalized, undistort_normalized
from trafficgeo.camera.orientation import Orientation, orientation_from_rotation, rotation_from_orientation
from trafficgeo.crs import parse_crs

#: What a camera's ``crs`` may be given as: text, a pyproj CRS or None (see the module docstring).
CRSInput = str | pyproj.CRS | None


def crs_to_text(crs: pyproj.CRS | None) -> str | None:
    """Text that :func:`trafficgeo.crs.parse_crs` reads back to the same CRS: ``"AUTH:CODE"`` (e.g. "EPSG:2949")
    when that code is the same CRS, else the CRS's own text (WKT or PROJ string) if it parses back equal, else WKT."""
    if crs is None:
        return None
    text = crs.to_string()
    try:
        if text and pyproj.CRS.from_user_input(text) == crs:
            return text
    except CRSError:
        pass
    return crs.to_wkt()


def _as_points(a: ArrayLike, dim: int, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == dim:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}), got {arr.shape}")
    return arr


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera.

    Attributes:
        image_size: (width, height) in pixels.
        K: 3x3 intrinsic matrix in pixels.
        dist: distortion [k1, k2, p1, p2, k3] (OpenCV order).
        R: 3x3 world->camera rotation (rows: image right, image down, optical axis in world coordinates).
        position: camera centre (X, Y, Z) in the world CRS units.
        crs: the world CRS as a ``pyproj.CRS`` (given as text, a CRS or None), or None for local coordinates.
    """

    image_size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    crs: pyproj.CRS | None = None  # given as text, a pyproj CRS or None; held parsed

    def __post_init__(self) -> None:
        w, h = (int(x) for x in self.image_size)
        object.__setattr__(self, "image_size", (w, h))
        given = self.crs
        object.__setattr__(self, "crs", None if given is None or given == "" else parse_crs(given))  # "" = local
        K = np.array(self.K, dtype=np.float64).reshape(3, 3)
        R = np.array(self.R, dtype=np.float64).reshape(3, 3)
        pos = np.array(self.position, dtype=np.float64).reshape(3)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", as_dist(self.dist))
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "position", pos)
        if w <= 0 or h <= 0:
            raise ValueError(f"image_size must be positive, got {self.image_size}")
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(R)) and np.all(np.isfinite(pos))):
            raise ValueError("camera parameters must be finite")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1.0) > 1e-12 or np.any(K[1:, 0] != 0) or K[2, 1] != 0:
            raise ValueError("K must be upper triangular with positive focal lengths and K[2, 2] = 1")
        if np.max(np.abs(R @ R.T - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0:
            raise ValueError("R must be a rotation matrix (orthonormal, det = +1)")

    def __repr__(self) -> str:
        return (f"Camera(image_size={self.image_size}, K={self.K.tolist()}, dist={self.dist.tolist()}, "
                f"R={self.R.tolist()}, position={self.position.tolist()}, crs={self.crs_text!r})")

    @property
    def crs_text(self) -> str | None:
        """The CRS as camera JSON writes it (:func:`crs_to_text`); None without one."""
        return crs_to_text(self.crs)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_orientation(
        cls,
        image_size: tuple[int, int],
        focal_px: float,
        position: ArrayLike,
        heading_deg: float,
        tilt_deg: float,
        roll_deg: float = 0.0,
        *,
        dist: ArrayLike | None = None,
        principal_point: tuple[float, float] | None = None,
        crs: CRSInput = None,
    ) -> Camera:
        """A camera with square pixels and zero skew, posed by heading/tilt/roll (degrees).

        ``principal_point`` defaults to the image centre ``((W-1)/2, (H-1)/2)``.
        """
        w, h = image_size
        cx, cy = principal_point if principal_point is not None else ((w - 1) / 2.0, (h - 1) / 2.0)
        K = np.array([[focal_px, 0.0, cx], [0.0, focal_px, cy], [0.0, 0.0, 1.0]])
        R = rotation_from_orientation(heading_deg, tilt_deg, roll_deg)
        return cls(image_size=(w, h), K=K, dist=as_dist(dist), R=R, position=np.asarray(position, float), crs=crs)

    @classmethod
    def from_rvec_tvec(cls, image_size: tuple[int, int], K: ArrayLike, dist: ArrayLike, rvec: ArrayLike,
                       tvec: ArrayLike, *, origin: ArrayLike = (0.0, 0.0, 0.0), crs: CRSInput = None) -> Camera:
        """From OpenCV ``rvec``/``tvec`` that map ``Xw - origin`` to camera coordinates."""
        R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
        t = np.asarray(tvec, dtype=np.float64).reshape(3)
        position = np.asarray(origin, dtype=np.float64).reshape(3) - R.T @ t
        return cls(image_size=image_size, K=np.asarray(K, float), dist=as_dist(dist), R=R, position=position,
                   crs=crs)

    def replace(self, **changes: object) -> Camera:
        """A copy with some attributes replaced."""
        values = {k: getattr(self, k) for k in ("image_size", "K", "dist", "R", "position", "crs")}
        values.update(changes)
        return Camera(**values)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ derived quantities
    @property
    def width(self) -> int:
        return self.image_size[0]

    @property
    def height(self) -> int:
        return self.image_size[1]

    @property
    def focal_px(self) -> float:
        """Mean focal length in pixels, (fx + fy) / 2."""
        return float(0.5 * (self.K[0, 0] + self.K[1, 1]))

    @property
    def principal_point(self) -> tuple[float, float]:
        return float(self.K[0, 2]), float(self.K[1, 2])

    @property
    def orientation(self) -> Orientation:
        """Heading, tilt, roll in degrees (see :mod:`trafficgeo.camera.orientation`)."""
        return orientation_from_rotation(self.R)

    @property
    def optical_axis(self) -> np.ndarray:
        """Unit vector of the viewing direction in world coordinates."""
        return self.R[2].copy()

    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view in degrees (pinhole, ignoring distortion)."""
        w, h = self.image_size
        return (float(np.degrees(2 * np.arctan(w / (2 * self.K[0, 0])))),
                float(np.degrees(2 * np.arctan(h / (2 * self.K[1, 1])))))

    def rvec_tvec(self, origin: ArrayLike = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """OpenCV ``rvec`` (Rodrigues, rad) and ``tvec`` mapping ``Xw - origin`` to camera coordinates."""
        rvec, _ = cv2.Rodrigues(self.R)
        tvec = -self.R @ (self.position - np.asarray(origin, dtype=np.float64).reshape(3))
        return rvec.ravel(), tvec

    # ------------------------------------------------------------------ world <-> image
    def world_to_camera(self, world: ArrayLike) -> np.ndarray:
        """Camera-frame coordinates (N, 3) of world points (N, 3), in CRS units."""
        pts = _as_points(world, 3, "world points")
        return (pts - self.position) @ self.R.T

    def project(self, world: ArrayLike) -> np.ndarray:
        """Pixels (N, 2) of world points (N, 3). Points on or behind the camera plane get NaN."""
        xc = self.world_to_camera(world)
        z = xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = xc[:, :2] / z[:, None]
        xn[~(z > 0)] = np.nan
        return self.normalized_to_pixels(distort_normalized(xn, self.dist))

    def normalized_to_pixels(self, xyd: np.ndarray) -> np.ndarray:
        """Apply K to distorted normalized coordinates (N, 2) -> pixels (N, 2)."""
        K = self.K
        u = K[0, 0] * xyd[:, 0] + K[0, 1] * xyd[:, 1] + K[0, 2]
        v = K[1, 1] * xyd[:, 1] + K[1, 2]
        return np.stack([u, v], axis=-1)

    def pixels_to_normalized(self, uv: ArrayLike) -> np.ndarray:
        """Undistorted normalized coordinates (N, 2) of pixels (N, 2); NaN where the lens model has no inverse."""
        pts = _as_points(uv, 2, "pixels")
        K = self.K
        yd = (pts[:, 1] - K[1, 2]) / K[1, 1]
        xd = (pts[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        return undistort_normalized(np.stack([xd, yd], axis=-1), self.dist)

    def undistort_pixels(self, uv: ArrayLike) -> np.ndarray:
        """Pixels (N, 2) as an ideal distortion-free camera with the same K would see them."""
        xn = self.pixels_to_normalized(uv)
        return self.normalized_to_pixels(xn)

    def rays(self, uv: ArrayLike) -> np.ndarray:
        """Unit viewing directions (N, 3) in world coordinates for pixels (N, 2); rays start at ``position``.

        NaN rows for pixels outside the invertible region of the lens model.
        """
        xn = self.pixels_to_normalized(uv)
        d_cam = np.concatenate([xn, np.ones((xn.shape[0], 1))], axis=1)
        d_world = d_cam @ self.R
        return d_world / np.linalg.norm(d_world, axis=1, keepdims=True)

    def intersect_horizontal_plane(self, uv: ArrayLike, z: ArrayLike) -> np.ndarray:
        """World points (N, 3) where the rays of pixels ``uv`` meet the horizontal planes ``Z = z``.

        ``z`` is a scalar or (N,) array in CRS units. Rays parallel to the plane or meeting it behind the camera
        give NaN. (General surfaces live in :mod:`trafficgeo.geo`.)
        """
        d = self.rays(uv)
        zz = np.broadcast_to(np.asarray(z, dtype=np.float64), (d.shape[0],))
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (zz - self.position[2]) / d[:, 2]
        s = np.where(s > 0, s, np.nan)
        return self.position + s[:, None] * d

    def in_image(self, uv: ArrayLike, margin: float = 0.0) -> np.ndarray:
        """Boolean (N,) whether pixels lie within the frame (pixel-centre convention), shrunk by ``margin``."""
        pts = _as_points(uv, 2, "pixels")
        w, h = self.image_size
        return ((pts[:, 0] >= -0.5 + margin) & (pts[:, 0] <= w - 0.5 - margin)
                & (pts[:, 1] >= -0.5 + margin) & (pts[:, 1] <= h - 0.5 - margin))
