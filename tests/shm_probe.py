"""Two-process probe of the camera transport (tests/test_transport.py): `python shm_probe.py pub|sub FRAMES`.

`pub` publishes FRAMES 800x600 rgb8 images (1.44 MB) at 20 Hz, reliable, once both ends have matched (the writer sees
the reader, and `sub` says on a latched topic that its reader sees the writer: discovery is not symmetric), then prints
the Fast DDS shared-memory segments mapped into its process as JSON: their size and which of 8 pieces of the
image (random bytes, 64 each, spread over the frame) each holds, i.e. whether the frame was written into it. `sub` prints how many images arrived and their stamp -> callback latencies as JSON.
Both run with the project's ROS environment (msfsu_common.ros_env) unless the caller set a profile.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from msfsu_common.ros_env import configure_ros_environment

TOPIC = "/msfsu_test/shm_probe/image"
READY_TOPIC = "/msfsu_test/shm_probe/ready"
WIDTH, HEIGHT, RATE_HZ = 800, 600, 20.0


def mapped_segments(frame: bytes) -> list[dict[str, object]]:
    """Fast DDS segments (not port files) mapped into this process: path, size, pieces of `frame` found in it."""
    paths = {line.split()[-1] for line in Path("/proc/self/maps").read_text().splitlines()
             if "/dev/shm/fastrtps_" in line and "port" not in line.rsplit("/", 1)[-1]}
    segments = []
    for path in sorted(paths):
        try:
            content = Path(path).read_bytes()
        except FileNotFoundError:
            continue
        offsets = np.linspace(0, len(frame) - 64, 8).astype(int)
        segments.append({"path": path, "size": len(content),
                         "frame_pieces_found": sum(content.find(frame[o:o + 64]) >= 0 for o in offsets)})
    return segments


def main(role: str, frames: int) -> None:
    configure_ros_environment()
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image
    from std_msgs.msg import Empty

    from msfsu_common.image_codec import encode_image

    rclpy.init()
    node = Node(f"shm_probe_{role}")
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    deadline = time.monotonic() + 30.0
    if role == "pub":
        publisher = node.create_publisher(Image, TOPIC, qos)
        ready: list[Empty] = []
        node.create_subscription(Empty, READY_TOPIC, ready.append, latched)
        image = Image(**encode_image(np.random.default_rng(0).integers(0, 256, (HEIGHT, WIDTH, 3), np.uint8), "rgb8"))
        while (publisher.get_subscription_count() == 0 or not ready) and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        for index in range(frames):
            image.header.stamp.sec, image.header.stamp.nanosec = divmod(time.time_ns(), 1_000_000_000)
            publisher.publish(image)
            time.sleep(1.0 / RATE_HZ)
        time.sleep(1.0)  # reliable: retransmissions, if any, before the segments are read and the process ends
        print(json.dumps({"segments": mapped_segments(bytes(image.data))}), flush=True)
    else:
        latencies_ms: list[float] = []

        def on_image(msg: Image) -> None:
            latencies_ms.append((time.time_ns() - msg.header.stamp.sec * 1_000_000_000 - msg.header.stamp.nanosec) / 1e6)

        subscription = node.create_subscription(Image, TOPIC, on_image, qos)
        while subscription.get_publisher_count() == 0 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        node.create_publisher(Empty, READY_TOPIC, latched).publish(Empty())
        while len(latencies_ms) < frames and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        print(json.dumps({"received": len(latencies_ms), "latency_ms": latencies_ms}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))
