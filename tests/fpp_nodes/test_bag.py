"""rosbag2 record and replay: real bags, real nodes, identical clouds."""

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import Image, PointCloud2

from fpp_msgs_py import Qos, Topics, cloud_to_xyz, stamp_ns
from fpp_nodes.bag import BagError, BagWriter, read_bag
from fpp_nodes.core.calibration import Calibration
from fpp_nodes.core.simulation import Rig
from fpp_nodes.core.workflow import simulated_calibration

from rosgraph import ProbeNode, fresh_domain_id, node_processes


def stamp(msg):
    return stamp_ns(msg.header.stamp)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_round_trip_and_damage(tmp_path, storage):
    writer = BagWriter(tmp_path / "bag", storage)
    writer.write_calibration("format: x\n", 1)
    for i in range(5):
        writer.write("/camera/image_raw", "sensor_msgs/msg/Image", 10 + i, bytes([0, 1, 0, 0]) + bytes(40))
    writer.close()
    rec = read_bag(tmp_path / "bag")
    assert rec.calibration_yaml == "format: x\n" and [m[2] for m in rec.messages] == [10, 11, 12, 13, 14]
    with pytest.raises(BagError, match="never overwritten"):
        BagWriter(tmp_path / "bag", storage)
    data = next((tmp_path / "bag").glob(f"*.{'mcap' if storage == 'mcap' else 'db3'}"))
    data.write_bytes(data.read_bytes()[: len(data.read_bytes()) // 2])
    with pytest.raises(BagError, match="cannot read bag|truncated"):
        read_bag(tmp_path / "bag")
    with pytest.raises(BagError, match="does not exist"):
        read_bag(tmp_path / "none")
    data.write_bytes(bytes(range(256)) * 64)  # not a bag file at all
    with pytest.raises(BagError, match="cannot read bag"):
        read_bag(tmp_path / "bag")
    (tmp_path / "bag" / "metadata.yaml").write_text("rosbag2_bagfile_information: [")
    with pytest.raises(BagError, match="cannot read bag"):
        read_bag(tmp_path / "bag")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A few seconds of the live sensor with a calibration that is not the default, recorded;
    the clouds the live sensor made meanwhile, by stamp."""
    d = tmp_path_factory.mktemp("bag")
    rig = Rig()
    calibration, _ = simulated_calibration(rig, rig.pattern_set(), seed=1)  # not the shipped one (seed 0)
    calibration.save(d / "cal.yaml")
    procs, robot = node_processes(fresh_domain_id(), d), None
    try:
        robot = ProbeNode(procs.domain_id)
        clouds = []
        robot.node.create_subscription(PointCloud2, Topics.POINTS, clouds.append, Qos.LARGE)
        procs.start("sensor", "-p", f"calibration:={d / 'cal.yaml'}", "-p", "scene:=objects", "-p", "seed:=4")
        assert robot.spin_until(lambda: len(clouds) >= 1, 60)
        procs.start(
            "record", "-p", f"output:={d / 'bag'}", "-p", f"calibration:={d / 'cal.yaml'}", "-p", "outputs:=true"
        )
        # the recorder's own word that each topic flows to it (a subscription in the graph can still be
        # unmatched by the sensor's publishers for a while, and what comes meanwhile is not in the bag)
        flowing = [f"first message on /{t}" for t in (Topics.PATTERN, Topics.CAMERA_IMAGE, Topics.POINTS)]
        assert robot.spin_until(lambda: all(line in procs.logs("record") for line in flowing), 60)
        recording_from = len(clouds)
        assert robot.spin_until(lambda: len(clouds) >= recording_from + 10, 60)
    finally:
        procs.stop()
        if robot:
            robot.close()
    return d, {stamp(c): cloud_to_xyz(c) for c in clouds}


def test_replay_reconstructs_identical_clouds_without_the_original_parameters(recorded, tmp_path):
    d, live = recorded
    with Reader(d / "bag") as reader:  # the outputs are in the bag to look at; the replay makes them anew
        assert {"/points", "/depth/image"} <= {c.topic for c in reader.connections if c.msgcount > 0}
    assert (
        Calibration.from_yaml(read_bag(d / "bag").calibration_yaml).to_dict()
        == Calibration.load(d / "cal.yaml").to_dict()
    )
    procs = node_processes(fresh_domain_id(), tmp_path)
    robot = ProbeNode(procs.domain_id)
    try:
        clouds = []
        robot.node.create_subscription(PointCloud2, Topics.POINTS, clouds.append, Qos.LARGE)
        procs.start("capture_sequence")  # started with the shipped calibration, not the bag's
        procs.start("fpp_depth")
        assert robot.spin_until(lambda: robot.node.count_publishers(Topics.POINTS) > 0, 30)
        player = procs.start("replay", "-p", f"bag:={d / 'bag'}", "-p", "rate:=2.0")
        assert robot.spin_until(lambda: player.poll() is not None, 60) and player.returncode == 0
        robot.spin_until(lambda: False, 2.0)
    finally:
        robot.close()
        procs.stop()
    replayed = {stamp(c): cloud_to_xyz(c) for c in clouds}
    common = sorted(set(live) & set(replayed))
    assert len(common) >= 5, (len(live), len(replayed), procs.logs())
    for s in common:
        np.testing.assert_array_equal(replayed[s], live[s])
    assert "using the calibration from fpp/calibration" in procs.logs()


def test_a_truncated_bag_stops_with_one_error_and_publishes_nothing(recorded, tmp_path, ros_graph):
    d, _ = recorded
    procs, robot = ros_graph
    broken = tmp_path / "broken"
    broken.mkdir()
    for f in (d / "bag").iterdir():
        data = f.read_bytes()
        (broken / f.name).write_bytes(data[: int(len(data) * 0.6)] if f.suffix == ".mcap" else data)
    frames = []
    robot.node.create_subscription(Image, Topics.CAMERA_IMAGE, frames.append, Qos.FRAMES)
    player = procs.start("replay", "-p", f"bag:={broken}")
    assert robot.spin_until(lambda: player.poll() is not None, 60)
    assert player.returncode == 2 and not frames
    errors = [line for line in procs.logs().splitlines() if "FATAL" in line]
    assert len(errors) == 1 and "bag" in errors[0] and "Traceback" not in procs.logs()
