"""Helpers for tests that run real nodes in real processes talking over DDS.

Each test gets its own ROS_DOMAIN_ID so parallel or leftover runs never cross. Nodes are started the
way a user starts them: `ros2 run fpp_nodes <executable>` in the environment of scripts/env.bash.
"""

from __future__ import annotations

import itertools
import os
import subprocess
import time
from functools import lru_cache
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from fpp_nodes.nodes.health import TOPIC as DIAGNOSTICS
from fpp_nodes.processes import NodeProcesses

ROOT = Path(__file__).resolve().parents[1]
_ids = itertools.count()


def fresh_domain_id() -> int:
    """A domain id unique to this test process and test (Fast DDS allows 0-232)."""
    return 30 + (os.getpid() * 13 + next(_ids)) % 170


@lru_cache(maxsize=1)
def ros_env() -> dict:
    out = subprocess.run(["bash", "-c", f"source {ROOT}/scripts/env.bash && env -0"], capture_output=True, check=True)
    return dict(item.split("=", 1) for item in out.stdout.decode().split("\0") if "=" in item)


def node_processes(domain_id: int, log_dir: Path) -> NodeProcesses:
    """ros2 run ... processes on the test's domain, in the environment of scripts/env.bash."""
    return NodeProcesses(domain_id, log_dir, ros_env())


class ProbeNode:
    """An rclpy node in the test process, in its own context on the test's domain."""

    def __init__(self, domain_id: int, name: str = "test_probe"):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, done, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if done():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return done()

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class Diagnostics:
    """The newest DiagnosticStatus of each node, and every message each has said."""

    def __init__(self, robot):
        self.latest, self.said = {}, {}
        robot.node.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on, 50)

    def _on(self, msg):
        for status in msg.status:
            self.latest[status.name] = status
            self.said.setdefault(status.name, []).append(status.message)

    def value(self, node: str, key: str, default="0") -> str | None:
        """The node's newest value for key (default where its report has no such key: a counter that
        never counted); None while the node has not reported at all."""
        status = self.latest.get(node)
        return next((kv.value for kv in status.values if kv.key == key), default) if status else None

    def counter(self, node: str, key: str) -> int:
        """A counter's newest total, -1 while the node has not reported (so `>= n` waits are honest)."""
        value = self.value(node, key)
        return -1 if value is None else int(value)
