"""sim_bridge node: the embedded simulator on the ROS graph, stepped in lockstep (CARLA synchronous mode).

Each frame is published through msfsu_sim.lockstep (shared with the closed-loop benchmark); the
simulation advances when a VehicleControl stamped with that frame time arrives, or after
`control_timeout` seconds of wall time with the last control (so a dead controller cannot stall the
graph). Results therefore do not depend on CPU speed.
"""

from __future__ import annotations

from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter

from msfsu_common.node_runner import StartupError, run_node
from msfsu_common.params import declare
from msfsu_sim.environment import SimConfig, SimEnvironment
from msfsu_sim.lockstep import LockstepLink
from msfsu_sim.scenarios import TOWNS, TRAFFIC, WEATHERS


class SimBridge(Node):
    def __init__(self, environment: SimEnvironment | None = None,
                 parameter_overrides: list[Parameter] | None = None, context: Context | None = None) -> None:
        super().__init__("sim_bridge", parameter_overrides=parameter_overrides or [], context=context)
        self.town = declare(self, "town", "town_a", f"map: {', '.join(TOWNS)}")
        self.weather = declare(self, "weather", "clear_noon", f"weather: {', '.join(WEATHERS)}")
        self.traffic = declare(self, "traffic", "regular", f"traffic: {', '.join(TRAFFIC)}")
        self.seed = declare(self, "seed", 0, "seed of traffic and pedestrians (next episode: seed + 1)", 0, 2**31 - 1)
        width = declare(self, "width", 400, "camera width, px", 32, 1920)
        height = declare(self, "height", 300, "camera height, px", 32, 1080)
        self.control_timeout = declare(self, "control_timeout", 1.0,
                                       "step with the last control after this many wall seconds", 0.01, 60.0)
        qos_depth = declare(self, "qos_depth", 5, "queue depth of the reliable sensor publishers", 1, 100)
        labels = declare(self, "labels", False, "render and publish 5-class ids (a third render pass)")
        for name, choices in (("town", TOWNS), ("weather", WEATHERS), ("traffic", TRAFFIC)):
            if getattr(self, name) not in choices:
                raise StartupError(f"unknown {name} '{getattr(self, name)}' (accepted: {', '.join(choices)})")

        self.environment = environment or SimEnvironment(SimConfig(width=width, height=height, labels=labels))
        self.link = LockstepLink(self, self.environment, qos_depth)
        self.lockstep_steps = 0
        self.timeout_steps = 0
        self.episode = 0
        self.start_episode()
        self.create_timer(0.002, self.tick)

    def start_episode(self) -> None:
        self.obs = self.environment.reset(self.town, self.weather, self.traffic, self.seed + self.episode)
        self.link.start_episode(self.obs)

    def tick(self) -> None:
        link = self.link
        if not (link.answered or link.waited_s() > self.control_timeout):
            return
        if link.answered:
            self.lockstep_steps += 1
        else:
            self.timeout_steps += 1
        self.obs = self.environment.step(*link.control)
        if self.obs.done:
            outcome = "arrived" if self.obs.arrived else "collision" if self.obs.collision else "out of road"
            self.get_logger().info(f"episode {self.episode} ended at {link.shifted(self.obs).time_s:.1f} s: {outcome}")
            self.episode += 1
            link.end_episode(self.obs)
            self.start_episode()
            return
        link.publish_frame(self.obs)


def main(args: list[str] | None = None) -> int:
    return run_node(SimBridge, args)
