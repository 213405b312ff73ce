"""The sensor's stream across processes at 30 camera frames/s: frames in, sequences out, drops and
latency per stage, for the QoS the sensor uses (names.Qos: RELIABLE, short KEEP_LAST).

    source scripts/env.bash && python scripts/bench_stream.py [--seconds 30] [--rate 30]

The four nodes run as separate processes (ros2 run), this script is the robot. As a peer in the same
run it also subscribes to the cloud BEST_EFFORT, to show what that choice would lose.
"""
from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from fpp_msgs_py import Topics
from fpp_nodes.nodes.demo import Robot, per_cloud


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--domain", type=int, default=91)
    args = parser.parse_args()
    env = dict(os.environ, ROS_DOMAIN_ID=str(args.domain), RCUTILS_LOGGING_BUFFERED_STREAM="0")
    logs = Path(tempfile.mkdtemp(prefix="bench_stream_"))
    procs = []
    for exe, params in (("fpp_depth", []), ("capture_sequence", []), ("fringe_camera_sim", []),
                        ("pattern_projector", ["-p", f"rate:={args.rate}"])):
        log = open(logs / f"{exe}.log", "w")
        procs.append(subprocess.Popen(["ros2", "run", "fpp_nodes", exe, "--ros-args", *params], env=env,
                                      stdout=log, stderr=subprocess.STDOUT, start_new_session=True))
    rclpy.init(domain_id=args.domain)
    robot = Robot(depth_images=False)
    best_effort = []
    robot.create_subscription(PointCloud2, Topics.POINTS, lambda m: best_effort.append(m.header.stamp),
                              QoSProfile(depth=2, reliability=ReliabilityPolicy.BEST_EFFORT))
    try:
        while not robot.clouds:  # start counting at the first cloud: every node is up
            rclpy.spin_once(robot, timeout_sec=0.1)
        robot.frames.clear(), robot.clouds.clear(), best_effort.clear()
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            rclpy.spin_once(robot, timeout_sec=0.05)
    finally:
        for p in procs:
            os.killpg(p.pid, signal.SIGINT)
        for p in procs:
            p.wait(timeout=15)
        robot.destroy_node()
        rclpy.try_shutdown()
    summary = re.search(r"frames in (\d+), sequences complete (\d+), dropped (\d+)",
                        (logs / "capture_sequence.log").read_text())
    frames_in, complete, dropped = (int(x) for x in summary.groups())
    rows = per_cloud(robot)
    print(f"\n{args.seconds:g} s at {args.rate:g} camera frames/s, 640x480 mono8; 4 nodes in 4 processes + this robot "
          "(capture_sequence's counts cover its whole run)")
    print(f"{'frames in':>10} {'sequences complete':>18} {'dropped':>7} {'clouds here RELIABLE':>20} "
          f"{'clouds here BEST_EFFORT':>23}")
    print(f"{frames_in:10d} {complete:18d} {dropped:7d} {len(robot.clouds):20d} {len(best_effort):23d}")
    print(f"\n{'stage (ms)':16} {'p50':>7} {'p95':>7} {'max':>7}")
    for stage in ("camera", "capture+depth", "end-to-end", "sequence"):
        values = np.array([r[stage] for r in rows])
        print(f"{stage:16} {np.percentile(values, 50):7.1f} {np.percentile(values, 95):7.1f} {values.max():7.1f}")
    print(f"\nRMSE of the clouds against ground truth: {np.mean([r['rmse_mm'] for r in rows]):.4f} mm "
          f"(mean of {len(rows)}); node logs in {logs}")


if __name__ == "__main__":
    main()
