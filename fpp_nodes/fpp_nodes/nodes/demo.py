"""demo: the main job. Starts the simulated sensor (projector -> camera -> capture -> multi-shot depth)
in its own process, subscribes as a robot would, writes a few point clouds (.ply) and pictures of
them (depth, error against the simulator's ground truth, a rendered view, a height profile), and
prints the latency of each stage and the accuracy against the ground truth.

    ros2 run fpp_nodes demo [--out out/demo] [--clouds 5] [--scene sculpture] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import Image, PointCloud2

from fpp_msgs_py import Qos, Topics, cloud_to_xyz, image_to_numpy, stamp_ns

from .. import pictures
from ..core import io
from ..core.calibration import Calibration, default_calibration_path
from ..core.metrics import depth_errors
from ..processes import start_process, stop_process


class DemoRobot(Node):
    """Subscribes to everything a robot and its operator look at, noting when each message arrives."""

    def __init__(self, max_clouds: int | None = None):
        super().__init__("demo_robot")
        self.max_clouds = max_clouds
        self.frames, self.clouds, self.cnn_clouds, self.truth = {}, [], [], None
        self.frames_per_sequence = Calibration.load(default_calibration_path()).patterns.count  # what sensor runs
        clock = time.time_ns
        self.create_subscription(
            Image, Topics.CAMERA_IMAGE, lambda m: self.frames.__setitem__(stamp_ns(m.header.stamp), clock()), Qos.FRAMES
        )
        self.create_subscription(PointCloud2, Topics.POINTS, self._on_cloud, Qos.LARGE)
        self.create_subscription(PointCloud2, "cnn/" + Topics.POINTS, self._on_cnn_cloud, Qos.LARGE)
        self.create_subscription(
            Image, Topics.TRUTH, lambda m: setattr(self, "truth", image_to_numpy(m).copy()), Qos.LATCHED
        )

    def sequences_seen(self) -> bool:
        """Whether every cloud's sequence, first frame to last, has reached this robot."""
        stamps = np.array(sorted(self.frames))
        n = self.frames_per_sequence
        return all(last_frame(stamps, stamp_ns(c.header.stamp), n) is not None for c, _ in self.clouds)

    def _on_cloud(self, cloud: PointCloud2):
        """A cloud counts when this robot saw its sequence's first frame (it is stamped with it): one that
        began before the subscription matched cannot have its latency told."""
        full = self.max_clouds is not None and len(self.clouds) >= self.max_clouds
        if stamp_ns(cloud.header.stamp) in self.frames and not full:
            self.clouds.append((cloud, time.time_ns()))

    def _on_cnn_cloud(self, cloud: PointCloud2):
        if self.max_clouds is None or len(self.cnn_clouds) < self.max_clouds:
            self.cnn_clouds.append((cloud, time.time_ns()))


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="demo", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", default="out/demo")
    parser.add_argument("--clouds", type=int, default=5)
    parser.add_argument("--scene", default="sculpture")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args(rclpy.utilities.remove_ros_args(argv if argv is not None else sys.argv)[1:])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sensor = start_process(
        [
            sys.executable,
            "-m",
            "fpp_nodes.nodes.sensor",
            "--ros-args",
            "-p",
            f"scene:={args.scene}",
            "-p",
            f"seed:={args.seed}",
        ],
        dict(os.environ),
        None,
        None,
    )
    rclpy.init()
    robot = DemoRobot(max_clouds=args.clouds)
    try:
        end = time.monotonic() + args.timeout
        while len(robot.clouds) < args.clouds and time.monotonic() < end and sensor.poll() is None:
            rclpy.spin_once(robot, timeout_sec=0.1)
        # Callbacks run one at a time: on a busy machine a cloud can be taken before its sequence's last
        # frames, and the single-shot clouds beside them come later (the network and its decoding take
        # longer). Wait for them (bounded), not for a fixed time.
        settle = time.monotonic() + 30.0
        while not (robot.sequences_seen() and len(robot.cnn_clouds) >= len(robot.clouds)) and time.monotonic() < settle:
            rclpy.spin_once(robot, timeout_sec=0.05)
        if sensor.poll() is not None:
            sys.exit(f"demo: the sensor exited with status {sensor.returncode}")
        if len(robot.clouds) < args.clouds or robot.truth is None:
            sys.exit(f"demo: only {len(robot.clouds)} clouds in {args.timeout:g} s")
        report(robot, out)
    finally:
        robot.destroy_node()
        rclpy.try_shutdown()
        stop_process(sensor)


def per_cloud(robot: DemoRobot) -> list[dict]:
    """Latency of each stage (ms) and accuracy of every cloud received, from the stamps (when each
    pattern was shown) and the arrival times here."""
    frame_stamps = np.array(sorted(robot.frames))
    rows = []
    for cloud, arrived in robot.clouds:
        first = stamp_ns(cloud.header.stamp)
        last = last_frame(frame_stamps, first, robot.frames_per_sequence)
        if last is None:
            continue  # not all of its frames were seen here
        rmse, cover = cloud_rmse_mm(cloud, robot.truth)
        rows.append(
            {
                "camera": (robot.frames[last] - last) / 1e6,
                "capture+depth": (arrived - robot.frames[last]) / 1e6,
                "end-to-end": (arrived - last) / 1e6,
                "sequence": (last - first) / 1e6,
                "rmse_mm": rmse,
                "cover": cover,
            }
        )
    return rows


def last_frame(frame_stamps: np.ndarray, first: int, n: int) -> int | None:
    """Stamp of the last frame of the sequence that began at `first`, None unless all of its frames were
    seen (the frames between are its own: no gap much longer than the median frame period)."""
    k = np.searchsorted(frame_stamps, first) + n - 1
    period = np.median(np.diff(frame_stamps)) if len(frame_stamps) > 1 else 0
    if k >= len(frame_stamps) or frame_stamps[k] - first > 1.5 * (n - 1) * period:
        return None
    return int(frame_stamps[k])


def cloud_rmse_mm(cloud, truth_m) -> tuple[float, float]:
    """RMSE (mm) of a cloud's depth against the truth (NaN: no depth), and its coverage of the truth."""
    e = depth_errors(cloud_to_xyz(cloud)[..., 2] * 1000.0, truth_m * 1000.0)
    return e.rmse_mm, e.coverage


def write_pictures(out: Path, clouds: list, truth_m: np.ndarray, prefix: str, label: str) -> np.ndarray | None:
    """depth and error pictures of every cloud, a rendered view of the first; colours on the truth's
    range, so both paths' pictures compare. Returns the first cloud's depth (mm) for the profile."""
    truth = truth_m * 1000.0
    lo, hi = pictures.depth_range(truth)
    first = None
    for i, (cloud, _) in enumerate(clouds):
        xyz = cloud_to_xyz(cloud)
        depth = xyz[..., 2] * 1000.0
        cv2.imwrite(str(out / f"{prefix}depth_{i:02d}.png"), pictures.depth_picture(depth, lo, hi, f"{label} depth"))
        cv2.imwrite(
            str(out / f"{prefix}error_{i:02d}.png"), pictures.error_picture(depth, truth, title=f"{label} - truth")
        )
        if i == 0:  # the scene does not move: one view is enough
            cv2.imwrite(str(out / f"{prefix}cloud_{i:02d}.png"), pictures.cloud_view(xyz, lo=lo / 1000, hi=hi / 1000))
            first = depth
    return first


def report(robot: DemoRobot, out: Path) -> None:
    rows = per_cloud(robot)
    for i, (cloud, _) in enumerate(robot.clouds):
        io.write_ply(out / f"cloud_{i:02d}.ply", cloud_to_xyz(cloud))
    curves = {
        "ground truth": robot.truth * 1000.0,
        "multi-shot": write_pictures(out, robot.clouds, robot.truth, "", "multi-shot"),
    }
    print(
        f"\n{len(rows)} clouds (640x480, organized) from the simulated sensor; milliseconds, from the stamps "
        "(when each pattern was shown) to arrival here"
    )
    print(
        f"{'cloud':>5} {'camera':>7} {'capture+depth':>13} {'end-to-end':>10} {'sequence':>9} "
        f"{'RMSE mm':>8} {'cover':>6}"
    )
    for i, r in enumerate(rows):
        print(
            f"{i:5d} {r['camera']:7.1f} {r['capture+depth']:13.1f} {r['end-to-end']:10.1f} {r['sequence']:9.1f} "
            f"{r['rmse_mm']:8.4f} {r['cover']:6.1%}"
        )
    print(
        "camera: a sequence's last frame arrives, after its pattern was shown; capture+depth: then the cloud "
        "arrives;\nend-to-end: last pattern shown to cloud here; sequence: first to last pattern shown. "
        "RMSE and cover (of lit pixels) against the simulator's exact depth."
    )
    if robot.cnn_clouds:
        print("\nside by side, the single-shot path (cnn_depth on each sequence's single-shot frame, the composite):")
        print(f"{'cloud':>5} {'image->cloud ms':>15} {'RMSE mm':>8} {'cover':>6}")
        for i, (cloud, arrived) in enumerate(robot.cnn_clouds):
            io.write_ply(out / f"cnn_cloud_{i:02d}.ply", cloud_to_xyz(cloud))
            rmse, cover = cloud_rmse_mm(cloud, robot.truth)
            print(f"{i:5d} {(arrived - stamp_ns(cloud.header.stamp)) / 1e6:15.1f} {rmse:8.3f} {cover:6.1%}")
        curves["single-shot (CNN)"] = write_pictures(out, robot.cnn_clouds, robot.truth, "cnn_", "single-shot")
    row = pictures.profile_row(curves["ground truth"])
    cv2.imwrite(str(out / "profile.png"), pictures.height_profile(row, {k: v[row] for k, v in curves.items()}))
    print(
        f"wrote {len(robot.clouds) + len(robot.cnn_clouds)} .ply clouds (metres) and their pictures to {out}: "
        "[cnn_]depth_NN.png, [cnn_]error_NN.png (against the simulator's exact depth), [cnn_]cloud_00.png "
        "(rendered view), profile.png (depth along one row)"
    )


if __name__ == "__main__":
    main()
