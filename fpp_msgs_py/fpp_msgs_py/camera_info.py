"""sensor_msgs/CameraInfo for a distortion-free pinhole camera (the calibration's intrinsics)."""

from __future__ import annotations

from sensor_msgs.msg import CameraInfo


def camera_info(width: int, height: int, fx: float, fy: float, cx: float, cy: float, header=None) -> CameraInfo:
    msg = CameraInfo()
    if header is not None:
        msg.header = header
    msg.width, msg.height = int(width), int(height)
    msg.distortion_model = "plumb_bob"
    msg.d = [0.0] * 5
    msg.k = [float(fx), 0.0, float(cx), 0.0, float(fy), float(cy), 0.0, 0.0, 1.0]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [float(fx), 0.0, float(cx), 0.0, 0.0, float(fy), float(cy), 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def intrinsics_from_camera_info(msg: CameraInfo) -> dict:
    return {"width": msg.width, "height": msg.height, "fx": msg.k[0], "fy": msg.k[4], "cx": msg.k[2], "cy": msg.k[5]}
