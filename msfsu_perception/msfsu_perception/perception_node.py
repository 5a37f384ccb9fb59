"""perception node: RGB + depth (+ navigation command) -> DrivingAction and segmentation.

Sensor callbacks only decode (zero-copy where the encoding allows) and pair frames. Which frame is inferred
when, and with which command, is the ROS-free FrameScheduler's (skip to the newest, the command wait); this node
wires it. Inference runs on the same executor thread: a pair wakes a guard condition, whose callback the
executor runs after the messages that were ready with it, so a pair that arrived meanwhile replaces the older
one (counted as skipped) and a slow model never builds a backlog. One Python thread does all of it: a second
thread for inference has to win the GIL back from the executor each time it returns from OpenCV or OpenVINO (up
to CPython's 5 ms switch interval each time); benchmarks/soak/design/ compares the two. Each frame goes through
`infer_frame` (msfsu_perception.frame_inference), the collector's network driver's function too. Every rejected
input is logged and counted by reason in /diagnostics (FrameStats, msfsu_perception.frame_stats); the node keeps
serving the next good message. With `publish_stage_times` each served frame's stage times go to
/msfsu/stage_times (msfsu_common.stage_times).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from msfsu_common import topics
from msfsu_common.diagnostics import OK, WARN, diagnostic_array
from msfsu_common.image_codec import ImageFormatError, decode_depth, decode_rgb, encode_image
from msfsu_common.message_types import stamp_ns
from msfsu_common.node_runner import StartupError, run_node
from msfsu_common.params import NodeParameters, retime
from msfsu_common.stage_times import StageTimesPublisher, StageTrace, received
from msfsu_common.transport import SENSOR_QUEUE_DEPTH
from msfsu_common.road_option import RoadOption, parse_road_option
from msfsu_interfaces.msg import DrivingAction, NavigationCommand
from msfsu_perception.backends import BackendUnavailableError
from msfsu_perception.checkpoint import CheckpointError
from msfsu_perception.frame_inference import infer_frame
from msfsu_perception.frame_scheduler import Command, DecodedImage, Frame, FrameScheduler, Served
from msfsu_perception.frame_stats import FrameStats
from msfsu_perception.inference import DrivingModel, input_rgb
from msfsu_perception.preprocessing import MAX_INVALID_DEPTH_FRACTION
from msfsu_perception.synchronizer import ApproximateTimeSynchronizer, Pair
from msfsu_common.semantic_classes import overlay
from msfsu_common.settings import setting

@dataclass(frozen=True)
class PerceptionStartup:
    """The perception node's read-only parameters: the network, how it runs, and the sensor subscriptions."""

    checkpoint: str = setting("", "MSFSU checkpoint file (.pt) written by msfsu-train")
    num_threads: int = setting(0, "torch intra-op threads (0: library default)", 0, 256)
    backend: str = setting("auto", "inference backend: auto (fastest installed: openvino, onnxruntime, torch), torch "
                           "(reference), onnxruntime or openvino")
    precision: str = setting("auto", "fp32, bf16, int8 (needs <checkpoint>.calibration.npz) or auto (fastest that "
                             "passed the accuracy gate on this checkpoint and runs on this CPU, else fp32)")
    device: str = setting("auto", "where the network runs: auto (a CUDA GPU when torch sees one, else the CPU), cpu or "
                          "cuda (frames preprocessed on the GPU, the network in a CUDA graph)")
    sync_queue_size: int = setting(10, "frames kept per stream for pairing", 1, 1000)
    sensor_reliability: str = setting("reliable", "sensor QoS", choices=("reliable", "best_effort"))
    sensor_queue_depth: int = setting(SENSOR_QUEUE_DEPTH, "sensor subscription queue depth", 1, 1000)


@dataclass(frozen=True)
class PerceptionSettings:
    """The perception node's live parameters: frame checks, pairing, the command wait and what it publishes."""

    max_invalid_depth_fraction: float = setting(
        MAX_INVALID_DEPTH_FRACTION, "tolerated share of invalid depth pixels (NaN/inf, 16UC1 0), read as the far clip; "
        "a frame with more is dropped", 0.0, 1.0)
    sync_slop: float = setting(0.02, "max RGB/depth stamp difference, s", 0.0, 10.0)
    command_wait: float = setting(
        0.0, "wait up to this long (wall time, s) for a command stamped at or after a frame before inferring it, as in "
        "lockstep, where the route node answers each frame's odometry; 0: infer at once with the latest command",
        0.0, 10.0)
    publish_overlay: bool = setting(False, "also publish an rgb8 colour overlay")
    publish_stage_times: bool = setting(False, "publish each served frame's stage times on /msfsu/stage_times")
    diagnostics_period: float = setting(1.0, "diagnostics period, s", 0.05, 60.0)


class PerceptionNode(Node):
    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__("perception", parameter_overrides=parameter_overrides or [])
        self.parameters = NodeParameters(self, live=PerceptionSettings, read_only=PerceptionStartup,
                                         apply=self.apply_settings)
        startup, settings = self.parameters.read_only, self.parameters.live
        checkpoint, backend, precision, device = startup.checkpoint, startup.backend, startup.precision, startup.device
        if not checkpoint:
            raise StartupError("parameter 'checkpoint' is required (path to an MSFSU checkpoint)")
        try:
            self.model = DrivingModel.from_checkpoint(checkpoint, num_threads=startup.num_threads or None,
                                                      backend=backend, precision=precision, device=device)
        except CheckpointError as error:
            raise StartupError(f"cannot use checkpoint '{checkpoint}': {error}") from error
        except (BackendUnavailableError, ValueError) as error:
            raise StartupError(f"cannot run '{checkpoint}' on {backend}/{precision} (device {device}): {error}") from error
        preprocess = self.model.preprocess
        # The first inference allocates and compiles (several times a frame's time): done before any subscription,
        # so the first sensor frame is not late and the frames behind it are not skipped.
        warm_up_started = time.perf_counter()
        self.model.predict(np.zeros((preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32),
                           RoadOption.LANE_FOLLOW)
        warm_up_ms = (time.perf_counter() - warm_up_started) * 1e3
        self.synchronizer: ApproximateTimeSynchronizer[DecodedImage, DecodedImage] = ApproximateTimeSynchronizer(
            queue_size=startup.sync_queue_size, slop_ns=int(settings.sync_slop * 1e9))
        sensor_qos = QoSProfile(
            depth=startup.sensor_queue_depth,
            reliability=ReliabilityPolicy.BEST_EFFORT if startup.sensor_reliability == "best_effort"
            else ReliabilityPolicy.RELIABLE,
        )
        self.action_pub = self.create_publisher(DrivingAction, topics.DRIVING_ACTION, 10)
        self.segmentation_pub = self.create_publisher(Image, topics.SEGMENTATION, 5)
        self.overlay_pub: Publisher | None = None  # made the first time publish_overlay is on
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.stage_times = StageTimesPublisher(self, settings.publish_stage_times)
        # the command first: an executor takes the ready subscriptions in the order they were made, so a frame and the
        # command sent before it that wait together are taken command first (and inference, a guard condition, after both)
        self.create_subscription(NavigationCommand, topics.NAVIGATION_COMMAND, self.on_command, 10)
        self.create_subscription(Image, topics.RGB, lambda msg, info: self.on_rgb(msg, info), sensor_qos)
        if self.model.preprocess.use_depth:
            self.create_subscription(Image, topics.DEPTH, lambda msg, info: self.on_depth(msg, info), sensor_qos)
        self.diagnostics_timer = self.create_timer(settings.diagnostics_period, self.publish_diagnostics)
        # on the wall clock: sim time stands still while the simulator waits for the graph; period: follow_command_wait
        self.release_timer = self.create_timer(1.0, self.release_overdue, clock=Clock(clock_type=ClockType.STEADY_TIME),
                                               autostart=False)

        self.scheduler = FrameScheduler(settings.command_wait)
        self.stats = FrameStats(time.monotonic())
        self.inference_due = self.create_guard_condition(self.run_inference)
        self.follow_command_wait(settings.command_wait)
        self.follow_overlay(settings.publish_overlay)
        self.get_logger().info(f"loaded {checkpoint}: input {preprocess.channels}x{preprocess.input_height}x"
                               f"{preprocess.input_width}, segmentation={self.model.has_segmentation}, "
                               f"{self.model.device} {self.model.backend}/{self.model.precision}, warm-up inference {warm_up_ms:.0f} ms")

    # --- live parameters (msfsu_common.params) --------------------------------------------------
    def apply_settings(self, settings: PerceptionSettings) -> None:
        """New parameters in force: the next frame, pair, command wait and diagnostics use them."""
        self.synchronizer.slop_ns = int(settings.sync_slop * 1e9)
        self.stage_times.enabled = settings.publish_stage_times
        retime(self.diagnostics_timer, settings.diagnostics_period)
        self.follow_command_wait(settings.command_wait)
        self.follow_overlay(settings.publish_overlay)

    def follow_command_wait(self, wait_s: float) -> None:
        """The scheduler holds frames for `wait_s`; the release timer checks every quarter of it while it is > 0."""
        if wait_s > 0:
            retime(self.release_timer, wait_s / 4)
        else:
            self.release_timer.cancel()
        self.serve(self.scheduler.set_command_wait(wait_s))

    def follow_overlay(self, enabled: bool) -> None:
        if enabled and self.overlay_pub is None:
            self.overlay_pub = self.create_publisher(Image, topics.SEGMENTATION_OVERLAY, 5)

    # --- sensor callbacks: decode, validate, pair ---------------------------------------------
    def reject(self, reason: str, detail: str) -> None:
        total = self.stats.drop(reason)
        self.get_logger().warn(f"dropped input ({reason}): {detail} [total {total}]",
                               throttle_duration_sec=1.0)

    def on_rgb(self, msg: Image, info: Mapping[str, Any] | None = None) -> None:
        marks = received("rgb", info)
        try:
            rgb = decode_rgb(msg)
        except ImageFormatError as error:
            self.reject("bad_rgb", str(error))
            return
        decoded = DecodedImage(msg.header, rgb, marks)
        if not self.model.preprocess.use_depth:
            self.offer(Pair(stamp_ns(msg.header), decoded, None))
            return
        self.offer(self.synchronizer.add_a(stamp_ns(msg.header), decoded))

    def on_depth(self, msg: Image, info: Mapping[str, Any] | None = None) -> None:
        marks = received("depth", info)
        try:
            depth = decode_depth(msg)
        except ImageFormatError as error:
            self.reject("bad_depth", str(error))
            return
        self.offer(self.synchronizer.add_b(stamp_ns(msg.header), DecodedImage(msg.header, depth, marks)))

    def offer(self, pair: Pair[DecodedImage, DecodedImage | None] | None) -> None:
        """Hand a paired frame to the scheduler (in place of any frame still waiting) and wake inference."""
        if pair is None:
            return
        rgb, depth = pair.a, pair.b
        trace = StageTrace(rgb.marks + (depth.marks if depth is not None else []))
        trace.mark("paired")
        self.scheduler.offer(Frame(pair.stamp_ns, rgb.header, rgb.pixels, None if depth is None else depth.pixels,
                                   trace))
        self.inference_due.trigger()

    def on_command(self, msg: NavigationCommand) -> None:
        try:
            option = parse_road_option(msg.command)
        except ValueError as error:
            self.reject("bad_command", f"{error}; keeping {self.scheduler.command.name}")
            return
        self.serve(self.scheduler.on_command(Command(option, stamp_ns(msg.header))))

    # --- inference (guard condition and release timer callbacks) ------------------------------
    def run_inference(self) -> None:
        self.serve(self.scheduler.take(time.monotonic()))

    def release_overdue(self) -> None:
        """Serve a frame whose command did not come within command_wait, with the latest command (counted)."""
        served = self.scheduler.release_overdue(time.monotonic())
        if served is not None:
            self.get_logger().warn(f"no command for a frame within command_wait: served with {served.command.name} "
                                   f"[total {self.scheduler.command_timeouts}]", throttle_duration_sec=1.0)
        self.serve(served)

    def serve(self, served: Served | None) -> None:
        """Infer `served` (nothing when None); a bad frame or a failed inference is counted, never raised."""
        if served is None:
            return
        try:
            self.infer(served)
        except ValueError as error:  # InvalidDepthError included
            self.reject("bad_frame", str(error))
        except Exception as error:  # noqa: BLE001 - a failed frame must not kill the node
            self.stats.drop("inference_error")
            self.get_logger().error(f"inference failed: {error!r}", throttle_duration_sec=1.0)

    def infer(self, served: Served) -> None:
        frame, command, trace = served.frame, served.command, served.frame.trace
        trace.mark("inference_start")
        started = time.perf_counter()
        header, live = frame.header, self.parameters.live
        inferred = infer_frame(self.model, frame.rgb, frame.depth, command, live.max_invalid_depth_fraction, trace.mark)
        prediction = inferred.prediction
        action = DrivingAction(steer=prediction.steer, target_speed=prediction.target_speed, command=int(command))
        action.header = header
        self.action_pub.publish(action)
        trace.mark("action_published")
        if prediction.class_ids is not None:
            self.segmentation_pub.publish(Image(header=header, **encode_image(prediction.class_ids, "mono8")))
            if live.publish_overlay:
                self.overlay_pub.publish(Image(header=header, **encode_image(
                    overlay(input_rgb(inferred.inputs), prediction.class_ids), "rgb8")))
        self.stats.served((time.perf_counter() - started) * 1e3,
                          (self.get_clock().now().nanoseconds - frame.stamp_ns) * 1e-6, inferred.depth_invalid_share)
        self.stage_times.publish(header.stamp, trace)

    # --- diagnostics --------------------------------------------------------------------------
    @property
    def compute_ms(self) -> deque[float]:
        """Compute times (ms) of the recent frames served (benchmarks/perception.py reads them)."""
        return self.stats.compute_ms

    def publish_diagnostics(self) -> None:
        report = self.stats.report(time.monotonic(), self.scheduler, self.synchronizer.dropped)
        level, message = (WARN, "dropping inputs") if report.dropping else (OK, "running")
        self.diagnostics_pub.publish(diagnostic_array(
            self.get_clock().now().to_msg(), "msfsu/perception", level, message, report.values))


def main(args=None) -> int:
    return run_node(PerceptionNode, args)
