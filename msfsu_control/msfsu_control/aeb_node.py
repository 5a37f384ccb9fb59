"""aeb node: the emergency brake between perception and control (a thin adapter over msfsu_control.aeb).

It takes the network's DrivingAction (topics.NETWORK_ACTION: profiles with aeb on remap perception's output there),
the network's segmentation and the camera's depth at its pixels (topics.SEGMENTATION_DEPTH, from perception) of the
same frame and the odometry, and sends the action on to the control (topics.DRIVING_ACTION) with its target speed
capped or set to 0 while it intervenes: one action out per action in, same stamp, so lockstep and the control's
watchdog work as without it. It publishes what it did on topics.AEB_INTERVENTION while it intervenes (and once when
it lets go) and its counts on /diagnostics.

Why between perception and control (on the action) and not after the control (on VehicleControl): the control's PID
already turns a target speed below its stop speed into a full brake, its steer rate limit and watchdog stay the one
place that writes the vehicle's command, and the data flow stays one way (sensors -> network -> DrivingAction -> PID
-> VehicleControl).

Perception publishes the frame's depth samples and segmentation just after its action (the camera's full depth
image goes to perception only, not to a second process): an action waits for both up to `input_wait` seconds of wall
time (lockstep: the frame's own, however busy the machine is), then is judged without what is missing (a counted
drop: msfsu_control.aeb's fail-safe rule). The odometry of the frame arrives before the network has inferred it.
Where the depth samples come from, the aeb node needs the camera's image size (only its aspect enters the geometry),
lens, mount and the network's crop: read-only parameters, defaults the simulator's front camera. A jump of the car's
position by more than RESTART_JUMP_M between two odometry messages is a new start (the simulator's next episode):
the brake's state is reset, so no decision of one episode carries into the next.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from msfsu_common import topics
from msfsu_common.camera_geometry import FrontCamera
from msfsu_common.diagnostics import ERROR, OK, WARN, diagnostic_array
from msfsu_common.image_codec import ImageFormatError, decode_depth, decode_mono8
from msfsu_common.message_types import stamp_ns, yaw_of
from msfsu_common.node_runner import run_node
from msfsu_common.params import NodeParameters
from msfsu_common.reset import offer_reset
from msfsu_common.settings import setting
from msfsu_common.stage_times import StageTimesPublisher, StageTrace, received
from msfsu_control.aeb import BRAKE, CAP, NONE, AebConfig, Decision, EmergencyBrake
from msfsu_control.control_node import planar_speed
from msfsu_interfaces.msg import AebIntervention, DrivingAction

KEPT_FRAMES = 8  # segmentations and depth images kept by stamp, newest last
# the car's position jumping this far between two odometry messages is a new start (a simulator's next episode, a
# relocalised vehicle), not driving: the brake's memory of the scene (its decision held, the gaps it tracked) goes
RESTART_JUMP_M = 10.0
DROP_ERROR_SHARE = 0.5  # diagnostics ERROR while more than this share of the recent frames were dropped
RECENT_FRAMES = 50


@dataclass(frozen=True)
class AebSettings:
    """The aeb node's live parameters."""

    enabled: bool = setting(True, "intervene (false: judge and report, but pass every action through unchanged)")
    input_wait: float = setting(0.1, "wall seconds an action waits for its frame's segmentation and depth", 0.0, 5.0)
    publish_stage_times: bool = setting(False, "publish each action's stage times on /msfsu/stage_times")
    brake: AebConfig = field(default_factory=AebConfig)


@dataclass(frozen=True)
class AebCamera:
    """Where the camera whose depth and crop the AEB reads sits (read-only; defaults: the simulator's front camera)."""

    camera_width_px: int = setting(400, "camera image width, pixels", 1, 100000)
    camera_height_px: int = setting(300, "camera image height, pixels", 1, 100000)
    camera_fov_deg: float = setting(80.0, "horizontal field of view, degrees", 10.0, 179.0)
    camera_forward_m: float = setting(1.0, "camera ahead of the car's centre, m", -10.0, 10.0)
    camera_right_m: float = setting(0.0, "camera right of the car's centre line, m", -5.0, 5.0)
    camera_height_m: float = setting(2.095, "camera above the road, m", 0.1, 10.0)
    camera_pitch_deg: float = setting(-2.0, "camera pitch, degrees (negative: down)", -89.0, 89.0)
    crop_top_fraction: float = setting(0.5, "rows the network's crop removes from the top (its checkpoint's)", 0.0, 0.95)


def camera_parameters(camera: FrontCamera) -> dict[str, int | float]:
    """The aeb node's read-only camera parameters for `camera` (what the profiles' `aeb_camera` argument takes; the
    crop is the network's, given apart)."""
    return {"camera_width_px": camera.width, "camera_height_px": camera.height, "camera_fov_deg": camera.fov_deg,
            "camera_forward_m": camera.forward_m, "camera_right_m": camera.right_m, "camera_height_m": camera.up_m,
            "camera_pitch_deg": camera.pitch_deg}


class AebNode(Node):
    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__("aeb", parameter_overrides=parameter_overrides or [])
        self.parameters = NodeParameters(self, live=AebSettings, read_only=AebCamera, apply=self.apply_settings)
        self.brake = EmergencyBrake(self.parameters.live.brake)
        camera = self.parameters.read_only  # read-only: the view is made once
        self.view = FrontCamera(camera.camera_width_px, camera.camera_height_px, camera.camera_fov_deg,
                                camera.camera_forward_m, camera.camera_right_m, camera.camera_height_m,
                                camera.camera_pitch_deg).view(camera.crop_top_fraction, 0, 0)
        self.stage_times = StageTimesPublisher(self, self.parameters.live.publish_stage_times)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.action_pub = self.create_publisher(DrivingAction, topics.DRIVING_ACTION, qos)
        self.intervention_pub = self.create_publisher(AebIntervention, topics.AEB_INTERVENTION, 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.restarts = 0
        self.published = self.interventions = self.bad_messages = 0
        self.forget()
        # odometry first, as the control node: an action and its frame's odometry waiting together take the odometry
        self.create_subscription(Odometry, topics.ODOMETRY, self.on_odometry, qos)
        self.create_subscription(Image, topics.SEGMENTATION_DEPTH, self.on_depth, qos)
        self.create_subscription(Image, topics.SEGMENTATION, self.on_segmentation, qos)
        self.create_subscription(DrivingAction, topics.NETWORK_ACTION, lambda msg, info: self.on_action(msg, info), qos)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.wait_timer = self.create_timer(0.01, self.release_overdue, clock=steady, autostart=False)
        self.create_timer(1.0, self.publish_diagnostics, clock=steady)
        offer_reset(self, self.forget)

    def forget(self) -> str:
        """A new start: the brake's tracks and decision, the car's pose and speed, and the frames waiting, forgotten
        (the counters stay)."""
        self.brake.reset()
        self.speed = 0.0
        self.position: tuple[float, float] | None = None
        self.yaw: float | None = None  # counter-clockwise from the odometry frame's x (the brake's crossing tracks)
        self.segmentations: OrderedDict[int, object] = OrderedDict()  # stamp ns -> class ids
        self.depths: OrderedDict[int, object] = OrderedDict()  # stamp ns -> metres at the segmentation's pixels
        # stamp -> (action, wall arrival, its stage marks)
        self.pending: OrderedDict[int, tuple[DrivingAction, float, StageTrace]] = OrderedDict()
        self.last_kind = NONE
        self.recent_drops: list[bool] = []
        return "tracks, pose, speed and waiting frames forgotten"

    def apply_settings(self, settings: AebSettings) -> None:
        self.brake.config = settings.brake
        self.stage_times.enabled = settings.publish_stage_times

    # ----- inputs -----
    def on_odometry(self, msg: Odometry) -> None:
        speed = planar_speed(msg)
        if math.isfinite(speed):
            self.speed = speed
        position = (msg.pose.pose.position.x, msg.pose.pose.position.y)
        if not all(map(math.isfinite, position)):
            return
        yaw = yaw_of(msg.pose.pose.orientation)
        self.yaw = yaw if math.isfinite(yaw) else None
        if self.position is not None and math.dist(position, self.position) > RESTART_JUMP_M:
            self.brake.reset()  # a new start: nothing of the last scene carries over
            self.restarts += 1
            self.get_logger().info(f"the car moved {math.dist(position, self.position):.0f} m between two odometry "
                                   "messages: a new start, the brake's state reset")
        self.position = position

    def _keep(self, store: OrderedDict, stamp: int, value: object) -> None:
        store[stamp] = value
        while len(store) > KEPT_FRAMES:
            store.popitem(last=False)

    def on_depth(self, msg: Image) -> None:
        try:
            self._keep(self.depths, stamp_ns(msg.header), decode_depth(msg))
        except ImageFormatError as error:
            self._bad(f"depth samples dropped: {error}")
            return
        self.serve_ready()

    def on_segmentation(self, msg: Image) -> None:
        try:
            self._keep(self.segmentations, stamp_ns(msg.header), decode_mono8(msg))
        except ImageFormatError as error:
            self._bad(f"segmentation dropped: {error}")
            return
        self.serve_ready()

    def _bad(self, text: str) -> None:
        self.bad_messages += 1
        self.get_logger().warn(f"{text}; total {self.bad_messages}", throttle_duration_sec=5.0)

    def on_action(self, msg: DrivingAction, info: Mapping[str, Any] | None = None) -> None:
        trace = StageTrace(received("network_action", info))
        if not (math.isfinite(msg.steer) and math.isfinite(msg.target_speed)):
            self._bad("non-finite DrivingAction passed on for the control to reject")
            self.action_pub.publish(msg)
            return
        self.pending[stamp_ns(msg.header)] = (msg, time.monotonic(), trace)
        self.serve_ready()
        if self.pending and self.wait_timer.is_canceled():
            self.wait_timer.reset()

    def ready(self, stamp: int) -> bool:
        return stamp in self.segmentations and stamp in self.depths

    def serve_ready(self) -> None:
        """Serve the waiting actions in stamp order while the oldest has its segmentation and depth."""
        while self.pending:
            stamp = next(iter(self.pending))
            if not self.ready(stamp):
                return
            action, _, trace = self.pending.pop(stamp)
            self.serve(action, stamp, trace)
        self.wait_timer.cancel()

    def release_overdue(self) -> None:
        """Actions that waited input_wait for their segmentation and depth are judged without what is missing (a
        counted drop)."""
        wait = self.parameters.live.input_wait
        while self.pending:
            stamp, (action, arrived, trace) = next(iter(self.pending.items()))
            if self.ready(stamp):
                self.serve_ready()
                return
            if time.monotonic() - arrived < wait:
                return
            self.pending.pop(stamp)
            self.serve(action, stamp, trace)
        self.wait_timer.cancel()

    # ----- the decision -----
    def serve(self, action: DrivingAction, stamp: int, trace: StageTrace) -> None:
        trace.mark("aeb_inputs_ready")
        segmentation, depth = self.segmentations.get(stamp), self.depths.get(stamp)
        pose = None if self.position is None or self.yaw is None else (*self.position, self.yaw)
        decision = self.brake.step(stamp * 1e-9, float(action.target_speed), float(action.steer), self.speed,
                                   segmentation, depth, self.view, pose)
        live = self.parameters.live
        out = DrivingAction(header=action.header, steer=action.steer, command=action.command,
                            target_speed=decision.target_speed if live.enabled else action.target_speed)
        self.action_pub.publish(out)
        trace.mark("aeb_published")
        self.stage_times.publish(action.header.stamp, trace)
        self.published += 1
        self.recent_drops = (self.recent_drops + [bool(decision.dropped)])[-RECENT_FRAMES:]
        if decision.kind != NONE or self.last_kind != NONE:
            self.publish_intervention(action, decision)
        if decision.kind != NONE and self.last_kind == NONE:
            self.interventions += 1
            self.get_logger().info(f"{decision.kind}: {decision.reason}, gap {decision.gap_m:.1f} m, "
                                   f"time to collision {decision.ttc_s:.1f} s")
        self.last_kind = decision.kind

    def publish_intervention(self, action: DrivingAction, decision: Decision) -> None:
        self.intervention_pub.publish(AebIntervention(
            header=action.header, decision=decision.kind, reason=decision.reason, gap_m=decision.gap_m,
            ttc_s=decision.ttc_s, obstacle_pixels=decision.pixels, target_speed_in=action.target_speed,
            target_speed_out=decision.target_speed, dropped=decision.dropped))

    def publish_diagnostics(self) -> None:
        drops = self.brake.drops
        share = sum(self.recent_drops) / len(self.recent_drops) if self.recent_drops else 0.0
        if share > DROP_ERROR_SHARE:
            level, message = ERROR, f"blind: {share:.0%} of the last frames could not be judged (actions pass through)"
        elif self.last_kind in (CAP, BRAKE):
            level, message = WARN, f"intervening: {self.last_kind} ({self.brake.reason})"
        else:
            level, message = OK, "watching" if self.parameters.live.enabled else "watching, not intervening (enabled false)"
        self.diagnostics_pub.publish(diagnostic_array(
            self.get_clock().now().to_msg(), "msfsu/aeb", level, message,
            {"actions": self.published, "interventions": self.interventions, "state": self.brake.state,
             **{f"frames_{kind}": count for kind, count in self.brake.decisions.items()},
             **{f"dropped_{reason}": count for reason, count in drops.items()}, "bad_messages": self.bad_messages,
             "restarts": self.restarts}))


def main(args=None) -> int:
    return run_node(AebNode, args)
