"""record: writes the fringe stream to a rosbag2 (MCAP by default, sqlite3 on request), with the
calibration in it, so that the bag replays and reconstructs on its own.

Subscribes projector/pattern, camera/image_raw and camera/camera_info as raw CDR (no decoding).
Parameters: output (bag folder, must not exist), storage (mcap | sqlite3), calibration (file).
"""
from __future__ import annotations

import sys
import time

from rclpy.node import Node

from fpp_msgs_py import Qos

from ..bag import STREAM_TOPICS, BagWriter
from .common import MESSAGE_TYPES, declare, load_calibration, run


class Record(Node):
    def __init__(self, **kwargs):
        super().__init__("record", **kwargs)
        output = declare(self, "output", time.strftime("bags/fpp_%Y%m%d_%H%M%S"), "bag folder to create", True)
        storage = declare(self, "storage", "mcap", "mcap or sqlite3", True)
        calibration = load_calibration(self)
        self.writer = BagWriter(output, storage)
        self.writer.write_calibration(calibration.to_yaml(), time.time_ns())
        self.counts = {}
        for topic, msgtype in STREAM_TOPICS.items():
            name = topic.lstrip("/")  # relative, so a namespace applies
            self.create_subscription(MESSAGE_TYPES[msgtype], name,
                                     lambda data, t=topic, m=msgtype: self._write(t, m, data), Qos.FRAMES, raw=True)
        self.get_logger().info(f"recording {', '.join(STREAM_TOPICS)} to {output} ({storage})")

    def _write(self, topic: str, msgtype: str, data: bytes):
        self.writer.write(topic, msgtype, time.time_ns(), data)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def destroy_node(self):
        self.writer.close()
        print(f"[record] bag closed: {self.counts}", file=sys.stderr)  # rosout may be gone at shutdown
        return super().destroy_node()


def main(args=None):
    run(Record, args=args)


if __name__ == "__main__":
    main()
