"""In-process ROS graph for integration tests: real rclpy, real DDS (this host, private domain id)."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import Any

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


class Probe(Node):
    """Publishes test inputs and collects what the graph publishes."""

    def __init__(self) -> None:
        super().__init__("probe")
        self.received: dict[str, list[Any]] = {}
        self._outputs: dict[str, Any] = {}

    def collect(self, msg_type: type, topic: str, qos: QoSProfile = RELIABLE) -> list[Any]:
        messages = self.received.setdefault(topic, [])
        self.create_subscription(msg_type, topic, messages.append, qos)
        return messages

    def publish(self, topic: str, msg: Any, qos: QoSProfile = RELIABLE) -> None:
        """Publish; a new publisher first waits (up to 10 s) to be matched with a subscriber."""
        if topic not in self._outputs:
            publisher = self.create_publisher(type(msg), topic, qos)
            RosGraph.wait_for(lambda: publisher.get_subscription_count() > 0)
            self._outputs[topic] = publisher
        self._outputs[topic].publish(msg)

    def stop_publishing(self, topic: str) -> None:
        self.destroy_publisher(self._outputs.pop(topic))


class RosGraph:
    """Nodes spun by an executor in a background thread; close() shuts down in the safe order.

    Single-threaded: every callback runs in the spin thread, so once it is joined none runs any more (a
    MultiThreadedExecutor's pool could still run one on a node being destroyed: rclpy's shutdown does not wait).
    """

    def __init__(self) -> None:
        rclpy.init(domain_id=int(os.environ["ROS_DOMAIN_ID"]))
        self.executor = SingleThreadedExecutor()
        self.nodes: list[Node] = []
        self.probe = self.add(Probe())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        # Not executor.spin(): its thread could still be inside a wait when close() shuts the executor down and
        # destroys the executor's guard condition (an exception in this thread). This loop is left first.
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def add(self, node: Node) -> Node:
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    @staticmethod
    def wait_for(predicate: Callable[[], bool], timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.01)
        return predicate()

    def close(self) -> None:
        """Stop spinning, then shut the executor down (waits for running callbacks), then destroy the nodes."""
        self._stop.set()
        self._thread.join()
        self.executor.shutdown(timeout_sec=10.0)
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        rclpy.shutdown()


class Parameters:
    """An rclpy parameter client of one node in the graph (the node's real parameter services)."""

    def __init__(self, graph: RosGraph, node_name: str) -> None:
        self.graph = graph
        self.client = AsyncParameterClient(graph.probe, node_name)
        assert self.client.wait_for_services(timeout_sec=10.0)

    def result(self, future):
        assert self.graph.wait_for(future.done)
        return future.result()

    def set_each(self, **values) -> list[SetParametersResult]:
        """`set_parameters` (what `ros2 param set` sends): each parameter its own set."""
        return self.result(self.client.set_parameters([Parameter(k, value=v) for k, v in values.items()])).results

    def set_together(self, **values) -> SetParametersResult:
        """`set_parameters_atomically`: one set."""
        return self.result(self.client.set_parameters_atomically(
            [Parameter(k, value=v) for k, v in values.items()])).result

    def get(self, *names: str) -> list:
        return [parameter_value_to_python(v) for v in self.result(self.client.get_parameters(list(names))).values]


class Lifecycle:
    """A lifecycle client of one managed node in the graph, as `ros2 lifecycle get` / `set` are: the node's
    lifecycle_msgs services `<node>/get_state` and `<node>/change_state`, transitions named by their labels."""

    def __init__(self, graph: RosGraph, node_name: str) -> None:
        self.graph = graph
        self.change_state = graph.probe.create_client(ChangeState, f"/{node_name}/change_state")
        self.get_state = graph.probe.create_client(GetState, f"/{node_name}/get_state")
        for client in (self.change_state, self.get_state):
            assert client.wait_for_service(timeout_sec=10.0), client.srv_name

    def _call(self, client, request, timeout: float):
        future = client.call_async(request)
        assert self.graph.wait_for(future.done, timeout), f"{client.srv_name} did not answer in {timeout} s"
        return future.result()

    def state(self, timeout: float = 30.0, resend_after: float = 2.0) -> str:
        """The node's state label. The request is sent again every `resend_after` s until answered: a request sent
        the moment the service is discovered can be lost while the server's side of the match is still forming
        (seen on a loaded 2-core CI machine), and asking for the state twice changes nothing."""
        deadline = time.monotonic() + timeout
        while True:
            future = self.get_state.call_async(GetState.Request())
            if self.graph.wait_for(future.done, min(resend_after, max(0.0, deadline - time.monotonic()))):
                return future.result().current_state.label
            self.get_state.remove_pending_request(future)
            assert time.monotonic() < deadline, f"{self.get_state.srv_name} did not answer in {timeout} s"

    def set(self, transition: str, timeout: float = 60.0) -> bool:
        """Ask for `transition` (configure, activate, deactivate, cleanup, shutdown); whether the node took it."""
        return self._call(self.change_state, ChangeState.Request(transition=Transition(label=transition)),
                          timeout).success
