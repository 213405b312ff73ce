"""What every node shares: declaring validated parameters, loading the calibration, the main loop."""

from __future__ import annotations

import ctypes
import hashlib
import sys
import threading

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import String

from fpp_msgs_py import Qos, Topics, camera_info

from ..core.calibration import Calibration, default_calibration_path

MESSAGE_TYPES = {
    "sensor_msgs/msg/Image": Image,
    "sensor_msgs/msg/CameraInfo": CameraInfo,
    "sensor_msgs/msg/PointCloud2": PointCloud2,
}


def declare(node: Node, name: str, default, description: str, read_only: bool = False):
    """Declare a parameter with its description and return its value. A parameter of floats also takes
    whole numbers (rate:=60, distortion:=[0,0,0,0,0], as users write them, which rclpy's typing by the
    default refuses with a traceback), returned as floats; anything else there is a ValueError."""
    floats = isinstance(default, float) or (
        isinstance(default, list) and len(default) > 0 and all(isinstance(x, float) for x in default)
    )
    descriptor = ParameterDescriptor(description=description, read_only=read_only, dynamic_typing=floats)
    node.declare_parameter(name, default, descriptor)
    value = node.get_parameter(name).value
    if not floats:
        return value
    if isinstance(default, list):
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{name} must be a list of numbers, got {value!r}")
        return [number(name, x) for x in value]
    return number(name, value)


def number(name: str, value) -> float:
    """A float parameter's value: a whole number too, never a bool or a string."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    return float(value)


def load_calibration(node: Node) -> tuple[Calibration, str]:
    """The calibration named by the node's `calibration` parameter, and where it came from."""
    path = (
        declare(
            node,
            "calibration",
            "",
            "calibration YAML (empty: the simulated rig's, shipped with the package)",
            read_only=True,
        )
        or default_calibration_path()
    )
    calibration = Calibration.load(path)  # CalibrationError names the problem
    node.get_logger().info(f"calibration {describe(calibration, path)}")
    return calibration, path


def camera_info_of(camera) -> CameraInfo:
    """The calibration's camera as sensor_msgs/CameraInfo, which has no field for its bits."""
    return camera_info(**{k: v for k, v in camera.to_dict().items() if k != "bits"})


def warn_if_narrow(health, camera, frame) -> None:
    """Say on /diagnostics (and in the log, at most every 5 s) that mono16 frames use 12 bits or fewer
    where the calibration does not say the camera's bits (CameraIntrinsics.narrow_hint)."""
    if hint := camera.narrow_hint(frame):
        health.report("frames of fewer bits than mono16", hint)


def describe(calibration: Calibration, source: str) -> str:
    """Which calibration, for logs and /diagnostics: where from, its size, a hash of its content."""
    digest = hashlib.sha256(calibration.to_yaml().encode()).hexdigest()[:12]
    return (
        f"{source} ({calibration.camera.width}x{calibration.camera.height}, {calibration.patterns.count} patterns, "
        f"sha256 {digest})"
    )


def follow_calibration(node: Node, current, use) -> None:
    """Switch to a calibration published on fpp/calibration (a replayed bag's): use(calibration) is
    called when one arrives that differs from current(); a bad one (unreadable, or one use() refuses
    with a ValueError) is an error and changes nothing."""

    def callback(msg: String):
        try:
            calibration = Calibration.from_yaml(msg.data)
            if calibration.to_dict() == current().to_dict():
                return
            use(calibration)
        except ValueError as e:  # CalibrationError, ModelError
            node.get_logger().error(f"calibration on {Topics.CALIBRATION} ignored: {e}")
            return
        node.get_logger().info(f"using the calibration from {Topics.CALIBRATION}")

    node.create_subscription(String, Topics.CALIBRATION, callback, Qos.LATCHED)


def on_set(node: Node, checks: dict):
    """Validate runtime parameter changes: checks maps a name to check(name, value), which raises
    ValueError for a value the node cannot use; the change is then refused with that message."""

    def callback(params):
        for p in params:
            try:
                checks.get(p.name, lambda name, value: None)(p.name, p.value)
            except ValueError as e:
                return SetParametersResult(successful=False, reason=str(e))
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(callback)


def check_positive(name: str, value) -> None:
    if not number(name, value) > 0:
        raise ValueError(f"{name} must be > 0, got {value!r}")


def spin(nodes: list[Node]) -> None:
    """Run the nodes until shutdown, on single-threaded executors: rclpy's multi-threaded executor was
    seen to hand a subscription's messages to its callback out of order, which breaks sequences. One
    executor for all, except that beside other nodes (sensor) a node with LONG_CALLBACKS gets one of its
    own, on a thread of its own, so that their messages do not wait behind its callbacks (cnn_depth's
    network: the multi-shot path's capture+depth in make demo, median 53 -> 35 ms, docs/using-the-sensor.md);
    the heavy work releases the GIL."""
    shared, beside = SingleThreadedExecutor(), []
    for n in nodes:
        if getattr(n, "LONG_CALLBACKS", False) and len(nodes) > 1:
            beside.append(SingleThreadedExecutor())
            beside[-1].add_node(n)
        else:
            shared.add_node(n)
    failures = []
    for e in beside:
        threading.Thread(target=_spin, args=(e, failures), daemon=True).start()
    try:
        _spin(shared, failures)
    finally:
        for e in beside:
            e.shutdown(timeout_sec=10)  # after the callback in hand
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
    if failures:
        raise failures[0]


def _spin(executor: SingleThreadedExecutor, failures: list) -> None:
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as e:
        # Ctrl+C shuts the context down from rclpy's signal handler, which can land while the executor
        # takes a message or a callback publishes: what that raises is the shutdown, not an error. An
        # error stops every executor of the process (the shutdown ends their spin).
        if rclpy.ok():
            failures.append(e)
            rclpy.try_shutdown()


# glibc's mallopt parameters (malloc.h) and the largest mmap threshold it takes on 64-bit systems
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, MAX_MMAP_THRESHOLD = -1, -3, 32 << 20


def reuse_freed_buffers() -> bool:
    """Have the C library serve buffers up to 32 MB from its heap and keep up to 32 MB of it free
    between frames. By default glibc maps each buffer over 128 kB fresh from the kernel and unmaps
    it when freed, so every frame's arrays (megabytes each) come back as new pages, each zeroed at its
    first touch: in cnn_depth at 30 frames/s, 2,800 page faults and 8.6 ms of system time a frame,
    a seventh of the node's CPU time; with this none and 1.3 ms, for 26 MB more resident memory
    (make bench-cnn; docs/single-shot.md, the node's speed). False where the C library is not glibc
    (nothing changes)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(
            libc.mallopt(M_MMAP_THRESHOLD, MAX_MMAP_THRESHOLD) and libc.mallopt(M_TRIM_THRESHOLD, MAX_MMAP_THRESHOLD)
        )
    except (OSError, AttributeError):
        return False


def run(*node_factories, args=None) -> None:
    """main() of an executable: make the nodes (classes or functions returning a node), spin, shut
    down cleanly; a bad configuration is one error line and exit status 2, not a traceback."""
    reuse_freed_buffers()
    try:
        rclpy.init(args=args)
    except RuntimeError as e:  # rcl's: arguments it cannot parse (a list of mixed types, say)
        print(f"[FATAL] {e}", file=sys.stderr)
        sys.exit(2)
    nodes = []
    try:
        for make in node_factories:
            nodes.append(make())
    except (ValueError, OSError, ParameterException) as e:  # ParameterException: a value of the wrong type
        print(f"[FATAL] {e}", file=sys.stderr)
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
        sys.exit(2)
    warn_of_unknown_parameters(nodes)
    spin(nodes)


RCLPY_PARAMETERS = {"use_sim_time", "start_type_description_service"}  # every rclpy node declares them


def warn_of_unknown_parameters(nodes: list[Node]) -> list[str]:
    """Log one warning naming the parameters given (-p, a parameters file) that no node of the process
    has: rclpy ignores them without a word, so a misspelt name (min_confidance:=0.5) left the default in
    force unnoticed. A warning, not a refusal: a parameters file shared by several nodes may hold other
    nodes' parameters. Returns the names."""
    given = {name for n in nodes for name in getattr(n, "_parameter_overrides", {})}  # rclpy keeps them so
    unknown = sorted(name for name in given if not any(n.has_parameter(name) for n in nodes))
    if unknown:
        names = sorted({name for n in nodes for name in n.list_parameters([], 0).names} - RCLPY_PARAMETERS)
        nodes[0].get_logger().warning(
            f"ignored parameter{'s' * (len(unknown) > 1)} {', '.join(unknown)}: no node here has "
            f"{'them' if len(unknown) > 1 else 'it'} (a misspelling?); the parameters here: {', '.join(names)}"
        )
    return unknown
