"""A node's ROS parameters, declared from its settings dataclasses (msfsu_common.settings), each live or read-only.

`NodeParameters(node, live=..., read_only=..., apply=...)` declares every setting of the two classes as a parameter
with a ParameterDescriptor (description, range, choices) and holds their values as two frozen instances:

- read-only (`read_only`): ParameterDescriptor(read_only=True). Read once at start; rclpy refuses a set with the
  reason `Trying to set a read-only parameter: NAME.`. For what needs a restart: checkpoint, backend, topics, QoS.
  rclpy's own `use_sim_time` is made read-only too: a node's clock does not change under its watchdog and timers.
- live (`live`): a set passes rclpy's type and range checks, then the on-set callback builds the new live settings
  whole (settings.with_values: ranges, choices, the class's cross-field rules) and refuses the whole set, with the
  reason, if any value fails. Once rclpy has stored the values, the post-set callback replaces `live` with that
  instance, logs one line (`parameters set: kp 5.0 -> 3.0`) and calls `apply(new)`, which must not fail (the
  values are stored by then). Both run in one callback of the node's executor (the parameter service's), so every
  message the node takes after it sees the whole new configuration.

A set is one request of `set_parameters_atomically` (all its parameters or none) or one parameter of a
`set_parameters` request (what `ros2 param set` and rqt_reconfigure send: rclpy sets each of its parameters alone).
Invalid start-up values (overrides) stop the node with a StartupError naming the parameter.

The values in force, of both kinds, are the status `msfsu/<node>/parameters` on /diagnostics, published at start,
after every set that changed a value and every STATUS_PERIOD_S of wall time (a monitor that joins later, or marks a
status stale when it stops coming, sees them). The publisher is volatile like every /diagnostics publisher of the
stack: a latched one would make a recorder that found it first subscribe transient local, and miss the others.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Generic, TypeVar

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter
from rclpy.timer import Timer

from msfsu_common import settings, topics
from msfsu_common.diagnostics import OK, diagnostic_array
from msfsu_common.node_runner import StartupError

L = TypeVar("L")
R = TypeVar("R")
USE_SIM_TIME = "use_sim_time"
READ_ONLY_NOTE = "read-only: read at start; restart the node to change it"
STATUS_PERIOD_S = 1.0


def descriptor(parameter: settings.Parameter, read_only: bool) -> ParameterDescriptor:
    """The ROS descriptor of a setting: its description, range (numbers), choices and kind."""
    spec = parameter.setting
    notes = ([f"one of: {', '.join(spec.choices)}"] if spec.choices else []) + ([READ_ONLY_NOTE] if read_only else [])
    result = ParameterDescriptor(description=spec.description, read_only=read_only,
                                 additional_constraints="; ".join(notes))
    if spec.low is not None:
        if isinstance(parameter.default, int):
            result.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)]
        else:
            result.floating_point_range = [FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high))]
    return result


def retime(timer: Timer, period_s: float) -> None:
    """Give `timer` a new period from now on: its next call comes `period_s` after this one."""
    timer.timer_period_ns = int(period_s * 1e9)
    timer.reset()


def ros_value(value: Any) -> Any:
    """A settings value as rclpy declares it (sequences as lists)."""
    return list(value) if isinstance(value, tuple) else value


class NodeParameters(Generic[L, R]):
    """The parameters of one node: `live` and `read_only` are the values in force (see the module doc)."""

    def __init__(self, node: Node, live: type[L] | None = None, read_only: type[R] | None = None,
                 apply: Callable[[L], None] | None = None) -> None:
        self._node = node
        self._apply = apply
        self.read_only: R | None = self._declare(read_only, True)
        self.live: L | None = self._declare(live, False)
        self._live_names = set(settings.values(self.live)) if self.live is not None else set()
        # what a log of the run says the node ran with beyond its defaults: said once the node spins, so a node that
        # fails to start says only why
        self._given = [change for instance in (self.read_only, self.live) if instance is not None
                       for change in settings.differences(type(instance)(), instance)]
        if self._given:
            self._given_timer = node.create_timer(0.0, self._log_given, clock=Clock(clock_type=ClockType.STEADY_TIME))
        node.set_descriptor(USE_SIM_TIME, ParameterDescriptor(
            type=ParameterType.PARAMETER_BOOL, read_only=True, additional_constraints=READ_ONLY_NOTE,
            description="take the node clock from /clock (rclpy's parameter)"))
        self._status_pub = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        node.create_timer(STATUS_PERIOD_S, self.publish_status, clock=Clock(clock_type=ClockType.STEADY_TIME))
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._take)
        self.publish_status()

    def _log_given(self) -> None:
        self._node.destroy_timer(self._given_timer)
        self._node.get_logger().info(f"parameters other than the defaults: {', '.join(self._given)}")

    def _declare(self, settings_type: type | None, read_only: bool) -> Any:
        if settings_type is None:
            return None
        given = {}
        for parameter in settings.parameters(settings_type):
            try:
                given[parameter.name] = self._node.declare_parameter(
                    parameter.name, ros_value(parameter.default), descriptor(parameter, read_only)).value
            except ParameterException as error:
                raise StartupError(f"parameter '{parameter.name}': {error}") from error
        try:
            return settings.with_values(settings_type(), given)
        except ValueError as error:
            raise StartupError(f"invalid parameters: {error}") from error

    def _candidate(self, parameters: list[RosParameter]) -> L:
        """The live settings with the live parameters of `parameters` set (ValueError: which one fails)."""
        return settings.with_values(self.live, {p.name: p.value for p in parameters if p.name in self._live_names})

    def _validate(self, parameters: list[RosParameter]) -> SetParametersResult:
        if self.live is not None:
            try:
                self._candidate(parameters)
            except ValueError as error:
                return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _take(self, parameters: list[RosParameter]) -> None:
        if self.live is None:
            return
        old, new = self.live, self._candidate(parameters)
        changes = settings.differences(old, new)
        if not changes:
            return
        self.live = new
        self._node.get_logger().info(f"parameters set: {', '.join(changes)}")
        if self._apply is not None:
            self._apply(new)
        self.publish_status()

    def values(self) -> dict[str, str]:
        """Name -> rendered value of every parameter in force (read-only first)."""
        found = {}
        for instance in (self.read_only, self.live):
            if instance is not None:
                found.update({name: settings.render(value) for name, value in settings.values(instance).items()})
        return found

    def publish_status(self) -> None:
        self._status_pub.publish(diagnostic_array(
            self._node.get_clock().now().to_msg(), f"msfsu/{self._node.get_name()}/parameters", OK,
            "values in force", self.values()))
