"""`main()` of every node: environment, rclpy.init, spin, clean shutdown, exit code."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

from msfsu_common.ros_env import configure_ros_environment


class StartupError(RuntimeError):
    """A node cannot start (bad parameter, missing/incompatible checkpoint); message says why."""


class NodeFinished(Exception):
    """Raised from a callback by a node whose job is done (a bag played to its end): exit code 0."""


def run_node(node_factory: Callable[[], object], args: Sequence[str] | None = None) -> int:
    """Create the node, spin it until Ctrl-C / shutdown, and return a process exit code."""
    configure_ros_environment()
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.node import Node

    rclpy.init(args=list(args) if args is not None else sys.argv)
    node: Node | None = None
    exit_code = 0
    try:
        node = node_factory()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except StartupError as error:
        print(f"[FATAL] {error}", file=sys.stderr, flush=True)
        exit_code = 1
    except (KeyboardInterrupt, ExternalShutdownException, NodeFinished):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return exit_code
