"""The launcher's lifecycle manager: brings the managed nodes of a launch to a target state through their
lifecycle_msgs services, as launch_ros's autostart does (`ros2 lifecycle set` drives the same services by hand).

Each managed node goes on its own, in the order of the transitions: configure (unconfigured -> inactive), then
activate (-> active); a target of `inactive` stops after configure, `unconfigured` asks for nothing. The manager is
polled from the launcher's loop (`poll`), so stop signals and nodes that exit are seen while a node configures
(loading a network takes seconds to minutes). It has its own rclpy context, discovery kept on this host, and
closes it once every node is there: the launch holds no participant of its own while it runs.

A service request can be lost: one sent as soon as the service shows up may reach none of a new node's readers
(the service can show up through an endpoint of an older participant of that name), and a reply can miss a reader
that matched late. A transition unanswered for STATE_PROBE_S is therefore checked with the node's get_state: in the
step's goal state, the step is done; still in its start state, the request is sent again (a configure that failed
and whose reply was lost fails again, with its reason logged again); while the node works on it (its executor
busy), get_state waits with it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from msfsu_common.ros_env import configure_ros_environment

TARGETS = ("active", "inactive", "unconfigured")
TRANSITIONS = {"active": ("configure", "activate"), "inactive": ("configure",), "unconfigured": ()}
SERVICE_TIMEOUT_S = 300.0  # a node offers its services once it has started (imports: torch on a busy machine)
STATE_PROBE_S = 5.0  # a transition unanswered this long: ask the node for its state (module doc)
STATES = {"configure": ("unconfigured", "inactive"), "activate": ("inactive", "active")}  # step -> (start, goal)


class LifecycleError(RuntimeError):
    """A managed node did not reach the target state; the message is one line that says which and why."""


@dataclass
class _Progress:
    """Where one managed node is: the transitions still to ask for, the request in flight."""

    name: str
    client: Any  # ChangeState
    state_client: Any  # GetState
    steps: list[str]
    since: float = field(default_factory=time.monotonic)
    request: Any = None  # the future of the transition asked for
    asked_at: float = 0.0  # when it was asked for, or its state was last probed
    probe: Any = None  # the future of a get_state asked for while the transition is unanswered


class LifecycleManager:
    """Drives `names` (managed nodes of this ROS domain) to `target`; `poll()` until `done`, then `close()`."""

    def __init__(self, names: list[str], target: str) -> None:
        configure_ros_environment()
        import rclpy
        from lifecycle_msgs.srv import ChangeState, GetState
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions

        self.target = target
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)  # the launcher's handlers
        self.node = Node("bringup_lifecycle_manager", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.pending = [_Progress(name, self.node.create_client(ChangeState, f"/{name}/change_state"),
                                  self.node.create_client(GetState, f"/{name}/get_state"), list(TRANSITIONS[target]))
                        for name in names if TRANSITIONS[target]]

    @property
    def done(self) -> bool:
        return not self.pending

    def poll(self, timeout_s: float) -> list[str]:
        """Wait up to `timeout_s` for answers, then advance every node; returns what each node that moved did, as
        `[bringup]` lines. LifecycleError when a node refuses a transition or offers no lifecycle service."""
        self.executor.spin_once(timeout_sec=timeout_s)
        done: list[str] = []
        for progress in list(self.pending):
            done += self._advance(progress)
        return done

    def _advance(self, progress: _Progress) -> list[str]:
        if progress.request is not None:
            if progress.request.done() and progress.request.result().success:
                return self._step_done(progress)
            return self._probe(progress, refused=progress.request.done())
        if not progress.client.service_is_ready():
            if time.monotonic() - progress.since > SERVICE_TIMEOUT_S:
                raise LifecycleError(f"{progress.name} offers no lifecycle service {progress.client.srv_name} after "
                                     f"{SERVICE_TIMEOUT_S:.0f} s: is it a lifecycle node? (`lifecycle: true` in the "
                                     "profile says so)")
            return []
        self._ask(progress)
        return []

    def _ask(self, progress: _Progress) -> None:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        progress.request = progress.client.call_async(
            ChangeState.Request(transition=Transition(label=progress.steps[0])))
        progress.asked_at, progress.probe = time.monotonic(), None

    def _step_done(self, progress: _Progress) -> list[str]:
        step = progress.steps.pop(0)
        progress.request = progress.probe = None
        if not progress.steps:
            self.pending.remove(progress)
        return [f"{progress.name}: {step} done"]

    def _probe(self, progress: _Progress, refused: bool) -> list[str]:
        """A transition refused, or unanswered for STATE_PROBE_S: what the node's state says of it (module doc; a
        refusal that finds the node in the goal state answered a request sent twice)."""
        from lifecycle_msgs.srv import GetState

        if progress.probe is None:
            if refused or time.monotonic() - progress.asked_at > STATE_PROBE_S:
                progress.probe = progress.state_client.call_async(GetState.Request())
            return []
        if not progress.probe.done():
            return []
        state = progress.probe.result().current_state.label
        start, goal = STATES[progress.steps[0]]
        if state == goal:  # taken (the reply lost, or the refusal was of a request sent again)
            return self._step_done(progress)
        if refused:
            raise LifecycleError(f"{progress.name} did not {progress.steps[0]} (its log says why)")
        if state == start:  # the request lost (or refused, the reply lost): ask again
            self._ask(progress)
        else:
            progress.asked_at, progress.probe = time.monotonic(), None
        return []

    def close(self) -> None:
        """Destroy the manager's node and context (its participant leaves /dev/shm clean)."""
        if self.context.ok():
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
            self.context.try_shutdown()
