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
def near_rig():
    """A rig at another standoff: 600 mm, with the default's field of view (half the focal length)."""
    return Rig(standoff_mm=600.0, focal_px=Rig.focal_px / 2)


@pytest.fixture(scope="session")
def near_calibration(near_rig):
    """near_rig calibrated from noisy planes at 540-660 mm: its working range is theirs."""
    planes = (540.0, 570.0, 600.0, 630.0, 660.0)
    return simulated_calibration(near_rig, near_rig.pattern_set(), 7, planes, working_range_mm=None)[0]


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
