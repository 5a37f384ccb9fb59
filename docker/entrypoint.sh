#!/usr/bin/env bash
# The image's entry point, which tini (the container's first process) runs: source ROS 2 and the workspace, keep DDS
# discovery on this host, give the ros2 CLI tools the Fast DDS profile the stack's own processes use here
# (msfsu_common.ros_env: the stack's shared-memory profile where /dev/shm holds it, Fast DDS's defaults and one line on
# stderr where it does not, a profile the user named as it is), then exec the command in tini's process group, where
# docker stop's signal reaches it and everything it starts (docs/deployment_docker.md, "Stopping").
# MSFSU_ROS_SETUP and MSFSU_WORKSPACE_SETUP name other setup files (a ROS or workspace installed elsewhere).
set -e
source "${MSFSU_ROS_SETUP:-/opt/ros/jazzy/setup.bash}"
source "${MSFSU_WORKSPACE_SETUP:-/opt/msfsu/ros2_ws/install/setup.bash}"
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
profile=$(python3 -m msfsu_common.ros_env)
if [ -n "$profile" ]; then
    export FASTRTPS_DEFAULT_PROFILES_FILE=$profile
else
    unset FASTRTPS_DEFAULT_PROFILES_FILE
fi
exec "$@"
