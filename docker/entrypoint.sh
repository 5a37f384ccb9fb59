#!/usr/bin/env bash
# Source ROS 2 and the workspace, keep DDS discovery on this host and use the stack's Fast DDS profile unless
# told otherwise, run the command.
set -e
source /opt/ros/jazzy/setup.bash
source /opt/msfsu/ros2_ws/install/setup.bash
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
# camera frames over shared memory for ros2 CLI tools too (the stack's own processes set it themselves)
export FASTRTPS_DEFAULT_PROFILES_FILE=${FASTRTPS_DEFAULT_PROFILES_FILE:-/opt/msfsu/msfsu_common/msfsu_common/fastdds_profile.xml}
exec "$@"
