"""A closed-loop episode through carla-ros-bridge's own message types: the embedded simulator speaks them as the bridge
does (sim_bridge's carla_messages: the route as the waypoint publisher's nav_msgs/Path, the car driven by
carla_msgs/CarlaEgoVehicleControl on the bridge's topic; its own Route, command and VehicleControl moved off the
graph), and the nodes of the shipped `carla` profile, with the profile's parameters and remappings, drive the shipped
network to the destination: the route node's commands come from the path's shape, the car moves on the CARLA
controls alone.

Every node runs in one process on one executor, spun on the main thread (Panda3D's task manager installs a signal
handler when it steps); the profile's remappings are given to rclpy as node-scoped remapping rules. That process is
a pytest of its own (INNER): MetaDrive allows one engine per process, and the pytest worker that runs this file may
hold another test file's simulator.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")
from carla_msgs.msg import CarlaEgoVehicleControl  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from msfsu_bringup.launcher import load_profile, node_parameters, profile_path  # noqa: E402
from msfsu_common import topics  # noqa: E402
from msfsu_common.message_types import stamp_ns  # noqa: E402
from msfsu_common.node_runner import NodeFinished  # noqa: E402
from msfsu_common.road_option import RoadOption  # noqa: E402
from msfsu_interfaces.msg import NavigationCommand, VehicleControl  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
CHECKPOINT = REPO / "models" / "msfsu_default.pt"
ROUTES = REPO / "msfsu_evaluation" / "msfsu_evaluation" / "closed_loop" / "routes.json"
ROUTE = ("corl2017", "one_turn", "train", 0)  # town_a, 86 m with one right turn at a junction
# where the simulator's own messages go: nothing of the graph takes them
SIM_ROUTE, SIM_CONTROL = "/msfsu/sim/route", "/msfsu/sim/vehicle_control"
MAX_FRAMES = 600  # the expert drives the route in under 200


def route_spec():
    from msfsu_sim.sim_types import RouteSpec

    suite, task, condition, index = ROUTE
    [route] = [r for r in json.loads(ROUTES.read_text())["routes"] if (r["suite"], r["task"], r["condition"],
                                                                      r["index"]) == ROUTE]
    return route, RouteSpec(start=tuple(route["start"]), lane=route["lane"], longitude_m=route["longitude_m"],
                            destination=route["destination"])


class Probe(Node):
    def __init__(self) -> None:
        super().__init__("carla_probe")
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.carla_controls: list[CarlaEgoVehicleControl] = []
        self.vehicle_controls: list[VehicleControl] = []
        self.commands: dict[int, int] = {}  # the route node's, by odometry stamp
        self.truth: dict[int, int] = {}  # the simulator's own (RoadOption labels of its map), by frame stamp
        self.odometry: list[Odometry] = []
        self.create_subscription(CarlaEgoVehicleControl, topics.CARLA_VEHICLE_CONTROL, self.carla_controls.append, qos)
        self.create_subscription(VehicleControl, topics.VEHICLE_CONTROL, self.vehicle_controls.append, qos)
        self.create_subscription(NavigationCommand, topics.NAVIGATION_COMMAND,
                                 lambda msg: self.commands.__setitem__(stamp_ns(msg.header), msg.command), qos)
        self.create_subscription(NavigationCommand, topics.SIM_NAVIGATION_COMMAND,
                                 lambda msg: self.truth.__setitem__(stamp_ns(msg.header), msg.command), qos)
        self.create_subscription(Odometry, topics.ODOMETRY, self.odometry.append, qos)


def graph_nodes(checkpoint: Path) -> tuple[list[tuple[str, list[Parameter]]], list[str]]:
    """The carla profile's nodes as (name, parameters) and its remappings as node-scoped rclpy arguments; fp32 (the
    int8 network would be built on a fresh clone's first run: half a minute), the simulator's camera for the brake."""
    _, specs = load_profile(profile_path("carla"), {"checkpoint": str(checkpoint), "precision": "fp32",
                                                    "aeb_camera": "{}"})
    assert [spec.name for spec in specs] == ["route", "perception", "aeb", "control"]
    remaps = [argument for spec in specs for source, target in spec.remappings.items()
              for argument in ("-r", f"{spec.name}:{source}:={target}")]
    nodes = [(spec.name, [Parameter(name, value=value) for name, value in node_parameters(spec).items()])
             for spec in specs]
    return nodes, remaps


@pytest.fixture
def episode(tmp_path):
    """Drive the route once; return the simulator bridge, the probe and the route node when the episode has ended."""
    from msfsu_control.aeb_node import AebNode
    from msfsu_control.control_node import ControlNode
    from msfsu_control.route_node import RouteNode
    from msfsu_perception.perception_node import PerceptionNode
    from msfsu_sim.assets import install_assets
    from msfsu_sim.bridge_node import SimBridge
    from msfsu_sim.environment import SimConfig, SimEnvironment

    route, spec = route_spec()

    class RoutedEnvironment(SimEnvironment):
        """The simulator on the benchmark's route (sim_bridge drives a town's default route)."""

        def reset(self, *args, **kwargs):
            return super().reset(*args, route=spec, **kwargs)

    nodes, remaps = graph_nodes(CHECKPOINT)
    simulator_remaps = ["-r", f"sim_bridge:{topics.ROUTE}:={SIM_ROUTE}",
                        "-r", f"sim_bridge:{topics.NAVIGATION_COMMAND}:={topics.SIM_NAVIGATION_COMMAND}",
                        "-r", f"sim_bridge:{topics.VEHICLE_CONTROL}:={SIM_CONTROL}"]
    install_assets()
    environment = RoutedEnvironment(SimConfig(labels=False))
    rclpy.init(args=["test_carla_closed_loop", "--ros-args", *remaps, *simulator_remaps],
               domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    executor = SingleThreadedExecutor()
    made: list[Node] = []
    try:
        classes = {"route": RouteNode, "perception": lambda p: PerceptionNode(p, autostart=True), "aeb": AebNode,
                   "control": ControlNode}
        for name, parameters in nodes:
            made.append(classes[name](parameters))
        route_node = made[0]
        probe = Probe()
        made.append(probe)
        bridge = SimBridge(environment, [Parameter("town", value=route["town"]),
                                         Parameter("weather", value=route["weather"]),
                                         Parameter("traffic", value="empty"), Parameter("episodes", value=1),
                                         Parameter("carla_messages", value=True),
                                         Parameter("control_timeout", value=5.0)])
        made.append(bridge)
        for node in made:
            executor.add_node(node)
        try:
            while bridge.lockstep_steps + bridge.timeout_steps < MAX_FRAMES:
                executor.spin_once(timeout_sec=0.05)
        except NodeFinished:  # the bridge after its episode
            pass
        yield bridge, probe, route_node
    finally:
        executor.shutdown()
        for node in reversed(made):
            node.destroy_node()
        rclpy.try_shutdown()
        environment.close()


INNER = "MSFSU_CARLA_EPISODE"  # set in the process the episode runs in


def test_an_episode_drives_to_its_destination_on_carla_controls_and_the_path_s_turns():
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:xdist", "-p", "no:cacheprovider",
                          f"{__file__}::test_the_episode_in_a_process_of_its_own"], env={**os.environ, INNER: "1"},
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0 and "1 passed" in run.stdout, run.stdout[-4000:] + run.stderr[-2000:]


@pytest.mark.skipif(not os.environ.get(INNER), reason="the test above runs it in a process of its own")
def test_the_episode_in_a_process_of_its_own(episode):
    bridge, probe, route_node = episode
    assert dict(bridge.status.outcomes) == {"arrived": 1}, bridge.status.summary()
    # every frame answered in lockstep, by the controls of the bridge's topic: the stack's own control never came
    assert bridge.timeout_steps <= 1 and bridge.lockstep_steps > 50, bridge.status.summary()
    assert bridge.link.controls_received >= bridge.lockstep_steps
    assert probe.vehicle_controls == [] and len(probe.carla_controls) >= bridge.lockstep_steps
    assert max(control.throttle for control in probe.carla_controls) > 0.2
    # the route node's route was the bridge-style Path (the simulator's Route went elsewhere): options from its shape
    assert route_node.tracker is not None and RoadOption.STRAIGHT not in route_node.tracker.options
    assert set(route_node.tracker.options) == {RoadOption.LANE_FOLLOW, RoadOption.RIGHT}
    # ... and its commands announce the junction's turn where the simulator's map labels it
    turn_frames = [stamp for stamp, command in probe.truth.items() if command == RoadOption.RIGHT]
    assert len(turn_frames) > 10
    agreeing = [stamp for stamp in turn_frames if probe.commands.get(stamp) == RoadOption.RIGHT]
    assert len(agreeing) >= 0.8 * len(turn_frames), (len(agreeing), len(turn_frames))
    assert RoadOption.RIGHT in probe.commands.values() and set(probe.commands.values()) <= {
        RoadOption.LANE_FOLLOW, RoadOption.RIGHT}
