"""A robot in its own process: waits for the sensor's clouds and depth images, checks them, and prints
one JSON line with what it saw. Used by test_two_hosts.py, run in another network namespace:

    python tests/fpp_nodes/nodes/cloud_probe.py --clouds 2 --depths 1 --timeout 120   # ROS_DOMAIN_ID: the environment's

Exit status 0 when enough arrived in time, 1 otherwise; the JSON is printed either way.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import time

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import Image, PointCloud2

from fpp_msgs_py import Qos, Topics, cloud_to_xyz, image_to_numpy, stamp_ns


def cloud_summary(msg: PointCloud2) -> dict:
    z = cloud_to_xyz(msg)[..., 2]
    return {
        "height": msg.height,
        "width": msg.width,
        "bytes": len(msg.data),
        "point_step": msg.point_step,
        "fields": [f.name for f in msg.fields],
        "frame_id": msg.header.frame_id,
        "stamp_ns": stamp_ns(msg.header.stamp),
        "arrived_ns": time.time_ns(),
        "finite_z": float(np.isfinite(z).mean()),
        "median_z_m": float(np.nanmedian(z)),
    }


def depth_summary(msg: Image) -> dict:
    depth = image_to_numpy(msg)
    return {
        "height": msg.height,
        "width": msg.width,
        "encoding": msg.encoding,
        "bytes": len(msg.data),
        "frame_id": msg.header.frame_id,
        "stamp_ns": stamp_ns(msg.header.stamp),
        "finite": float(np.isfinite(depth).mean()),
        "median_m": float(np.nanmedian(depth)),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--clouds", type=int, default=2)
    parser.add_argument("--depths", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args(argv)
    start = time.monotonic()
    rclpy.init()
    node = Node("cloud_probe")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    clouds, depths = [], []
    # summaries are made in the callback, so no multi-megabyte message is kept
    node.create_subscription(PointCloud2, Topics.POINTS, lambda m: clouds.append(cloud_summary(m)), Qos.LARGE)
    node.create_subscription(Image, Topics.DEPTH, lambda m: depths.append(depth_summary(m)), Qos.LARGE)
    discovered = None
    try:
        while time.monotonic() - start < args.timeout and (len(clouds) < args.clouds or len(depths) < args.depths):
            executor.spin_once(timeout_sec=0.1)
            if discovered is None and node.count_publishers(Topics.POINTS):
                discovered = time.monotonic() - start
        publishers = [
            {"node": f"{p.node_namespace.rstrip('/')}/{p.node_name}", "topic_type": p.topic_type}
            for p in node.get_publishers_info_by_topic("/" + Topics.POINTS)
        ]
        nodes = sorted(f"{ns.rstrip('/')}/{name}" for name, ns in node.get_node_names_and_namespaces())
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    ok = len(clouds) >= args.clouds and len(depths) >= args.depths
    print(
        json.dumps(
            {
                "ok": ok,
                "hostname": socket.gethostname(),
                "domain_id": os.environ.get("ROS_DOMAIN_ID"),
                "discovered_after_s": discovered,
                "elapsed_s": time.monotonic() - start,
                "publishers_of_points": publishers,
                "nodes": nodes,
                "clouds": clouds,
                "depths": depths,
            }
        )
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
