"""Camera stamp -> VehicleControl through the perception and control nodes, spun in this process on a private ROS
domain (LOCALHOST discovery): a camera publisher sends RGB + metric depth + odometry at a fixed rate and times each
frame's first VehicleControl (benchmarks/perception.py's end-to-end section).

Warm-up frames until 3 controls came back (discovery, the first slow inferences; 30 s at most), then the measured
frames on a fixed schedule, then 1 s for the last frames' controls; a frame no control answered counts as dropped.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from msfsu_evaluation.metrics import LatencySummary, latency_summary

if TYPE_CHECKING:
    from rclpy.node import Node

    from msfsu_interfaces.msg import VehicleControl


@dataclass(frozen=True)
class EndToEnd:
    backend: str
    precision: str
    sent: int
    latency: LatencySummary | None
    dropped: int
    compute_ms_p50: float | None  # the perception node's preprocessing + network + publishing


def end_to_end(checkpoint: Path, backend: str, precision: str, threads: int, camera: tuple[int, int],
               frames: int, rate_hz: float) -> EndToEnd:
    """Camera stamp -> VehicleControl received, perception + control nodes spun in this process."""
    from domain_coordinator import domain_id

    from msfsu_common.ros_env import configure_ros_environment

    configure_ros_environment()
    with domain_id() as domain:
        return _end_to_end_on_domain(domain, checkpoint, backend, precision, threads, camera, frames, rate_hz)


class _BenchmarkCamera:
    """On `node`: a fixed RGB + depth pair and odometry, stamped when sent, on the perception node's topics, and the
    delay of each VehicleControl from the camera stamp it answers (the first per stamp: not a later watchdog brake).
    Only frames sent while `measuring` count."""

    def __init__(self, node: Node, camera: tuple[int, int]) -> None:
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Image

        from msfsu_common import topics
        from msfsu_common.image_codec import encode_image
        from msfsu_interfaces.msg import VehicleControl

        width, height = camera
        rng = np.random.default_rng(0)
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.node = node
        self.rgb = Image(**encode_image(rng.integers(0, 256, (height, width, 3), np.uint8), "rgb8"))
        self.depth = Image(**encode_image(rng.uniform(1.0, 80.0, (height, width)).astype(np.float32), "32FC1"))
        self.odometry = Odometry()
        self.odometry.twist.twist.linear.x = 5.0
        # published in this order each frame: odometry, then RGB, then depth
        self.publishers = [(node.create_publisher(kind, topic, qos), msg) for topic, kind, msg in (
            (topics.ODOMETRY, Odometry, self.odometry), (topics.RGB, Image, self.rgb),
            (topics.DEPTH, Image, self.depth))]
        node.create_subscription(VehicleControl, topics.VEHICLE_CONTROL, self.on_control, 10)
        self.sent_ns: list[int] = []
        self.latency_ms: dict[int, float] = {}
        self.measuring = False
        self.lock = threading.Lock()

    def send(self) -> None:
        stamp = self.node.get_clock().now()
        for msg in (self.rgb, self.depth, self.odometry):
            msg.header.stamp = stamp.to_msg()
        for publisher, msg in self.publishers:
            publisher.publish(msg)
        if self.measuring:
            self.sent_ns.append(stamp.nanoseconds)

    def on_control(self, msg: VehicleControl) -> None:
        received = self.node.get_clock().now().nanoseconds
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with self.lock:
            self.latency_ms.setdefault(stamp, (received - stamp) * 1e-6)

    def answered_ms(self) -> list[float]:
        """The delays of the measured frames that a control answered, in sending order."""
        with self.lock:
            return [self.latency_ms[sent] for sent in self.sent_ns if sent in self.latency_ms]


@contextmanager
def _spinning(nodes: list[Node]) -> Iterator[None]:
    """Each node spun by an executor of its own on a thread of its own, as if each ran in its own process; on leaving,
    the executors shut down and the nodes destroyed."""
    from rclpy.executors import SingleThreadedExecutor

    executors = [SingleThreadedExecutor() for _ in nodes]
    spinners = []
    for executor, node in zip(executors, nodes):
        executor.add_node(node)
        spinners.append(threading.Thread(target=executor.spin, daemon=True))
        spinners[-1].start()
    try:
        yield
    finally:
        for executor, spinner, node in zip(executors, spinners, nodes):
            executor.shutdown(timeout_sec=10.0)
            spinner.join(timeout=10.0)
            executor.remove_node(node)
            node.destroy_node()


def _send_frames(feed: _BenchmarkCamera, frames: int, rate_hz: float) -> None:
    """Warm-up frames until 3 controls came back (discovery, the first slow inferences; 30 s at most), then `frames`
    measured frames at `rate_hz` on a fixed schedule, then 1 s for the last frames' controls."""
    period = 1.0 / rate_hz
    deadline = time.monotonic() + 30.0
    while len(feed.latency_ms) < 3 and time.monotonic() < deadline:
        feed.send()
        time.sleep(period)
    feed.measuring = True
    next_send = time.monotonic()
    for _ in range(frames):
        feed.send()
        next_send += period
        time.sleep(max(0.0, next_send - time.monotonic()))
    time.sleep(1.0)


def _end_to_end_on_domain(domain: int, checkpoint: Path, backend: str, precision: str, threads: int,
                          camera: tuple[int, int], frames: int, rate_hz: float) -> EndToEnd:
    """`end_to_end` on ROS domain `domain`: rclpy initialised for it, and shut down on leaving."""
    import rclpy
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from msfsu_control.control_node import ControlNode
    from msfsu_perception.perception_node import PerceptionNode

    rclpy.init(domain_id=domain)
    parameters = [Parameter("checkpoint", value=str(checkpoint)), Parameter("backend", value=backend),
                  Parameter("precision", value=precision), Parameter("num_threads", value=threads)]
    perception, control = PerceptionNode(parameters), ControlNode()
    feed = _BenchmarkCamera(Node("benchmark_camera"), camera)
    try:
        with _spinning([perception, control, feed.node]):
            _send_frames(feed, frames, rate_hz)
            samples = feed.answered_ms()
            compute = float(np.median(perception.compute_ms)) if perception.compute_ms else None
        sent = len(feed.sent_ns)
        return EndToEnd(perception.model.backend, perception.model.precision, sent,
                        latency_summary(samples) if samples else None, sent - len(samples), compute)
    finally:
        rclpy.shutdown()


def end_to_end_lines(result: EndToEnd, camera: tuple[int, int], rate_hz: float) -> list[str]:
    head = (f"End to end (camera stamp -> VehicleControl, {camera[0]}x{camera[1]} rgb8 + 32FC1 at {rate_hz:g} Hz, "
            f"perception on {result.backend}/{result.precision}): ")
    if result.latency is None:
        return [head + f"no control arrived for {result.sent} frames"]
    latency = result.latency
    return [head + f"p50 {latency.p50_ms:.1f} ms, p95 {latency.p95_ms:.1f} ms, max {latency.max_ms:.1f} ms, "
            f"{result.dropped} of {result.sent} frames dropped; perception compute p50 {result.compute_ms_p50:.1f} ms"]
