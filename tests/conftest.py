import numpy as np
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
def pixel_grid():
    def grid(shape):
        return np.arange(shape[1], dtype=np.float64)[None, :], np.arange(shape[0], dtype=np.float64)[:, None]
    return grid


@pytest.fixture
def ros_graph(tmp_path):
    """(processes, robot) on a fresh ROS domain; everything is stopped afterwards."""
    from rosgraph import Processes, Robot, fresh_domain_id
    domain = fresh_domain_id()
    procs = Processes(domain, tmp_path)
    robot = Robot(domain)
    yield procs, robot
    robot.close()
    procs.stop()
