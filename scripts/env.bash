# Source this to use the sensor from a shell: the project's Python, its ROS 2 workspace, and `ros2`.
#   source scripts/env.bash && ros2 run fpp_nodes sensor
_fpp_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$_fpp_root/.venv/bin/activate"
source "$_fpp_root/ros_ws/install/setup.bash"
# PyPI's ROS keeps its own packages (message definitions) in the virtual environment.
export AMENT_PREFIX_PATH="$AMENT_PREFIX_PATH:$_fpp_root/.venv"
unset _fpp_root
