"""sensor_msgs/CameraInfo for the calibration's camera: pinhole intrinsics and OpenCV's plumb-bob
lens distortion (k1, k2, p1, p2, k3). Depth images are in the raw (distorted) image; the point clouds
are already undistorted."""

from __future__ import annotations

from sensor_msgs.msg import CameraInfo


def camera_info(
    width: int, height: int, fx: float, fy: float, cx: float, cy: float, header=None, distortion=(0.0,) * 5
) -> CameraInfo:
    msg = CameraInfo()
    if header is not None:
        msg.header = header
    msg.width, msg.height = int(width), int(height)
    msg.distortion_model = "plumb_bob"
    msg.d = [float(k) for k in distortion]
    msg.k = [float(fx), 0.0, float(cx), 0.0, float(fy), float(cy), 0.0, 0.0, 1.0]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [float(fx), 0.0, float(cx), 0.0, 0.0, float(fy), float(cy), 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def intrinsics_from_camera_info(msg: CameraInfo) -> dict:
    return {
        "width": msg.width,
        "height": msg.height,
        "fx": msg.k[0],
        "fy": msg.k[4],
        "cx": msg.k[2],
        "cy": msg.k[5],
        "distortion": [float(k) for k in msg.d],
    }
