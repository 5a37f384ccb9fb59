"""`main()` of every node: environment, rclpy.init, spin, clean shutdown, exit code.

Stop signals. rclpy's own SIGINT/SIGTERM handlers stay off (`SignalHandlerOptions.NO`). They hand the signal to a
thread of rclpy's that first wakes the executor and then shuts the context down; an executor woken between the two
sees a live context, waits again and, with nothing else to wake it (a timer on a paused /clock), never returns;
a wait set built between the two raises RCLError instead. That thread also shuts the context down while the main
thread tears the node down, a race that can leave a node answering neither SIGINT nor SIGTERM (what was seen:
docs/decisions.md, "rclpy's signal handling off in every node"). Here SIGINT and SIGTERM
raise KeyboardInterrupt in the main thread (`interrupt_on_signals`), and the executor waits at most
`SIGNAL_POLL_S` at a time, so a signal is acted on within that time by the one thread that then tears down.
A second stop signal during the teardown ends the process at once (the default action). A managed (lifecycle)
node is taken through its shutdown transition before it is destroyed, from whichever state it is in
(`shut_down_managed`): it releases what it holds as `ros2 lifecycle set <node> shutdown` would have it do.
A teardown that takes longer than STALL_REPORT_S prints every thread's stack to stderr (faulthandler) and goes on:
a node that does not stop says where it waits, in the launcher's log, before the launcher escalates.
"""

from __future__ import annotations

import faulthandler
import signal
import sys
from collections.abc import Callable, Sequence

from msfsu_common.processes import interrupt_on_signals
from msfsu_common.ros_env import configure_ros_environment

SIGNAL_POLL_S = 0.1  # the longest a stop signal waits for the executor's wait to return
STALL_REPORT_S = 5.0  # a teardown this long prints where it waits (half the launcher's grace before SIGTERM)


class StartupError(RuntimeError):
    """A node cannot start (bad parameter, missing/incompatible checkpoint); message says why."""


class NodeFinished(Exception):
    """Raised from a callback by a node whose job is done (a bag played to its end): exit code 0."""


class NodeFailed(RuntimeError):
    """Raised from a callback by a node that cannot do its job (a bag player nothing listens to): its message as one
    line on stderr, exit code 1."""


def init_ros(args: Sequence[str] | None = None) -> None:
    """`rclpy.init` for a process whose main thread spins: stop signals raise KeyboardInterrupt (module doc)."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    interrupt_on_signals()
    rclpy.init(args=list(args) if args is not None else None, signal_handler_options=SignalHandlerOptions.NO)


def spin(executor) -> None:
    """Run the executor's callbacks until its context shuts down; a stop signal interrupts within SIGNAL_POLL_S."""
    while executor.context.ok():
        executor.spin_once(timeout_sec=SIGNAL_POLL_S)


def shut_down_managed(node: object) -> None:
    """The shutdown transition of a lifecycle node in a primary state other than finalized; nothing for a plain
    node, a finalized one, or one stopped inside a transition (rclpy refuses the shutdown then: its state machine
    is mid-way, and the node is destroyed as it is)."""
    from rclpy.impl.implementation_singleton import rclpy_implementation
    from rclpy.lifecycle import LifecycleNode

    if not isinstance(node, LifecycleNode):
        return
    try:
        node.trigger_shutdown()
    except rclpy_implementation.RCLError:
        pass


def run_node(node_factory: Callable[[], object], args: Sequence[str] | None = None) -> int:
    """Create the node, spin it until Ctrl-C / SIGTERM / shutdown, and return a process exit code."""
    return run_nodes([node_factory], args)


def run_nodes(node_factories: Sequence[Callable[[], object]], args: Sequence[str] | None = None) -> int:
    """`run_node` for several nodes composed in one process: one executor, one thread, so a message one of them
    publishes to another is taken without waking a second process."""
    configure_ros_environment()
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    init_ros(args if args is not None else sys.argv)
    nodes: list = []
    exit_code = 0
    try:
        executor = SingleThreadedExecutor()
        for factory in node_factories:
            nodes.append(factory())
            executor.add_node(nodes[-1])
        spin(executor)
    except (StartupError, NodeFailed) as error:
        print(f"[FATAL] {error}", file=sys.stderr, flush=True)
        exit_code = 1
    except (KeyboardInterrupt, ExternalShutdownException, NodeFinished):
        pass
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_DFL)
        faulthandler.dump_traceback_later(STALL_REPORT_S)
        try:
            for node in reversed(nodes):
                shut_down_managed(node)
                node.destroy_node()
            rclpy.try_shutdown()
        finally:
            faulthandler.cancel_dump_traceback_later()
    return exit_code
