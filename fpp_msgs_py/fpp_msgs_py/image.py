"""sensor_msgs/Image <-> numpy for the encodings the sensor uses: mono8, mono16, 32FC1.

Reading is zero-copy where the message allows (a view on msg.data); a message whose size, step or
encoding is wrong raises ImageError naming the problem.
"""

from __future__ import annotations

import array

import numpy as np
from sensor_msgs.msg import Image

ENCODINGS = {
    "mono8": np.dtype(np.uint8),
    "8UC1": np.dtype(np.uint8),
    "mono16": np.dtype(np.uint16),
    "16UC1": np.dtype(np.uint16),
    "32FC1": np.dtype(np.float32),
}
_BY_DTYPE = {np.dtype(np.uint8): "mono8", np.dtype(np.uint16): "mono16", np.dtype(np.float32): "32FC1"}


class ImageError(ValueError):
    """An Image message that cannot be read as the array it claims to hold."""


def numpy_to_image(array_2d: np.ndarray, header=None, encoding: str | None = None) -> Image:
    """A 2-D uint8 / uint16 / float32 array as an Image (mono8 / mono16 / 32FC1, little-endian)."""
    a = np.asarray(array_2d)
    if a.ndim != 2:
        raise ImageError(f"an Image holds a 2-D array here, got shape {a.shape}")
    encoding = encoding or _BY_DTYPE.get(a.dtype)
    if encoding not in ENCODINGS or ENCODINGS[encoding] != a.dtype:
        raise ImageError(f"cannot publish a {a.dtype} array as {encoding!r}; use uint8, uint16 or float32")
    msg = Image()
    if header is not None:
        msg.header = header
    msg.height, msg.width = a.shape
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = a.shape[1] * a.dtype.itemsize
    data = array.array("B")
    data.frombytes(
        np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<"), copy=False)).reshape(-1).view(np.uint8).data
    )
    msg.data = data
    return msg


def image_to_numpy(msg: Image) -> np.ndarray:
    """The (height, width) array an Image holds; a view on its data when no byte swap is needed."""
    dtype = ENCODINGS.get(msg.encoding)
    if dtype is None:
        raise ImageError(f"encoding {msg.encoding!r} is not supported (mono8, mono16, 32FC1)")
    if msg.height == 0 or msg.width == 0:
        raise ImageError(f"image is empty ({msg.width}x{msg.height})")
    row = msg.width * dtype.itemsize
    if msg.step < row:
        raise ImageError(f"step {msg.step} is shorter than a row of {msg.width} {msg.encoding} pixels ({row} bytes)")
    if len(msg.data) != msg.step * msg.height:
        raise ImageError(f"image data is {len(msg.data)} bytes, expected step x height = {msg.step * msg.height}")
    rows = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.step)
    if msg.step != row:  # padded rows: one copy to drop the padding
        rows = np.ascontiguousarray(rows[:, :row])
    pixels = rows.view(dtype.newbyteorder(">" if msg.is_bigendian else "<"))
    return pixels.astype(dtype, copy=False)  # a copy only to swap big-endian bytes
