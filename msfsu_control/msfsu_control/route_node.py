"""route node: Route + Odometry -> NavigationCommand at a fixed rate (see RouteTracker)."""

from __future__ import annotations

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from msfsu_common import topics
from msfsu_common.node_runner import run_node
from msfsu_common.params import declare
from msfsu_control.route_tracker import RouteTracker, RouteTrackerConfig
from msfsu_interfaces.msg import NavigationCommand, Route

# The route is published once per episode: latch it like a map (transient local).
ROUTE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class RouteNode(Node):
    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__("route", parameter_overrides=parameter_overrides or [])
        defaults = RouteTrackerConfig()
        self.config = RouteTrackerConfig(
            lookahead_m=declare(self, "lookahead", defaults.lookahead_m,
                                "announce a junction option this far ahead, m", 0.0, 500.0),
            search_window_m=declare(self, "search_window", defaults.search_window_m,
                                    "max forward progress jump per update, m", 1.0, 1000.0),
        )
        rate = declare(self, "rate", 10.0, "command publish rate, Hz", 0.1, 100.0)
        self.tracker: RouteTracker | None = None
        self.position: tuple[float, float] | None = None
        self.command_pub = self.create_publisher(NavigationCommand, topics.NAVIGATION_COMMAND, 10)
        self.create_subscription(Route, topics.ROUTE, self.on_route, ROUTE_QOS)
        self.create_subscription(Odometry, topics.ODOMETRY, self.on_odometry, 10)
        self.create_timer(1.0 / rate, self.publish_command)

    def on_route(self, msg: Route) -> None:
        points = np.array([[pose.position.x, pose.position.y] for pose in msg.poses], dtype=np.float64)
        try:
            self.tracker = RouteTracker(points, np.asarray(msg.options), self.config)
        except ValueError as error:
            self.get_logger().error(f"route rejected: {error}")
            return
        self.get_logger().info(f"new route: {len(points)} poses, {self.tracker.length_m:.0f} m")

    def on_odometry(self, msg: Odometry) -> None:
        self.position = (msg.pose.pose.position.x, msg.pose.pose.position.y)

    def publish_command(self) -> None:
        if self.tracker is None or self.position is None:
            self.get_logger().info("waiting for route and odometry", throttle_duration_sec=10.0)
            return
        command = NavigationCommand(command=int(self.tracker.update(*self.position)))
        command.header.stamp = self.get_clock().now().to_msg()
        self.command_pub.publish(command)


def main(args=None) -> int:
    return run_node(RouteNode, args)
