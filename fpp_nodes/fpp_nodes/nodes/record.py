"""record: writes the fringe stream to a rosbag2 (MCAP by default, sqlite3 on request), with the
calibration in it, so that the bag replays and reconstructs on its own.

Subscribes projector/pattern, camera/image_raw and camera/camera_info as raw CDR (no decoding); with
outputs:=true also points, depth/image and depth/camera_info, to look at (Foxglove); a replay makes
those anew. Parameters: output (bag folder, must not exist), storage (mcap | sqlite3), calibration
(file), outputs (bool). Logs the first message on each topic: from then on that topic is recorded.
"""

from __future__ import annotations

import signal
import sys
import time

from rclpy.node import Node

from fpp_msgs_py import Qos

from ..bag import OUTPUT_TOPICS, STREAM_TOPICS, BagWriter
from .common import MESSAGE_TYPES, declare, load_calibration, run

STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


class Record(Node):
    def __init__(self, **kwargs):
        super().__init__("record", **kwargs)
        output = declare(self, "output", time.strftime("bags/fpp_%Y%m%d_%H%M%S"), "bag folder to create", True)
        storage = declare(self, "storage", "mcap", "mcap or sqlite3", True)
        outputs = declare(
            self, "outputs", False, "also record points, depth/image, depth/camera_info (to look at)", True
        )
        calibration, _ = load_calibration(self)
        self.writer = BagWriter(output, storage)
        self.writer.write_calibration(calibration.to_yaml(), time.time_ns())
        self.counts = {}
        topics = STREAM_TOPICS | (OUTPUT_TOPICS if outputs else {})
        for topic, msgtype in topics.items():
            name = topic.lstrip("/")  # relative, so a namespace applies
            self.create_subscription(
                MESSAGE_TYPES[msgtype],
                name,
                lambda data, t=topic, m=msgtype: self._write(t, m, data),
                Qos.FRAMES,
                raw=True,
            )
        self.get_logger().info(f"recording {', '.join(topics)} to {output} ({storage})")

    def _write(self, topic: str, msgtype: str, data: bytes):
        # Ctrl-C waits until the message is written: mid-write it would leave the bag's index short of it
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            self.writer.write(topic, msgtype, time.time_ns(), data)
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if self.counts[topic] == 1:  # matched and flowing: discovery alone does not say so
            self.get_logger().info(f"first message on {topic}")

    def destroy_node(self):
        self.writer.close()
        print(f"[record] bag closed: {self.counts}", file=sys.stderr)  # rosout may be gone at shutdown
        return super().destroy_node()


def main(args=None):
    run(Record, args=args)


if __name__ == "__main__":
    main()
