"""The ros2 launch files (msfsu_bringup/launch/*.launch.py) are the launcher's profiles: one per shipped profile, its
arguments the profile's with the same defaults, its nodes the ones the launcher starts (here, without launch_ros).

Where apt's ROS 2 with launch_ros and the stack's colcon install are sourced (the Docker image's environment; not the
pip environment of `make setup`, which has no launch wheels), `ros2 launch` replays a bag through the graph, ends
with 0 when the bag has played, and ends non-zero when perception is never activated; elsewhere those tests skip,
saying what is missing."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader

from msfsu_bringup.launch_description import LIFECYCLE_ARGUMENT, launch_arguments, launch_nodes
from msfsu_bringup.launcher import PROFILE_DIR, _typed, load_profile, read_profile, shipped_profiles
from msfsu_common import topics
from msfsu_perception.synthetic import write_synthetic_bag

REPO = Path(__file__).resolve().parents[1]
LAUNCH_DIR = REPO / "msfsu_bringup" / "launch"


def test_every_shipped_profile_has_its_launch_file_and_every_launch_file_reads_its_profile():
    files = sorted(path.name.removesuffix(".launch.py") for path in LAUNCH_DIR.glob("*.launch.py"))
    assert files == shipped_profiles()
    for name in files:
        text = (LAUNCH_DIR / f"{name}.launch.py").read_text()
        assert f'profile_launch_description("{name}")' in text


@pytest.mark.parametrize("profile", shipped_profiles())
def test_a_launch_files_arguments_are_its_profiles_with_the_same_defaults(profile):
    path = PROFILE_DIR / f"{profile}.yaml"
    defaults = read_profile(path).get("arguments") or {}
    declared = launch_arguments(path)
    assert list(declared) == [*defaults, LIFECYCLE_ARGUMENT] and declared[LIFECYCLE_ARGUMENT] == "active"
    for name, default in defaults.items():
        if default is None:
            assert declared[name] is None, name  # required, as the launcher's
        else:
            assert _typed(declared[name], default) == default, name  # the text reads back to the default


@pytest.mark.parametrize("profile", shipped_profiles())
def test_a_launch_file_starts_the_nodes_the_launcher_starts(profile):
    path = PROFILE_DIR / f"{profile}.yaml"
    required = {name: "x.pt" if name == "checkpoint" else "bags/sample"
                for name, default in launch_arguments(path).items() if default is None}
    given = {name: default for name, default in launch_arguments(path).items() if default is not None} | required
    nodes, target = launch_nodes(path, given)
    assert target == "active"
    assert nodes == load_profile(path, required)[1]
    with_record = {**given, "record": "runs/x"} if "record" in given else given
    assert len(launch_nodes(path, with_record)[0]) == len(nodes) + ("record" in given)


def test_a_lifecycle_target_that_is_none_is_refused_in_one_line():
    path = PROFILE_DIR / "replay.yaml"
    given = {name: default or "x" for name, default in launch_arguments(path).items()}
    with pytest.raises(ValueError, match="^lifecycle:=paused is none of active, inactive, unconfigured$"):
        launch_nodes(path, {**given, LIFECYCLE_ARGUMENT: "paused"})


# --- ros2 launch, where apt's ROS 2 and the stack's colcon install are sourced ---------------------------------------
def launch_environment_missing() -> str | None:
    """Why `ros2 launch msfsu_bringup ...` cannot run here (None: it can)."""
    if importlib.util.find_spec("launch_ros") is None:
        return "launch_ros is not installed (apt's ROS 2 has it; the pip wheels of `make setup` do not)"
    if shutil.which("ros2") is None or importlib.util.find_spec("ros2launch") is None:
        return "no `ros2 launch` (ros2cli with ros2launch) on PATH"
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        share = Path(get_package_share_directory("msfsu_bringup"))
    except PackageNotFoundError:
        return "msfsu_bringup is in no sourced ament index (colcon build the workspace and source its install)"
    if not (share / "launch" / "replay.launch.py").is_file():
        return f"{share} holds no launch/replay.launch.py (an install from before the launch files)"
    return None


needs_ros2_launch = pytest.mark.skipif(launch_environment_missing() is not None,
                                       reason=str(launch_environment_missing()))


def ros2_launch(bag: Path, checkpoint: Path, *arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ros2", "launch", "msfsu_bringup", "replay.launch.py", f"bag:={bag}",
                           f"checkpoint:={checkpoint}", *arguments], capture_output=True, text=True, timeout=300)


@needs_ros2_launch
def test_ros2_launch_replays_a_bag_through_the_graph_and_ends_with_it(tiny_checkpoint, tmp_path):
    bag, outputs = tmp_path / "input", tmp_path / "outputs"
    write_synthetic_bag(bag, n_frames=20, split="test")
    result = ros2_launch(bag, tiny_checkpoint, f"record:={outputs}", "rate:=0.5")
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-4000:]
    assert "Failed to make transition" not in output
    with Reader(outputs) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts[topics.DRIVING_ACTION] >= 18 and counts[topics.VEHICLE_CONTROL] >= 18, counts


@needs_ros2_launch
def test_ros2_launch_ends_non_zero_when_perception_is_never_activated(tiny_checkpoint, tmp_path):
    bag = tmp_path / "input"
    write_synthetic_bag(bag, n_frames=5, split="test")
    result = ros2_launch(bag, tiny_checkpoint, "lifecycle:=unconfigured", "wait_timeout:=3")
    output = result.stdout + result.stderr
    assert result.returncode != 0, output[-4000:]
    assert f"no subscriber on {topics.RGB} after 3 s: nothing played" in output
    assert "[bringup] bag_player exited with code 1" in output
