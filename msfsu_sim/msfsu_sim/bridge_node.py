"""sim_bridge node: the embedded simulator on the ROS graph, stepped in lockstep (CARLA synchronous mode).

Each frame (sensors, odometry, navigation command, expert action, /clock) is published with the sim
time of the camera frame; the simulation advances when a VehicleControl stamped with that frame time
arrives, or after `control_timeout` seconds of wall time with the last control (so a dead controller
cannot stall the graph). Results therefore do not depend on CPU speed.
"""

from __future__ import annotations

import array
import dataclasses
import time

import numpy as np
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from msfsu_common import topics
from msfsu_common.message_types import message_class
from msfsu_common.node_runner import StartupError, run_node
from msfsu_common.params import declare
from msfsu_interfaces.msg import VehicleControl
from msfsu_sim.environment import STEP_S, Observation, SimConfig, SimEnvironment
from msfsu_sim.expert import Expert
from msfsu_sim.messages import TYPES, MessageBuilder
from msfsu_sim.scenarios import TOWNS, TRAFFIC, WEATHERS


def _pack(values: np.ndarray) -> object:
    """uint8 sequences as array.array (rclpy's fast path); fixed float arrays stay numpy."""
    return array.array("B", values.tobytes()) if values.dtype == np.uint8 else values


class SimBridge(Node):
    def __init__(self, environment: SimEnvironment | None = None,
                 parameter_overrides: list[Parameter] | None = None, context: Context | None = None) -> None:
        super().__init__("sim_bridge", parameter_overrides=parameter_overrides or [], context=context)
        self.town = declare(self, "town", "town_a", f"map: {', '.join(TOWNS)}")
        self.weather = declare(self, "weather", "clear_noon", f"weather: {', '.join(WEATHERS)}")
        self.traffic = declare(self, "traffic", "regular", f"traffic: {', '.join(TRAFFIC)}")
        self.seed = declare(self, "seed", 0, "seed of traffic and pedestrians (next episode: seed + 1)", 0, 2**31 - 1)
        width = declare(self, "width", 400, "camera width, px", 32, 1920)
        height = declare(self, "height", 300, "camera height, px", 32, 1080)
        self.control_timeout = declare(self, "control_timeout", 1.0,
                                       "step with the last control after this many wall seconds", 0.01, 60.0)
        qos_depth = declare(self, "qos_depth", 5, "queue depth of the reliable sensor publishers", 1, 100)
        for name, choices in (("town", TOWNS), ("weather", WEATHERS), ("traffic", TRAFFIC)):
            if getattr(self, name) not in choices:
                raise StartupError(f"unknown {name} '{getattr(self, name)}' (accepted: {', '.join(choices)})")

        self.build = MessageBuilder(message_class, _pack)
        qos = QoSProfile(depth=qos_depth, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        frame_topics = (topics.CLOCK, topics.RGB, topics.DEPTH, topics.SEMANTIC_IDS, topics.ODOMETRY,
                        topics.NAVIGATION_COMMAND, topics.EXPERT_ACTION)
        self.publishers_ = {topic: self.create_publisher(message_class(TYPES[topic]), topic, qos)
                            for topic in frame_topics}
        self.route_pub = self.create_publisher(message_class(TYPES[topics.ROUTE]), topics.ROUTE, latched)
        self.create_subscription(VehicleControl, topics.VEHICLE_CONTROL, self.on_control, qos)

        self.environment = environment or SimEnvironment(SimConfig(width=width, height=height))
        self.expert = Expert()
        self.control = (0.0, 0.0, 1.0)  # steer, throttle, brake: hold still until told otherwise
        self.answered = False
        self.lockstep_steps = 0
        self.timeout_steps = 0
        self.episode = 0
        self.time_offset = 0.0  # /clock keeps running forward across episodes
        self.start_episode()
        self.create_timer(0.002, self.tick)

    def start_episode(self) -> None:
        self.obs = self._shifted(self.environment.reset(self.town, self.weather, self.traffic,
                                                        self.seed + self.episode))
        self.expert.reset()
        self.route_pub.publish(self.build.route(self.obs.time_s, self.environment.route))
        self.publish_frame(self.obs)

    def _shifted(self, obs: Observation) -> Observation:
        return dataclasses.replace(obs, time_s=obs.time_s + self.time_offset)

    def publish_frame(self, obs: Observation) -> None:
        env = self.environment
        messages = self.build.sensors(obs)
        action = self.expert.act(obs.odometry, env.tracker, obs.command, env.obstacles(), STEP_S)
        messages[topics.EXPERT_ACTION] = self.build.driving_action(obs.time_s, action)
        for topic, message in messages.items():
            self.publishers_[topic].publish(message)
        self.frame_published = time.monotonic()
        self.answered = False

    def on_control(self, msg: VehicleControl) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        self.control = (float(msg.steer), float(msg.throttle), 0.0 if msg.hand_brake else float(msg.brake))
        if msg.hand_brake:
            self.control = (self.control[0], 0.0, 1.0)
        if abs(stamp - self.obs.time_s) < STEP_S / 2:
            self.answered = True

    def tick(self) -> None:
        timed_out = time.monotonic() - self.frame_published > self.control_timeout
        if not (self.answered or timed_out):
            return
        if self.answered:
            self.lockstep_steps += 1
        else:
            self.timeout_steps += 1
        self.obs = self._shifted(self.environment.step(*self.control))
        if self.obs.done:
            outcome = "arrived" if self.obs.arrived else "collision" if self.obs.collision else "out of road"
            self.get_logger().info(f"episode {self.episode} ended at {self.obs.time_s:.1f} s: {outcome}")
            self.episode += 1
            self.time_offset = self.obs.time_s + STEP_S
            self.start_episode()
            return
        self.publish_frame(self.obs)


def main(args: list[str] | None = None) -> int:
    return run_node(SimBridge, args)
