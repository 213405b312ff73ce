"""Node health on /diagnostics (diagnostic_msgs/DiagnosticArray), the way ROS drivers report it.

Once a second each node publishes one DiagnosticStatus named after the node: totals and rates of what
came in and went out, what was dropped or rejected and why, latency percentiles (and those of its stages,
where a node times them: cnn_depth's network, decode and publish), and what it runs with (calibration, model).
Level OK; WARN when something was dropped or rejected since the last report (the message says what: the
newest three kinds of problem); counters are totals since start, rates are over the last report.
"""

from __future__ import annotations

import re
import threading
import time
from collections import Counter, deque

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

TOPIC = "/diagnostics"  # absolute: the aggregator and rqt_robot_monitor listen there
HARDWARE_ID = "fpp_sensor"
FEW_USABLE = 0.01  # below this share of usable pixels an output shows (almost) no fringes


class Health:
    def __init__(self, node: Node, period_s: float = 1.0):
        self.node = node
        self.totals: Counter = Counter()
        self.window: Counter = Counter()
        self.times_s: dict[str, deque] = {}  # "latency", or a stage's name -> its last 200 times
        self.facts: dict[str, str] = {}  # what the node runs with: calibration, model
        self.problems: dict[str, str] = {}  # since the previous report: wording (numbers aside) -> latest message
        self.logged: dict[str, float] = {}  # a problem's wording (numbers aside) -> when it was last logged
        self.lock = threading.RLock()  # a node may count from a thread of its own beside the executor's
        self.publisher = node.create_publisher(DiagnosticArray, TOPIC, 10)
        self.since = time.monotonic()
        node.create_timer(period_s, self.publish)

    def count(self, key: str, n: int = 1) -> None:
        with self.lock:
            self.totals[key] += n
            self.window[key] += n

    def latency(self, seconds: float, stage: str = "latency") -> None:
        """One output's latency, or the time one of its stages took (reported as "<stage> p50 (ms)")."""
        with self.lock:
            self.times_s.setdefault(stage, deque(maxlen=200)).append(seconds)

    def fact(self, key: str, value: str) -> None:
        with self.lock:
            self.facts[key] = value

    def report(self, key: str, message: str) -> None:
        """Count a dropped or rejected input under key, say why on /diagnostics and in the log."""
        self.count(key)
        wording, now = re.sub(r"[\d.]+", "#", message), time.monotonic()
        with self.lock:
            self.problems.pop(wording, None)
            self.problems[wording] = message  # newest last
            if now - self.logged.get(wording, -1e9) < 5.0:  # each kind of problem at most every 5 s
                return
            self.logged[wording] = now
        self.node.get_logger().warn(message)

    def usable_pixels(self, share: float, key: str) -> None:
        """Note the share of pixels an output could use; (almost) none is a problem counted under key.
        The output goes out all the same: a robot should see nothing rather than old data."""
        self.fact("usable pixels (last)", f"{share:.1%}")
        if share < FEW_USABLE:
            self.report(key, f"only {share:.2%} of pixels show usable fringes (dark, saturated or out of focus?)")

    def status(self, now: float) -> DiagnosticStatus:
        """The report over the window from the previous one until now (changes nothing)."""
        elapsed = max(now - self.since, 1e-9)
        values = {key: str(n) for key, n in sorted(self.totals.items())}
        values.update({f"{key} rate (Hz)": f"{self.window[key] / elapsed:.2f}" for key in sorted(self.totals)})
        for stage, times in self.times_s.items():
            p50, p95 = np.percentile(times, [50, 95]) * 1000
            values.update({f"{stage} p50 (ms)": f"{p50:.1f}", f"{stage} p95 (ms)": f"{p95:.1f}"})
        values.update(self.facts)
        problems = list(self.problems.values())[-3:]
        level, message = (DiagnosticStatus.WARN, "; ".join(problems)) if problems else (DiagnosticStatus.OK, "ok")
        return DiagnosticStatus(
            level=level,
            name=self.node.get_fully_qualified_name(),
            message=message,
            hardware_id=HARDWARE_ID,
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )

    def publish(self) -> None:
        """Publish the report and start the next window."""
        now = time.monotonic()
        with self.lock:
            msg = DiagnosticArray(status=[self.status(now)])
            self.window.clear()
            self.problems.clear()
            self.since = now
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.publisher.publish(msg)
