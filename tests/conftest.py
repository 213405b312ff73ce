import pytest

from fpp_nodes.core.simulation import Rig
from fpp_nodes.core.workflow import simulated_calibration


@pytest.fixture(scope="session")
def rig():
    return Rig()


@pytest.fixture(scope="session")
def patterns(rig):
    return rig.pattern_set()


@pytest.fixture(scope="session")
def calibration(rig, patterns):
    """The default rig calibrated from noisy planes, as a user would."""
    return simulated_calibration(rig, patterns, seed=7)[0]


@pytest.fixture(scope="session")
def ideal_rig():
    """No noise, no blur, 16-bit camera, linear projector: only geometry is left."""
    return Rig(noise_sigma=0.0, blur_sigma_px=0.0, camera_bit_depth=16, projector_gamma=1.0)


@pytest.fixture(scope="session")
def ideal_patterns(ideal_rig):
    return ideal_rig.pattern_set(bit_depth=16)


@pytest.fixture
def ros_graph(tmp_path):
    """(processes, robot) on a fresh ROS domain; everything is stopped afterwards."""
    from rosgraph import ProbeNode, fresh_domain_id, node_processes

    domain = fresh_domain_id()
    procs = node_processes(domain, tmp_path)
    robot = ProbeNode(domain)
    yield procs, robot
    robot.close()
    procs.stop()
