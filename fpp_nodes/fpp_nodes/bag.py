"""rosbag2 files of the fringe stream, through `rosbags` (pure Python; PyPI has no rosbag2_py).

A bag holds the raw stream (projector/pattern, camera/image_raw, camera/camera_info) as the CDR
bytes that crossed DDS, and the calibration as a std_msgs/String on fpp/calibration, so that a
replay reconstructs without the original parameters; optionally also the sensor's outputs (points,
depth/image, depth/camera_info), to look at; a replay leaves those out and makes them anew. MCAP by
default (it opens in Foxglove), sqlite3 on request; message definitions are stored, so the stock
`ros2 bag` reads both.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

CALIBRATION_TOPIC = "/fpp/calibration"
STREAM_TOPICS = {
    "/projector/pattern": "sensor_msgs/msg/Image",
    "/camera/image_raw": "sensor_msgs/msg/Image",
    "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
}
OUTPUT_TOPICS = {
    "/points": "sensor_msgs/msg/PointCloud2",
    "/depth/image": "sensor_msgs/msg/Image",
    "/depth/camera_info": "sensor_msgs/msg/CameraInfo",
}
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


class BagError(ValueError):
    """A bag that cannot be written or read whole."""


class BagWriter:
    def __init__(self, path, storage: str = "mcap"):
        plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise BagError(f"storage must be 'mcap' or 'sqlite3', got {storage!r}")
        if Path(path).exists():
            raise BagError(f"{path} exists; a bag is never overwritten")
        self.writer = Writer(path, version=9, storage_plugin=plugins[storage])
        self.writer.open()
        self.connections = {}

    def write(self, topic: str, msgtype: str, stamp_ns: int, data: bytes) -> None:
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=TYPESTORE)
        self.writer.write(self.connections[topic], stamp_ns, data)

    def write_calibration(self, yaml_text: str, stamp_ns: int) -> None:
        msg = TYPESTORE.types["std_msgs/msg/String"](data=yaml_text)
        self.write(
            CALIBRATION_TOPIC, "std_msgs/msg/String", stamp_ns, TYPESTORE.serialize_cdr(msg, "std_msgs/msg/String")
        )

    def close(self) -> None:
        self.writer.close()


@dataclass
class Recording:
    messages: list[tuple[str, str, int, bytes]]  # (topic, msgtype, timestamp ns, CDR bytes), in time order
    calibration_yaml: str | None


def read_bag(path) -> Recording:
    """Read a whole bag, or raise BagError naming why it cannot be (missing, truncated, corrupt)."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag {path} does not exist")
    try:
        with Reader(path) as reader:
            messages = [(c.topic, c.msgtype, t, bytes(data)) for c, t, data in reader.messages()]
            counts = {c.topic: c.msgcount for c in reader.connections}
    except Exception as e:  # rosbags raises many kinds for damaged files; all mean the same here
        raise BagError(f"cannot read bag {path}: {type(e).__name__}: {e}") from None
    got = {}
    for topic, *_ in messages:
        got[topic] = got.get(topic, 0) + 1
    if any(got.get(topic, 0) < n for topic, n in counts.items()):  # more than promised: cut off at close, intact
        raise BagError(f"bag {path} is truncated: its index promises {counts}, it holds {got}")
    if not any(topic in STREAM_TOPICS for topic, *_ in messages):
        raise BagError(f"bag {path} holds no fringe stream")
    calibration = None
    for topic, msgtype, _, data in messages:
        if topic == CALIBRATION_TOPIC:
            calibration = TYPESTORE.deserialize_cdr(data, msgtype).data
    return Recording([m for m in messages if m[0] in STREAM_TOPICS], calibration)
