"""control and route nodes in a real graph."""

import math

import numpy as np
from geometry_msgs.msg import Pose
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter

from msfsu_common import topics
from msfsu_common.road_option import RoadOption
from msfsu_control.control_node import ControlNode
from msfsu_control.route_node import ROUTE_QOS, RouteNode
from msfsu_interfaces.msg import DrivingAction, NavigationCommand, Route, VehicleControl


def odometry(x: float = 0.0, y: float = 0.0, speed: float = 0.0) -> Odometry:
    msg = Odometry()
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(x), float(y)
    msg.twist.twist.linear.x = float(speed)
    return msg


def action(steer: float, speed: float, sec: int = 1) -> DrivingAction:
    msg = DrivingAction(steer=steer, target_speed=speed, command=int(RoadOption.LANE_FOLLOW))
    msg.header.stamp.sec = sec
    return msg


def test_control_follows_actions_with_the_frame_stamp(graph):
    graph.add(ControlNode())
    controls = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
    graph.probe.publish(topics.ODOMETRY, odometry(speed=2.0))
    assert graph.wait_for(lambda: graph.nodes[-1].speed == 2.0)
    graph.probe.publish(topics.DRIVING_ACTION, action(steer=-0.3, speed=8.0, sec=42))
    assert graph.wait_for(lambda: any(c.header.stamp.sec == 42 for c in controls))
    control = next(c for c in controls if c.header.stamp.sec == 42)
    assert control.steer == np.float32(-0.3) and control.brake == 0.0
    assert 0.0 < control.throttle <= 0.75


def test_watchdog_brakes_when_inputs_stop(graph):
    node = graph.add(ControlNode([Parameter("watchdog_timeout", value=0.2)]))
    controls = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
    graph.probe.publish(topics.ODOMETRY, odometry(speed=5.0))
    assert graph.wait_for(lambda: node.speed == 5.0)
    graph.probe.publish(topics.DRIVING_ACTION, action(steer=0.0, speed=8.0))
    assert graph.wait_for(lambda: any(c.throttle > 0 for c in controls))
    count = len(controls)
    assert graph.wait_for(lambda: any(c.brake == 1.0 and c.throttle == 0.0 for c in controls[count:]), timeout=2.0)
    assert node.watchdog_brakes > 0


def test_non_finite_action_is_rejected_and_next_one_served(graph):
    node = graph.add(ControlNode())
    controls = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
    graph.probe.publish(topics.ODOMETRY, odometry(speed=1.0))
    assert graph.wait_for(lambda: node.speed == 1.0)
    graph.probe.publish(topics.DRIVING_ACTION, action(steer=math.nan, speed=5.0, sec=7))
    graph.probe.publish(topics.DRIVING_ACTION, action(steer=0.1, speed=5.0, sec=8))
    assert graph.wait_for(lambda: any(c.header.stamp.sec == 8 for c in controls))
    assert node.rejected_actions == 1
    assert not any(c.header.stamp.sec == 7 for c in controls)


def test_route_node_announces_the_turn_of_an_l_shaped_route(graph):
    node = graph.add(RouteNode([Parameter("lookahead", value=10.0), Parameter("rate", value=50.0)]))
    commands = graph.probe.collect(NavigationCommand, topics.NAVIGATION_COMMAND)
    points = [(float(x), 0.0) for x in range(0, 50)] + [(50.0, float(y)) for y in range(0, 50)]
    options = [4] * 49 + [1] + [4] * 50  # LEFT on the corner segment
    route = Route(poses=[Pose() for _ in points], options=options)
    for pose, (x, y) in zip(route.poses, points):
        pose.position.x, pose.position.y = x, y
    graph.probe.publish(topics.ROUTE, route, ROUTE_QOS)
    seen = []
    for x, y in [(5, 0), (20, 0), (42, 0), (49, 0.5), (50, 10), (50, 30)]:
        graph.probe.publish(topics.ODOMETRY, odometry(x, y))
        assert graph.wait_for(lambda: node.position == (x, y))
        count = len(commands)
        assert graph.wait_for(lambda: len(commands) > count + 2)  # a few commands at this position
        seen.append(RoadOption(commands[-1].command))
    lf, left = RoadOption.LANE_FOLLOW, RoadOption.LEFT
    assert seen == [lf, lf, left, left, lf, lf]
