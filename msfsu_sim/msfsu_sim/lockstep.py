"""One simulator frame out, the control that answers it back: the lockstep path shared by the sim_bridge
node and the closed-loop benchmark (which drives episodes itself instead of on a timer).

Each frame (sensors, odometry, navigation command, expert action, /clock) is published with the sim
time of the camera frame; a VehicleControl stamped with that time answers it. Sim time keeps running
forward across episodes (/clock never jumps back, so nodes on sim time need no reset).
"""

from __future__ import annotations

import array
import dataclasses
import time

import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from msfsu_common import topics
from msfsu_common.message_types import message_class
from msfsu_common.transport import SENSOR_QUEUE_DEPTH
from msfsu_interfaces.msg import VehicleControl
from msfsu_sim.environment import STEP_S, Observation, SimEnvironment
from msfsu_sim.expert import Expert
from msfsu_sim.messages import TYPES, MessageBuilder

HOLD_STILL = (0.0, 0.0, 1.0)  # steer, throttle, brake until a control arrives


def _pack(values: np.ndarray) -> object:
    """uint8 sequences as array.array (rclpy's fast path); fixed float arrays stay numpy."""
    return array.array("B", values.tobytes()) if values.dtype == np.uint8 else values


class LockstepLink:
    """Publishers and the control subscription of a simulator node (`node` owns them)."""

    def __init__(self, node: Node, environment: SimEnvironment, qos_depth: int = SENSOR_QUEUE_DEPTH,
                 expert_actions: bool = True) -> None:
        """`expert_actions`: publish the expert's action for every frame (the label; `sim_expert` drives on it)."""
        self.environment = environment
        self.build = MessageBuilder(message_class, _pack)
        qos = QoSProfile(depth=qos_depth, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        frame_topics = (topics.CLOCK, topics.RGB, topics.DEPTH, topics.SEMANTIC_IDS, topics.ODOMETRY,
                        topics.NAVIGATION_COMMAND, topics.EXPERT_ACTION)
        self.publishers = {topic: node.create_publisher(message_class(TYPES[topic]), topic, qos)
                           for topic in frame_topics}
        self.route_pub = node.create_publisher(message_class(TYPES[topics.ROUTE]), topics.ROUTE, latched)
        node.create_subscription(VehicleControl, topics.VEHICLE_CONTROL, self.on_control, qos)
        self.expert = Expert() if expert_actions else None
        self.control = HOLD_STILL
        self.control_stamp_s: float | None = None  # stamp of the control in effect (None: none this episode)
        self.control_received = time.monotonic()  # wall time the last control arrived (or the episode started)
        self.controls_received = 0  # VehicleControl messages taken, ever
        self.answered = False
        self.frame_time_s = 0.0
        self.episode_start_s = 0.0
        self.frame_published = time.monotonic()
        self.time_offset = 0.0

    def shifted(self, obs: Observation) -> Observation:
        """The observation on the link's clock (episode time + the time of the episodes before)."""
        return dataclasses.replace(obs, time_s=obs.time_s + self.time_offset)

    def start_episode(self, obs: Observation) -> None:
        """Publish the new episode's route (latched) and first frame; `obs` as the environment returned it."""
        if self.expert is not None:
            self.expert.reset()
        self.control, self.control_stamp_s = HOLD_STILL, None
        shifted = self.shifted(obs)
        self.episode_start_s, self.control_received = shifted.time_s, time.monotonic()
        self.route_pub.publish(self.build.route(shifted.time_s, self.environment.route))
        self.publish_frame(obs)

    def end_episode(self, last: Observation) -> None:
        """The next episode's clock starts one step after the last frame of this one."""
        self.time_offset = self.shifted(last).time_s + STEP_S

    def publish_frame(self, obs: Observation) -> None:
        """The frame's sensors first, then the expert's action (its look at the scene takes several ms in traffic)."""
        obs = self.shifted(obs)
        for topic, message in self.build.sensors(obs).items():
            self.publishers[topic].publish(message)
        if self.expert is not None:
            action = self.expert.act_on(obs, self.environment)
            self.publishers[topics.EXPERT_ACTION].publish(self.build.driving_action(obs.time_s, action))
        self.frame_time_s = obs.time_s
        self.frame_published = time.monotonic()
        self.answered = False

    def on_control(self, msg: VehicleControl) -> None:
        self.controls_received += 1
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if stamp < self.episode_start_s - STEP_S / 2:
            return  # late for an episode that ended: it must not drive the next one
        steer = float(msg.steer)
        self.control = (steer, 0.0, 1.0) if msg.hand_brake else (steer, float(msg.throttle), float(msg.brake))
        self.control_stamp_s, self.control_received = stamp, time.monotonic()
        if abs(stamp - self.frame_time_s) < STEP_S / 2:
            self.answered = True

    def control_age_s(self) -> float | None:
        """Sim time from the control in effect to the current frame (0: it answers this frame; None: no control)."""
        return None if self.control_stamp_s is None else max(0.0, self.frame_time_s - self.control_stamp_s)

    def waited_s(self) -> float:
        """Wall time since the current frame was published."""
        return time.monotonic() - self.frame_published
