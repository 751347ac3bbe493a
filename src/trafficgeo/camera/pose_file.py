"""A calibrated camera from an OpenCV pose file (intrinsics + extrinsics, no GCPs), and back.

An OpenCV FileStorage file (``.yml``/``.yaml``, ``.xml`` or ``.json``) holding, besides the intrinsics that
:func:`~trafficgeo.camera.opencv_yaml.read_intrinsics_yaml` reads (``camera_matrix``, ``dist_coeffs``, image size):

    rotation      R, rotation_matrix, rmat, rot_CF_F (3x3)  or  rvec, rotation_vector, rot_vec (Rodrigues, rad);
                  a 3-vector under any of these names is read as Rodrigues, a 3x3 as a matrix
    translation   t, tvec, T, translation_vector, trans_CF_F (3 values, in the world frame's units)
    crs           (optional) the CRS of the world frame, or of the target when a geodetic origin is given
    origin        (optional) origin_lat, origin_lon [deg], origin_alt [m], or origin = [lat, lon, alt]
    frame         (optional) "enu" (default) or "ned": the axes of the local frame at a geodetic origin

OpenCV's convention: a world point ``X`` maps to camera coordinates ``x_cam = R X + t`` (x right, y down, z forward),
the camera centre is ``-R^T t``. This is what ``cv2.solvePnP``/``cv2.calibrateCamera`` return and what the
traj-ext tools store (``rot_CF_F``, ``trans_CF_F``, ``camera_matrix``, ``dist_coeffs``).

The world frame is either

* a projected CRS (``crs``; X east, Y north, Z up in CRS units), or local coordinates when there is no CRS; or
* a local tangent frame (east-north-up, or north-east-down) in metres at a geodetic origin (latitude, longitude
  in degrees WGS 84, altitude in metres in the vertical reference the CRS's Z uses, e.g. the DEM's). The camera is
  then moved into the target ``crs``: its centre is transformed exactly (local frame -> ECEF -> geodetic ->
  ``crs`` with pyproj), its rotation by the rotation between the local axes and the CRS's grid axes at the camera
  centre (the polar part of the transformation's Jacobian, so the meridian convergence is accounted for).

How exact the geodetic form is over a site of a few hundred metres: a rigid camera cannot follow the map
projection's scale factor ``k`` (grid distances are ``k`` times true ones) nor the earth's curvature, so points at
a distance ``d`` from the camera land ``|k - 1| d`` (UTM: ``|k - 1| <= 1e-3``, typically 4e-4, i.e. 0.1 m at
300 m) plus ``d^2 / (2 R_earth)`` (7 mm at 300 m) and ``d^2 / R_earth`` x tan(latitude) from the turning of the
meridians (2 cm at 300 m, 45 deg) off their exact place; in pixels that is at most about ``f |k - 1| / 2``
(0.2 px for f = 1000 px in UTM). The geoid's slope over the site (mm) is neglected.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyproj
from numpy.typing import ArrayLike

from trafficgeo.camera.model import Camera, CRSInput
from trafficgeo.camera.opencv_yaml import (
    cv_error_detail,
    first_key,
    node_array,
    node_scalar,
    read_intrinsics_yaml,
    write_storage,
)
from trafficgeo.crs import is_geographic, metres_per_unit, parse_crs
from trafficgeo.errors import InputError

ROTATION_KEYS = ("R", "rotation_matrix", "rmat", "rot_CF_F", "rvec", "rotation_vector", "rot_vec")
TRANSLATION_KEYS = ("t", "tvec", "T", "translation_vector", "trans_CF_F")
FRAMES = ("enu", "ned")
_HINT = "give an OpenCV pose file with camera_matrix, a rotation (R or rvec) and t (trafficgeo.camera.pose_file)"
_WGS84_3D = pyproj.CRS.from_epsg(4979)  # lon, lat [deg], ellipsoidal height [m]
_WGS84_2D = pyproj.CRS.from_epsg(4326)
_ECEF = pyproj.CRS.from_epsg(4978)


def _rotation(arr: np.ndarray, where: str) -> np.ndarray:
    """A 3x3 rotation from a 3x3 matrix or a Rodrigues 3-vector (rad)."""
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: has values that are not finite numbers; {_HINT}")
    if arr.size == 3:
        R, _ = cv2.Rodrigues(arr.reshape(3, 1).astype(np.float64))
        return R
    if arr.size != 9:
        raise InputError(f"{where}: has {arr.size} values; give a 3x3 rotation matrix or a 3-value rvec (rad)")
    R = arr.reshape(3, 3)
    if np.max(np.abs(R @ R.T - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0:
        raise InputError(f"{where}: is not a rotation matrix (orthonormal, det = +1); {_HINT}")
    return R


def _enu_basis(lat_deg: float, lon_deg: float) -> np.ndarray:
    """(3, 3) matrix whose columns are the east, north and up unit vectors at (lat, lon) in ECEF."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    return np.array([[-np.sin(lo), -np.sin(la) * np.cos(lo), np.cos(la) * np.cos(lo)],
                     [np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la) * np.sin(lo)],
                     [0.0, np.cos(la), np.sin(la)]])


def local_to_crs(points: ArrayLike, origin: tuple[float, float, float], crs: pyproj.CRS,
                 frame: str = "enu") -> np.ndarray:
    """Points (N, 3) of a local tangent frame (metres; ``frame`` "enu" or "ned") at the geodetic ``origin``
    (lat, lon [deg], alt [m]) -> (N, 3) in the projected ``crs``: X, Y and Z in CRS units, Z = altitude."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    enu = p if frame == "enu" else np.column_stack([p[:, 1], p[:, 0], -p[:, 2]])
    lat, lon, alt = (float(v) for v in origin)
    to_ecef = pyproj.Transformer.from_crs(_WGS84_3D, _ECEF, always_xy=True)
    x0 = np.array(to_ecef.transform(lon, lat, alt))
    ecef = x0 + enu @ _enu_basis(lat, lon).T
    to_geo = pyproj.Transformer.from_crs(_ECEF, _WGS84_3D, always_xy=True)
    glon, glat, h = to_geo.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
    x, y = pyproj.Transformer.from_crs(_WGS84_2D, crs, always_xy=True).transform(glon, glat)
    return np.column_stack([x, y, np.asarray(h) / metres_per_unit(crs)])


def _rotation_local_to_crs(centre: np.ndarray, origin: tuple[float, float, float], crs: pyproj.CRS,
                           frame: str) -> np.ndarray:
    """The rotation A with d_local ~ A d_crs at ``centre`` (local metres): the polar part of the Jacobian."""
    steps = np.eye(3)
    J = (local_to_crs(centre + steps, origin, crs, frame) - local_to_crs(centre - steps, origin, crs, frame)).T / 2
    U, _, Vt = np.linalg.svd(np.linalg.inv(J))  # d_local = J^-1 d_crs; keep its rotation
    A = U @ Vt
    if np.linalg.det(A) < 0:
        U[:, -1] *= -1
        A = U @ Vt
    return A


def camera_from_pose(image_size: tuple[int, int], K: ArrayLike, dist: ArrayLike, R: ArrayLike, t: ArrayLike, *,
                     crs: CRSInput = None, origin: tuple[float, float, float] | None = None,
                     frame: str = "enu") -> Camera:
    """A :class:`Camera` from OpenCV's pose ``x_cam = R X + t`` (``R`` 3x3 or a Rodrigues ``rvec``).

    Without ``origin``, ``X`` is in ``crs`` (or local coordinates without one). With a geodetic ``origin`` (lat,
    lon [deg], alt [m]), ``X`` is in the local ``frame`` ("enu" or "ned", metres) at it and the camera is moved
    into ``crs`` (required, projected); see the module docstring for how exact that is.
    """
    Rm = _rotation(np.asarray(R, dtype=np.float64), "R")
    tv = np.asarray(t, dtype=np.float64).reshape(3)
    if frame not in FRAMES:
        raise InputError(f"frame '{frame}': the local frame is 'enu' (east-north-up) or 'ned' (north-east-down)",
                         parameters=("frame",))
    if origin is None:
        if crs is not None and is_geographic(parse_crs(crs)):
            raise InputError("`crs`: the pose's world frame must be a projected CRS (metres or feet), not "
                             "longitude/latitude; for a local frame at a geodetic point give `origin`",
                             parameters=("crs", "origin"))
        return Camera(image_size=image_size, K=K, dist=dist, R=Rm, position=-Rm.T @ tv, crs=crs)
    target = parse_crs(crs) if crs is not None else None
    if target is None or is_geographic(target):
        raise InputError("`crs`: a camera posed at a geodetic origin needs a projected target CRS, e.g. "
                         "EPSG:32633 (the UTM zone of the site)", parameters=("crs",))
    lat, lon, alt = _check_origin(origin)
    _check_origin_in_area(lat, lon, alt, target)
    centre = -Rm.T @ tv
    position = local_to_crs(centre, (lat, lon, alt), target, frame)[0]
    if not np.all(np.isfinite(position)):
        raise InputError(f"origin {lat:g}, {lon:g}, {alt:g}: the camera cannot be placed in {target.name}; check "
                         "the origin (lat, lon in degrees) and `crs`", parameters=("origin", "crs"))
    A = _rotation_local_to_crs(centre, (lat, lon, alt), target, frame)
    return Camera(image_size=image_size, K=K, dist=dist, R=Rm @ A, position=position, crs=target)


def _check_origin(origin: ArrayLike) -> tuple[float, float, float]:
    try:
        lat, lon, alt = (float(v) for v in origin)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise InputError(f"origin {origin!r}: give the geodetic origin as (lat, lon, alt): degrees, degrees, "
                         "metres", parameters=("origin",)) from None
    if not (np.isfinite([lat, lon, alt]).all() and -90 <= lat <= 90 and -180 <= lon <= 180):
        raise InputError(f"origin {lat:g}, {lon:g}, {alt:g}: latitude must be within +/-90 and longitude within "
                         "+/-180 degrees (lat first)", parameters=("origin",))
    return lat, lon, alt


AREA_MARGIN_DEG = 2.0  # degrees around a CRS's area of use still taken as inside it


def _check_origin_in_area(lat: float, lon: float, alt: float, crs: pyproj.CRS) -> None:
    """Refuse a geodetic origin outside the target CRS's area of use (with :data:`AREA_MARGIN_DEG`): latitude and
    longitude given the other way round put the camera thousands of km away, where the CRS does not hold."""
    area = crs.area_of_use
    if area is None:
        return
    west, south, east, north = area.west, area.south, area.east, area.north
    inside_lon = (west - AREA_MARGIN_DEG <= lon <= east + AREA_MARGIN_DEG if west <= east
                  else lon >= west - AREA_MARGIN_DEG or lon <= east + AREA_MARGIN_DEG)  # across the antimeridian
    if not (inside_lon and south - AREA_MARGIN_DEG <= lat <= north + AREA_MARGIN_DEG):
        swapped = " (latitude and longitude swapped?)" if -90 <= lon <= 90 and (
            west - AREA_MARGIN_DEG <= lat <= east + AREA_MARGIN_DEG) else ""
        raise InputError(f"origin {lat:g}, {lon:g}, {alt:g}: outside the area of {crs.name} (lat {south:g} to "
                         f"{north:g}, lon {west:g} to {east:g}){swapped}; give the origin as lat, lon, alt and the "
                         "CRS of the site", parameters=("origin", "crs"))


def _file_origin(fs: Any, src: str) -> tuple[float, float, float] | None:
    keys = ("origin_lat", "origin_lon", "origin_alt")
    nodes = [fs.getNode(k) for k in keys]
    present = [not n.empty() and not n.isNone() for n in nodes]
    if any(present):
        values = [node_scalar(n) for n in nodes]
        missing = [k for k, v in zip(keys, values, strict=True) if v is None]
        if missing:
            raise InputError(f"{src}: keys {', '.join(missing)} are missing or not numbers; give origin_lat, "
                             "origin_lon (degrees) and origin_alt (metres) together")
        return values[0], values[1], values[2]  # type: ignore[return-value]
    found = first_key(fs, ("origin",))
    if found is None:
        return None
    arr = node_array(found[1], f"{src}, key 'origin'").reshape(-1)
    if arr.size != 3:
        raise InputError(f"{src}, key 'origin': expected [lat, lon, alt] (degrees, degrees, metres)")
    return float(arr[0]), float(arr[1]), float(arr[2])


def _file_text(fs: Any, key: str, src: str) -> str | None:
    node = fs.getNode(key)
    if node.empty() or node.isNone():
        return None
    if not node.isString():
        raise InputError(f"{src}, key '{key}': must be text")
    return node.string().strip()


def read_pose_file(path: str | os.PathLike[str], *, crs: CRSInput = None,
                   origin: tuple[float, float, float] | None = None, frame: str | None = None,
                   image_size: tuple[int, int] | None = None) -> Camera:
    """The :class:`Camera` of an OpenCV pose file (see the module docstring for keys and frames).

    ``crs``, ``origin`` (lat, lon [deg], alt [m]) and ``frame`` override the file's ``crs``, ``origin_*`` and
    ``frame`` keys; ``image_size`` (width, height) [px] is needed when the file has none.

    Raises:
        InputError: unreadable file, no camera matrix, rotation or translation, a matrix that is not a rotation,
            no image size, a geodetic origin without a projected ``crs``; the message names the file and key.
    """
    p = Path(path)
    src = str(p)
    intr = read_intrinsics_yaml(p)  # checks the file exists and parses, and the intrinsics
    try:
        fs = cv2.FileStorage(src, cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        raise InputError(f"{src}: not a readable OpenCV FileStorage file ({cv_error_detail(exc)}); {_HINT}") from None
    try:
        found = first_key(fs, ROTATION_KEYS)
        if found is None:
            raise InputError(f"{src}: no rotation (looked for keys {', '.join(ROTATION_KEYS)}); {_HINT}")
        rkey, rnode = found
        R = _rotation(node_array(rnode, f"{src}, key '{rkey}'"), f"{src}, key '{rkey}'")
        found = first_key(fs, TRANSLATION_KEYS)
        if found is None:
            raise InputError(f"{src}: no translation (looked for keys {', '.join(TRANSLATION_KEYS)}); {_HINT}")
        tkey, tnode = found
        t = node_array(tnode, f"{src}, key '{tkey}'").reshape(-1)
        if t.size != 3 or not np.all(np.isfinite(t)):
            raise InputError(f"{src}, key '{tkey}': expected 3 finite values (x_cam = R X + t); {_HINT}")
        file_crs = _file_text(fs, "crs", src)
        file_frame = _file_text(fs, "frame", src)
        file_origin = _file_origin(fs, src)
    finally:
        fs.release()
    size = image_size if image_size is not None else intr.image_size
    if size is None:
        raise InputError(f"{src}: no image size (image_width, image_height); add them or give `image_size`",
                         parameters=("image_size",))
    use_frame = (frame or file_frame or "enu").lower()
    use_origin = origin if origin is not None else file_origin
    use_crs = crs if crs is not None else (file_crs or None)
    try:
        return camera_from_pose(size, intr.K, intr.dist, R, t, crs=use_crs, origin=use_origin, frame=use_frame)
    except InputError as exc:
        raise InputError(f"{src}: {exc}", parameters=exc.parameters) from None


def write_pose_file(path: str | os.PathLike[str], camera: Camera, *, rotation: str = "rvec") -> None:
    """Write ``camera`` as an OpenCV pose file in its own CRS (``x_cam = R X + t``, X in CRS units), atomically.

    ``rotation`` "rvec" writes ``rvec`` (Rodrigues, rad), "R" the 3x3 matrix ``R``. Keys: image_width,
    image_height, camera_matrix, dist_coeffs, rvec or R, t, crs (when the camera has one). Values are written with
    17 significant digits, so reading back is exact to rounding.
    """
    if rotation not in ("rvec", "R"):
        raise InputError(f"rotation '{rotation}': write 'rvec' or 'R'", parameters=("rotation",))
    p = Path(path)
    if p.suffix.lower() not in (".yml", ".yaml", ".xml", ".json"):
        raise InputError(f"{p}: unsupported pose file suffix '{p.suffix}'; use .yml (or .yaml, .xml, .json)")
    rvec, tvec = camera.rvec_tvec()

    def write(fs: cv2.FileStorage) -> None:
        fs.write("image_width", int(camera.width))
        fs.write("image_height", int(camera.height))
        fs.write("camera_matrix", np.ascontiguousarray(camera.K))
        fs.write("dist_coeffs", np.ascontiguousarray(camera.dist).reshape(5, 1))
        if rotation == "rvec":
            fs.write("rvec", np.ascontiguousarray(rvec).reshape(3, 1))
        else:
            fs.write("R", np.ascontiguousarray(camera.R))
        fs.write("t", np.ascontiguousarray(tvec).reshape(3, 1))
        if camera.crs_text is not None:
            fs.write("crs", camera.crs_text)

    write_storage(p, write)
