"""route node: Route + Odometry -> NavigationCommand (see RouteTracker).

A command answers an odometry message, at most `rate` per second of odometry time, and carries its stamp: the command
is a function of the route and the odometry alone. (A timer would take whatever position came last: in lockstep the
same frame could get its own position or the one before, depending on how busy the machine is.)"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from msfsu_common import topics
from msfsu_common.message_types import stamp_ns
from msfsu_common.node_runner import run_node
from msfsu_common.params import NodeParameters
from msfsu_common.reset import offer_reset
from msfsu_common.settings import setting
from msfsu_control.route_tracker import RouteTracker, RouteTrackerConfig
from msfsu_interfaces.msg import NavigationCommand, Route

# The route is published once per episode: latch it like a map (transient local).
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
        self.route: Route | None = None  # the last route accepted
        self.forget()
        self.command_pub = self.create_publisher(NavigationCommand, topics.NAVIGATION_COMMAND, 10)
        self.create_subscription(Route, topics.ROUTE, self.on_route, ROUTE_QOS)
        self.create_subscription(Odometry, topics.ODOMETRY, self.on_odometry, 10)
        offer_reset(self, self.forget)

    def forget(self) -> str:
        """No position and no progress, as at the start: the route (kept) is tracked again from its beginning."""
        self.tracker: RouteTracker | None = None
        self.position: tuple[float, float] | None = None
        self.last_command_ns: int | None = None  # odometry stamp of the last command
        if self.route is None:
            return "position forgotten; waiting for a route"
        self.on_route(self.route)
        return "position and progress forgotten; the route is tracked from its beginning"

    def apply_settings(self, settings: RouteSettings) -> None:
        """New parameters in force: the next odometry message is tracked and rate-limited with them."""
        if self.tracker is not None:
            self.tracker.config = settings.tracker

    def on_route(self, msg: Route) -> None:
        points = np.array([[pose.position.x, pose.position.y] for pose in msg.poses], dtype=np.float64)
        try:
            self.tracker = RouteTracker(points, np.asarray(msg.options), self.parameters.live.tracker)
        except ValueError as error:
            self.get_logger().error(f"route rejected: {error}")
            return
        self.route = msg
        self.last_command_ns = None  # the next odometry message gets the new route's first command
        self.get_logger().info(f"new route: {len(points)} poses, {self.tracker.length_m:.0f} m")

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
