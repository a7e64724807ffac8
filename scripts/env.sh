# Source me: the environment every ros_ehs command runs in (set up by scripts/setup.sh).
_ehs_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export VIRTUAL_ENV="${EHS_VENV:-$_ehs_root/.venv}"
# the editable install puts console scripts where ros2 run looks: lib/ros_ehs (setup.cfg)
export PATH="$VIRTUAL_ENV/lib/ros_ehs:$VIRTUAL_ENV/bin:$PATH"
# the ROS wheels install their prefix into the venv: ament_index finds nothing without this
export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$_ehs_root/.cache/numba}"
export MPLBACKEND=Agg
unset _ehs_root
