"""The sensor as robots see it: real nodes in separate processes, talking over DDS."""

from dataclasses import replace

import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

from fpp_msgs_py import Frames, Qos, Topics, cloud_to_xyz, header_at, image_to_numpy, numpy_to_image, stamp_ns
from fpp_nodes.core.calibration import back_project
from fpp_nodes.core.metrics import depth_errors
from fpp_nodes.core.patterns import pattern_images
from fpp_nodes.core.scenes import make_scene
from fpp_nodes.core.simulation import Rig, render
from fpp_nodes.core.workflow import simulated_calibration


def collect(robot, topic, msg_type, qos=Qos.LARGE):
    got = []
    robot.node.create_subscription(msg_type, topic, got.append, qos)
    return got


def rmse_mm(cloud: PointCloud2, truth_m: np.ndarray):
    """RMSE (mm) of a cloud's depth against the truth, and its coverage of the truth's pixels."""
    e = depth_errors(cloud_to_xyz(cloud)[..., 2] * 1000.0, truth_m * 1000.0)
    return e.rmse_mm, e.coverage


def show(robot, pattern_pub, camera_pub, pairs, t: int) -> int:
    """Publish (pattern line, camera frame: an array or an Image) pairs as projector and camera would, stamped
    t, t + 33 ms, ...; the next stamp."""
    for line, frame in pairs:
        header = header_at(t, Frames.CAMERA)
        msg = numpy_to_image(frame) if isinstance(frame, np.ndarray) else frame
        msg.header = header
        pattern_pub.publish(numpy_to_image(line, header))
        camera_pub.publish(msg)
        t += 33_000_000
        robot.spin_until(lambda: False, 0.01)
    return t


def projector_and_camera(robot, clouds, lines, frames):
    """Publishers playing projector and camera into capture_sequence -> fpp_depth, once a warm-up sequence
    (lines, frames) has come back as a cloud: the links between those two processes cannot be seen from
    here, and a sequence sent before every link is matched is lost. Empties clouds; returns the publishers,
    how many warm-up sequences were sent (capture_sequence counts each complete) and the next stamp."""
    pattern_pub = robot.node.create_publisher(Image, Topics.PATTERN, Qos.FRAMES)
    camera_pub = robot.node.create_publisher(Image, Topics.CAMERA_IMAGE, Qos.FRAMES)
    heard = (
        pattern_pub.get_subscription_count,
        camera_pub.get_subscription_count,
        lambda: robot.node.count_publishers(Topics.POINTS),
        lambda: robot.node.count_subscribers(Topics.SEQUENCE),
    )
    assert robot.spin_until(lambda: all(f() for f in heard), 30)
    t, sent = 1_000_000_000, []
    while not clouds and len(sent) < 10:  # a cloud takes a second or two
        sent.append(t)
        t = show(robot, pattern_pub, camera_pub, zip(lines, frames), t)
        robot.spin_until(lambda: bool(clouds), 5)
    assert clouds, f"no cloud from {len(sent)} warm-up sequences"
    # the chain works from the first that came back on: the later ones' clouds are on their way
    assert robot.spin_until(lambda: stamp_ns(clouds[-1].header.stamp) == sent[-1], 30)
    clouds.clear()
    return pattern_pub, camera_pub, len(sent), t


def check_clouds(robot, clouds, truth, count=2, timeout=60):
    assert robot.spin_until(lambda: len(clouds) >= count and truth, timeout), "no clouds arrived"
    truth_m = image_to_numpy(truth[0])
    for cloud in clouds[:count]:
        assert (cloud.height, cloud.width) == (480, 640) and cloud.header.frame_id == Frames.CAMERA
        assert [f.name for f in cloud.fields][:3] == ["x", "y", "z"]
        error, coverage = rmse_mm(cloud, truth_m)
        assert error < 0.06 and coverage > 0.95, (error, coverage)


def test_composed_sensor_with_a_late_subscriber(ros_graph):
    procs, robot = ros_graph
    procs.start("sensor", "-p", "scene:=objects", "-p", "seed:=3")  # -p reaches every node of the process
    truth = collect(robot, Topics.TRUTH, Image, Qos.LATCHED)
    clouds = collect(robot, Topics.POINTS, PointCloud2)
    check_clouds(robot, clouds, truth)
    # a subscriber that joins late gets depth images from then on, and the latched truth
    late = collect(robot, Topics.DEPTH, Image)
    info = collect(robot, Topics.DEPTH_INFO, CameraInfo, Qos.INFO)
    quality = collect(robot, Topics.QUALITY, Image)
    assert robot.spin_until(lambda: len(late) >= 2 and info and len(quality) >= 2, 30)
    depth = image_to_numpy(late[-1])
    assert late[-1].encoding == "32FC1" and depth.shape == (480, 640)
    assert 1.1 < np.nanmedian(depth) < 1.3  # metres
    assert info[-1].k[0] == pytest.approx(Rig().focal_px)
    # quality: each pixel's expected depth noise in mm, NaN where depth is; this rig's is about 0.024 mm
    same = {stamp_ns(m.header.stamp): m for m in quality}
    paired = [
        (image_to_numpy(m), image_to_numpy(same[stamp_ns(m.header.stamp)]))
        for m in late
        if stamp_ns(m.header.stamp) in same
    ]
    assert paired
    for depth, noise in paired:
        assert quality[-1].encoding == "32FC1" and np.array_equal(np.isnan(depth), np.isnan(noise))
        assert 0.015 < np.nanmedian(noise) < 0.04


def test_health_on_diagnostics(ros_graph):
    """Every node of the composed sensor reports on /diagnostics: rates, drops, latency, what it runs with."""
    import yaml

    from fpp_nodes.core.model import default_model_path

    from rosgraph import Diagnostics

    procs, robot = ros_graph
    procs.start("sensor")
    points, cnn_points = collect(robot, Topics.POINTS, PointCloud2), collect(robot, "cnn/" + Topics.POINTS, PointCloud2)
    diagnostics = Diagnostics(robot)
    assert robot.spin_until(lambda: len(points) >= 3 and cnn_points, 60), procs.logs()
    names = {"/pattern_projector", "/fringe_camera_sim", "/capture_sequence", "/fpp_depth", "/cnn/cnn_depth"}
    assert robot.spin_until(lambda: names <= set(diagnostics.latest), 30), diagnostics.latest.keys()
    robot.spin_until(lambda: False, 1.5)  # one more report, covering the running stream
    assert all(
        diagnostics.latest[n].level == b"\x00" and diagnostics.latest[n].hardware_id == "fpp_sensor" for n in names
    ), {n: diagnostics.latest[n].message for n in names}
    assert float(diagnostics.value("/pattern_projector", "patterns shown rate (Hz)")) > 10
    assert float(diagnostics.value("/capture_sequence", "sequences complete rate (Hz)")) > 0.5
    assert diagnostics.value("/capture_sequence", "sequences dropped", "none") == "none"  # never counted: none
    assert float(diagnostics.value("/fpp_depth", "latency p50 (ms)")) > 0
    assert "sha256" in diagnostics.value("/fpp_depth", "calibration", "")
    # the simulated camera's blur, 0.5 px, as the fringes show it (measured 0.51)
    assert 0.4 < float(diagnostics.value("/fpp_depth", "fringe blur (last)", "0 px").split()[0]) < 0.6
    # the rig as calibrated: its composite frames' codes fit the calibration's (reconstruct.CodeFit)
    assert float(diagnostics.value("/fpp_depth", "codes' misfit to the calibration (last check)").split()[0]) < 0.05
    card = yaml.safe_load(open(default_model_path()[:-5] + ".yaml"))
    assert diagnostics.value("/cnn/cnn_depth", "model sha256") == card["sha256"][:12]
    assert float(diagnostics.value("/cnn/cnn_depth", "latency p95 (ms)")) > 0
    # its two stages; the second ends each frame's latency (image in to outputs published), so is within it
    stages = ("network", "decode and publish", "latency")
    network, decoding, latency = (float(diagnostics.value("/cnn/cnn_depth", f"{s} p50 (ms)")) for s in stages)
    assert network > 0 and 0 < decoding <= latency, (network, decoding, latency)
    # a replayed bag's calibration reaches cnn_depth in its namespace as it reaches the others
    for name, namespace in (("cnn_depth", "/cnn"), ("fpp_depth", "/")):
        topics = dict(robot.node.get_subscriber_names_and_types_by_node(name, namespace))
        assert "/fpp/calibration" in topics, (name, sorted(topics))


def test_each_node_in_its_own_process(ros_graph):
    procs, robot = ros_graph
    for exe in ("pattern_projector", "fringe_camera_sim", "capture_sequence", "fpp_depth"):
        procs.start(exe)
    truth = collect(robot, Topics.TRUTH, Image, Qos.LATCHED)
    clouds = collect(robot, Topics.POINTS, PointCloud2)
    check_clouds(robot, clouds, truth)


def single_shot_depths(ros_graph, count: int, projector=(), camera=(), cnn=()) -> list:
    """pattern_projector showing the composite alone on every tick, fringe_camera_sim and cnn_depth (each
    with more ros arguments): the first count depth images, each checked against the simulated truth."""
    procs, robot = ros_graph
    procs.start("pattern_projector", "-p", "single_shot_only:=true", *projector)
    procs.start("fringe_camera_sim", *camera)
    procs.start("cnn_depth", *cnn)
    truth = collect(robot, Topics.TRUTH, Image, Qos.LATCHED)
    depths = collect(robot, Topics.DEPTH, Image)
    assert robot.spin_until(lambda: len(depths) >= count and truth, 120), procs.logs()
    truth_mm = image_to_numpy(truth[0]) * 1000.0
    for d in depths[:count]:
        depth_mm = image_to_numpy(d) * 1000.0
        e = depth_errors(depth_mm, truth_mm)
        assert e.coverage > 0.85 and np.nanmedian(np.abs(depth_mm - truth_mm)) < 0.1, e
    return depths[:count]


def test_a_single_shot_sensor_gives_depth_from_every_frame_not_once_a_sequence(ros_graph):
    """pattern_projector with single_shot_only shows the composite on every tick, so cnn_depth on the
    camera's frames measures far more often than once a sequence (17 ticks), and as well."""
    depths = single_shot_depths(ros_graph, 6)
    ticks = np.diff([stamp_ns(d.header.stamp) for d in depths]) * 30 / 1e9  # the projector's 30 Hz
    assert ticks.min() < 17 / 2, ticks  # a sequence of 17 patterns would space them 17 ticks apart


def test_a_projector_above_the_camera_through_the_nodes(ros_graph, tmp_path):
    """The rigs fpp simulate draws, the simulated camera draws too (baseline_mm, projector_below_mm,
    projector_roll_deg): a projector 200 mm above the camera, showing horizontal fringes
    (pattern_projector orientation:=horizontal), and cnn_depth with that rig's calibration, which shows
    the network the frames transposed."""
    rig = Rig(baseline_mm=0.0, projector_below_mm=-200.0)
    calibration, _ = simulated_calibration(
        rig, rig.pattern_set(orientation="horizontal"), seed=7, working_range_mm=(1100.0, 1300.0)
    )
    calibration.save(tmp_path / "above.yaml")
    placed = ("-p", "baseline_mm:=0.0", "-p", "projector_below_mm:=-200.0", "-p", "scene:=objects", "-p", "seed:=5")
    single_shot_depths(
        ros_graph,
        2,
        projector=("-p", "orientation:=horizontal"),
        camera=placed,
        cnn=("-p", f"calibration:={tmp_path / 'above.yaml'}"),
    )


def test_broken_sequences_over_dds_are_dropped_never_mixed(ros_graph):
    """A test node plays projector and camera, with a missing, a duplicated and an out-of-order frame."""
    procs, robot = ros_graph
    procs.start("capture_sequence")
    procs.start("fpp_depth")
    rig = Rig()
    patterns = rig.pattern_set()
    capture = render(rig, make_scene(rig, "objects", 8), patterns, np.random.default_rng(8))
    lines = pattern_images(patterns)
    clouds = collect(robot, Topics.POINTS, PointCloud2)
    pattern_pub, camera_pub, warm_ups, t = projector_and_camera(robot, clouds, lines, capture.images)
    k = patterns.count
    plays = [
        list(range(k)),  # complete
        [i for i in range(k) if i != 5],  # missing frame
        list(range(8)) + [7] + list(range(8, k)),  # duplicated frame
        [0, 1, 2, 4, 3] + list(range(5, k)),  # out of order
        list(range(k)),
    ]  # complete
    first_stamps = []
    for play in plays:
        first_stamps.append(t)
        t = show(robot, pattern_pub, camera_pub, [(lines[i], capture.images[i]) for i in play], t)
    robot.spin_until(lambda: len(clouds) >= 2, 60)
    robot.spin_until(lambda: False, 2.0)  # a cloud that should not exist would have arrived by now
    stamps = [stamp_ns(c.header.stamp) for c in clouds]
    assert stamps == [first_stamps[0], first_stamps[4]], procs.logs()
    truth_m = np.where(capture.valid, capture.depth_mm / 1000, np.nan)
    for cloud in clouds:
        assert rmse_mm(cloud, truth_m)[0] < 0.06
    procs.stop()
    assert "sequence dropped (missing frame: expected pattern 5, got 6)" in procs.logs()  # logged as it happens
    # the counts printed at shutdown; the swapped pair shows as a missing frame (4 came when 3 was due)
    counts = f"sequences complete {2 + warm_ups}, dropped 3 {{'missing frame': 2, 'duplicated frame': 1}}"
    assert counts in procs.logs()


@pytest.mark.parametrize(
    "executable, parameter, said",
    [
        ("pattern_projector", "steps:=2", "steps must be >= 3"),
        # the composed sensor's capture_sequence would never complete a sequence: what to run instead
        ("sensor", "single_shot_only:=true", "for a single-shot sensor run"),
    ],
)
def test_a_bad_parameter_is_one_fatal_line(ros_graph, executable, parameter, said):
    procs, _ = ros_graph
    proc = procs.start(executable, "-p", parameter)
    assert proc.wait(timeout=60) == 2
    assert said in procs.logs() and "Traceback" not in procs.logs()


def test_a_parameter_no_node_has_is_named_and_the_node_runs_on(ros_graph):
    """rclpy ignores a parameter no node declares without a word, so a misspelt one left the default in
    force unnoticed; our nodes name it, once, with theirs, and run on (a parameters file shared by several
    nodes may hold others'). In one process (sensor) a parameter of any of its nodes is no stranger."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from fpp_nodes.nodes.common import warn_of_unknown_parameters

    procs, robot = ros_graph
    patterns = collect(robot, Topics.PATTERN, Image)
    procs.start("pattern_projector", "-p", "rte:=60", "-p", "rate:=20")
    assert robot.spin_until(lambda: len(patterns) >= 3, 30), procs.logs()
    assert "ignored parameter rte: no node here has it (a misspelling?); the parameters here: bit_depth" in procs.logs()
    given = [Parameter("scene", value="objects"), Parameter("sceen", value="objects")]
    camera, depth = (Node(name, context=robot.context, parameter_overrides=given) for name in ("camera", "depth"))
    camera.declare_parameter("scene", "sculpture")
    assert warn_of_unknown_parameters([camera, depth]) == ["sceen"]
    camera.destroy_node()
    depth.destroy_node()


def test_no_work_for_outputs_nobody_subscribes_to(ros_graph):
    """fpp_depth in this process: a sequence with no subscriber is skipped, not reconstructed."""
    from fpp_nodes.nodes.fpp_depth import FppDepth

    _, robot = ros_graph
    depth_node = FppDepth(context=robot.context)
    robot.executor.add_node(depth_node)
    rig = Rig()
    capture = render(rig, make_scene(rig, "sculpture", 2), rig.pattern_set(), np.random.default_rng(2))
    sequence = numpy_to_image(capture.images.reshape(-1, 640), Header(frame_id=Frames.CAMERA))
    publisher = robot.node.create_publisher(Image, Topics.SEQUENCE, Qos.LARGE)
    assert robot.spin_until(lambda: publisher.get_subscription_count() > 0, 30)
    publisher.publish(sequence)
    counts = depth_node.health.totals
    assert robot.spin_until(lambda: counts["sequences skipped (no subscribers)"] == 1, 30) and counts["depth out"] == 0
    clouds = collect(robot, Topics.POINTS, PointCloud2)
    assert robot.spin_until(lambda: depth_node.points_pub.get_subscription_count() > 0, 30)
    publisher.publish(sequence)
    assert robot.spin_until(lambda: len(clouds) == 1, 30) and counts["depth out"] == 1
    robot.executor.remove_node(depth_node)
    depth_node.destroy_node()


def test_cnn_depth_decodes_one_frame_while_the_next_runs_through_the_network(ros_graph):
    """cnn_depth in this process, up to three frames in hand at once (its thread decodes one, one may
    wait for it, and the executor's runs the next through the network): frames of two scenes in turn,
    each sent as soon as the one before is in hand, come back in order, each with its own scene's depth."""
    from fpp_nodes.nodes.cnn_depth import CnnDepth

    _, robot = ros_graph
    node = CnnDepth(context=robot.context)
    robot.executor.add_node(node)
    rig = Rig()
    patterns = rig.pattern_set()
    scenes = [render(rig, make_scene(rig, "objects", s), patterns, np.random.default_rng(s)) for s in (1, 2)]
    camera_pub = robot.node.create_publisher(Image, Topics.CAMERA_IMAGE, Qos.FRAMES)
    # every depth image kept for the probe: this process's one executor thread runs the network too, so
    # the probe takes them late, and the node's newest-only depth of 2 is for subscribers of their own
    depths = collect(robot, Topics.DEPTH, Image, Qos.FRAMES)
    assert robot.spin_until(lambda: camera_pub.get_subscription_count() and node.depth_pub.get_subscription_count(), 30)
    sent = [1_000_000_000 + k * 1_000_000 for k in range(12)]
    for k, t in enumerate(sent):
        camera_pub.publish(
            numpy_to_image(scenes[k % 2].images[patterns.single_shot_index], header_at(t, Frames.CAMERA))
        )
        assert robot.spin_until(lambda: node.health.totals["frames in"] == k + 1, 30)
    assert robot.spin_until(lambda: len(depths) == len(sent), 60)
    back = [stamp_ns(d.header.stamp) for d in depths]
    assert back == sent
    for d in depths:
        truth = scenes[sent.index(stamp_ns(d.header.stamp)) % 2].depth_mm
        error = image_to_numpy(d) * 1000.0 - truth
        assert np.nanmedian(np.abs(error)) < 0.1
    robot.executor.remove_node(node)
    node.destroy_node()
    assert not node.decoder_thread.is_alive()


def test_cnn_depth_measures_with_a_replayed_rigs_calibration(ros_graph, near_rig, near_calibration):
    """A bag's calibration on fpp/calibration (as replay publishes it), here of a rig at 600 mm:
    cnn_depth decodes the shipped network's phases with it, so that rig's frames come back at their own
    depth (with the simulated rig's calibration they would be about 600 mm off), and its camera_info
    is that rig's."""
    from std_msgs.msg import String

    from fpp_nodes.nodes.cnn_depth import CnnDepth

    _, robot = ros_graph
    node = CnnDepth(context=robot.context)
    robot.executor.add_node(node)
    calibration_pub = robot.node.create_publisher(String, Topics.CALIBRATION, Qos.LATCHED)
    calibration_pub.publish(String(data=near_calibration.to_yaml()))
    assert robot.spin_until(lambda: node.calibration.to_dict() == near_calibration.to_dict(), 120)
    patterns = near_calibration.patterns
    capture = render(near_rig, make_scene(near_rig, "objects", 21), patterns, np.random.default_rng(21))
    camera_pub = robot.node.create_publisher(Image, Topics.CAMERA_IMAGE, Qos.FRAMES)
    depths, infos = collect(robot, Topics.DEPTH, Image), collect(robot, Topics.DEPTH_INFO, CameraInfo, Qos.INFO)
    assert robot.spin_until(lambda: camera_pub.get_subscription_count() and node.depth_pub.get_subscription_count(), 30)
    camera_pub.publish(numpy_to_image(capture.images[patterns.single_shot_index], header_at(1, Frames.CAMERA)))
    assert robot.spin_until(lambda: depths and infos, 60)
    error = image_to_numpy(depths[0]) * 1000.0 - capture.depth_mm
    assert np.isfinite(error).sum() > 0.9 * capture.valid.sum() and np.nanmedian(np.abs(error)) < 0.1
    assert infos[0].k[0] == pytest.approx(near_calibration.camera.fx)
    robot.executor.remove_node(node)
    node.destroy_node()


def test_main_job_writes_clouds_and_reports(tmp_path):
    """`ros2 run fpp_nodes demo` (what `make demo` runs) on its own domain."""
    import subprocess

    from rosgraph import fresh_domain_id, ros_env

    env = dict(ros_env(), ROS_DOMAIN_ID=str(fresh_domain_id()))
    r = subprocess.run(
        ["ros2", "run", "fpp_nodes", "demo", "--out", str(tmp_path), "--clouds", "2", "--scene", "objects"],
        env=env,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert len(list(tmp_path.glob("cloud_*.ply"))) == 2 and len(list(tmp_path.glob("depth_*.png"))) >= 1
    rows = [line.split() for line in r.stdout.splitlines() if line.strip()[:1].isdigit() and "%" in line]
    multi, single = [row for row in rows if len(row) == 7], [row for row in rows if len(row) == 4]
    assert len(multi) == 2 and all(float(row[5]) < 0.06 for row in multi), r.stdout
    assert len(single) == 2, r.stdout  # the single-shot path beside it, a cloud for each: RMSE and cover


def test_the_demo_times_a_cloud_only_once_its_whole_sequence_is_here():
    """The demo's report times a cloud from its sequence's last frame: none until all 17 frames have
    reached the robot (under load a cloud can be taken before them), nor across a long gap in them."""
    from fpp_nodes.nodes.demo import last_frame

    period = 33_333_333  # ns: 30 frames/s
    stamps = 1_800_000_000_000_000_000 + period * np.arange(40)
    assert last_frame(stamps, int(stamps[3]), 17) == stamps[19]
    assert last_frame(stamps[:19], int(stamps[3]), 17) is None  # its last frame not taken yet
    gap = np.concatenate([stamps[:8], stamps[30:]])  # the robot missed 22 frames
    assert last_frame(gap, int(gap[0]), 17) is None


def test_a_camera_with_a_lens_gives_clouds_along_its_true_rays(ros_graph, tmp_path):
    """The simulated camera with barrel distortion and the calibration that knows it: the cloud's XYZ is
    each pixel's true ray times its depth, within 0.06 mm RMS of the exact points (a pinhole's rays:
    0.17 mm, and over 0.4 mm in the corners)."""
    procs, robot = ros_graph
    lens = (-0.9, 0.0, 2e-4, -2e-4, 0.0)
    rig = Rig(distortion=lens)
    simulated_calibration(rig, rig.pattern_set(), seed=7)[0].save(tmp_path / "lens.yaml")
    procs.start("sensor", "-p", f"calibration:={tmp_path / 'lens.yaml'}", "-p", f"distortion:={list(lens)}")
    truth = collect(robot, Topics.TRUTH, Image, Qos.LATCHED)
    clouds = collect(robot, Topics.POINTS, PointCloud2)
    info = collect(robot, Topics.DEPTH_INFO, CameraInfo, Qos.INFO)
    assert robot.spin_until(lambda: clouds and truth and info, 60), procs.logs()
    assert list(info[-1].d) == pytest.approx(list(lens)) and info[-1].distortion_model == "plumb_bob"
    exact = back_project(image_to_numpy(truth[0]) * 1000.0, rig.camera())
    pinhole = back_project(image_to_numpy(truth[0]) * 1000.0, replace(rig.camera(), distortion=(0.0,) * 5))
    xyz = cloud_to_xyz(clouds[-1]) * 1000.0
    ok = np.isfinite(xyz).all(axis=-1) & np.isfinite(exact).all(axis=-1)
    assert ok.mean() > 0.9 and np.sqrt(np.mean(np.sum((xyz - exact)[ok] ** 2, axis=-1))) < 0.06  # pinhole: 0.17
    assert np.linalg.norm((exact - pinhole)[0, 0]) > 0.4
