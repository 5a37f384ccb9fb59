"""Parameters set on running nodes through their parameter services (msfsu_common.params): live ones take effect
from the next message, whole or not at all; read-only and invalid ones are refused with a reason."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Log, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy
from ros_graph import Parameters
from test_control_graph import action, l_shaped_route, odometry, odometry_at

from msfsu_common import topics
from msfsu_common.params import NodeParameters
from msfsu_common.road_option import RoadOption
from msfsu_common.settings import setting
from msfsu_control.control_node import ControlNode
from msfsu_control.pid import ActionController, SpeedControlConfig
from msfsu_control.route_node import ROUTE_QOS, RouteNode
from msfsu_interfaces.msg import NavigationCommand, VehicleControl

SPEED = 4.0  # m/s, the odometry of every control test
# desired speeds a little above SPEED: errors under max_error, throttles under max_throttle, so every gain shows
# (float32 values: what a DrivingAction carries)
TARGETS = [float(np.float32(4.02 + 0.01 * (index % 7))) for index in range(200)]


def refused(reason: str) -> SetParametersResult:
    return SetParametersResult(successful=False, reason=reason)


def log_lines(graph, node_name: str) -> list[str]:
    return [entry.msg for entry in graph.probe.received.get("/rosout", []) if entry.name == node_name]


def status_values(graph, name: str) -> dict[str, str] | None:
    """The last diagnostics status called `name`, as key -> value."""
    for array in reversed(graph.probe.received.get(topics.DIAGNOSTICS, [])):
        for status in array.status:
            if status.name == name:
                return {pair.key: pair.value for pair in status.values}
    return None


def core_controls(count: int, changed_at: int | None = None, config: SpeedControlConfig | None = None):
    """(throttle, brake, steer) the control core gives for TARGETS[:count] at SPEED, 1 s apart; from action
    `changed_at` on with `config`."""
    core = ActionController()
    controls = []
    for index, target in enumerate(TARGETS[:count]):
        if index == changed_at:
            core.configure(config, 0.0)
        control = core.step(0.0, target, SPEED, 1.0)
        controls.append(tuple(np.float32(value) for value in (control.throttle, control.brake, control.steer)))
    return controls


class ControlUnderTest:
    """A control node (watchdog far away) with fresh odometry at SPEED, fed TARGETS one action per call."""

    def __init__(self, graph) -> None:
        self.graph = graph
        self.node = graph.add(ControlNode([Parameter("watchdog_timeout", value=30.0)]))
        graph.probe.collect(Log, "/rosout")
        graph.probe.collect(DiagnosticArray, topics.DIAGNOSTICS)
        self.controls = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
        graph.probe.publish(topics.ODOMETRY, odometry(speed=SPEED))
        assert graph.wait_for(lambda: self.node.speed == SPEED)
        self.parameters = Parameters(graph, "control")
        self.sent = 0

    def send(self) -> None:
        self.sent += 1
        self.graph.probe.publish(topics.DRIVING_ACTION, action(steer=0.0, speed=TARGETS[self.sent - 1], sec=self.sent))

    def received(self) -> list[tuple]:
        """(throttle, brake, steer) of every control sent so far, in action order (waits for them)."""
        assert self.graph.wait_for(lambda: len(self.controls) == self.sent), (len(self.controls), self.sent)
        return [(c.throttle, c.brake, c.steer) for c in sorted(self.controls, key=lambda c: c.header.stamp.sec)]


def test_kp_set_while_actions_flow_changes_the_next_control_exactly_as_the_core_computes_it(graph):
    control = ControlUnderTest(graph)
    for _ in range(10):
        control.send()
        time.sleep(0.02)
    requested_at = control.sent  # the actions before this one cannot see the new gain
    future = control.parameters.client.set_parameters([Parameter("kp", value=3.0)])
    answered_by = None  # the first action sent after the node answered: it must see the new gain
    while answered_by is None or control.sent < answered_by + 5:
        if answered_by is None and future.done():
            answered_by = control.sent
        control.send()
        time.sleep(0.02)
    assert future.result().results == [SetParametersResult(successful=True)]
    received = control.received()
    new_config = replace(SpeedControlConfig(), kp=3.0)
    changed_at = [index for index in range(requested_at, answered_by + 1)
                  if received == core_controls(control.sent, index, new_config)]
    assert len(changed_at) == 1, "the controls are the core's with kp changed between two actions"
    assert received[-1] != core_controls(control.sent)[-1]  # kp 5 would give another throttle
    assert control.parameters.get("kp") == [3.0]
    assert graph.wait_for(lambda: log_lines(graph, "control").count("parameters set: kp 5.0 -> 3.0") == 1)
    assert graph.wait_for(lambda: (status_values(graph, "msfsu/control/parameters") or {}).get("kp") == "3.0")
    assert status_values(graph, "msfsu/control/parameters")["ki"] == "0.5"


def test_out_of_range_wrong_type_and_read_only_sets_are_refused_with_their_reasons_and_change_nothing(graph):
    control = ControlUnderTest(graph)
    control.send()
    assert control.parameters.set_each(kp=200.0, ki=1, use_sim_time=True) == [
        refused("Parameter kp out of range Min: 0.0, Max: 100.0, value: 200.0"),
        refused("Wrong parameter type, expected 'Type.DOUBLE' got 'Type.INTEGER'"),
        refused("Trying to set a read-only parameter: use_sim_time."),
    ]
    assert control.parameters.get("kp", "ki", "use_sim_time") == [5.0, 0.5, False]
    control.send()
    assert control.received() == core_controls(2)
    assert not [line for line in log_lines(graph, "control") if line.startswith("parameters set")]


def test_a_set_of_several_parameters_with_one_invalid_changes_none_of_them(graph):
    control = ControlUnderTest(graph)
    control.send()
    assert control.parameters.set_together(kp=3.0, ki=0.1, max_throttle=1.5) == refused(
        "Parameter max_throttle out of range Min: 0.0, Max: 1.0, value: 1.5")
    assert control.parameters.get("kp", "ki", "max_throttle") == [5.0, 0.5, 0.75]
    control.send()
    assert control.received() == core_controls(2)


def test_route_lookahead_set_live_changes_the_next_command(graph):
    node = graph.add(RouteNode())  # lookahead 15 m; the L-shaped route turns LEFT 49 m from its start
    commands = graph.probe.collect(NavigationCommand, topics.NAVIGATION_COMMAND)
    graph.probe.publish(topics.ROUTE, l_shaped_route(), ROUTE_QOS)
    assert graph.wait_for(lambda: node.tracker is not None)
    parameters = Parameters(graph, "route")

    def command_at(sec: int, x: float) -> RoadOption:
        graph.probe.publish(topics.ODOMETRY, odometry_at(sec, x, 0.0))
        assert graph.wait_for(lambda: any(c.header.stamp.sec == sec for c in commands))
        return RoadOption(next(c for c in commands if c.header.stamp.sec == sec).command)

    assert command_at(1, 30.0) is RoadOption.LANE_FOLLOW
    assert parameters.set_each(lookahead=25.0) == [SetParametersResult(successful=True)]
    assert command_at(2, 30.0) is RoadOption.LEFT


@dataclass(frozen=True)
class Band:
    """Live settings of a test node with a cross-field rule."""

    low: float = setting(1.0, "lower edge", 0.0, 10.0)
    high: float = setting(2.0, "upper edge", 0.0, 10.0)

    def __post_init__(self) -> None:
        if self.low > self.high:
            raise ValueError(f"low {self.low} is above high {self.high}")


@dataclass(frozen=True)
class BandTopics:
    topic: str = setting("/band", "where the band goes")


class BandNode(Node):
    def __init__(self) -> None:
        super().__init__("band")
        self.applied: list[Band] = []
        self.parameters = NodeParameters(self, live=Band, read_only=BandTopics, apply=self.applied.append)


def test_a_node_receives_each_accepted_set_whole_and_a_set_breaking_a_cross_field_rule_is_refused(graph):
    node = graph.add(BandNode())
    graph.probe.collect(Log, "/rosout")
    parameters = Parameters(graph, "band")
    assert parameters.set_together(low=5.0, high=6.0) == SetParametersResult(successful=True)  # low 5 alone: refused
    assert node.applied == [Band(5.0, 6.0)] and node.parameters.live == Band(5.0, 6.0)
    assert parameters.set_together(low=7.0) == refused("low 7.0 is above high 6.0")
    assert parameters.set_each(low=0.5, high=0.4) == [SetParametersResult(successful=True),
                                                      refused("low 0.5 is above high 0.4")]
    assert parameters.set_each(topic="/elsewhere") == [refused("Trying to set a read-only parameter: topic.")]
    assert node.applied == [Band(5.0, 6.0), Band(0.5, 6.0)]
    assert parameters.get("low", "high", "topic") == [0.5, 6.0, "/band"]
    assert graph.wait_for(lambda: log_lines(graph, "band") == ["parameters set: low 1.0 -> 5.0, high 2.0 -> 6.0",
                                                               "parameters set: low 5.0 -> 0.5"])


def test_a_node_started_with_values_other_than_its_defaults_logs_them_once(graph):
    """A run's log says what each node ran with beyond its defaults (e.g. a benchmark agent's --aeb-param)."""
    logged: list[str] = []

    class Logger:
        def info(self, message: str) -> None:
            logged.append(message)

    class StartedBandNode(Node):
        def __init__(self, name: str, overrides: list[Parameter]) -> None:
            super().__init__(name, parameter_overrides=overrides)
            self.parameters = NodeParameters(self, live=Band, read_only=BandTopics)

        def get_logger(self):
            return Logger()

    graph.add(StartedBandNode("band", [Parameter("high", value=6.0), Parameter("topic", value="/b")]))
    assert graph.wait_for(lambda: logged == ["parameters other than the defaults: topic /band -> /b, high 2.0 -> 6.0"])
    graph.add(StartedBandNode("band_defaults", []))
    graph.wait_for(lambda: len(logged) > 1, timeout=1.0)
    assert len(logged) == 1  # once, and nothing for defaults only


def test_the_values_in_force_are_published_every_second_on_a_volatile_diagnostics_publisher(graph):
    """Volatile like every /diagnostics publisher of the stack: a recorder that found a latched one first would
    subscribe transient local and record none of the others."""
    graph.add(BandNode())
    statuses = graph.probe.collect(DiagnosticArray, topics.DIAGNOSTICS)
    assert graph.wait_for(lambda: sum(s.status[0].name == "msfsu/band/parameters" for s in statuses) >= 2, timeout=5.0)
    assert status_values(graph, "msfsu/band/parameters") == {"topic": "/band", "low": "1.0", "high": "2.0"}
    publishers = [p for p in graph.probe.get_publishers_info_by_topic(topics.DIAGNOSTICS) if p.node_name == "band"]
    assert [p.qos_profile.durability for p in publishers] == [DurabilityPolicy.VOLATILE]
