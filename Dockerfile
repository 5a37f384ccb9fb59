# MSFSU onboard stack on the official ROS 2 Jazzy image (Ubuntu 24.04, Python 3.12): the replay graph (bag player,
# perception, control, recorder, msfsu-eval-bag), without the simulator (docker/requirements.txt says why).
# ROS comes from apt (ros2cli, `ros2 run`, `ros2 bag`), the Python-only dependencies from PyPI, torch as the CPU
# build. Not built in CI (no Docker engine on the CI machines): docs/deployment_docker.md says how to check it, and
# tests/test_docker_image.py checks what can be checked without an engine.
#
# The base by digest: the multi-platform index of ros:jazzy-ros-base that public projects pinned in September 2026
# (docs/deployment_docker.md, "The base image"; `docker buildx imagetools inspect ros:jazzy-ros-base` gives today's).
FROM ros:jazzy-ros-base@sha256:c3706ef0a0aa45413c07803cf433602f543b22e45b4855f6fca955c2d8ecc4e8

# Build-only settings: ARG, so they are set for the RUN steps below and not in the image's environment.
ARG PIP_BREAK_SYSTEM_PACKAGES=1
ARG PIP_NO_CACHE_DIR=1
ARG DEBIAN_FRONTEND=noninteractive

ENV ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST \
    PYTHONUNBUFFERED=1

# The PyPI wheels of docker/requirements.txt (torch's CPU build aside) link only glibc, libstdc++, libgcc_s and zlib,
# all in the base image (openvino's GPU plugin, unused on the CPU, also OpenCL): no GL, glib or GUI library.
# tini (Ubuntu's, 0.19) is the container's first process (ENTRYPOINT below).
RUN apt-get update && apt-get install -y --no-install-recommends \
        python3-pip ros-jazzy-rosbag2-storage-mcap tini \
    && rm -rf /var/lib/apt/lists/*

# One resolution for everything, into /usr/local, torch as the CPU build or not at all (install_requirements.sh);
# then a check that no CUDA build came in by another way (check_torch_cpu.py).
COPY docker/requirements.txt docker/install_requirements.sh docker/check_torch_cpu.py /tmp/msfsu/
RUN /tmp/msfsu/install_requirements.sh /tmp/msfsu/requirements.txt \
    && python3 /tmp/msfsu/check_torch_cpu.py \
    && rm -rf /tmp/msfsu

WORKDIR /opt/msfsu
COPY . /opt/msfsu
RUN . /opt/ros/jazzy/setup.sh \
    && cd ros2_ws \
    && colcon build --cmake-args -DBUILD_TESTING=OFF \
    && rm -rf build log \
    && mkdir -p /root/intel && echo 0 > /root/intel/openvino_telemetry

# The default model's int8 network, built here from its calibration frames as the perception node would build it at
# its first configure (tens of seconds, torchvision's and NNCF's messages): a container's node loads it in seconds.
RUN . /opt/ros/jazzy/setup.sh && . ros2_ws/install/setup.sh \
    && python3 -m msfsu_perception.prepare_model models/msfsu_default.pt --precision int8

# tini runs the entry point as the container's first process, passing the stop signal to its whole process group
# (-g) and reaping what is orphaned below it (-s, also where it is not PID 1). docker stop sends SIGINT, the stop
# signal of ROS 2 nodes: Jazzy's `ros2 run` waits for its node then, where SIGTERM would end it before the node's
# shutdown (docs/deployment_docker.md, "Stopping").
STOPSIGNAL SIGINT
ENTRYPOINT ["/usr/bin/tini", "-g", "-s", "--", "/opt/msfsu/docker/entrypoint.sh"]
# The graph on the sample bag: `docker run --rm --shm-size=1g msfsu` replays it and ends; any other command replaces it
CMD ["ros2", "launch", "msfsu_bringup", "replay.launch.py", "bag:=bags/sample", "checkpoint:=models/msfsu_default.pt"]
