"""route node: Route (or the bridge's nav_msgs/Path waypoints) + Odometry -> NavigationCommand (see RouteTracker).

The route comes from either of two latched topics, whichever sent the newest: the stack's own Route on /msfsu/route
(poses with their RoadOptions, as the simulator publishes it), or carla-ros-bridge's waypoint publisher's
nav_msgs/Path on /carla/<role>/waypoints (poses only: the options are taken from the path's shape at junctions,
msfsu_control.path_options). A command answers an odometry message, at most `rate` per second of odometry time, and
carries its stamp: the command is a function of the route and the odometry alone. (A timer would take whatever
position came last: in lockstep the same frame could get its own position or the one before, depending on how busy
the machine is.)"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from nav_msgs.msg import Odometry, Path
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from msfsu_common import topics
from msfsu_common.message_types import stamp_ns
from msfsu_common.node_runner import run_node
from msfsu_common.params import NodeParameters
from msfsu_common.reset import offer_reset
from msfsu_common.settings import setting
from msfsu_control.path_options import path_tracker
from msfsu_control.route_tracker import RouteTracker, RouteTrackerConfig
from msfsu_interfaces.msg import NavigationCommand, Route

# The route is published once per episode: latch it like a map (transient local; carla_waypoint_publisher's QoS too).
ROUTE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


@dataclass(frozen=True)
class RouteSettings:
    """The route node's parameters, all live: the tracker's and the command rate."""

    tracker: RouteTrackerConfig = field(default_factory=RouteTrackerConfig)
    rate: float = setting(10.0, "most commands per second of odometry time (one per odometry message up to it)",
                          0.1, 100.0)

    @property
    def min_interval_ns(self) -> int:
        """Odometry stamps closer than this to the last command's get none: 10 % short of the period, so odometry
        at exactly `rate` is never skipped."""
        return int(0.9e9 / self.rate)


class RouteNode(Node):
    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__("route", parameter_overrides=parameter_overrides or [])
        self.parameters = NodeParameters(self, live=RouteSettings, apply=self.apply_settings)
        self.route: tuple[Callable[[Any], None], Any] | None = None  # the last route accepted: its handler, message
        self.forget()
        self.command_pub = self.create_publisher(NavigationCommand, topics.NAVIGATION_COMMAND, 10)
        self.create_subscription(Route, topics.ROUTE, self.on_route, ROUTE_QOS)
        self.create_subscription(Path, topics.WAYPOINTS, self.on_path, ROUTE_QOS)
        self.create_subscription(Odometry, topics.ODOMETRY, self.on_odometry, 10)
        offer_reset(self, self.forget)

    def forget(self) -> str:
        """No position and no progress, as at the start: the route (kept) is tracked again from its beginning."""
        self.tracker: RouteTracker | None = None
        self.position: tuple[float, float] | None = None
        self.last_command_ns: int | None = None  # odometry stamp of the last command
        if self.route is None:
            return "position forgotten; waiting for a route"
        handler, message = self.route
        handler(message)
        return "position and progress forgotten; the route is tracked from its beginning"

    def apply_settings(self, settings: RouteSettings) -> None:
        """New parameters in force: the next odometry message is tracked and rate-limited with them."""
        if self.tracker is not None:
            self.tracker.config = settings.tracker

    def on_route(self, msg: Route) -> None:
        points = np.array([[pose.position.x, pose.position.y] for pose in msg.poses], dtype=np.float64)
        try:
            tracker = RouteTracker(points, np.asarray(msg.options), self.parameters.live.tracker)
        except ValueError as error:
            self.get_logger().error(f"route rejected: {error}")
            return
        self.take(tracker, f"new route: {len(points)} poses, {tracker.length_m:.0f} m", (self.on_route, msg))

    def on_path(self, msg: Path) -> None:
        points = np.array([[pose.pose.position.x, pose.pose.position.y] for pose in msg.poses], dtype=np.float64)
        try:
            tracker = path_tracker(points, self.parameters.live.tracker)
        except ValueError as error:
            self.get_logger().error(f"waypoints rejected: {error}")
            return
        turns = [f"{tracker.option_at(start).name} at {start:.0f} m" for start, _ in tracker.junction_spans()]
        self.take(tracker, f"new route from {topics.WAYPOINTS}: {len(points)} poses, {tracker.length_m:.0f} m, turns "
                           f"from its shape: {', '.join(turns) or 'none'}", (self.on_path, msg))

    def take(self, tracker: RouteTracker, description: str, source: tuple[Callable[[Any], None], Any]) -> None:
        """The new route in force: the next odometry message gets its first command; `source` (its handler and
        message) makes it again after a reset."""
        self.tracker = tracker
        self.route = source
        self.last_command_ns = None
        self.get_logger().info(description)

    def on_odometry(self, msg: Odometry) -> None:
        self.position = (msg.pose.pose.position.x, msg.pose.pose.position.y)
        if self.tracker is None:
            self.get_logger().info("waiting for a route", throttle_duration_sec=10.0)
            return
        stamp = stamp_ns(msg.header)
        min_interval_ns = self.parameters.live.min_interval_ns
        if self.last_command_ns is not None and 0 <= stamp - self.last_command_ns < min_interval_ns:
            return  # this period has its command (a stamp that went back, a bag played again, starts anew)
        self.last_command_ns = stamp
        command = NavigationCommand(command=int(self.tracker.update(*self.position)))
        command.header.stamp = msg.header.stamp
        self.command_pub.publish(command)


def main(args=None) -> int:
    return run_node(RouteNode, args)
