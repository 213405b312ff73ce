"""replay: plays a bag of the fringe stream back into the graph with its original timing.

The whole bag is read and checked before anything is published: a missing, truncated or corrupt bag
stops with one error line and publishes nothing. The calibration stored in the bag is published,
latched, on fpp/calibration; capture_sequence and fpp_depth switch to it. Topics are published with
relative names, so a namespace or `-r camera/image_raw:=other` remaps them.
Playing starts once every topic has a subscriber, or after start_delay seconds (messages sent before
discovery completes would be lost). Parameters: bag (path), rate (speed factor), loop (bool),
start_delay (s).
"""

from __future__ import annotations

import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from std_msgs.msg import String

from fpp_msgs_py import Qos, Topics

from ..bag import BagError, read_bag
from .common import MESSAGE_TYPES, check_positive, declare


class Replay(Node):
    def __init__(self, **kwargs):
        super().__init__("replay", **kwargs)
        path = declare(self, "bag", "", "bag folder to play", True)
        self.rate = declare(self, "rate", 1.0, "playback speed factor", True)
        self.loop = declare(self, "loop", False, "play over and over", True)
        self.start_delay = declare(
            self, "start_delay", 10.0, "longest wait for every topic to have a subscriber, s", True
        )
        check_positive("rate", self.rate)
        if not path:
            raise ValueError("parameter 'bag' is required")
        self.recording = read_bag(path)  # BagError before any publisher exists
        unknown = {m for _, m, _, _ in self.recording.messages} - set(MESSAGE_TYPES)
        if unknown:
            raise BagError(f"{path} holds message types replay does not publish: {', '.join(sorted(unknown))}")
        self.publishers_ = {
            topic: self.create_publisher(MESSAGE_TYPES[msgtype], topic.lstrip("/"), Qos.FRAMES)
            for topic, msgtype, _, _ in self.recording.messages
        }
        if self.recording.calibration_yaml is not None:
            self.create_publisher(String, Topics.CALIBRATION, Qos.LATCHED).publish(
                String(data=self.recording.calibration_yaml)
            )
        self.get_logger().info(f"{path}: {len(self.recording.messages)} messages on {', '.join(self.publishers_)}")

    def play(self):
        messages = self.recording.messages
        end = time.monotonic() + self.start_delay
        while time.monotonic() < end and not all(p.get_subscription_count() for p in self.publishers_.values()):
            rclpy.spin_once(self, timeout_sec=0.05)
        time.sleep(0.2)  # matched on our side; give the subscribers' side a moment too
        while True:
            start, first = time.monotonic(), messages[0][2]
            for topic, _, stamp_ns, data in messages:
                delay = start + (stamp_ns - first) / 1e9 / self.rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                self.publishers_[topic].publish(data)
            if not self.loop:
                return


def main(args=None):
    rclpy.init(args=args)
    node = None
    try:
        node = Replay()
        node.play()
        rclpy.spin_once(node, timeout_sec=0.5)  # let the last messages go out
    except (BagError, ValueError) as e:
        print(f"[FATAL] {e}", file=sys.stderr)
        sys.exit(2)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
