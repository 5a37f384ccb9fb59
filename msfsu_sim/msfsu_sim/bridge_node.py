"""sim_bridge node: the embedded simulator on the ROS graph, stepped in lockstep (CARLA synchronous mode)
or free-running (asynchronous mode).

Each frame is published through msfsu_sim.lockstep (shared with the closed-loop benchmark). In lockstep
(`real_time_factor` 0, the default) the simulation advances when a VehicleControl stamped with that frame
time arrives, or after `control_timeout` seconds of wall time with the last control (so a dead controller
cannot stall the graph): results do not depend on CPU speed. With `real_time_factor` R > 0 it steps on the
wall clock, R simulated seconds per second, with whatever control arrived last (msfsu_sim.pacing): the
graph has to keep up, as on a vehicle.

Every `status_period` simulated seconds it logs a status line (msfsu_sim.status), one per episode end,
and after `episodes` episodes (0: run on) a summary, then it exits (the bringup launch ends with it).
"""

from __future__ import annotations

import time

from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter

from msfsu_common.node_runner import NodeFinished, StartupError, run_node
from msfsu_common.params import declare
from msfsu_common.transport import MAX_CAMERA_HEIGHT, MAX_CAMERA_WIDTH, SENSOR_QUEUE_DEPTH
from msfsu_sim.environment import SimConfig, SimEnvironment
from msfsu_sim.lockstep import LockstepLink
from msfsu_sim.pacing import RealTimePacer
from msfsu_sim.scenarios import TOWNS, TRAFFIC, WEATHERS
from msfsu_sim.status import RunStatus


class SimBridge(Node):
    def __init__(self, environment: SimEnvironment | None = None,
                 parameter_overrides: list[Parameter] | None = None, context: Context | None = None) -> None:
        super().__init__("sim_bridge", parameter_overrides=parameter_overrides or [], context=context)
        self.town = declare(self, "town", "town_a", f"map: {', '.join(TOWNS)}")
        self.weather = declare(self, "weather", "clear_noon", f"weather: {', '.join(WEATHERS)}")
        self.traffic = declare(self, "traffic", "regular", f"traffic: {', '.join(TRAFFIC)}")
        self.seed = declare(self, "seed", 0, "seed of traffic and pedestrians (next episode: seed + 1)", 0, 2**31 - 1)
        width = declare(self, "width", 400, "camera width, px", 32, MAX_CAMERA_WIDTH)
        height = declare(self, "height", 300, "camera height, px", 32, MAX_CAMERA_HEIGHT)
        self.control_timeout = declare(self, "control_timeout", 1.0,
                                       "step with the last control after this many wall seconds", 0.01, 60.0)
        qos_depth = declare(self, "qos_depth", SENSOR_QUEUE_DEPTH, "queue depth of the reliable sensor publishers", 1, 100)
        labels = declare(self, "labels", False, "render and publish 5-class ids (a third render pass)")
        status_period = declare(self, "status_period", 5.0, "log a status line every this many sim seconds (0: off)",
                                0.0, 3600.0)
        episodes = declare(self, "episodes", 0, "exit after this many episodes (0: run on)", 0, 1_000_000)
        real_time_factor = declare(self, "real_time_factor", 0.0, "0: lockstep; R > 0: free-running, R simulated "
                                   "seconds per wall second with the last control that arrived", 0.0, 10.0)
        for name, choices in (("town", TOWNS), ("weather", WEATHERS), ("traffic", TRAFFIC)):
            if getattr(self, name) not in choices:
                raise StartupError(f"unknown {name} '{getattr(self, name)}' (accepted: {', '.join(choices)})")

        self.environment = environment or SimEnvironment(SimConfig(width=width, height=height, labels=labels))
        self.link = LockstepLink(self, self.environment, qos_depth)
        self.pacer = RealTimePacer(real_time_factor) if real_time_factor > 0 else None
        self.overdue = False  # free-running: the next step was due before its frame was out
        self.episode = 0
        self.status = RunStatus(status_period, episodes, free_running=self.pacer is not None)
        self.start_episode()
        self.create_timer(0.002, self.tick)

    def start_episode(self) -> None:
        self.obs = self.environment.reset(self.town, self.weather, self.traffic, self.seed + self.episode)
        self.link.start_episode(self.obs)
        if self.pacer is not None:
            self.pacer.start()
        self.status.start_episode(self.environment.tracker.length_m)

    @property
    def lockstep_steps(self) -> int:
        """Steps taken on the control of their frame (all episodes)."""
        return self.status.total.lockstep

    @property
    def timeout_steps(self) -> int:
        """Steps taken with an older control: after `control_timeout` (lockstep) or when due (free-running)."""
        return self.status.total.timeout

    def tick(self) -> None:
        link = self.link
        if self.pacer is not None:
            if time.monotonic() < self.pacer.due():
                return
            self.pacer.step_taken(self.overdue, link.control_age_s())
        elif not (link.answered or link.waited_s() > self.control_timeout):
            return
        self.obs = self.environment.step(*link.control)
        line = self.status.step(self.obs, link.answered)
        if line is not None:
            self.get_logger().info(line)
        if self.obs.done:
            self.get_logger().info(self.status.end_episode(self.obs))
            self.episode += 1
            link.end_episode(self.obs)
            if self.status.finished:
                self.get_logger().info(self.status.summary())
                raise NodeFinished()
            self.start_episode()
            return
        link.publish_frame(self.obs)
        self.overdue = self.pacer is not None and self.pacer.late()


def main(args: list[str] | None = None) -> int:
    return run_node(SimBridge, args)
