"""cnn_depth at 640x480: frames per second and latency of the node, beside a bare onnxruntime session
on the same model in the same run (the node's overhead is the difference).

    source scripts/env.bash && python scripts/bench_cnn.py [--model PATH] [--seconds 20]

Rows: the bare session on the network's input (640 x 480 for the default model), with --threads and
with the node's threads (its network's peer: the node gives the network one core and the decoding the
other); DepthModel (what the node runs on a frame: scale, pad, run the network, decode, mask untrusted
pixels) with --threads; the node in its own process with its own defaults (the network on one core,
decoding earlier frames on the other), fed by this script first as fast as it takes frames (it keeps
only the newest: its most frames/s), then as a 30 frames/s camera (does it keep up?), timed from each
frame's stamp to its depth image arriving here, and where that time went by the node's own /diagnostics
(its network, its decoding and publishing, and from its image callback to the depth published; the
rest is the frame's way in and the depth image's way here); with the node process's CPU time (user and system) and page
faults per frame back, and its resident memory at the end, from /proc (Linux), and this script's own CPU time
per frame back (its publisher and subscriber share the two cores with the node).
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from fpp_msgs_py import Qos, Topics, numpy_to_image, stamp_ns
from fpp_nodes.core.model import DepthModel, default_model_path
from fpp_nodes.core.scenes import make_scene
from fpp_nodes.core.simulation import Rig, render
from fpp_nodes.nodes.cnn_depth import NETWORK_THREADS
from fpp_nodes.nodes.health import TOPIC as DIAGNOSTICS
from fpp_nodes.processes import start_process, stop_process

from machine import describe
from streamkit import process_times, process_tree, rss_mb

CAMERA_RATE = 30  # frames/s: the target, a common camera's rate


def timed(fn, n):
    fn()
    times = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return np.array(times) * 1000


def resident_mb(pid: int) -> float:
    """Resident memory (VmRSS) of a process and its descendants, MB."""
    return sum(rss_mb(int(proc.name)) or 0.0 for proc in process_tree(pid))


def feed(robot, pub, image, seconds, rate, arrivals):
    """Send image to the node for seconds, at rate frames/s (0: as fast as it takes them); returns
    (frames sent, seconds taken, latencies in ms of the depth images back)."""
    arrivals.clear()
    sent, start = 0, time.monotonic()
    while time.monotonic() - start < seconds:
        header = Header(frame_id="camera_optical_frame", stamp=robot.get_clock().now().to_msg())
        pub.publish(numpy_to_image(image, header))
        sent += 1
        rclpy.spin_once(robot, timeout_sec=0.005)
        while rate and time.monotonic() < start + sent / rate:
            rclpy.spin_once(robot, timeout_sec=max(start + sent / rate - time.monotonic(), 0.0))
    elapsed = time.monotonic() - start
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        rclpy.spin_once(robot, timeout_sec=0.05)
    return sent, elapsed, np.array(arrivals)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=default_model_path())
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime threads of the session and DepthModel rows")
    parser.add_argument("--node-threads", type=int, default=0, help="the node's threads parameter (0: its default)")
    parser.add_argument("--domain", type=int, default=92)
    args = parser.parse_args()
    rig = Rig()
    patterns = rig.pattern_set()
    image = render(rig, make_scene(rig, "sculpture", 5), patterns, np.random.default_rng(5)).images[
        patterns.single_shot_index
    ]
    model = DepthModel(args.model, threads=args.threads)
    h, w = 480 // model.downsample, 640 // model.downsample
    x = np.zeros((1, 1, h + (-h) % 32, w + (-w) % 32), np.float32)
    bare = timed(lambda: model.session.run([model.output], {"image": x}), 50)
    node_threads = args.node_threads or NETWORK_THREADS
    peer = DepthModel(args.model, threads=node_threads)
    bare_node = timed(lambda: peer.session.run([peer.output], {"image": x}), 50)
    full = timed(lambda: model(image), 50)

    env = dict(os.environ, ROS_DOMAIN_ID=str(args.domain))
    node_proc = start_process(
        [
            "ros2",
            "run",
            "fpp_nodes",
            "cnn_depth",
            "--ros-args",
            "-p",
            f"model:={args.model}",
            *(["-p", f"threads:={args.node_threads}"] if args.node_threads else []),
        ],
        env,
        None,
        None,
    )
    rclpy.init(domain_id=args.domain)
    robot = Node("bench_cnn")
    arrivals = []
    robot.create_subscription(
        Image, Topics.DEPTH, lambda m: arrivals.append((time.time_ns() - stamp_ns(m.header.stamp)) / 1e6), Qos.LARGE
    )
    pub = robot.create_publisher(Image, Topics.CAMERA_IMAGE, Qos.FRAMES)
    health = {}  # the node's newest /diagnostics values: its last 200 frames' stage times

    def on_health(msg):
        for status in msg.status:
            if status.name == "/cnn_depth":
                health.update({kv.key: kv.value for kv in status.values})

    robot.create_subscription(DiagnosticArray, DIAGNOSTICS, on_health, 10)
    try:
        while pub.get_subscription_count() == 0 or robot.count_subscribers(Topics.CAMERA_IMAGE) == 0:
            rclpy.spin_once(robot, timeout_sec=0.1)
        time.sleep(1.0)
        runs = {}
        for rate in (0, CAMERA_RATE):
            before, own = process_times(node_proc.pid), os.times()  # the node is this script's child: not in own
            sent_back = feed(robot, pub, image, args.seconds, rate, arrivals)
            own = sum(os.times()[:2]) - sum(own[:2])
            runs[rate] = (*sent_back, process_times(node_proc.pid) - before, own)
        network, decoding, inside = (
            float(health.get(f"{k} p50 (ms)", "nan")) for k in ("network", "decode and publish", "latency")
        )
        resident = resident_mb(node_proc.pid)
    finally:
        stop_process(node_proc, timeout=15)
        robot.destroy_node()
        rclpy.try_shutdown()
    print(
        "\n"
        + describe(
            {
                "onnxruntime intra-op (session and DepthModel)": args.threads,
                "onnxruntime intra-op (node)": args.node_threads or "its default",
                "cv2 (DepthModel and node, default)": cv2.getNumThreads(),
            }
        )
    )
    print(
        f"model {args.model} ({model.card.get('architecture')}, width {model.card.get('width')}, "
        f"{model.card.get('parameters')} parameters), 640x480 mono8 frames\n"
    )
    print(f"{'':44} {'ms p50':>7} {'ms p95':>7} {'frames/s':>9}")
    for label, ms in (
        (f"bare onnxruntime session ({'x'.join(map(str, x.shape[2:][::-1]))})", bare),
        (f"bare session, the node's {node_threads} thread(s)", bare_node),
        ("DepthModel (+ decode, mask untrusted)", full),
    ):
        print(f"{label:44} {np.median(ms):7.1f} {np.percentile(ms, 95):7.1f} {1000 / np.median(ms):9.1f}")
    for rate, (sent, elapsed, lat, *_) in runs.items():
        fed = f"{rate} frames/s camera" if rate else "frames as fast as it takes"
        print(
            f"{'cnn_depth node, ' + fed:44} {np.median(lat):7.1f} {np.percentile(lat, 95):7.1f} "
            f"{len(lat) / elapsed:9.1f}   sent {sent}, back {len(lat)}"
        )
    print("\nCPU a frame back, ms:             node user  node system  page faults  this script (user+system)")
    for rate, (_, _, lat, (user, system, faults), own) in runs.items():
        frames = max(len(lat), 1)
        fed = f"{rate} frames/s camera" if rate else "as fast as it takes"
        print(
            f"{fed:32} {1000 * user / frames:10.1f} {1000 * system / frames:12.1f} {faults / frames:12.0f}"
            f" {1000 * own / frames:26.1f}"
        )
    print(f"node process resident memory at the end: {resident:.0f} MB")
    print(
        f"\nat {CAMERA_RATE} frames/s, p50 of the node's last 200 frames (its /diagnostics): network {network:.1f} ms, "
        f"decode and publish {decoding:.1f} ms, image in to depth published {inside:.1f} ms; stamp to depth "
        f"here {np.median(runs[CAMERA_RATE][2][-200:]):.1f} ms (the same frames)"
    )
    print(
        "\nnode: stamp to depth image here; it keeps the newest frame, so frames not back were dropped, not "
        f"queued. Node latency at {CAMERA_RATE} frames/s / bare session: "
        f"{np.median(runs[CAMERA_RATE][2]) / np.median(bare):.1f}x ({args.threads} threads), "
        f"{np.median(runs[CAMERA_RATE][2]) / np.median(bare_node):.1f}x (the node's {node_threads})"
    )


if __name__ == "__main__":
    main()
