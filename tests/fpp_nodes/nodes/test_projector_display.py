"""projector_display: patterns on a screen, republished with when they were shown.

The pure part (pattern -> the frame to show) directly; the node in its own process with SDL's offscreen
video driver (any machine); and under Xvfb, where a screenshot of the X screen must show the pattern
pixel for pixel (skipped where Xvfb or a screenshot tool is missing)."""

import importlib.util
import os
import re
import select
import shutil
import signal
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from sensor_msgs.msg import Image

from fpp_msgs_py import Frames, Qos, Topics, header_at, image_to_numpy, numpy_to_image, stamp_ns
from fpp_nodes.core.patterns import pattern_images
from fpp_nodes.nodes.projector_display import check_driver, screen_frame

from rosgraph import Diagnostics

OFFSCREEN = {"SDL_VIDEODRIVER": "offscreen"}  # SDL draws into memory: the whole node path, no screen needed
NODE = "/projector_display"


# the pure part


def test_a_vertical_line_fills_the_screen_down(patterns):
    line = pattern_images(patterns)[13]  # frequency 100, step 1: 1 x 1280
    frame = screen_frame(line, 1280, 800)
    assert line.shape == (1, 1280) and frame.shape == (800, 1280) and frame.dtype == np.uint8
    assert frame.flags.c_contiguous and (frame == line).all()


def test_a_horizontal_line_fills_the_screen_across(rig):
    line = pattern_images(rig.pattern_set(orientation="horizontal", single_shot="paper"))[6]  # 800 x 1
    frame = screen_frame(line, 1280, 800)
    assert line.shape == (800, 1) and frame.shape == (800, 1280)
    assert (frame == line).all() and not (frame[:, 0] == frame[0, 0]).all()


def test_a_full_image_is_shown_as_it_is(patterns):
    composite = pattern_images(patterns)[-1]
    assert composite.shape == (800, 1280)
    assert np.array_equal(screen_frame(composite, 1280, 800), composite)


def test_16_bit_patterns_show_their_top_8_bits(ideal_patterns):
    images = pattern_images(ideal_patterns)
    line, composite = images[9], images[-1]
    assert line.dtype == np.uint16 and line.max() > 255
    assert np.array_equal(screen_frame(line, 1280, 800), np.broadcast_to(line >> 8, (800, 1280)))
    assert np.array_equal(screen_frame(composite, 1280, 800), composite >> 8)
    assert screen_frame(np.array([[0, 255, 256, 65535]], np.uint16), 4, 2).tolist() == [[0, 0, 1, 255]] * 2


@pytest.mark.parametrize(
    "pattern, message",
    [
        (np.zeros((800, 1280), np.float32), "float32 pixels cannot be shown"),
        (np.zeros((1, 640), np.uint8), "a pattern of 1 x 640 (rows x columns) does not fit the projector's 800 x 1280"),
        (np.zeros((800, 1280, 3), np.uint8), "800 x 1280 x 3"),
        (np.zeros((1280, 800), np.uint8), "does not fit"),
    ],
)
def test_what_cannot_be_shown_is_refused(pattern, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        screen_frame(pattern, 1280, 800)


def test_a_driver_that_shows_nothing_is_no_display_unless_asked_for():
    with pytest.raises(OSError, match="fell back to its 'offscreen' driver"):
        check_driver("offscreen", None)
    with pytest.raises(OSError, match="'dummy'"):
        check_driver("dummy", "x11")
    check_driver("offscreen", "offscreen")
    check_driver("x11", None)


# the node, in its own process


def collect(robot, topic=Topics.DISPLAYED):
    got = []
    robot.node.create_subscription(Image, topic, got.append, Qos.FRAMES)
    return got


def now_ns(robot) -> int:
    return robot.node.get_clock().now().nanoseconds


def handshake(robot, procs, publisher, displayed, pattern, timeout=60.0):
    """Publish a pattern until it comes back on projector/displayed: then both directions are matched
    (a message published before the node's publisher has discovered ours would be lost, unseen)."""
    came_back = lambda: any(bytes(m.data) == pattern.tobytes() for m in displayed)  # noqa: E731
    end = time.monotonic() + timeout
    while not came_back() and time.monotonic() < end:
        publisher.publish(numpy_to_image(pattern, header_at(now_ns(robot), Frames.PROJECTOR)))
        robot.spin_until(came_back, 0.5)
    assert came_back(), procs.logs()


def started(procs, robot, *args, env=OFFSCREEN):
    proc = procs.start("projector_display", *args, env=env)
    return proc, robot.node.create_publisher(Image, Topics.PATTERN, Qos.FRAMES), collect(robot)


GREY = np.full((800, 1280), 7, np.uint8)  # the handshake's pattern, in no pattern set


def test_each_pattern_comes_back_stamped_when_it_was_shown(ros_graph, patterns):
    procs, robot = ros_graph
    proc, publisher, displayed = started(procs, robot, "-p", "fullscreen:=false")
    handshake(robot, procs, publisher, displayed, GREY)
    sent = []
    for image in pattern_images(patterns):  # a burst: the whole set as fast as it can be published
        sent.append(numpy_to_image(image, header_at(now_ns(robot), Frames.PROJECTOR)))
        publisher.publish(sent[-1])
    back = lambda: [m for m in displayed if bytes(m.data) != GREY.tobytes()]  # noqa: E731
    assert robot.spin_until(lambda: len(back()) >= len(sent), 60), (len(back()), procs.logs())
    robot.spin_until(lambda: False, 0.5)  # nothing more may come
    assert len(back()) == len(sent) == patterns.count
    previous = 0
    for out, source in zip(back(), sent):
        assert (out.height, out.width, out.encoding, out.step) == (source.height, source.width, "mono8", source.step)
        assert bytes(out.data) == bytes(source.data) and out.header.frame_id == Frames.PROJECTOR
        shown = stamp_ns(out.header.stamp)
        assert shown >= stamp_ns(source.header.stamp) and shown >= previous  # never before it was asked for
        previous = shown
    assert "1280x800 patterns in a window" in procs.logs()
    # one SIGINT, as Ctrl+C sends (NodeProcesses.stop sends it twice: its second can land mid-shutdown)
    os.killpg(proc.pid, signal.SIGINT)
    assert proc.wait(timeout=30) == 0 and "Traceback" not in procs.logs(), (proc.returncode, procs.logs())


def test_a_bad_pattern_is_rejected_and_counted_and_the_node_goes_on(ros_graph, patterns):
    procs, robot = ros_graph
    proc, publisher, displayed = started(procs, robot, "-p", "fullscreen:=false")
    diagnostics = Diagnostics(robot)
    handshake(robot, procs, publisher, displayed, GREY)
    good = pattern_images(patterns)[5]
    for bad in (np.zeros((800, 1280), np.float32), np.zeros((1, 640), np.uint8), good):
        publisher.publish(numpy_to_image(bad, header_at(now_ns(robot), Frames.PROJECTOR)))
    assert robot.spin_until(lambda: any(bytes(m.data) == good.tobytes() for m in displayed), 30), procs.logs()
    assert robot.spin_until(lambda: diagnostics.counter(NODE, "patterns rejected") >= 2, 30), diagnostics.latest
    said = " ".join(diagnostics.said[NODE])
    assert "pattern not shown (32FC1): float32 pixels cannot be shown" in said
    assert "a pattern of 1 x 640 (rows x columns) does not fit" in said
    assert diagnostics.counter(NODE, "patterns rejected") == 2 and proc.poll() is None
    assert not any(m.encoding == "32FC1" or m.width == 640 for m in displayed)  # none of the bad ones went out


def test_full_screen_at_another_resolution_and_16_bit_are_said_once(ros_graph, ideal_patterns):
    """SDL's offscreen screen is 1024 x 768: the 1280 x 800 patterns are shown 1:1, cut off, and the log
    says so once; 16-bit patterns go out as they came, the log says once how they are shown."""
    procs, robot = ros_graph
    proc, publisher, displayed = started(procs, robot)  # full-screen, the default
    line = pattern_images(ideal_patterns)[14]
    handshake(robot, procs, publisher, displayed, line)
    publisher.publish(numpy_to_image(line, header_at(now_ns(robot), Frames.PROJECTOR)))
    assert robot.spin_until(lambda: len(displayed) >= 2, 30)  # (at least) twice
    assert displayed[0].encoding == "mono16" and np.array_equal(image_to_numpy(displayed[0]), line)
    logs = procs.logs()
    assert logs.count("display 0 runs at 1024x768, the patterns are 1280x800") == 1, logs
    assert "NOT scaled" in logs and "cut off" in logs
    assert logs.count("16-bit patterns are shown as their top 8 bits") == 1 and proc.poll() is None


def free_x_display() -> str:
    return next(f":{n}" for n in range(900, 1000) if not Path(f"/tmp/.X11-unix/X{n}").exists())


def test_no_display_is_one_fatal_line(ros_graph):
    procs, _ = ros_graph
    proc = procs.start("projector_display", env={"SDL_VIDEODRIVER": "x11", "DISPLAY": free_x_display()})
    assert proc.wait(timeout=60) == 2
    logs = procs.logs()
    assert "[FATAL] no display to show patterns on" in logs and "Traceback" not in logs, logs


# on an X screen


@contextmanager
def xvfb(xvfb_path: str, size: str):
    """An Xvfb server on a display number it picks (-displayfd: it says which once it is ready)."""
    read_end, write_end = os.pipe()
    server = subprocess.Popen(
        [xvfb_path, "-displayfd", str(write_end), "-screen", "0", size, "-nolisten", "tcp"],
        pass_fds=(write_end,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(write_end)
    try:
        number = b""
        end = time.monotonic() + 60
        while not number.endswith(b"\n") and time.monotonic() < end and server.poll() is None:
            if select.select([read_end], [], [], 0.5)[0]:
                chunk = os.read(read_end, 16)
                if not chunk:
                    break
                number += chunk
        assert number.strip().isdigit(), f"Xvfb did not start (exit status {server.poll()})"
        yield f":{int(number)}"
    finally:
        os.close(read_end)
        server.terminate()
        server.wait(timeout=30)


def read_xwd(data: bytes) -> np.ndarray:
    """An xwd file (X Window Dump, ZPixmap, 24/32 bits per pixel, TrueColor) as height x width x RGB."""
    header = np.frombuffer(data[:100], ">u4")
    size, version, pixmap_format, depth, width, height = header[:6]
    byte_order, bits_per_pixel, bytes_per_line = header[7], header[11], header[12]
    masks, ncolors = header[14:17], header[19]
    assert version == 7 and pixmap_format == 2 and bits_per_pixel == 32, (version, pixmap_format, bits_per_pixel)
    start = int(size) + 12 * int(ncolors)
    rows = np.frombuffer(data[start : start + int(bytes_per_line) * int(height)], np.uint8)
    rows = rows.reshape(int(height), int(bytes_per_line))[:, : 4 * int(width)]
    pixels = rows.copy().view("<u4" if byte_order == 0 else ">u4").astype(np.uint32)
    masks = [int(m) for m in masks]
    shifts = [(m & -m).bit_length() - 1 for m in masks]
    return np.stack([(pixels & m) >> s for m, s in zip(masks, shifts)], axis=-1).astype(np.uint8)


def screenshot_tool():
    """A function (display) -> the root window as height x width x RGB, and its name; None if none here."""
    xwd = shutil.which("xwd")
    if xwd:

        def grab(display):
            dump = subprocess.run([xwd, "-root", "-silent", "-display", display], capture_output=True, check=True)
            return read_xwd(dump.stdout)

        return grab
    if importlib.util.find_spec("mss"):
        import mss

        def grab(display):
            with mss.mss(display=display) as shots:
                return np.array(shots.grab(shots.monitors[0]))[..., 2::-1]  # BGRA -> RGB

        return grab
    return None


def test_the_pattern_is_on_an_x_screen_pixel_for_pixel(ros_graph, patterns):
    xvfb_path, grab = shutil.which("Xvfb"), screenshot_tool()
    if xvfb_path is None:
        pytest.skip("Xvfb is not installed (Debian: apt-get install xvfb x11-apps)")
    if grab is None:
        pytest.skip("no screenshot tool: neither xwd (Debian: x11-apps) nor python's mss")
    procs, robot = ros_graph
    images = pattern_images(patterns)
    with xvfb(xvfb_path, f"{patterns.width}x{patterns.height}x24") as display:
        proc, publisher, displayed = started(procs, robot, env={"SDL_VIDEODRIVER": "x11", "DISPLAY": display})
        for image in (images[13], images[-1]):  # a line of the finest fringes, then the composite
            handshake(robot, procs, publisher, displayed, image)
            expected = np.broadcast_to(image[..., None], (patterns.height, patterns.width, 3)).astype(int)
            # the X server draws what the window was given after the flip; wait for it (a resize, a map)
            end, worst = time.monotonic() + 30, None
            while time.monotonic() < end:
                shot = grab(display)
                worst = np.abs(shot.astype(int) - expected).max() if shot.shape == expected.shape else shot.shape
                if worst == 0 or (np.isscalar(worst) and worst <= 1):
                    break
                robot.spin_until(lambda: False, 0.2)
            assert np.isscalar(worst) and worst <= 1, (worst, procs.logs())
            del displayed[:]
        assert proc.poll() is None
