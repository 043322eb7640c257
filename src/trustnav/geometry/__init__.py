"""Geometry below perception and the simulator: the camera model (intrinsics, mount, pose,
projection, back-projection onto the ground). Imports nothing of trustnav."""

from trustnav.geometry.camera import NEAR, CameraPose, CameraSpec

__all__ = ["NEAR", "CameraPose", "CameraSpec"]
