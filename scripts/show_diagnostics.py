"""Print the sensor's health from /diagnostics (PyPI's ROS 2 has no `ros2 topic echo`).

source scripts/env.bash
python scripts/show_diagnostics.py            # every report as it comes, until Ctrl-C
python scripts/show_diagnostics.py --once     # the first report of each node seen within --wait s
"""

import argparse
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node

from fpp_nodes.nodes.health import TOPIC as DIAGNOSTICS

LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


def show(status) -> str:
    lines = [
        f"{status.name}: {LEVELS.get(status.level[0], status.level[0])} ({status.message}), "
        f"hardware_id {status.hardware_id}"
    ]
    return "\n".join(lines + [f"    {kv.key}: {kv.value}" for kv in status.values])


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--once", action="store_true")
    parser.add_argument("--wait", type=float, default=5.0, help="with --once: how long to collect reports, s")
    args = parser.parse_args()
    rclpy.init()
    node = Node("show_diagnostics")
    seen = {}

    def on_report(msg: DiagnosticArray):
        for status in msg.status:
            if not args.once:
                print(show(status), flush=True)
            seen[status.name] = status

    node.create_subscription(DiagnosticArray, DIAGNOSTICS, on_report, 50)
    end = time.monotonic() + args.wait
    try:
        while not args.once or time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    if args.once:
        print("\n".join(show(seen[name]) for name in sorted(seen)) or f"no reports on /diagnostics in {args.wait:g} s")
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
