# MSFSU onboard stack on the official ROS 2 Jazzy image (Ubuntu 24.04, Python 3.12).
# Here ROS comes from apt (ros2cli, `ros2 run`, `ros2 bag`); the Python-only dependencies from PyPI,
# torch as the CPU build. Not built in CI (no Docker engine on the CI machines): see README.
FROM ros:jazzy-ros-base

ENV ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST \
    PIP_BREAK_SYSTEM_PACKAGES=1 \
    PIP_NO_CACHE_DIR=1 \
    PYTHONUNBUFFERED=1

RUN apt-get update && apt-get install -y --no-install-recommends \
        python3-pip g++ ros-jazzy-rosbag2-storage-mcap \
        libegl1 libegl-mesa0 libgl1-mesa-dri \
    && rm -rf /var/lib/apt/lists/*

# numpy stays at the apt version: the ROS message extensions are compiled against NumPy 1.x.
COPY docker/requirements.txt /tmp/requirements.txt
RUN pip3 install --index-url https://download.pytorch.org/whl/cpu torch==2.13.0 \
    && pip3 install -r /tmp/requirements.txt

WORKDIR /opt/msfsu
COPY . /opt/msfsu
RUN . /opt/ros/jazzy/setup.sh \
    && cd ros2_ws \
    && colcon build --cmake-args -DBUILD_TESTING=OFF \
    && rm -rf build log \
    && . install/setup.sh \
    && python3 -m msfsu_sim.assets \
    && mkdir -p /root/intel && echo 0 > /root/intel/openvino_telemetry

ENTRYPOINT ["/opt/msfsu/docker/entrypoint.sh"]
CMD ["bash"]
