"""The shipped profiles name topics through msfsu_common.topics (YAML cannot import it: checked here)."""

from __future__ import annotations

import ast
import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from msfsu_bringup.launcher import load_profile, profile_path
from msfsu_common import topics

PROFILES = ("replay", "sim", "sim_expert", "agent", "carla")
REPO = Path(__file__).resolve().parents[2]
TOPIC_NAMES = {value for name, value in vars(topics).items() if name.isupper() and value.startswith("/")}


def strings(value: object) -> Iterator[str]:
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from strings(key)
            yield from strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from strings(item)


def load(name: str) -> dict:
    return yaml.safe_load(profile_path(name).read_text())


def test_every_profile_is_checked():
    assert sorted(p.stem for p in profile_path("replay").parent.glob("*.yaml")) == sorted(PROFILES)


@pytest.mark.parametrize("name", PROFILES)
def test_every_topic_a_profile_names_is_a_topics_constant(name):
    profile = load(name)
    named = {text for text in strings([profile["arguments"], profile["nodes"]]) if text.startswith("/")}
    assert named <= TOPIC_NAMES, sorted(named - TOPIC_NAMES)


def test_sim_profile_moves_the_simulators_command_to_the_sim_topic():
    [bridge] = [node for node in load("sim")["nodes"] if node["name"] == "sim_bridge"]
    assert bridge["remappings"] == {topics.NAVIGATION_COMMAND: topics.SIM_NAVIGATION_COMMAND}


def test_sim_expert_profile_drives_control_with_the_experts_action():
    [control] = [node for node in load("sim_expert")["nodes"] if node["name"] == "control"]
    assert control["remappings"] == {topics.DRIVING_ACTION: topics.EXPERT_ACTION}


def test_the_benchmarked_agent_graph_infers_each_frame_with_its_own_command():
    """The closed-loop benchmark drives the agent profile in lockstep: its perception waits for the command stamped
    for each frame (command_wait > 0) instead of taking whatever command came last, which in graph revision 1 was the
    previous frame's whenever the route node answered after the images. What the node does with the wait is
    tests/test_perception_graph.py's (test_command_wait_*); control's odometry order is tests/test_control_graph.py's
    (test_an_action_waiting_with_its_frames_odometry_is_served_with_that_odometry)."""
    nodes = {node.name: node for node in load_profile(profile_path("agent"), {"checkpoint": "x.pt"})[1]}
    assert nodes["perception"].parameters["command_wait"] > 0
    assert all(node.parameters["use_sim_time"] for node in nodes.values())  # stamps are the simulator's frames


@pytest.mark.parametrize("real_time_factor", ["0.0", "1.0"])
def test_the_sim_profile_waits_for_each_frames_command_in_lockstep_as_the_agent_profile_does(real_time_factor):
    """Driving the simulator by hand in lockstep is the benchmarked graph: perception's command_wait is the agent
    profile's; free-running (real_time_factor > 0) nothing answers a frame's own odometry in step, so it is 0."""
    [agent_perception] = [n for n in load_profile(profile_path("agent"), {"checkpoint": "x.pt"})[1]
                          if n.name == "perception"]
    nodes = load_profile(profile_path("sim"), {"checkpoint": "x.pt", "real_time_factor": real_time_factor})[1]
    [perception] = [node for node in nodes if node.name == "perception"]
    lockstep = float(real_time_factor) == 0.0
    expected = agent_perception.parameters["command_wait"] if lockstep else 0.0
    assert perception.parameters["command_wait"] == expected
    assert isinstance(perception.parameters["command_wait"], float)


def is_lifecycle_node(package: str, executable: str) -> bool:
    """Whether the console script `executable` of `package` (its setup.py) runs a node class derived from rclpy's
    LifecycleNode (read from the module's source: importing the simulator's node would load the simulator)."""
    [module] = re.findall(rf"[\"']{re.escape(executable)}\s*=\s*([\w.]+):",
                          (REPO / package / "setup.py").read_text())
    tree = ast.parse((REPO / package / Path(*module.split("."))).with_suffix(".py").read_text())
    return any(isinstance(base, ast.Name) and base.id == "LifecycleNode"
               for node in ast.walk(tree) if isinstance(node, ast.ClassDef) for base in node.bases)


@pytest.mark.parametrize("name", PROFILES)
def test_a_profile_marks_exactly_its_lifecycle_nodes_so_the_launcher_drives_them(name):
    """A lifecycle node left unmarked would stay unconfigured (no subscription: a bag player waiting for one times
    out); a plain node marked would end the launch when it offers no lifecycle service."""
    nodes = load(name)["nodes"]
    assert {node["name"]: bool(node.get("lifecycle")) for node in nodes} == {
        node["name"]: is_lifecycle_node(node["package"], node["executable"]) for node in nodes}
    assert ("perception" in {node["name"] for node in nodes}) == any(node.get("lifecycle") for node in nodes)


def test_the_carla_profile_drives_a_car_through_the_bridges_own_messages_in_lockstep():
    """Against a live carla-ros-bridge: the control goes out as the bridge's CarlaEgoVehicleControl only, every node
    runs on the bridge's /clock, perception waits for each frame's command as in the benchmarked graph, and the brake
    sees with the recipe's camera (docs/carla.md) unless told otherwise."""
    nodes = {node.name: node for node in load_profile(profile_path("carla"), {"checkpoint": "x.pt"})[1]}
    assert list(nodes) == ["route", "perception", "aeb", "control"]
    assert nodes["control"].parameters["output"] == "carla"
    assert all(node.parameters["use_sim_time"] for node in nodes.values())
    [agent_perception] = [n for n in load_profile(profile_path("agent"), {"checkpoint": "x.pt"})[1]
                          if n.name == "perception"]
    assert nodes["perception"].parameters["command_wait"] == agent_perception.parameters["command_wait"] > 0
    assert nodes["perception"].remappings == {topics.DRIVING_ACTION: topics.NETWORK_ACTION}
    recipe = json.loads((REPO / "docs" / "carla.md").read_text().split("```json\n", 1)[1].split("```", 1)[0])
    [rgb] = [sensor for sensor in recipe["objects"][0]["sensors"] if sensor["id"] == topics.RGB_SENSOR]
    camera = nodes["aeb"].parameters
    assert (camera["camera_width_px"], camera["camera_height_px"], camera["camera_fov_deg"]) == (
        rgb["image_size_x"], rgb["image_size_y"], rgb["fov"])
    assert (camera["camera_forward_m"], camera["camera_right_m"], camera["camera_height_m"]) == (
        rgb["spawn_point"]["x"], rgb["spawn_point"]["y"], rgb["spawn_point"]["z"])
    assert camera["camera_pitch_deg"] == rgb["spawn_point"]["pitch"]
    both = {node.name: node for node in load_profile(profile_path("carla"), {"checkpoint": "x.pt",
                                                                             "control_output": "both"})[1]}
    assert both["control"].parameters["output"] == "both"
    assert "aeb" not in {node.name for node in load_profile(profile_path("carla"), {"checkpoint": "x.pt",
                                                                                     "aeb": "false"})[1]}
