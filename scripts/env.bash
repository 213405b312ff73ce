# Source this to use the sensor from a shell: the project's Python, its ROS 2 workspace, and `ros2`.
#   source scripts/env.bash && ros2 run fpp_nodes sensor
_fpp_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$_fpp_root/.venv/bin/activate"
source "$_fpp_root/ros_ws/install/setup.bash"
# PyPI's ROS keeps its own packages (message definitions) in the virtual environment.
export AMENT_PREFIX_PATH="$AMENT_PREFIX_PATH:$_fpp_root/.venv"
# Fast DDS with shared-memory segments that hold a whole sequence or cloud (fpp_msgs_py/fastdds.xml).
export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_fpp_root/fpp_msgs_py/fpp_msgs_py/fastdds.xml}"
unset _fpp_root
