"""perception node: RGB + depth (+ navigation command) -> DrivingAction and segmentation.

Per frame it publishes the action first (nothing delays it), then, while something subscribes to
topics.SEGMENTATION_DEPTH (the emergency brake), the camera's depth at the centre of each segmentation pixel there,
then the segmentation and the overlay. Measured (benchmarks/soak/aeb): the brake's inputs published before the action
delayed the action by as much as the aeb node's wait for them saves.

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

A managed (lifecycle) node, driven through its lifecycle_msgs services (the launcher does it for its profiles):
configure loads, compiles and warms up the network and makes the publishers (a network that cannot be used leaves
the node unconfigured, the one-line reason logged and in /diagnostics); activate subscribes to the command and the
cameras and lets the publishers publish; deactivate unsubscribes and drops the frames waiting; cleanup releases the
network; shutdown (also on SIGINT / SIGTERM, msfsu_common.node_runner) releases everything. /diagnostics reports
the state in every state. The overlay is drawn on the network's input (the cropped, resized camera image) at its
size, the size of the segmentation: what the network saw and answered, pixel for pixel.
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
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from sensor_msgs.msg import Image

from msfsu_common import topics
from msfsu_common.camera_geometry import depth_at_crop_pixels
from msfsu_common.diagnostics import ERROR, OK, WARN, diagnostic_array
from msfsu_common.image_codec import ImageFormatError, decode_depth, decode_rgb, encode_image
from msfsu_common.message_types import stamp_ns
from msfsu_common.node_runner import StartupError, run_node
from msfsu_common.params import NodeParameters, retime
from msfsu_common.reset import offer_reset
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
    publish_overlay: bool = setting(False, "also publish an rgb8 colour overlay of the segmentation on the network's "
                                    "input, at its size (as /msfsu/segmentation)")
    publish_stage_times: bool = setting(False, "publish each served frame's stage times on /msfsu/stage_times")
    diagnostics_period: float = setting(1.0, "diagnostics period, s", 0.05, 60.0)


def load_network(startup: PerceptionStartup) -> tuple[DrivingModel, float]:
    """The network the read-only parameters name, loaded, compiled and warmed up by one inference (which allocates
    and compiles: several times a frame's time), and that inference's ms; StartupError with the one-line reason."""
    checkpoint, backend, precision, device = startup.checkpoint, startup.backend, startup.precision, startup.device
    if not checkpoint:
        raise StartupError("parameter 'checkpoint' is required (path to an MSFSU checkpoint)")
    try:
        model = DrivingModel.from_checkpoint(checkpoint, num_threads=startup.num_threads or None, backend=backend,
                                             precision=precision, device=device)
    except CheckpointError as error:
        raise StartupError(f"cannot use checkpoint '{checkpoint}': {error}") from error
    except (BackendUnavailableError, ValueError) as error:
        raise StartupError(f"cannot run '{checkpoint}' on {backend}/{precision} (device {device}): {error}") from error
    preprocess = model.preprocess
    started = time.perf_counter()
    model.predict(np.zeros((preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32),
                  RoadOption.LANE_FOLLOW)
    return model, (time.perf_counter() - started) * 1e3


class PerceptionNode(LifecycleNode):
    """The perception node, a managed (lifecycle) node (module doc: what each transition does).

    `autostart` (in-process users: tests, benchmarks) configures and activates it in the constructor and raises
    StartupError with the reason when it cannot configure; the `perception` executable starts it unconfigured, for
    the launcher or a ROS 2 tool (`ros2 lifecycle set /perception configure`) to drive.
    """

    def __init__(self, parameter_overrides: list[Parameter] | None = None, *, autostart: bool = True) -> None:
        super().__init__("perception", parameter_overrides=parameter_overrides or [])
        self.parameters = NodeParameters(self, live=PerceptionSettings, read_only=PerceptionStartup,
                                         apply=self.apply_settings)
        settings = self.parameters.live
        self.model: DrivingModel | None = None  # loaded by configure, released by cleanup and shutdown
        self.configure_error: str | None = None  # why the last configure failed (None: it did not)
        self.stage_times = StageTimesPublisher(self, settings.publish_stage_times)
        # reported in every state: the diagnostics publisher and timer are the node's own, not the lifecycle's
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.diagnostics_timer = self.create_timer(settings.diagnostics_period, self.publish_diagnostics)
        self._sensor_subscriptions: list[Subscription] = []  # while active
        offer_reset(self, self.forget)
        if autostart:
            self.start()

    def forget(self) -> str:
        """A new stream without a transition: the frames waiting for a pair or a command and the latest command are
        forgotten, as after deactivate and activate (the network and the counters stay)."""
        if self.model is None:
            return "nothing to forget: no network configured"
        self.scheduler.clear()
        self.synchronizer.clear()
        return "waiting frames and the latest command forgotten"

    def start(self) -> None:
        """Configure and activate in-process (no lifecycle manager); StartupError with the reason if it cannot."""
        if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            reason = self.configure_error or "configure failed"
            self.destroy_node()
            raise StartupError(reason)
        self.trigger_activate()

    def destroy_node(self) -> None:
        """rclpy's LifecycleNode (Jazzy) leaves its state machine, and with it the node and its participant, alive
        after destroy_node (other participants keep seeing a `perception` with lifecycle services): destroyed here."""
        super().destroy_node()
        self._state_machine.destroy_when_not_in_use()

    @property
    def lifecycle_state(self) -> str:
        """The state's label: unconfigured, inactive, active, finalized (or a transition's, during it)."""
        return self._state_machine.current_state[1]

    # --- lifecycle transitions ------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Load, compile and warm up the network; make the frame pairing, scheduling, counters and publishers.
        A network that cannot be used leaves the node unconfigured, with the reason logged and in /diagnostics."""
        startup, settings = self.parameters.read_only, self.parameters.live
        try:
            self.model, warm_up_ms = load_network(startup)
        except Exception as error:  # noqa: BLE001 - any reason is one line and an unconfigured node, never a crash
            self.configure_error = str(error) if isinstance(error, StartupError) else f"{startup.checkpoint}: {error!r}"
            self.get_logger().error(f"cannot configure: {self.configure_error}")
            return TransitionCallbackReturn.FAILURE
        self.configure_error = None
        self.synchronizer: ApproximateTimeSynchronizer[DecodedImage, DecodedImage] = ApproximateTimeSynchronizer(
            queue_size=startup.sync_queue_size, slop_ns=int(settings.sync_slop * 1e9))
        self.scheduler = FrameScheduler(settings.command_wait)
        self.stats = FrameStats(time.monotonic())
        self.action_pub = self.create_lifecycle_publisher(DrivingAction, topics.DRIVING_ACTION, 10)
        self.segmentation_pub = self.create_lifecycle_publisher(Image, topics.SEGMENTATION, 5)
        self.segmentation_depth_pub = self.create_lifecycle_publisher(Image, topics.SEGMENTATION_DEPTH, 5)
        self.overlay_pub: Publisher | None = None  # made the first time publish_overlay is on
        self.follow_overlay(settings.publish_overlay)
        self.inference_due = self.create_guard_condition(self.run_inference)
        # on the wall clock: sim time stands still while the simulator waits for the graph; period: follow_command_wait
        self.release_timer = self.create_timer(1.0, self.release_overdue, clock=Clock(clock_type=ClockType.STEADY_TIME),
                                               autostart=False)
        preprocess = self.model.preprocess
        self.get_logger().info(f"configured: loaded {startup.checkpoint}: input {preprocess.channels}x"
                               f"{preprocess.input_height}x{preprocess.input_width}, segmentation="
                               f"{self.model.has_segmentation}, {self.model.device} {self.model.backend}/"
                               f"{self.model.precision}, warm-up inference {warm_up_ms:.0f} ms")
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Subscribe to the command and the cameras; the publishers go live (the lifecycle's own on_activate)."""
        startup = self.parameters.read_only
        sensor_qos = QoSProfile(
            depth=startup.sensor_queue_depth,
            reliability=ReliabilityPolicy.BEST_EFFORT if startup.sensor_reliability == "best_effort"
            else ReliabilityPolicy.RELIABLE,
        )
        # the command first: an executor takes the ready subscriptions in the order they were made, so a frame and the
        # command sent before it that wait together are taken command first (and inference, a guard condition, after
        # both)
        self._sensor_subscriptions = [
            self.create_subscription(NavigationCommand, topics.NAVIGATION_COMMAND, self.on_command, 10),
            self.create_subscription(Image, topics.RGB, lambda msg, info: self.on_rgb(msg, info), sensor_qos)]
        if self.model.preprocess.use_depth:
            self._sensor_subscriptions.append(
                self.create_subscription(Image, topics.DEPTH, lambda msg, info: self.on_depth(msg, info), sensor_qos))
        result = super().on_activate(state)
        self.follow_command_wait(self.parameters.live.command_wait)
        self.get_logger().info("active: subscribed to the command and the cameras")
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Unsubscribe; frames waiting or held are dropped, unserved (what comes after a new activation is a new
        stream); the publishers fall silent."""
        self._unsubscribe()
        self.get_logger().info("inactive: unsubscribed, the network stays loaded")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Release the network and everything configure made: back to unconfigured."""
        self._release()
        self.get_logger().info("unconfigured: the network is released")
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """From any state: unsubscribe and release; the node is finalized (it keeps reporting that until its process
        ends)."""
        self._unsubscribe()
        self._release()
        self.get_logger().info("finalized")
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised (a bug): release what there is and go back to unconfigured, which a new configure
        can leave."""
        self.get_logger().error(f"a transition from {state.label} failed: releasing the network")
        self._unsubscribe()
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def _unsubscribe(self) -> None:
        for subscription in self._sensor_subscriptions:
            self.destroy_subscription(subscription)
        self._sensor_subscriptions = []
        if self.model is not None:
            self.release_timer.cancel()
            self.forget()

    def _release(self) -> None:
        if self.model is None:
            return
        for publisher in (self.action_pub, self.segmentation_pub, self.segmentation_depth_pub, self.overlay_pub):
            if publisher is not None:
                self.destroy_lifecycle_publisher(publisher)
        self.destroy_guard_condition(self.inference_due)
        self.destroy_timer(self.release_timer)
        self.model = None

    # --- live parameters (msfsu_common.params) --------------------------------------------------
    def apply_settings(self, settings: PerceptionSettings) -> None:
        """New parameters in force: the next frame, pair, command wait and diagnostics use them (whatever the state:
        a node configured later starts with them)."""
        self.stage_times.enabled = settings.publish_stage_times
        retime(self.diagnostics_timer, settings.diagnostics_period)
        if self.model is not None:
            self.synchronizer.slop_ns = int(settings.sync_slop * 1e9)
            self.follow_command_wait(settings.command_wait)
            self.follow_overlay(settings.publish_overlay)

    def follow_command_wait(self, wait_s: float) -> None:
        """The scheduler holds frames for `wait_s`; the release timer checks every quarter of it while it is > 0 and
        the node is active."""
        if wait_s > 0 and self._sensor_subscriptions:
            retime(self.release_timer, wait_s / 4)
        else:
            self.release_timer.cancel()
        self.serve(self.scheduler.set_command_wait(wait_s))

    def follow_overlay(self, enabled: bool) -> None:
        if enabled and self.overlay_pub is None:
            self.overlay_pub = self.create_lifecycle_publisher(Image, topics.SEGMENTATION_OVERLAY, 5)
            if self._sensor_subscriptions:  # made while active: live at once, as the others went at activation
                self.overlay_pub.on_activate(None)

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
        class_ids = prediction.class_ids
        self.action_pub.publish(action)
        trace.mark("action_published")
        if class_ids is not None:  # after the action: nothing delays it (the brake waits for these, input_wait)
            if frame.depth is not None and self.segmentation_depth_pub.get_subscription_count():
                self.segmentation_depth_pub.publish(Image(header=header, **encode_image(depth_at_crop_pixels(
                    frame.depth, self.model.preprocess.crop_top_fraction, class_ids.shape), "32FC1")))
            self.segmentation_pub.publish(Image(header=header, **encode_image(class_ids, "mono8")))
            if live.publish_overlay:
                self.overlay_pub.publish(Image(header=header, **encode_image(
                    overlay(input_rgb(inferred.inputs), class_ids), "rgb8")))
        self.stats.served((time.perf_counter() - started) * 1e3,
                          (self.get_clock().now().nanoseconds - frame.stamp_ns) * 1e-6, inferred.depth_invalid_share)
        self.stage_times.publish(header.stamp, trace)

    # --- diagnostics --------------------------------------------------------------------------
    @property
    def compute_ms(self) -> deque[float]:
        """Compute times (ms) of the recent frames served (benchmarks/perception.py reads them)."""
        return self.stats.compute_ms

    def publish_diagnostics(self) -> None:
        """The status `msfsu/perception`: the lifecycle state, and once configured the frame counters. Active:
        OK "running", WARN "dropping inputs"; inactive: OK; unconfigured or finalized: WARN, ERROR with the reason
        after a failed configure."""
        state = self.lifecycle_state
        values: dict[str, object] = {"lifecycle_state": state}
        if self.model is not None:
            report = self.stats.report(time.monotonic(), self.scheduler, self.synchronizer.dropped)
            values.update(report.values)
            level, message = (WARN, "dropping inputs") if report.dropping else (OK, "running")
            if state != "active":
                level, message = OK, f"{state}: configured, not subscribed"
        elif self.configure_error is not None:
            level, message = ERROR, f"{state}: configure failed: {self.configure_error}"
        else:
            level, message = WARN, f"{state}: no network loaded"
        self.diagnostics_pub.publish(diagnostic_array(
            self.get_clock().now().to_msg(), "msfsu/perception", level, message, values))


def main(args=None) -> int:
    return run_node(lambda: PerceptionNode(autostart=False), args)
