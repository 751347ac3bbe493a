"""The camera model: pinhole + OpenCV distortion, posed in a projected CRS (see :mod:`.model` for conventions)."""

from trafficgeo.camera.calibrated import (
    CalibratedCamera,
    CameraCovariance,
    CameraGCP,
    load_calibrated_camera,
    read_camera_json,
)
from trafficgeo.camera.distortion import distort_normalized, undistort_normalized
from trafficgeo.camera.io import camera_from_dict, camera_to_dict, write_camera_json
from trafficgeo.camera.model import Camera
from trafficgeo.camera.orientation import Orientation, orientation_from_rotation, rotation_from_orientation
from trafficgeo.camera.pose_file import camera_from_pose, read_pose_file, write_pose_file

__all__ = [
    "CalibratedCamera",
    "Camera",
    "CameraCovariance",
    "CameraGCP",
    "Orientation",
    "camera_from_dict",
    "camera_from_pose",
    "camera_to_dict",
    "distort_normalized",
    "load_calibrated_camera",
    "orientation_from_rotation",
    "read_camera_json",
    "read_pose_file",
    "rotation_from_orientation",
    "undistort_normalized",
    "write_camera_json",
    "write_pose_file",
]
