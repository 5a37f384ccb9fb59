# MSFSU onboard stack on the official ROS 2 Jazzy image (Ubuntu 24.04, Python 3.12): the replay graph (bag player,
# perception, control, recorder, msfsu-eval-bag), without the simulator (docker/requirements.txt says why).
# ROS comes from apt (ros2cli, `ros2 run`, `ros2 bag`), the Python-only dependencies from PyPI, torch as the CPU
# build. Not built in CI (no Docker engine on the CI machines): docs/deployment_docker.md says how to check it.
FROM ros:jazzy-ros-base

ENV ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST \
    PIP_BREAK_SYSTEM_PACKAGES=1 \
    PIP_NO_CACHE_DIR=1 \
    PYTHONUNBUFFERED=1

# The PyPI wheels of docker/requirements.txt (torch's CPU build aside) link only glibc, libstdc++, libgcc_s and zlib,
# all in the base image (openvino's GPU plugin, unused on the CPU, also OpenCL): no GL, glib or GUI library.
RUN apt-get update && apt-get install -y --no-install-recommends \
        python3-pip ros-jazzy-rosbag2-storage-mcap \
    && rm -rf /var/lib/apt/lists/*

# One resolution for everything, into /usr/local: --ignore-installed, because pip cannot uninstall apt's Python
# packages (no RECORD file) should a pin need another version of one; torch from the CPU index (its +cpu build
# satisfies torch==2.13.0), everything else from PyPI.
COPY docker/requirements.txt /tmp/requirements.txt
RUN pip3 install --ignore-installed --index-url https://download.pytorch.org/whl/cpu \
        --extra-index-url https://pypi.org/simple -r /tmp/requirements.txt

WORKDIR /opt/msfsu
COPY . /opt/msfsu
RUN . /opt/ros/jazzy/setup.sh \
    && cd ros2_ws \
    && colcon build --cmake-args -DBUILD_TESTING=OFF \
    && rm -rf build log \
    && mkdir -p /root/intel && echo 0 > /root/intel/openvino_telemetry

ENTRYPOINT ["/opt/msfsu/docker/entrypoint.sh"]
CMD ["bash"]
