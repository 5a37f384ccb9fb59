"""The network as a benchmark driver: the real node graph, in lockstep with the benchmark's simulator.

route, perception and control run as their own processes (bringup profile `agent`) in the ROS domain
of the calling worker process; this process publishes each frame through msfsu_sim.lockstep (the
sim_bridge node's code) from an in-process node and waits for the VehicleControl stamped with it. The
nodes stay up across episodes: each episode publishes a new latched route and /clock runs on.
The simulator's own command goes to /msfsu/sim/navigation_command, as in the `sim` profile: the
graph's command comes from the route node.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from msfsu_common import topics
from msfsu_common.processes import die_with_parent
from msfsu_sim.environment import Observation, SimEnvironment

SIM_COMMAND_TOPIC = "/msfsu/sim/navigation_command"
STARTUP_TIMEOUT_S = 180.0  # importing torch and loading the checkpoint on a busy 2-core machine
MATCH_DELAY_S = 1.0  # endpoints discovered: let the publishers match before the first frame
STOP_TIMEOUT_S = 30.0
LOG_TAIL_LINES = 20


class GraphError(RuntimeError):
    """The node graph did not start or died; the message ends with its log."""


def log_tail(log: Path) -> str:
    lines = log.read_text(errors="replace").splitlines()[-LOG_TAIL_LINES:] if log.exists() else []
    return f"last lines of {log}:\n" + "\n".join(lines)


class GraphAgent:
    """Driver (see episode.Driver) backed by the node graph; `close()` stops the graph."""

    def __init__(self, name: str, checkpoint: Path, environment: SimEnvironment, log: Path,
                 control_timeout_s: float = 5.0) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        from msfsu_sim.lockstep import LockstepLink

        self.name, self.log, self.control_timeout_s = name, log, control_timeout_s
        self.unanswered_frames = 0
        self.context = Context()
        rclpy.init(context=self.context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
        self.node = Node("benchmark_sim", context=self.context,
                         cli_args=["--ros-args", "-r", f"{topics.NAVIGATION_COMMAND}:={SIM_COMMAND_TOPIC}"])
        self.link = LockstepLink(self.node, environment)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        log.parent.mkdir(parents=True, exist_ok=True)
        with log.open("a") as output:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "msfsu_bringup", "agent", "--arg", f"checkpoint={checkpoint}"],
                stdout=output, stderr=subprocess.STDOUT, preexec_fn=die_with_parent())  # worker dies: launcher stops
        try:
            self._wait_until_ready()
        except BaseException:
            self.close()
            raise

    def _ready(self) -> bool:
        node = self.node
        return (node.count_subscribers(topics.RGB) > 0 and node.count_subscribers(topics.ROUTE) > 0
                and node.count_subscribers(topics.ODOMETRY) > 1 and node.count_publishers(topics.VEHICLE_CONTROL) > 0)

    def _wait_until_ready(self) -> None:
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while not self._ready():
            self._check_alive()
            if time.monotonic() > deadline:
                raise GraphError(f"the agent graph was not up after {STARTUP_TIMEOUT_S:.0f} s\n{log_tail(self.log)}")
            self.executor.spin_once(timeout_sec=0.1)
        settle = time.monotonic() + MATCH_DELAY_S
        while time.monotonic() < settle:
            self.executor.spin_once(timeout_sec=0.05)

    def _check_alive(self) -> None:
        if self.process.poll() is not None:
            raise GraphError(f"the agent graph exited with code {self.process.returncode}\n{log_tail(self.log)}")

    # ----- Driver -----
    def begin(self, obs: Observation, env: SimEnvironment) -> None:
        self.unanswered_frames = 0
        self.link.start_episode(obs)
        self._first_frame = True

    def act(self, obs: Observation, env: SimEnvironment) -> tuple[float, float, float]:
        """Publish the frame of `obs` (the first is published by `begin`) and wait for its control."""
        if not self._first_frame:
            self.link.publish_frame(obs)
        self._first_frame = False
        while not self.link.answered:
            if self.link.waited_s() > self.control_timeout_s:
                self._check_alive()
                self.unanswered_frames += 1
                break
            self.executor.spin_once(timeout_sec=0.01)
        return self.link.control

    def end(self, obs: Observation) -> None:
        self.link.end_episode(obs)

    def close(self) -> None:
        import rclpy

        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)  # the launcher stops its nodes
            try:
                self.process.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
