"""`ros2 launch msfsu_bringup <profile>.launch.py NAME:=VALUE ...`: the launcher's profiles as ROS 2 launch files.

Each shipped profile has a launch file (`launch/<profile>.launch.py`) that reads the same YAML the launcher reads
(`python -m msfsu_bringup <profile> --arg NAME=VALUE`), so the graph is defined once: the profile's arguments are the
launch arguments (the same names and defaults, given as the same text: `aeb:=false`, `aeb_camera:='{camera_fov_deg:
90.0}'`; a null default is a required argument), its nodes launch_ros Nodes with their parameters, remappings and
conditions resolved by `msfsu_bringup.launcher.load_profile`. What the launcher does around the nodes, the launch
does the launch_ros way:

- managed nodes (`lifecycle: true`) are LifecycleNodes brought to `lifecycle:=active` (default: configure, then
  activate, as launch_ros's lifecycle autostart does, through LifecycleTransition), `inactive` or `unconfigured`;
  a transition a node refuses ends the launch with exit code 1 and a line naming the node;
- the launch ends when any node exits (the bag player at the end of its bag, the simulator after its episodes),
  with exit code 1 and a line naming the node where one exited with another code than 0.

launch and launch_ros are imported only by `profile_launch_description` (apt's ROS 2 has them, the pip wheels do not:
docs/deployment_docker.md); the rest is the launcher's own code. The ROS environment (discovery on this host, the
stack's Fast DDS profile) is set in the launch's own process, whose environment its nodes inherit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from msfsu_bringup.launcher import (TARGETS, TRANSITIONS, NodeSpec, argument_text, load_profile, node_parameters,
                                    profile_path, read_profile)
from msfsu_common.ros_env import configure_ros_environment

LIFECYCLE_ARGUMENT = "lifecycle"  # the launch argument that stands for the launcher's --lifecycle
# a refused transition: the state a node goes back to from the transition's intermediate state
REFUSED = {"configure": ("configuring", "unconfigured"), "activate": ("activating", "inactive")}


def launch_arguments(path: Path) -> dict[str, str | None]:
    """Argument name -> default as launch text (None: required) of a profile, and the lifecycle argument."""
    defaults = read_profile(path).get("arguments") or {}
    if LIFECYCLE_ARGUMENT in defaults:
        raise ValueError(f"{path.name}: the argument name {LIFECYCLE_ARGUMENT!r} is the launch file's own")
    named = {name: None if default is None else argument_text(default) for name, default in defaults.items()}
    return {**named, LIFECYCLE_ARGUMENT: "active"}


def launch_nodes(path: Path, given: dict[str, str]) -> tuple[list[NodeSpec], str]:
    """The nodes of profile `path` for the launch arguments `given` (every argument, as text), and the lifecycle
    target; ProfileError / ValueError (one line) for values the profile refuses."""
    target = given.get(LIFECYCLE_ARGUMENT, "active")
    if target not in TARGETS:
        raise ValueError(f"{LIFECYCLE_ARGUMENT}:={target} is none of {', '.join(TARGETS)}")
    arguments = {name: value for name, value in given.items() if name != LIFECYCLE_ARGUMENT}
    return load_profile(path, arguments)[1], target


def profile_launch_description(profile: str) -> Any:
    """The LaunchDescription of shipped profile `profile` (or a YAML path): its arguments declared, its nodes made
    when the launch runs (the arguments' values known then)."""
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction

    configure_ros_environment()
    path = profile_path(profile)
    description = read_profile(path).get("description", "")
    declared = []
    for name, default in launch_arguments(path).items():
        about = (f"the launcher's --lifecycle: {', '.join(TARGETS)}" if name == LIFECYCLE_ARGUMENT
                 else f"profile argument of {path.name}")
        declared.append(DeclareLaunchArgument(name, description=about) if default is None
                        else DeclareLaunchArgument(name, default_value=default, description=about))
    return LaunchDescription([*declared, OpaqueFunction(function=_actions, args=[path, description])])


def _actions(context: Any, path: Path, description: str) -> list[Any]:
    """The profile's nodes as launch_ros actions, with the lifecycle transitions and the end of the launch."""
    import lifecycle_msgs.msg
    from launch.actions import LogInfo, OpaqueFunction, RegisterEventHandler
    from launch.event_handlers import OnProcessExit
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import LifecycleNode, LifecycleTransition, Node
    from launch_ros.event_handlers import OnStateTransition

    given = {name: LaunchConfiguration(name).perform(context) for name in launch_arguments(path)}
    nodes, target = launch_nodes(path, given)
    transition_ids = {"configure": lifecycle_msgs.msg.Transition.TRANSITION_CONFIGURE,
                      "activate": lifecycle_msgs.msg.Transition.TRANSITION_ACTIVATE}
    actions: list[Any] = [LogInfo(msg=f"[bringup] {path.stem}: {description}")]
    for spec in nodes:
        kind = LifecycleNode if spec.lifecycle else Node
        node = kind(package=spec.package, executable=spec.executable, name=spec.name, namespace="",
                    parameters=[node_parameters(spec)], remappings=list(spec.remappings.items()), output="screen")
        actions.append(node)
        actions.append(RegisterEventHandler(OnProcessExit(
            target_action=node, on_exit=[OpaqueFunction(function=_node_exited, args=[spec.name])])))
        if not spec.lifecycle:
            continue
        for step in TRANSITIONS["active"]:
            start, back = REFUSED[step]
            actions.append(RegisterEventHandler(OnStateTransition(
                target_lifecycle_node=node, start_state=start, goal_state=back,
                entities=[OpaqueFunction(function=_refused, args=[spec.name, step])])))
        if TRANSITIONS[target]:
            actions.append(LifecycleTransition(lifecycle_node_names=[spec.name],
                                               transition_ids=[transition_ids[step] for step in TRANSITIONS[target]]))
    return actions


def _node_exited(context: Any, name: str) -> list[Any]:
    """A node's end ends the launch (once: a second Shutdown would stop launch_ros's ROS adapter twice); an exit code
    other than 0 makes it exit with 1 (launch's return code after an error)."""
    from launch.actions import Shutdown

    code = context.locals.event.returncode
    if code != 0:
        raise RuntimeError(f"[bringup] {name} exited with code {code}: stopping the launch")
    return [] if context.is_shutdown else [Shutdown(reason=f"{name} exited with code 0")]


def _refused(context: Any, name: str, step: str) -> None:
    raise RuntimeError(f"[bringup] {name} did not {step} (its log says why): stopping the launch")
