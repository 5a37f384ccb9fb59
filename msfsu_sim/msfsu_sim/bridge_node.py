"""sim_bridge node: the embedded simulator on the ROS graph, stepped in lockstep (CARLA synchronous mode)
or free-running (asynchronous mode).

Each frame is published through msfsu_sim.lockstep (shared with the closed-loop benchmark). In lockstep
(`real_time_factor` 0, the default) the simulation advances when a VehicleControl stamped with that frame
time arrives, or after `control_timeout` seconds of wall time with the last control (so a dead controller
cannot stall the graph): results do not depend on CPU speed. With `real_time_factor` R > 0 it steps on the
wall clock, R simulated seconds per second, with whatever control arrived last (msfsu_sim.pacing): the
graph has to keep up, as on a vehicle.

With `carla_messages` it also speaks carla-ros-bridge's message types, as a CARLA car driven through the bridge
would: it takes carla_msgs/CarlaEgoVehicleControl on /carla/<role>/vehicle_control_cmd (the same fields as
VehicleControl; either answers a frame) and publishes each episode's route also as the bridge's waypoint publisher
does, a latched nav_msgs/Path on /carla/<role>/waypoints (poses only, no RoadOption).

Every `status_period` simulated seconds it logs a status line (msfsu_sim.status), one per episode end,
and after `episodes` episodes (0: run on) a summary, then it exits (the bringup launch ends with it).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from carla_msgs.msg import CarlaEgoVehicleControl
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from msfsu_common import topics
from msfsu_common.message_types import message_class
from msfsu_common.node_runner import NodeFinished, run_node
from msfsu_common.params import NodeParameters
from msfsu_common.settings import setting
from msfsu_common.transport import MAX_CAMERA_HEIGHT, MAX_CAMERA_WIDTH, SENSOR_QUEUE_DEPTH
from msfsu_sim.environment import SimConfig, SimEnvironment
from msfsu_sim.lockstep import LockstepLink
from msfsu_sim.messages import TYPES
from msfsu_sim.pacing import RealTimePacer
from msfsu_sim.scenarios import TOWNS, TRAFFIC, WEATHERS
from msfsu_sim.status import RunStatus


@dataclass(frozen=True)
class BridgeStartup:
    """The bridge's read-only parameters: the run's scenario and plan, the cameras, the publishers, the stepping mode."""

    town: str = setting("town_a", "map", choices=tuple(TOWNS))
    weather: str = setting("clear_noon", "weather", choices=tuple(WEATHERS))
    traffic: str = setting("regular", "traffic", choices=tuple(TRAFFIC))
    seed: int = setting(0, "seed of traffic and pedestrians (next episode: seed + 1)", 0, 2**31 - 1)
    width: int = setting(400, "camera width, px", 32, MAX_CAMERA_WIDTH)
    height: int = setting(300, "camera height, px", 32, MAX_CAMERA_HEIGHT)
    qos_depth: int = setting(SENSOR_QUEUE_DEPTH, "queue depth of the reliable sensor publishers", 1, 100)
    labels: bool = setting(False, "render and publish 5-class ids (a third render pass)")
    status_period: float = setting(5.0, "log a status line every this many sim seconds (0: off)", 0.0, 3600.0)
    episodes: int = setting(0, "exit after this many episodes (0: run on)", 0, 1_000_000)
    real_time_factor: float = setting(0.0, "0: lockstep; R > 0: free-running, R simulated seconds per wall second "
                                      "with the last control that arrived", 0.0, 10.0)
    carla_messages: bool = setting(False, "also take carla_msgs/CarlaEgoVehicleControl on "
                                   "/carla/ego_vehicle/vehicle_control_cmd and publish the route as nav_msgs/Path on "
                                   "/carla/ego_vehicle/waypoints (latched), as carla-ros-bridge does")


@dataclass(frozen=True)
class BridgeSettings:
    """The bridge's live parameter: how long a lockstep step waits for its control."""

    control_timeout: float = setting(1.0, "step with the last control after this many wall seconds", 0.01, 60.0)


class SimBridge(Node):
    def __init__(self, environment: SimEnvironment | None = None,
                 parameter_overrides: list[Parameter] | None = None, context: Context | None = None) -> None:
        super().__init__("sim_bridge", parameter_overrides=parameter_overrides or [], context=context)
        self.parameters = NodeParameters(self, live=BridgeSettings, read_only=BridgeStartup)
        startup = self.parameters.read_only
        self.environment = environment or SimEnvironment(SimConfig(width=startup.width, height=startup.height,
                                                                   labels=startup.labels))
        self.link = LockstepLink(self, self.environment, startup.qos_depth)
        self.waypoints_pub = None
        if startup.carla_messages:
            self.create_subscription(CarlaEgoVehicleControl, topics.CARLA_VEHICLE_CONTROL, self.link.on_control,
                                     QoSProfile(depth=startup.qos_depth, reliability=ReliabilityPolicy.RELIABLE))
            self.waypoints_pub = self.create_publisher(
                message_class(TYPES[topics.WAYPOINTS]), topics.WAYPOINTS,
                QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.pacer = RealTimePacer(startup.real_time_factor) if startup.real_time_factor > 0 else None
        self.overdue = False  # free-running: the next step was due before its frame was out
        self.episode = 0
        self.status = RunStatus(startup.status_period, startup.episodes, free_running=self.pacer is not None)
        self.start_episode()
        self.create_timer(0.002, self.tick)

    def start_episode(self) -> None:
        startup = self.parameters.read_only
        self.obs = self.environment.reset(startup.town, startup.weather, startup.traffic, startup.seed + self.episode)
        self.link.start_episode(self.obs)
        if self.waypoints_pub is not None:
            self.waypoints_pub.publish(self.link.build.path(self.link.episode_start_s, self.environment.route))
        if self.pacer is not None:
            self.pacer.start()
        self.status.start_episode(self.environment.tracker.length_m)

    @property
    def lockstep_steps(self) -> int:
        """Steps taken on the control of their frame (all episodes)."""
        return self.status.total.lockstep

    @property
    def timeout_steps(self) -> int:
        """Steps taken with an older control: after `control_timeout` (lockstep) or when due (free-running)."""
        return self.status.total.timeout

    def tick(self) -> None:
        link = self.link
        if self.pacer is not None:
            if time.monotonic() < self.pacer.due():
                return
            self.pacer.step_taken(self.overdue, link.control_age_s())
        elif not (link.answered or link.waited_s() > self.parameters.live.control_timeout):
            return
        self.obs = self.environment.step(*link.control)
        line = self.status.step(self.obs, link.answered)
        if line is not None:
            self.get_logger().info(line)
        if self.obs.done:
            self.get_logger().info(self.status.end_episode(self.obs))
            self.episode += 1
            link.end_episode(self.obs)
            if self.status.finished:
                self.get_logger().info(self.status.summary())
                raise NodeFinished()
            self.start_episode()
            return
        link.publish_frame(self.obs)
        self.overdue = self.pacer is not None and self.pacer.late()


def main(args: list[str] | None = None) -> int:
    return run_node(SimBridge, args)
