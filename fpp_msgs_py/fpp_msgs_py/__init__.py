"""numpy <-> standard ROS 2 messages for the fringe-projection sensor (in the spirit of sensor_msgs_py)."""

from .camera_info import camera_info, intrinsics_from_camera_info
from .image import ImageError, image_to_numpy, numpy_to_image
from .names import Frames, Qos, Topics
from .point_cloud2 import cloud_to_xyz, xyz_to_cloud
from .stamps import header_at, stamp_ns

__all__ = [
    "ImageError",
    "image_to_numpy",
    "numpy_to_image",
    "xyz_to_cloud",
    "cloud_to_xyz",
    "camera_info",
    "intrinsics_from_camera_info",
    "Topics",
    "Qos",
    "Frames",
    "stamp_ns",
    "header_at",
]
