"""A fresh start without a restart: each node that keeps state from frame to frame (the control's PID and watchdog,
the route node's tracker, the brake's tracks, perception's pairing and held frame) offers `~/reset`
(std_srvs/srv/Trigger, topics.RESET_SERVICE). A call makes the node forget that state as if it had just started, its
parameters and connections kept; the answer says what was forgotten. The closed-loop benchmark resets every node of
the graph before each episode (closed_loop.graph_agent), so an episode's outcome does not depend on the episode driven
before it; a user does the same between two drives with `ros2 service call /control/reset std_srvs/srv/Trigger`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from msfsu_common import topics


def offer_reset(node: Any, forget: Callable[[], str]) -> Any:
    """Create the node's `~/reset` service; `forget()` clears the node's state and says what it cleared."""
    from std_srvs.srv import Trigger

    def answer(_request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.message = forget()
        response.success = True
        node.get_logger().info(f"reset: {response.message}")
        return response

    return node.create_service(Trigger, topics.RESET_SERVICE, answer)


def reset_service_name(node_name: str) -> str:
    """The reset service of the node named `node_name` (in the root namespace), for a client."""
    return f"/{node_name}/{topics.RESET_SERVICE.removeprefix('~/')}"
