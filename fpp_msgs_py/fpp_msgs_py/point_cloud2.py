"""Organized sensor_msgs/PointCloud2 <-> numpy: fields x, y, z (float32, metres), optional intensity.

Layout follows depth_image_proc's point_cloud_xyz: height x width of the source image, row-major,
NaN where there is no measurement, is_dense False.
"""

from __future__ import annotations

import array

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

_XYZ = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
_XYZI = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])


def _fields(dtype: np.dtype) -> list[PointField]:
    return [
        PointField(name=name, offset=dtype.fields[name][1], datatype=PointField.FLOAT32, count=1)
        for name in dtype.names
    ]


def xyz_to_cloud(xyz: np.ndarray, header=None, intensity: np.ndarray | None = None) -> PointCloud2:
    """(H, W, 3) float32 metres (NaN = invalid) -> organized PointCloud2."""
    xyz = np.asarray(xyz, np.float32)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"an organized cloud needs an (H, W, 3) array, got {xyz.shape}")
    h, w = xyz.shape[:2]
    dtype = _XYZ if intensity is None else _XYZI
    if intensity is None:  # (H, W, 3) little-endian float32 already is the packed x, y, z layout
        points = np.ascontiguousarray(xyz, "<f4")
    else:
        points = np.empty((h, w), dtype)
        points["x"], points["y"], points["z"] = xyz[..., 0], xyz[..., 1], xyz[..., 2]
        points["intensity"] = intensity
    msg = PointCloud2()
    if header is not None:
        msg.header = header
    msg.height, msg.width = h, w
    msg.fields = _fields(dtype)
    msg.is_bigendian = False
    msg.point_step = dtype.itemsize
    msg.row_step = dtype.itemsize * w
    msg.is_dense = bool(np.isfinite(xyz).all())
    data = array.array("B")
    data.frombytes(points.reshape(-1).view(np.uint8).data)
    msg.data = data
    return msg


def cloud_to_xyz(msg: PointCloud2) -> np.ndarray:
    """(H, W, 3) float32 of a cloud with float32 x, y, z fields (any offsets, any extra fields)."""
    names = {f.name: f for f in msg.fields}
    if not all(n in names and names[n].datatype == PointField.FLOAT32 for n in "xyz"):
        raise ValueError("cloud needs float32 fields x, y and z")
    if len(msg.data) != msg.row_step * msg.height or msg.row_step < msg.point_step * msg.width:
        raise ValueError(
            f"cloud data is {len(msg.data)} bytes, expected row_step x height = {msg.row_step * msg.height}"
        )
    order = ">" if msg.is_bigendian else "<"
    dtype = np.dtype(
        {
            "names": list("xyz"),
            "formats": [order + "f4"] * 3,
            "offsets": [names[n].offset for n in "xyz"],
            "itemsize": msg.point_step,
        }
    )
    rows = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.row_step)[:, : msg.point_step * msg.width]
    points = np.ascontiguousarray(rows).view(dtype).reshape(msg.height, msg.width)
    return np.stack([points["x"], points["y"], points["z"]], axis=-1).astype(np.float32)
