"""control node: DrivingAction + Odometry -> VehicleControl (PID on speed), with a watchdog.

A control is published for every DrivingAction (same stamp, so a lockstep simulator knows which
frame it answers), as the stack's VehicleControl on /msfsu/vehicle_control and as carla-ros-bridge's
carla_msgs/CarlaEgoVehicleControl on /carla/<role>/vehicle_control_cmd, which drives a CARLA car (`output`: both,
or only one of them). The watchdog brakes (throttle 0, brake 1) whenever the action or the odometry
is older than `watchdog_timeout` on the node clock (sim time when use_sim_time is set), from the first action on:
before it, the node has sent nothing the car could still be acting on, and a brake stamped with the clock's time would
answer a lockstep simulator's frame in the network's place. Every brake it sends (`watchdog_brakes`) is one a running
graph should never need. `~/reset` (msfsu_common.reset) forgets the controller's state, the inputs' times and the
first action, as at the node's start. With `publish_stage_times` each control's stage times go to /msfsu/stage_times
(msfsu_common.stage_times).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from carla_msgs.msg import CarlaEgoVehicleControl
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.time import Time

from msfsu_common import topics
from msfsu_common.diagnostics import ERROR, OK, diagnostic_array
from msfsu_common.message_types import stamp_ns
from msfsu_common.node_runner import run_node
from msfsu_common.params import NodeParameters, retime
from msfsu_common.reset import offer_reset
from msfsu_common.settings import setting
from msfsu_common.stage_times import StageTimesPublisher, StageTrace, received
from msfsu_control.pid import ActionController, InvalidActionError, SpeedControlConfig, check_action
from msfsu_interfaces.msg import DrivingAction, VehicleControl


def planar_speed(odometry: Odometry) -> float:
    velocity = odometry.twist.twist.linear
    return math.hypot(velocity.x, velocity.y)


OUTPUTS = {"msfsu": ((VehicleControl, topics.VEHICLE_CONTROL),),
           "carla": ((CarlaEgoVehicleControl, topics.CARLA_VEHICLE_CONTROL),)}
OUTPUTS["both"] = OUTPUTS["msfsu"] + OUTPUTS["carla"]


@dataclass(frozen=True)
class ControlStartup:
    """The control node's read-only parameter: what its control is sent as."""

    output: str = setting("both", "send the control as both, msfsu (msfsu_interfaces/VehicleControl on "
                          "/msfsu/vehicle_control) or carla (carla_msgs/CarlaEgoVehicleControl on "
                          "/carla/ego_vehicle/vehicle_control_cmd, which carla-ros-bridge applies)",
                          choices=tuple(OUTPUTS))


@dataclass(frozen=True)
class ControlSettings:
    """The control node's parameters, all live: the controller's, its watchdog's and stage-time publishing."""

    speed: SpeedControlConfig = field(default_factory=SpeedControlConfig)
    max_steer_rate: float = setting(0.0, "max steer change per second (0: off)", 0.0, 100.0)
    watchdog_timeout: float = setting(0.5, "brake if action or odometry is older than this, s", 0.01, 60.0)
    publish_stage_times: bool = setting(False, "publish each control's stage times on /msfsu/stage_times")


class ControlNode(Node):
    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__("control", parameter_overrides=parameter_overrides or [])
        self.parameters = NodeParameters(self, live=ControlSettings, read_only=ControlStartup,
                                         apply=self.apply_settings)
        settings = self.parameters.live
        self.controller = ActionController(settings.speed, settings.max_steer_rate)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.control_pubs = [(message, self.create_publisher(message, topic, qos))
                             for message, topic in OUTPUTS[self.parameters.read_only.output]]
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.stage_times = StageTimesPublisher(self, settings.publish_stage_times)
        # odometry first: an executor takes the ready subscriptions in the order they were made, so an action and the
        # odometry of its frame that wait together are taken odometry first (the speed of that frame, not the one before)
        self.create_subscription(Odometry, topics.ODOMETRY, self.on_odometry, qos)
        self.create_subscription(DrivingAction, topics.DRIVING_ACTION, lambda msg, info: self.on_action(msg, info), qos)
        self.watchdog = self.create_timer(settings.watchdog_timeout / 2.0, self.check_watchdog)
        self.published = 0
        self.watchdog_brakes = 0
        self.rejected_actions = 0
        self.forget()
        offer_reset(self, self.forget)

    def forget(self) -> str:
        """The state of a new start: no speed, no input seen, the controller at rest (the watchdog waits for an
        action)."""
        self.controller.reset()
        self.speed: float | None = None
        self.odometry_time: Time | None = None
        self.action_time: Time | None = None  # None: no valid action since the start; the watchdog is not armed
        self.last_action_stamp: int | None = None  # ns
        return "controller, odometry and action forgotten; the watchdog waits for the next action"

    def apply_settings(self, settings: ControlSettings) -> None:
        """New parameters in force: the next action and the next watchdog check use them."""
        self.controller.configure(settings.speed, settings.max_steer_rate)
        retime(self.watchdog, settings.watchdog_timeout / 2.0)
        self.stage_times.enabled = settings.publish_stage_times

    def on_odometry(self, msg: Odometry) -> None:
        speed = planar_speed(msg)
        if not math.isfinite(speed):
            self.get_logger().warn("odometry with non-finite velocity dropped", throttle_duration_sec=5.0)
            return
        self.speed = speed
        self.odometry_time = self.get_clock().now()

    def on_action(self, msg: DrivingAction, info: Mapping[str, Any] | None = None) -> None:
        trace = StageTrace(received("action", info))
        try:
            check_action(msg.steer, msg.target_speed)
        except InvalidActionError as error:  # before it counts as fresh: garbage must not feed the watchdog
            self.rejected_actions += 1
            self.get_logger().error(f"{error}: dropped; total {self.rejected_actions}", throttle_duration_sec=1.0)
            return
        self.action_time = self.get_clock().now()
        if self.speed is None or self.stale_inputs():
            self.brake(msg.header.stamp, "no fresh odometry")
            return
        stamp = stamp_ns(msg.header)
        dt = (stamp - self.last_action_stamp) * 1e-9 if self.last_action_stamp is not None else 0.0
        output = self.controller.step(msg.steer, msg.target_speed, self.speed, dt)  # inputs checked: finite
        self.last_action_stamp = stamp
        self.publish_control(msg.header.stamp, output.throttle, output.steer, output.brake)
        trace.mark("control_published")
        self.published += 1
        self.stage_times.publish(msg.header.stamp, trace)

    def publish_control(self, stamp, throttle: float, steer: float, brake: float) -> None:
        """One control, stamped `stamp`, as every message type of `output` (the same fields in each)."""
        for message, publisher in self.control_pubs:
            control = message(throttle=throttle, steer=steer, brake=brake)
            control.header.stamp = stamp
            publisher.publish(control)

    def stale_inputs(self) -> list[str]:
        """Names of the inputs older than the watchdog timeout (or never received)."""
        now = self.get_clock().now()
        timeout_ns = int(self.parameters.live.watchdog_timeout * 1e9)
        return [name for name, t in (("action", self.action_time), ("odometry", self.odometry_time))
                if t is None or (now - t).nanoseconds > timeout_ns]

    def check_watchdog(self) -> None:
        if self.action_time is None:
            self.publish_diagnostics(OK, "waiting for the first action")
            return
        stale = self.stale_inputs()
        if stale:
            self.brake(self.get_clock().now().to_msg(), f"no fresh {' and '.join(stale)}")
        else:
            self.publish_diagnostics(OK, "tracking")

    def brake(self, stamp, reason: str) -> None:
        """Safe stop: throttle 0, full brake, controller state reset so it restarts cleanly."""
        self.controller.reset()
        self.publish_control(stamp, 0.0, 0.0, 1.0)
        self.watchdog_brakes += 1
        self.get_logger().warn(f"watchdog: braking ({reason})", throttle_duration_sec=2.0)
        self.publish_diagnostics(ERROR, f"watchdog braking: {reason}")

    def publish_diagnostics(self, level: bytes, message: str) -> None:
        self.diagnostics_pub.publish(diagnostic_array(
            self.get_clock().now().to_msg(), "msfsu/control", level, message,
            {"published": self.published, "watchdog_brakes": self.watchdog_brakes,
             "rejected_actions": self.rejected_actions}))


def main(args=None) -> int:
    return run_node(ControlNode, args)
