"""The sensor's stream across processes at 30 camera frames/s: frames in, sequences out, drops and
latency per stage, for the QoS the sensor uses (names.Qos: RELIABLE, short KEEP_LAST).

    source scripts/env.bash && python scripts/bench_stream.py [--seconds 30] [--rate 30] [--single-shot]

The four nodes run as separate processes (ros2 run), this script is the robot. As a peer in the same
run it also subscribes to the cloud BEST_EFFORT, to show what that choice would lose.
With --single-shot, the single-shot sensor instead: pattern_projector showing the composite alone on
every tick (single_shot_only), fringe_camera_sim and cnn_depth on its frames, three processes; depth
images and clouds per second (this robot subscribes to both), stamp to depth image here, and the depth's
accuracy against the simulator's truth. Both end with the CPU each node process and this robot took
over the counted seconds (from /proc: Linux), as a share of one core.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2

from fpp_msgs_py import Qos, Topics, image_to_numpy, stamp_ns
from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.nodes.demo import DemoRobot, per_cloud
from fpp_nodes.processes import NodeProcesses

from machine import describe
from streamkit import capture_counts, percentile_header, percentile_row, process_times


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--domain", type=int, default=91)
    parser.add_argument("--single-shot", action="store_true", help="the single-shot sensor at the camera's rate")
    args = parser.parse_args()
    logs = Path(tempfile.mkdtemp(prefix="bench_stream_"))
    procs = NodeProcesses(args.domain, logs)
    if args.single_shot:
        return single_shot(args, procs)
    for exe, params in (
        ("fpp_depth", []),
        ("capture_sequence", []),
        ("fringe_camera_sim", []),
        ("pattern_projector", ["-p", f"rate:={args.rate}"]),
    ):
        procs.start(exe, *params)
    rclpy.init(domain_id=args.domain)
    robot = DemoRobot()
    best_effort = []
    robot.create_subscription(
        PointCloud2,
        Topics.POINTS,
        lambda m: best_effort.append(m.header.stamp),
        QoSProfile(depth=2, reliability=ReliabilityPolicy.BEST_EFFORT),
    )
    # start counting at the first cloud: every node is up
    cpu = listen(robot, procs, args.seconds, lambda: robot.clouds, (robot.frames, robot.clouds, best_effort))
    counts = capture_counts(procs.logs("capture_sequence"))
    frames_in, complete, dropped = counts.frames_in, counts.complete, counts.dropped
    rows = per_cloud(robot)
    # the nodes do not set cv2's thread count: each process gets the default this one has
    print("\n" + describe({"cv2 (each node process, default)": cv2.getNumThreads()}, libs=("numpy", "cv2")))
    print(
        f"{args.seconds:g} s at {args.rate:g} camera frames/s, 640x480 mono8; 4 nodes in 4 processes + this robot "
        "(capture_sequence's counts cover its whole run)"
    )
    print(
        f"{'frames in':>10} {'sequences complete':>18} {'dropped':>7} {'clouds here RELIABLE':>20} "
        f"{'clouds here BEST_EFFORT':>23}"
    )
    print(f"{frames_in:10d} {complete:18d} {dropped:7d} {len(robot.clouds):20d} {len(best_effort):23d}")
    print("\n" + percentile_header("stage (ms)"))
    for stage in ("camera", "capture+depth", "end-to-end", "sequence"):
        print(percentile_row(stage, [r[stage] for r in rows]))
    print(
        f"\nRMSE of the clouds against ground truth: {np.mean([r['rmse_mm'] for r in rows]):.4f} mm "
        f"(mean of {len(rows)}); node logs in {logs}"
    )
    print(cpu)


def listen(robot, procs: NodeProcesses, seconds: float, ready, counted) -> str:
    """Spin the robot until ready(), empty what it has counted so far (counted), spin it for seconds more; then stop the
    nodes and ROS, whatever happened. Returns the CPU each node process and this robot took over those seconds."""
    try:
        while not ready():
            rclpy.spin_once(robot, timeout_sec=0.1)
        for got in counted:
            got.clear()
        before, own, start = [process_times(p.pid) for _, p, _ in procs.procs], os.times(), time.monotonic()
        end = start + seconds
        while time.monotonic() < end:
            rclpy.spin_once(robot, timeout_sec=0.05)
        after, own_after, took = [process_times(p.pid) for _, p, _ in procs.procs], os.times(), time.monotonic() - start
        shares = [(exe, (a - b)[:2].sum() / took) for (exe, _, _), a, b in zip(procs.procs, after, before)]
        shares.append(("this robot", (own_after.user + own_after.system - own.user - own.system) / took))
        return "CPU over those seconds, share of a core (user and system): " + ", ".join(
            f"{exe} {share:.0%}" for exe, share in shares
        )
    finally:
        procs.stop()
        robot.destroy_node()
        rclpy.try_shutdown()


def single_shot(args, procs: NodeProcesses) -> None:
    for exe, params in (
        ("cnn_depth", []),
        ("fringe_camera_sim", []),
        ("pattern_projector", ["-p", f"rate:={args.rate}", "-p", "single_shot_only:=true"]),
    ):
        procs.start(exe, *params)
    rclpy.init(domain_id=args.domain)
    robot = Node("bench_single_shot")
    depths, truth = [], []
    robot.create_subscription(Image, Topics.DEPTH, lambda m: depths.append((time.time_ns(), m)), Qos.LARGE)
    robot.create_subscription(Image, Topics.TRUTH, truth.append, Qos.LATCHED)
    clouds = []  # as a robot subscribes: the cloud beside the depth image
    robot.create_subscription(PointCloud2, Topics.POINTS, lambda m: clouds.append(time.time_ns()), Qos.LARGE)
    # start counting at the first of each: every node is up
    cpu = listen(robot, procs, args.seconds, lambda: depths and clouds and truth, (depths, clouds))
    truth_mm = image_to_numpy(truth[0]) * 1000.0
    over = ErrorTotals()
    for _, m in depths:
        over.add(image_to_numpy(m) * 1000.0, truth_mm, 1.0)
    latency = [(arrived - stamp_ns(m.header.stamp)) / 1e6 for arrived, m in depths]
    threads = {"cv2 (each node process, default)": cv2.getNumThreads()}
    print("\n" + describe(threads, libs=("numpy", "cv2", "onnxruntime")))
    print(
        f"{args.seconds:g} s at {args.rate:g} camera frames/s, 640x480 mono8, the projector showing the composite "
        "alone; 3 nodes in 3 processes + this robot"
    )
    print(
        f"depth images here: {len(depths)}, {len(depths) / args.seconds:.1f} a second; "
        f"clouds: {len(clouds)}, {len(clouds) / args.seconds:.1f} a second"
    )
    print("\n" + percentile_header("stage (ms)"))
    print(percentile_row("stamp to depth", latency))
    print(
        f"\nagainst the simulator's truth: RMSE {over.rmse:.3f} mm, {over.coverage:.1%} of the lit pixels, "
        f"{over.share_over:.2%} off by more than 1 mm; node logs in {procs.logs_dir}"
    )
    print(cpu)


if __name__ == "__main__":
    main()
