"""control and route nodes in a real graph."""

import math
import time

import numpy as np
import pytest
from carla_msgs.msg import CarlaEgoVehicleControl
from geometry_msgs.msg import Pose, PoseStamped
from nav_msgs.msg import Odometry, Path
from rclpy.executors import SingleThreadedExecutor
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


@pytest.mark.parametrize("output", ["both", "carla", "msfsu"])
def test_the_control_goes_out_as_the_bridges_carla_control_as_the_stacks_or_both(graph, output):
    """carla-ros-bridge applies CarlaEgoVehicleControl from /carla/<role>/vehicle_control_cmd: the same control,
    stamp and fields as the stack's VehicleControl, the automatic gearbox's defaults; and the watchdog's brake too."""
    node = graph.add(ControlNode([Parameter("output", value=output), Parameter("watchdog_timeout", value=0.3)]))
    carla = graph.probe.collect(CarlaEgoVehicleControl, topics.CARLA_VEHICLE_CONTROL)
    stack = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
    graph.probe.publish(topics.ODOMETRY, odometry(speed=2.0))
    assert graph.wait_for(lambda: node.speed == 2.0)
    graph.probe.publish(topics.DRIVING_ACTION, action(steer=-0.3, speed=8.0, sec=42))
    sent = carla if output != "msfsu" else stack
    assert graph.wait_for(lambda: any(c.header.stamp.sec == 42 for c in sent))
    assert graph.wait_for(lambda: any(c.brake == 1.0 and c.throttle == 0.0 for c in sent), timeout=3.0)  # watchdog
    time.sleep(0.2)  # whatever else was sent has arrived
    assert bool(carla) == (output in ("both", "carla")) and bool(stack) == (output in ("both", "msfsu"))
    if output == "both":
        assert [(c.header.stamp, c.throttle, c.steer, c.brake) for c in carla] == [
            (c.header.stamp, c.throttle, c.steer, c.brake) for c in stack][:len(carla)]
    for control in carla:
        assert (control.hand_brake, control.reverse, control.gear, control.manual_gear_shift) == (False, False, 0, False)
    if carla:
        first = next(c for c in carla if c.header.stamp.sec == 42)
        assert first.steer == np.float32(-0.3) and 0.0 < first.throttle <= 0.75 and first.brake == 0.0


def test_an_unknown_output_is_refused_at_start_in_one_line(graph):
    from msfsu_common.node_runner import StartupError

    with pytest.raises(StartupError, match="output 'ros1' is not one of msfsu, carla, both"):
        ControlNode([Parameter("output", value="ros1")])


def test_an_action_waiting_with_its_frames_odometry_is_served_with_that_odometry(graph):
    """In lockstep a frame's odometry and the action that answers it can wait together in the control node's queues
    (on a busy machine). Taken action first, the control would use the speed of the frame before, and the same
    episode would drive differently from run to run. The node takes the odometry first."""
    node = ControlNode([Parameter("watchdog_timeout", value=30.0)])  # no input goes stale in this test
    executor = SingleThreadedExecutor()  # spun only here: meanwhile, messages wait in the node's queues
    executor.add_node(node)
    try:
        controls = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
        graph.probe.publish(topics.ODOMETRY, odometry(speed=1.0))
        deadline = time.monotonic() + 10.0
        while node.speed != 1.0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert node.speed == 1.0
        graph.probe.publish(topics.ODOMETRY, odometry(speed=9.0))  # too fast for 5 m/s: the brake rule fires
        graph.probe.publish(topics.DRIVING_ACTION, action(steer=0.0, speed=5.0, sec=3))
        time.sleep(1.0)  # both delivered, neither taken
        deadline = time.monotonic() + 10.0
        while node.published == 0 and time.monotonic() < deadline:  # the parameters status timer may be ready too
            executor.spin_once(timeout_sec=1.0)
        assert graph.wait_for(lambda: any(c.header.stamp.sec == 3 for c in controls))
        control = next(c for c in controls if c.header.stamp.sec == 3)
        assert node.speed == 9.0 and (control.throttle, control.brake) == (0.0, 1.0)  # at 1 m/s it would accelerate
    finally:
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()


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


def test_the_watchdog_waits_for_the_first_action_and_a_reset_makes_it_wait_again(graph):
    """Before its first action (at start, after ~/reset) the node sends nothing: a brake stamped with the clock's time
    would answer a lockstep simulator's frame in the network's place. A reset forgets the controller too: the same
    inputs after it give the control a new node gives."""
    from std_srvs.srv import Trigger

    from msfsu_common.reset import reset_service_name

    node = graph.add(ControlNode([Parameter("watchdog_timeout", value=0.2)]))
    controls = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
    graph.probe.publish(topics.ODOMETRY, odometry(speed=1.0))
    assert graph.wait_for(lambda: node.speed == 1.0)
    time.sleep(0.6)  # three watchdog periods with stale odometry and no action yet
    assert controls == [] and node.watchdog_brakes == 0
    graph.probe.publish(topics.ODOMETRY, odometry(speed=1.0))  # fresh again for the first action
    graph.probe.publish(topics.DRIVING_ACTION, action(steer=0.2, speed=8.0, sec=5))
    assert graph.wait_for(lambda: any(c.header.stamp.sec == 5 for c in controls))
    first = next(c for c in controls if c.header.stamp.sec == 5)
    for sec in range(6, 20):  # the windowed integral fills
        graph.probe.publish(topics.DRIVING_ACTION, action(steer=0.2, speed=8.0, sec=sec))
    assert graph.wait_for(lambda: any(c.header.stamp.sec == 19 for c in controls))
    assert graph.wait_for(lambda: node.watchdog_brakes > 0, timeout=2.0)  # armed: the inputs went stale
    client = graph.probe.create_client(Trigger, reset_service_name("control"))
    assert client.wait_for_service(timeout_sec=5.0)
    future = client.call_async(Trigger.Request())
    assert graph.wait_for(future.done) and future.result().success
    brakes = node.watchdog_brakes
    time.sleep(0.6)
    assert node.watchdog_brakes == brakes and node.speed is None  # not armed again until an action comes
    graph.probe.publish(topics.ODOMETRY, odometry(speed=1.0))
    assert graph.wait_for(lambda: node.speed == 1.0)
    graph.probe.publish(topics.DRIVING_ACTION, action(steer=0.2, speed=8.0, sec=30))
    assert graph.wait_for(lambda: any(c.header.stamp.sec == 30 for c in controls))
    again = next(c for c in controls if c.header.stamp.sec == 30)
    assert (again.throttle, again.brake, again.steer) == (first.throttle, first.brake, first.steer)


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


def odometry_at(sec: float, x: float, y: float) -> Odometry:
    msg = odometry(x, y)
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(sec), round((sec % 1) * 1e9)
    return msg


def l_shaped_route() -> Route:
    points = [(float(x), 0.0) for x in range(0, 50)] + [(50.0, float(y)) for y in range(0, 50)]
    options = [4] * 49 + [1] + [4] * 50  # LEFT on the corner segment
    route = Route(poses=[Pose() for _ in points], options=options)
    for pose, (x, y) in zip(route.poses, points):
        pose.position.x, pose.position.y = x, y
    return route


def test_route_node_announces_the_turn_of_an_l_shaped_route(graph):
    graph.add(RouteNode([Parameter("lookahead", value=10.0)]))
    commands = graph.probe.collect(NavigationCommand, topics.NAVIGATION_COMMAND)
    graph.probe.publish(topics.ROUTE, l_shaped_route(), ROUTE_QOS)
    seen = []
    for sec, (x, y) in enumerate([(5, 0), (20, 0), (42, 0), (49, 0.5), (50, 10), (50, 30)], start=1):
        # the first odometry may come before the route: it is answered once the route is there
        graph.probe.publish(topics.ODOMETRY, odometry_at(sec, x, y))
        assert graph.wait_for(lambda: any(c.header.stamp.sec == sec for c in commands)), f"no command at {sec} s"
        seen.append(RoadOption(next(c for c in commands if c.header.stamp.sec == sec).command))
    lf, left = RoadOption.LANE_FOLLOW, RoadOption.LEFT
    assert seen == [lf, lf, left, left, lf, lf]


def test_route_node_answers_odometry_at_most_rate_times_per_second_of_its_stamps(graph):
    """One command per odometry message at the rate (10 Hz, a simulator's frames), stamped with it; faster odometry
    gets one command per period of its own stamps, whatever the wall clock does."""
    node = graph.add(RouteNode([Parameter("rate", value=10.0)]))
    commands = graph.probe.collect(NavigationCommand, topics.NAVIGATION_COMMAND)
    graph.probe.publish(topics.ROUTE, l_shaped_route(), ROUTE_QOS)
    assert graph.wait_for(lambda: node.tracker is not None)
    stamps = [1.0 + 0.1 * i for i in range(5)] + [1.5 + 0.02 * i for i in range(1, 16)]  # 10 Hz, then 50 Hz
    for i, sec in enumerate(stamps):  # one at a time (a burst would overflow the subscription's queue)
        graph.probe.publish(topics.ODOMETRY, odometry_at(sec, 5.0 + 0.01 * i, 0.0))
        assert graph.wait_for(lambda: node.position == (5.0 + 0.01 * i, 0.0))
    time.sleep(0.2)  # the last commands arrive
    got = [c.header.stamp.sec + c.header.stamp.nanosec * 1e-9 for c in commands]
    assert got == pytest.approx([1.0, 1.1, 1.2, 1.3, 1.4, 1.52, 1.62, 1.72])  # 50 Hz: every 5th


def bridge_waypoints(points: list[tuple[float, float]]) -> Path:
    """A route as carla_waypoint_publisher sends it: a nav_msgs/Path of stamped poses, no RoadOption."""
    path = Path()
    path.header.frame_id = "map"
    for x, y in points:
        pose = PoseStamped()
        pose.header.frame_id = "map"
        pose.pose.position.x, pose.pose.position.y = float(x), float(y)
        path.poses.append(pose)
    return path


def test_route_node_takes_the_bridges_waypoints_and_their_turns_from_the_paths_shape(graph):
    """The bridge's latched Path (waypoints 2 m apart, a right turn of radius 10 m): the turn is announced ahead of the
    bend and LANE_FOLLOW follows it; a later Route replaces it, and a Path that is no route leaves the route as it was."""
    node = graph.add(RouteNode([Parameter("lookahead", value=10.0)]))
    commands = graph.probe.collect(NavigationCommand, topics.NAVIGATION_COMMAND)
    angles = np.linspace(0.0, np.pi / 2, 9)[1:-1]
    points = ([(float(x), 0.0) for x in range(0, 40, 2)] + [(40 + 10 * np.sin(a), -10 * (1 - np.cos(a))) for a in angles]
              + [(50.0, -10.0 - y) for y in range(0, 40, 2)])
    graph.probe.publish(topics.WAYPOINTS, bridge_waypoints(points), ROUTE_QOS)
    assert graph.wait_for(lambda: node.tracker is not None)
    assert set(node.tracker.options) == {RoadOption.LANE_FOLLOW, RoadOption.RIGHT}
    seen = []
    for sec, (x, y) in enumerate([(5, 0), (35, 0), (45, -3), (50, -25), (50, -45)], start=1):
        graph.probe.publish(topics.ODOMETRY, odometry_at(sec, x, y))
        assert graph.wait_for(lambda: any(c.header.stamp.sec == sec for c in commands)), f"no command at {sec} s"
        seen.append(RoadOption(next(c for c in commands if c.header.stamp.sec == sec).command))
    lf, right = RoadOption.LANE_FOLLOW, RoadOption.RIGHT
    assert seen == [lf, right, right, lf, lf]
    tracker = node.tracker
    graph.probe.publish(topics.WAYPOINTS, bridge_waypoints([(1.0, 1.0)]), ROUTE_QOS)  # one pose: no route
    time.sleep(0.3)
    assert node.tracker is tracker
    graph.probe.publish(topics.ROUTE, l_shaped_route(), ROUTE_QOS)  # the newest route is the one driven
    assert graph.wait_for(lambda: node.tracker is not tracker and RoadOption.LEFT in node.tracker.options)
