"""fpp_msgs_py against the conventions of depth_image_proc and REP 118."""

import array

import numpy as np
import pytest
from sensor_msgs.msg import Image, PointField
from std_msgs.msg import Header

from fpp_msgs_py import (
    ImageError,
    camera_info,
    cloud_to_xyz,
    image_to_numpy,
    intrinsics_from_camera_info,
    numpy_to_image,
    xyz_to_cloud,
)


@pytest.mark.parametrize("dtype, encoding", [(np.uint8, "mono8"), (np.uint16, "mono16"), (np.float32, "32FC1")])
def test_image_round_trip(dtype, encoding):
    a = (np.arange(12 * 7).reshape(7, 12) * 3).astype(dtype)
    msg = numpy_to_image(a, Header(frame_id="f"))
    assert (msg.encoding, msg.height, msg.width, msg.step, msg.is_bigendian) == (encoding, 7, 12, 12 * a.itemsize, 0)
    back = image_to_numpy(msg)
    np.testing.assert_array_equal(back, a)
    assert np.shares_memory(back, np.frombuffer(msg.data, np.uint8))  # zero-copy read


def test_padded_rows_and_big_endian_images_are_read():
    a = np.arange(20, dtype=np.uint16).reshape(4, 5)
    msg = Image(height=4, width=5, encoding="mono16", is_bigendian=1, step=12)
    rows = np.zeros((4, 12), np.uint8)
    rows[:, :10] = a.astype(">u2").view(np.uint8).reshape(4, 10)
    msg.data = array.array("B", rows.tobytes())
    np.testing.assert_array_equal(image_to_numpy(msg), a)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(encoding="rgb8"), "not supported"),
        (dict(height=0), "empty"),
        (dict(step=3), "shorter than a row"),
        (dict(height=5), "expected step x height"),
    ],
)
def test_malformed_images_are_clear_errors(change, message):
    msg = numpy_to_image(np.zeros((4, 6), np.uint8))
    for key, value in change.items():
        setattr(msg, key, value)
    with pytest.raises(ImageError, match=message):
        image_to_numpy(msg)


def test_depth_is_32fc1_metres_with_nan_for_no_measurement():
    depth = np.array([[1.2, np.nan]], np.float32)
    msg = numpy_to_image(depth)
    assert msg.encoding == "32FC1" and np.isnan(image_to_numpy(msg)[0, 1])
    with pytest.raises(ImageError):
        numpy_to_image(depth.astype(np.float64))


def test_organized_cloud_like_depth_image_proc():
    xyz = np.random.default_rng(0).normal(size=(3, 4, 3)).astype(np.float32)
    xyz[1, 2] = np.nan
    msg = xyz_to_cloud(xyz, Header(frame_id="camera_optical_frame"), intensity=np.ones((3, 4)))
    assert (msg.height, msg.width, msg.is_dense, msg.point_step, msg.row_step) == (3, 4, False, 16, 64)
    assert [(f.name, f.offset, f.datatype) for f in msg.fields] == [
        ("x", 0, PointField.FLOAT32),
        ("y", 4, PointField.FLOAT32),
        ("z", 8, PointField.FLOAT32),
        ("intensity", 12, PointField.FLOAT32),
    ]
    np.testing.assert_array_equal(cloud_to_xyz(msg), xyz)
    assert xyz_to_cloud(np.zeros((2, 2, 3))).is_dense


def test_camera_info_from_intrinsics():
    msg = camera_info(640, 480, 4955.0, 4955.0, 319.5, 239.5)
    assert msg.k[0] == 4955.0 and msg.k[2] == 319.5 and msg.p[6] == 239.5 and list(msg.d) == [0.0] * 5
    assert intrinsics_from_camera_info(msg) == dict(
        width=640, height=480, fx=4955.0, fy=4955.0, cx=319.5, cy=239.5, distortion=[0.0] * 5
    )
    lens = camera_info(640, 480, 4955.0, 4955.0, 319.5, 239.5, distortion=(-0.9, 4.0, 1e-3, -2e-3, 0.0))
    assert lens.distortion_model == "plumb_bob" and intrinsics_from_camera_info(lens)["distortion"] == [
        -0.9,
        4.0,
        1e-3,
        -2e-3,
        0.0,
    ]
