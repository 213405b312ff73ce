"""The sensor and a robot on two hosts, joined by one network link.

The composed sensor (`ros2 run fpp_nodes sensor`) runs in one network namespace and a robot
(cloud_probe.py beside this file, its own process) in another. Each namespace has its own network stack: only
`lo` and one end of a veth pair, with 10.201.N.1/24 and 10.201.N.2/24 on that link only (no route
anywhere else), so the two are two hosts on one Ethernet segment. Fast DDS runs with its default
discovery (SPDP over UDP multicast, no static peers) and UDPv4 as its only transport
(FASTDDS_BUILTIN_TRANSPORTS=UDPv4): between real hosts there is no shared memory, and without it no
message can take a path other than the link.

What it shows: the robot discovers the sensor's nodes over the link on its own, and RELIABLE
multi-megabyte messages cross it whole: at least two organized 640x480 clouds (3.7 MB each, x, y, z in
metres in camera_optical_frame, z finite on most pixels) and a 32FC1 depth image, while the robot's end
of the link counts at least as many bytes received as those messages hold.

The namespaces, the veth pair and both processes are the test's own and are removed afterwards,
whatever happens. Where namespaces cannot be made (no CAP_NET_ADMIN, no `ip`, no veth), the test is
skipped with the reason.
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from fpp_msgs_py import Frames
from fpp_nodes.processes import start_process, stop_process

from rosgraph import fresh_domain_id, ros_env

TIMEOUT_S = 120  # for the robot to see its clouds; the test ends within about TIMEOUT_S + 45 s
_made = itertools.count()


def ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)


@dataclass
class Host:
    netns: str
    veth: str
    address: str  # on the veth, /24

    def exec_args(self, *command: str) -> list[str]:
        return ["ip", "netns", "exec", self.netns, *command]

    def links(self) -> list[str]:
        return [link["ifname"] for link in json.loads(ip("-j", "-n", self.netns, "link", "show").stdout)]

    def rx_bytes(self) -> int:
        (link,) = json.loads(ip("-j", "-s", "-n", self.netns, "link", "show", "dev", self.veth).stdout)
        return link["stats64"]["rx"]["bytes"]


@pytest.fixture
def two_hosts():
    """(sensor host, robot host): two network namespaces joined by a veth pair, removed afterwards."""
    if shutil.which("ip") is None:
        pytest.skip("no `ip` command (iproute2) to make network namespaces with")
    tag = f"{os.getpid()}x{next(_made)}"
    subnet = f"10.201.{os.getpid() % 250}"
    a = Host(f"fpp-sensor-{tag}", f"fa{tag}"[:15], f"{subnet}.1")
    b = Host(f"fpp-robot-{tag}", f"fb{tag}"[:15], f"{subnet}.2")
    made = []
    try:
        for host in (a, b):
            r = ip("netns", "add", host.netns)
            if r.returncode:
                pytest.skip(f"cannot make a network namespace here: ip netns add: {r.stderr.strip()}")
            made.append(host.netns)
        steps = [
            ("link", "add", a.veth, "type", "veth", "peer", "name", b.veth),
            ("link", "set", a.veth, "netns", a.netns),
            ("link", "set", b.veth, "netns", b.netns),
        ]
        for host in (a, b):
            steps += [
                ("-n", host.netns, "addr", "add", f"{host.address}/24", "dev", host.veth),
                ("-n", host.netns, "link", "set", "lo", "up"),
                ("-n", host.netns, "link", "set", host.veth, "up"),
            ]
        for step in steps:
            r = ip(*step)
            if r.returncode:
                pytest.skip(
                    f"cannot join network namespaces with a veth pair here: ip {' '.join(step)}: {r.stderr.strip()}"
                )
        r = subprocess.run(a.exec_args("true"), capture_output=True, text=True, timeout=30)
        if r.returncode:
            pytest.skip(f"cannot run a process in a network namespace here: ip netns exec: {r.stderr.strip()}")
        yield a, b
    finally:
        for netns in made:
            ip("netns", "delete", netns)  # takes its end of the veth pair, and so the pair, with it
        ip("link", "delete", a.veth)  # in case the pair never left this namespace


def test_discovery_and_large_clouds_between_two_hosts(two_hosts, tmp_path):
    sensor_host, robot_host = two_hosts
    for host in two_hosts:  # lo and the link: nothing else leads out of either host
        assert sorted(host.links()) == sorted(["lo", host.veth])
    env = {
        k: v
        for k, v in ros_env().items()
        if k not in ("ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS", "FASTRTPS_DEFAULT_PROFILES_FILE")
    }
    env.update(
        ROS_DOMAIN_ID=str(fresh_domain_id()),
        ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET",
        FASTDDS_BUILTIN_TRANSPORTS="UDPv4",
        PYTHONUNBUFFERED="1",
        RCUTILS_LOGGING_BUFFERED_STREAM="0",
    )
    rx_before = robot_host.rx_bytes()
    logs = {name: open(tmp_path / f"{name}.log", "w+") for name in ("sensor", "robot", "robot-stderr")}
    sensor = start_process(
        sensor_host.exec_args(
            "ros2", "run", "fpp_nodes", "sensor", "--ros-args", "-p", "scene:=objects", "-p", "seed:=3"
        ),
        env,
        logs["sensor"],
    )
    robot = start_process(
        robot_host.exec_args(
            sys.executable,
            str(Path(__file__).with_name("cloud_probe.py")),
            "--clouds",
            "2",
            "--depths",
            "1",
            "--timeout",
            str(TIMEOUT_S),
        ),
        env,
        logs["robot"],
        logs["robot-stderr"],
    )
    try:
        deadline = time.monotonic() + TIMEOUT_S + 30  # the robot gives up by itself after TIMEOUT_S
        while robot.poll() is None and sensor.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
    finally:
        stop_process(robot)
        stop_process(sensor)
        text = {}
        for name, log in logs.items():
            log.seek(0)
            text[name] = log.read()
            log.close()
    rx = robot_host.rx_bytes() - rx_before
    context = (
        f"robot stderr:\n{text['robot-stderr'][-3000:]}\nsensor (exit {sensor.returncode}):\n{text['sensor'][-3000:]}"
    )
    lines = [line for line in text["robot"].splitlines() if line.startswith("{")]
    assert lines, f"the robot printed no summary (exit {robot.returncode})\n{context}"
    seen = json.loads(lines[-1])
    assert seen["ok"], (
        f"in {TIMEOUT_S} s the robot saw {len(seen['clouds'])} clouds, {len(seen['depths'])} "
        f"depth images, nodes {seen['nodes']}\n{context}"
    )
    # discovery over the link: the sensor's nodes, and the cloud's publisher, seen from the other host
    assert {"/fpp_depth", "/capture_sequence", "/pattern_projector"} <= set(seen["nodes"])
    assert {"node": "/fpp_depth", "topic_type": "sensor_msgs/msg/PointCloud2"} in seen["publishers_of_points"]
    for cloud in seen["clouds"]:
        assert (cloud["height"], cloud["width"]) == (480, 640) and cloud["fields"][:3] == ["x", "y", "z"]
        assert cloud["bytes"] == 480 * 640 * cloud["point_step"] >= 3_686_400
        assert cloud["frame_id"] == Frames.CAMERA
        assert cloud["finite_z"] > 0.8 and 1.1 < cloud["median_z_m"] < 1.3  # metres
    depth = seen["depths"][0]
    assert (depth["height"], depth["width"], depth["encoding"]) == (480, 640, "32FC1")
    assert depth["finite"] > 0.8 and 1.1 < depth["median_m"] < 1.3
    received = sum(m["bytes"] for m in seen["clouds"] + seen["depths"])
    assert rx >= received, f"{rx} bytes came over the link, {received} bytes of messages arrived"
