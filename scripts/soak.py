"""Soak: the composed sensor (`ros2 run fpp_nodes sensor`, the multi-shot and the single-shot path in one
process) at 30 camera frames/s for a long time, with this script as a robot subscribed to both paths'
depth images and clouds.

    source scripts/env.bash && python scripts/soak.py [--minutes 10] [--rate 30] [--max-growth-mb 10]
    make soak [SOAK_MINUTES=10]

Counts are taken over a window that starts after warm-up (every output has arrived once, then
--warmup s) and lasts --minutes; outputs of inputs from the window that arrive up to --tail s after it
still count. Every complete sequence publishes fringe_single (its single-shot input) once, so the
robot's copy of it is the list of sequences assembled; gaps between their stamps are sequences lost
before assembly. A sequence is out on the multi-shot path when its cloud or depth image (stamped with
the sequence's first frame) arrives, on the single-shot path when the cnn output with the
fringe_single's stamp does. The robot takes everything as raw CDR into a deep history, so it is not
the one that falls behind.

The design keeps every complete sequence on the multi-shot path (RELIABLE, every sequence processed),
so a sequence lost before assembly, or assembled with neither its depth image nor its cloud coming
out, fails the run. One of the two missing is a message lost on its way here: the outputs are
RELIABLE KEEP_LAST 2, so under load a subscriber gets the newest, by design; it is reported apart.
cnn_depth keeps only the newest frame (KEEP_LAST 1) by design, so its drops are reported, as
expected, and fail nothing.

Resident memory (VmRSS) of the sensor process is sampled every 10 s from the end of the warm-up; start
and end are the medians of the first and last three samples. The sensor's memory settles at the
working set of the largest backlog it has had (messages held in DDS histories while the process
catches up), which takes minutes under load. Measured here in three ten-minute runs: twice a step of
+20 MB within the window's first two minutes, then the same to 0.1 MB at every minute mark to the
end; once +7 MB in minute 4, then -11 MB in minute 7. So the verdict compares the end with the
highest sample of the window's first half: a leak keeps growing past it, a settled working set does
not. Growth above --max-growth-mb fails the run: with the defaults (10 MB, 10 minutes), a leak
faster than 2 MB/min; a longer run catches slower ones.
The sensor is stopped with SIGINT at the end; a Traceback in its log or an exit status other than a
clean shutdown's fails the run.
Exit status 0 when all three verdicts are OK, 1 otherwise.
"""

from __future__ import annotations

import argparse
import bisect
import struct
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import Image, PointCloud2

from fpp_msgs_py import Frames, Qos, Topics
from fpp_nodes.nodes.health import TOPIC as DIAGNOSTICS
from fpp_nodes.processes import NodeProcesses

from machine import describe
from streamkit import capture_counts, percentile_header, percentile_row, rss_mb

PERCENTILES = (50, 95, 99)
OUTPUTS = {
    "points": (Topics.POINTS, PointCloud2),
    "depth": (Topics.DEPTH, Image),
    "cnn points": ("cnn/" + Topics.POINTS, PointCloud2),
    "cnn depth": ("cnn/" + Topics.DEPTH, Image),
}


def raw_header(data: bytes) -> tuple[int, str, int, int]:
    """(stamp ns, frame_id, height, width) of a CDR-serialized sensor_msgs/Image or PointCloud2, which
    both begin header, height, width; read without deserializing the megabytes after them."""
    sec, nanosec, length = struct.unpack_from("<iII", data, 4)
    frame_id = data[16 : 16 + length - 1].decode()
    offset = 16 + length
    offset += -(offset - 4) % 4  # CDR aligns to the field's size, counted after the 4-byte encapsulation
    height, width = struct.unpack_from("<II", data, offset)
    return sec * 1_000_000_000 + nanosec, frame_id, height, width


class SoakRobot(Node):
    """Notes (stamp ns, arrival ns) of every pattern shown, sequence assembled and output, taking the
    messages as raw CDR (no decoding) into a deep history, so that this robot is never the one that loses
    a message; keeps no message."""

    def __init__(self):
        super().__init__("soak_robot")
        self.patterns, self.singles = [], []
        self.outputs = {name: [] for name in OUTPUTS}
        self.bad = []  # outputs of the wrong size or frame
        self.diagnostics = {}  # node name -> its last DiagnosticStatus values, where nodes publish them
        deep = Qos.FRAMES  # RELIABLE, KEEP_LAST 20
        self.create_subscription(
            Image, Topics.PATTERN, lambda d: self.patterns.append(raw_header(d)[0]), deep, raw=True
        )
        self.create_subscription(
            Image, Topics.SINGLE, lambda d: self.singles.append((raw_header(d)[0], time.time_ns())), deep, raw=True
        )
        for name, (topic, msg_type) in OUTPUTS.items():
            self.create_subscription(
                msg_type, topic, lambda d, n=name: self.outputs[n].append(self._check(n, d)), deep, raw=True
            )
        self.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics, 10)

    def _check(self, name: str, data: bytes) -> tuple[int, int]:
        arrived = time.time_ns()
        stamp, frame_id, height, width = raw_header(data)
        if (height, width) != (480, 640) or frame_id != Frames.CAMERA:
            self.bad.append(f"{name}: {width}x{height} in {frame_id!r}")
        return stamp, arrived

    def _on_diagnostics(self, msg: DiagnosticArray):
        for status in msg.status:
            self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}


def account(robot: SoakRobot, t0: int, t1: int) -> dict:
    """Sequences in and out of each path for the inputs that arrived here between t0 and t1 (ns).
    Camera frames carry the stamps of the patterns they show, and this robot sees every pattern, so a
    stamp's index among the patterns says which frame it is: a sequence's frames are consecutive."""
    patterns = sorted(robot.patterns)
    index = {s: i for i, s in enumerate(patterns)}
    singles = sorted(s for s, arrived in robot.singles if t0 <= arrived < t1 and s in index)
    steps = np.diff([index[s] for s in singles])
    k = int(np.median(steps)) if len(steps) else 16  # frames per sequence
    gaps = int(sum(max(0, round(d / k) - 1) for d in steps))
    shown = sum(1 for s in patterns if t0 <= s < t1)
    out = {
        "frames_per_sequence": k,
        "patterns": shown,
        "pattern_rate": shown / ((t1 - t0) / 1e9),
        "assembled": len(singles),
        "lost_before_assembly": gaps,
        "unknown_singles": sum(1 for s, arrived in robot.singles if t0 <= arrived < t1 and s not in index),
    }
    for name, got in robot.outputs.items():
        arrivals = {}
        for stamp, arrived in got:
            arrivals.setdefault(stamp, arrived)
        firsts = sorted(index[s] for s in arrivals if s in index)  # multi-shot outputs: first frame's index
        latency, last_frame_latency, matched = [], [], set()
        for s in singles:
            if name.startswith("cnn"):  # stamped with the single-shot image itself
                c = s if s in arrivals else None
            else:  # stamped with the sequence's first frame, up to k - 1 frames before the single-shot image
                j = bisect.bisect_right(firsts, index[s]) - 1
                c = patterns[firsts[j]] if j >= 0 and index[s] - firsts[j] < k else None
            if c is None:
                continue
            matched.add(s)
            latency.append((arrivals[c] - c) / 1e6)
            if not name.startswith("cnn") and index[c] + k - 1 < len(patterns):
                last_frame_latency.append((arrivals[c] - patterns[index[c] + k - 1]) / 1e6)
        out[name] = {
            "out": len(latency),
            "lost": len(singles) - len(latency),
            "latency": latency,
            "last_frame_latency": last_frame_latency,
            "matched": matched,
        }
    # fpp_depth (cnn_depth) publishes the depth image and the cloud of an input from one callback: neither
    # arriving means the input was dropped in the sensor, one missing means that message was lost on its way

    for path, (points, depth) in (("", ("points", "depth")), ("cnn ", ("cnn points", "cnn depth"))):
        came_out = out[points]["matched"] | out[depth]["matched"]
        out[path + "unprocessed"] = sum(1 for s in singles if s not in came_out)
    return out


def spin_for(executor, seconds: float, until=lambda: False) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if until():
            return True
        executor.spin_once(timeout_sec=0.05)
    return until()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the measured window")
    parser.add_argument("--rate", type=float, default=30.0, help="camera frames (patterns) per second")
    parser.add_argument("--warmup", type=float, default=60.0, help="seconds after the first outputs, not counted")
    parser.add_argument("--tail", type=float, default=5.0, help="seconds to wait for the window's last outputs")
    parser.add_argument(
        "--max-growth-mb", type=float, default=10.0, help="largest RSS growth in the window's second half that passes"
    )
    parser.add_argument("--domain", type=int, default=215, help="ROS_DOMAIN_ID (outside the tests' 30-199)")
    parser.add_argument("--scene", default="sculpture")
    parser.add_argument("--threads", type=int, default=2, help="cnn_depth's onnxruntime intra-op threads")
    args = parser.parse_args()
    logs = Path(tempfile.mkdtemp(prefix="soak_"))
    procs = NodeProcesses(args.domain, logs)
    rclpy.init(domain_id=args.domain)
    robot = SoakRobot()
    executor = SingleThreadedExecutor()
    executor.add_node(robot)
    sensor = procs.start(
        "sensor", "-p", f"rate:={args.rate}", "-p", f"scene:={args.scene}", "-p", f"threads:={args.threads}"
    )
    rss = []  # (seconds into the window, MB)
    try:
        if (
            not spin_for(executor, 180, lambda: all(robot.outputs.values()) or sensor.poll() is not None)
            or sensor.poll() is not None
        ):
            sys.exit(f"soak: no output from every path in 180 s (sensor status {sensor.poll()}); logs in {logs}")
        spin_for(executor, args.warmup)
        t0 = time.time_ns()
        window = args.minutes * 60
        start = time.monotonic()
        next_sample = start
        while (now := time.monotonic()) < start + window and sensor.poll() is None:
            if now >= next_sample:
                rss.append((now - start, rss_mb(sensor.pid)))
                next_sample += 10.0
            executor.spin_once(timeout_sec=0.05)
        rss = [(t, mb) for t, mb in rss + [(time.monotonic() - start, rss_mb(sensor.pid))] if mb is not None]
        t1 = time.time_ns()
        spin_for(executor, args.tail)
        crashed = sensor.poll()
    finally:
        procs.stop()
        executor.shutdown()
        robot.destroy_node()
        rclpy.try_shutdown()
    if crashed is not None:
        sys.exit(f"soak: the sensor exited with status {crashed} during the run; logs in {logs}")
    return report(args, account(robot, t0, t1), rss, robot, procs, sensor.returncode)


def report(args, acc: dict, rss: list, robot: SoakRobot, procs: NodeProcesses, exit_status: int) -> int:
    log = procs.logs_dir  # the sensor's log is in there
    bad, counts = robot.bad, capture_counts(procs.logs("sensor"))
    minutes = args.minutes
    # the sensor does not set cv2's thread count: it gets the default this process has
    print(
        "\n"
        + describe(
            {"onnxruntime intra-op (cnn_depth)": args.threads, "cv2 (sensor process, default)": cv2.getNumThreads()}
        )
    )
    print(
        f"soak: composed sensor (multi-shot + single-shot in one process), {args.rate:g} camera frames/s "
        f"requested, {minutes:g} min measured after warm-up; 640x480 mono8, {acc['frames_per_sequence']} frames "
        "a sequence"
    )
    print(
        f"camera frames (patterns shown) {acc['patterns']}: {acc['pattern_rate']:.2f}/s of the {args.rate:g}/s "
        "requested"
    )
    print(f"\n{'path':12} {'sequences in':>12} {'out':>6} {'dropped':>8}  note")
    ms_lost = acc["lost_before_assembly"] + acc["unprocessed"]
    print(
        f"{'assembly':12} {acc['assembled'] + acc['lost_before_assembly']:12d} {acc['assembled']:6d} "
        f"{acc['lost_before_assembly']:8d}  complete sequences (gaps in their stamps are losses)"
    )
    for name, note in (
        ("points", "multi-shot: every complete sequence is kept"),
        ("depth", "multi-shot depth/image"),
        ("cnn points", "single-shot: newest frame only (KEEP_LAST 1), drops expected"),
        ("cnn depth", "single-shot cnn/depth/image"),
    ):
        row = acc[name]
        print(f"{name:12} {acc['assembled']:12d} {row['out']:6d} {row['lost']:8d}  {note}")
    if counts:
        print(
            f"capture_sequence over its whole run (start-up and shutdown included): frames in {counts.frames_in}, "
            f"sequences complete {counts.complete}, dropped {counts.dropped}"
            f"{' ' + counts.reasons if counts.reasons else ''}, frames matching no pattern {counts.unmatched}"
        )
    else:
        print(f"capture_sequence printed no counts at shutdown (see {log})")
    print("\n" + percentile_header("latency (ms)", 34, PERCENTILES) + f" {'n':>6}")
    for label, values in (
        ("points, from first frame's stamp", acc["points"]["latency"]),
        ("points, from last frame's stamp", acc["points"]["last_frame_latency"]),
        ("depth, from first frame's stamp", acc["depth"]["latency"]),
        ("cnn points, from its image's stamp", acc["cnn points"]["latency"]),
        ("cnn depth, from its image's stamp", acc["cnn depth"]["latency"]),
    ):
        print(percentile_row(label, values, 34, PERCENTILES) + f" {len(values):6d}")
    print("\nresident memory of the sensor process (VmRSS, MB), each minute of the window:")
    minute_marks = [next((mb for t, mb in rss if t >= 60 * m), rss[-1][1]) for m in range(int(minutes) + 1)]
    print("  " + "  ".join(f"{m}:{mb:.1f}" for m, mb in enumerate(minute_marks)) + f"  end:{rss[-1][1]:.1f}")
    values = [mb for _, mb in rss]
    start, end = float(np.median(values[:3])), float(np.median(values[-3:]))
    first_half_peak = max(mb for t, mb in rss if t <= rss[-1][0] / 2)
    slope = np.polyfit([t / 60 for t, _ in rss], values, 1)[0] if len(rss) > 2 else 0.0
    growth = end - first_half_peak
    memory_ok = growth <= args.max_growth_mb
    kept_ok = ms_lost == 0 and not bad
    print(
        f"  start {start:.1f} MB, end {end:.1f} MB (medians of the first and last 3 samples, 10 s apart): "
        f"{end - start:+.1f} MB; highest {max(values):.1f} MB, in the first half {first_half_peak:.1f} MB; "
        f"trend {slope:+.2f} MB/min"
    )
    if robot.diagnostics:  # the nodes' own totals since start, where they publish /diagnostics
        print("\nnode counters at the end (/diagnostics, totals since start):")
        for name, values in sorted(robot.diagnostics.items()):
            totals = ", ".join(f"{k} {v}" for k, v in values.items() if v.isdigit())
            print(f"  {name}: {totals}")
    print(
        f"\nRSS growth {growth:+.1f} MB over the second half ({minutes / 2:g} min; the end against the first "
        f"half's highest; threshold {args.max_growth_mb:g} MB): "
        f"{'OK' if memory_ok else 'FAIL'}"
    )
    print(
        f"multi-shot sequences dropped: {ms_lost} ({acc['lost_before_assembly']} before assembly, "
        f"{acc['unprocessed']} assembled but neither depth nor cloud came out): {'OK' if kept_ok else 'FAIL'}"
    )
    print(
        f"multi-shot outputs not delivered here though their sequence came out: "
        f"points {acc['points']['lost'] - acc['unprocessed']}, depth {acc['depth']['lost'] - acc['unprocessed']} "
        "(RELIABLE KEEP_LAST 2 writers: under load a subscriber gets the newest, by design; not a failure)"
    )
    if bad:
        print(f"outputs of the wrong size or frame: {len(bad)}, first: {bad[0]}")
    print(
        f"single-shot frames dropped: {acc['cnn unprocessed']} of {acc['assembled']} (neither cnn output came out; "
        f"newest frame only, by design: not a failure); cnn outputs not delivered here though their frame came "
        f"out: points {acc['cnn points']['lost'] - acc['cnn unprocessed']}, "
        f"depth {acc['cnn depth']['lost'] - acc['cnn unprocessed']}"
    )
    traceback = "Traceback" in procs.logs("sensor")
    # On SIGINT the nodes catch KeyboardInterrupt (ExternalShutdownException), shut down and exit 0
    # (fpp_nodes/nodes/common.py spin); anything else is a crash, or -9 where SIGKILL ended a hung shutdown.
    stopped_ok = exit_status == 0 and not traceback
    print(
        f"sensor stopped with SIGINT, exit status {exit_status}"
        f"{' (a Traceback is in its log)' if traceback else ''}: {'OK' if stopped_ok else 'FAIL'}; log: {log}"
    )
    return 0 if memory_ok and kept_ok and stopped_ok else 1


if __name__ == "__main__":
    sys.exit(main())
