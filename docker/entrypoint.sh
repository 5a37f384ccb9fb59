#!/usr/bin/env bash
# Source ROS 2 and the workspace, keep DDS discovery on this host unless told otherwise, run the command.
set -e
source /opt/ros/jazzy/setup.bash
source /opt/msfsu/ros2_ws/install/setup.bash
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
exec "$@"
