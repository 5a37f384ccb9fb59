import os
import sys
from pathlib import Path

import pytest
import yaml

from msfsu_bringup.launcher import ProfileError, load_profile, main, node_command, profile_path

PROFILE = {
    "description": "test",
    "arguments": {"bag": None, "rate": 1.0, "record": "", "loop": False},
    "nodes": [
        {"name": "player", "package": "msfsu_bringup", "executable": "bag_player",
         "parameters": {"bag": "${bag}", "rate": "${rate}", "loop": "${loop}", "note": "bag ${bag} at ${rate}"},
         "remappings": {"/a": "/b"}},
        {"name": "recorder", "package": "msfsu_bringup", "executable": "bag_recorder",
         "condition": "${record}", "parameters": {"output": "${record}"}},
    ],
}


@pytest.fixture
def profile(tmp_path) -> Path:
    path = tmp_path / "test.yaml"
    path.write_text(yaml.safe_dump(PROFILE))
    return path


def test_arguments_are_substituted_with_the_default_type(profile):
    _, nodes = load_profile(profile, {"bag": "/data/x", "rate": "2", "loop": "true"})
    assert [n.name for n in nodes] == ["player"]  # recorder disabled: record is ""
    assert nodes[0].parameters == {"bag": "/data/x", "rate": 2.0, "loop": True, "note": "bag /data/x at 2.0"}
    assert isinstance(nodes[0].parameters["rate"], float)


def test_conditional_node_starts_when_its_argument_is_set(profile):
    _, nodes = load_profile(profile, {"bag": "b", "record": "/tmp/out"})
    assert [n.name for n in nodes] == ["player", "recorder"]


def test_missing_and_unknown_arguments_are_clear_errors(profile):
    with pytest.raises(ProfileError, match="needs --arg bag=..."):
        load_profile(profile, {})
    with pytest.raises(ProfileError, match=r"unknown argument\(s\) \['speed'\]"):
        load_profile(profile, {"bag": "b", "speed": "3"})


def test_node_command_carries_name_params_file_and_remaps(profile, tmp_path):
    _, nodes = load_profile(profile, {"bag": "b"})
    command = node_command(nodes[0], tmp_path)
    assert command[0].endswith("bag_player")
    assert command[1:] == ["--ros-args", "-r", "__node:=player", "--params-file", str(tmp_path / "player.yaml"),
                           "-r", "/a:=/b"]
    params = yaml.safe_load((tmp_path / "player.yaml").read_text())
    assert params["/**"]["ros__parameters"]["rate"] == 1.0


def test_shipped_profiles_are_found_and_unknown_ones_listed():
    assert profile_path("replay").name == "replay.yaml"
    with pytest.raises(ProfileError, match="shipped: .*replay"):
        profile_path("nonexistent")


def test_the_help_lists_every_shipped_profile_with_what_it_is(capsys):
    with pytest.raises(SystemExit) as ended:
        main(["--help"])
    assert ended.value.code == 0
    text = capsys.readouterr().out
    shipped = sorted(path.stem for path in profile_path("replay").parent.glob("*.yaml"))
    assert f"shipped profile name ({', '.join(shipped)}) or a YAML path" in " ".join(text.split())
    listed = text.split("shipped profiles:\n", 1)[1].splitlines()
    assert [line.split()[0] for line in listed] == shipped
    assert all(len(line.split()) > 2 for line in listed)  # each with its description's first clause


def test_list_and_mapping_arguments_are_yaml_flow_text(tmp_path):
    path = tmp_path / "collections.yaml"
    path.write_text(yaml.safe_dump({
        "arguments": {"topics": [], "remap": {}},
        "nodes": [{"name": "player", "package": "msfsu_bringup", "executable": "bag_player",
                   "parameters": {"topics": "${topics}"}, "remappings": "${remap}"}],
    }))
    _, nodes = load_profile(path, {"topics": "[/a, /b]", "remap": "{/a: /c}"})
    assert nodes[0].parameters == {"topics": ["/a", "/b"]}
    assert nodes[0].remappings == {"/a": "/c"}
    defaults = load_profile(path, {})[1][0]
    assert defaults.remappings == {}
    node_command(defaults, tmp_path)  # an empty list has no ROS type: left out, the node's default applies
    assert yaml.safe_load((tmp_path / "player.yaml").read_text())["/**"]["ros__parameters"] == {}
    with pytest.raises(ProfileError, match="not a YAML dict"):
        load_profile(path, {"remap": "[/a]"})


def installed(prefix: Path, package: str, executable: str) -> Path:
    """`executable` of `package` as colcon installs it under `prefix` (ament index marker, lib/<package>/)."""
    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / package
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.touch()
    path = prefix / "lib" / package / executable
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("#!/bin/sh\n")
    path.chmod(0o755)
    return path


def test_a_node_runs_from_the_first_ament_prefix_that_lists_its_package(profile, tmp_path):
    _, nodes = load_profile(profile, {"bag": "b"})
    overlay, underlay = tmp_path / "overlay", tmp_path / "underlay"
    installed(overlay, "msfsu_control", "bag_player")  # another package's executable of that name does not count
    chosen = installed(underlay, "msfsu_bringup", "bag_player")
    installed(tmp_path / "later", "msfsu_bringup", "bag_player")
    environ = {"AMENT_PREFIX_PATH": os.pathsep.join(str(p) for p in (overlay, underlay, tmp_path / "later"))}
    assert node_command(nodes[0], tmp_path, environ)[0] == str(chosen)
    assert node_command(nodes[0], tmp_path, {})[0] == str(Path(sys.executable).parent / "bag_player")


def test_a_package_in_the_ament_index_without_the_executable_is_a_clear_error(profile, tmp_path):
    _, nodes = load_profile(profile, {"bag": "b"})
    installed(tmp_path, "msfsu_bringup", "bag_recorder")
    with pytest.raises(ProfileError, match=r"executable 'bag_player' of msfsu_bringup is not installed \(.*/lib/"
                                           r"msfsu_bringup/bag_player\)"):
        node_command(nodes[0], tmp_path, {"AMENT_PREFIX_PATH": str(tmp_path)})


def test_a_profile_naming_an_executable_not_installed_is_one_line_and_starts_no_node(tmp_path, capsys):
    path = tmp_path / "missing.yaml"
    path.write_text(yaml.safe_dump({"nodes": [
        {"name": "recorder", "package": "msfsu_bringup", "executable": "bag_recorder", "parameters": {"output": "x"}},
        {"name": "brake", "package": "msfsu_control", "executable": "no_such_node"}]}))
    assert main([str(path)]) == 2
    printed, err = capsys.readouterr()
    assert err.strip() == (f"bringup: executable 'no_such_node' of msfsu_control is not installed "
                           f"({Path(sys.executable).parent / 'no_such_node'})")
    assert "starting" not in printed  # checked before the first node started


def test_a_conditional_value_takes_then_where_its_argument_is_truthy_else_else(tmp_path):
    path = tmp_path / "conditional.yaml"
    path.write_text(yaml.safe_dump({"arguments": {"rate": 0.0, "name": ""}, "nodes": [
        {"name": "n", "package": "p", "executable": "e",
         "parameters": {"wait": {"if": "${rate}", "then": 0.0, "else": 0.1},
                        "label": {"if": "${name}", "then": "node ${name}", "else": "unnamed"}}}]}))
    assert load_profile(path, {})[1][0].parameters == {"wait": 0.1, "label": "unnamed"}
    assert load_profile(path, {"rate": "2", "name": "x"})[1][0].parameters == {"wait": 0.0, "label": "node x"}


def test_a_list_of_parameter_mappings_is_merged_in_order(tmp_path):
    """As launch_ros's `parameters`: a mapping argument adds (and overrides) entries; anything else in the list is
    one line naming the node."""
    path = tmp_path / "merged.yaml"
    path.write_text(yaml.safe_dump({"arguments": {"camera": {}}, "nodes": [
        {"name": "aeb", "package": "p", "executable": "e",
         "parameters": [{"use_sim_time": True, "camera_fov_deg": 80.0}, "${camera}"]}]}))
    assert load_profile(path, {})[1][0].parameters == {"use_sim_time": True, "camera_fov_deg": 80.0}
    merged = load_profile(path, {"camera": "{camera_fov_deg: 90.0, camera_height_m: 2.0}"})[1][0].parameters
    assert merged == {"use_sim_time": True, "camera_fov_deg": 90.0, "camera_height_m": 2.0}
    path.write_text(yaml.safe_dump({"arguments": {"fov": 90.0}, "nodes": [
        {"name": "aeb", "package": "p", "executable": "e", "parameters": [{"a": 1}, "${fov}"]}]}))
    with pytest.raises(ProfileError, match="parameters of node 'aeb' are a list whose items are not all mappings"):
        load_profile(path, {})
