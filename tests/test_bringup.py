"""`python -m msfsu_bringup replay` on a bag: the whole graph as separate processes, outputs recorded;
and what any way of ending a command leaves behind: no node process, no participant's Fast DDS
segment in /dev/shm (tests/process_hygiene.py); the same where ros2cli is installed (the Docker image)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from process_hygiene import alive, descendants, fast_dds_files, leaked_shm_files, wait_until_gone
from ros2cli import ros2cli_environment
from ros_graph import Lifecycle
from rosbags.rosbag2 import Reader

from msfsu_bringup.bag_player import STARTED_MESSAGE
from msfsu_common import topics
from msfsu_common.bag_io import METADATA_FILE
from msfsu_interfaces.msg import DrivingAction
from msfsu_perception.synthetic import write_synthetic_bag

N_FRAMES = 30
GRAPH_NODES = 3  # replay profile without recording: bag_player, perception, control


def replay(bag: Path, checkpoint: Path, *arguments: str) -> list[str]:
    return [sys.executable, "-m", "msfsu_bringup", "replay", "--arg", f"bag={bag}",
            "--arg", f"checkpoint={checkpoint}", *arguments]


def test_replay_profile_runs_a_bag_through_the_graph_and_records_outputs(tiny_checkpoint, tmp_path):
    bag, outputs = tmp_path / "input", tmp_path / "outputs"
    write_synthetic_bag(bag, n_frames=N_FRAMES, split="test")
    present_before = fast_dds_files()
    launch = subprocess.Popen(replay(bag, tiny_checkpoint, "--arg", f"record={outputs}", "--arg", "rate=0.5"),
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    nodes: set[int] = set()
    while launch.poll() is None:  # follow the node processes while they run
        nodes |= descendants(launch.pid)
        time.sleep(0.2)
    output = launch.communicate(timeout=180)[0]
    assert launch.returncode == 0, output
    assert "bag_player exited with code 0" in output
    with Reader(outputs) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    # Half speed leaves the tiny network time per frame even under load (it would skip, serving the newest).
    assert counts["/msfsu/driving_action"] >= N_FRAMES - 2
    assert counts["/msfsu/segmentation"] >= N_FRAMES - 2
    assert counts["/msfsu/vehicle_control"] >= N_FRAMES - 2
    assert len(nodes) >= GRAPH_NODES + 1 and not alive(nodes)  # the launch ended normally: every node with it
    assert leaked_shm_files(present_before) == set()


def test_a_replay_whose_perception_is_never_activated_ends_non_zero_saying_why(tiny_checkpoint, tmp_path):
    """`--lifecycle unconfigured` and nobody activating perception: the player waits `wait_timeout`, then the launch
    ends with exit code 1 and the player's line (it used to play the bag into nothing and exit 0)."""
    bag = tmp_path / "input"
    write_synthetic_bag(bag, n_frames=10, split="test")
    launch = subprocess.run(replay(bag, tiny_checkpoint, "--arg", "wait_timeout=3", "--lifecycle", "unconfigured"),
                            capture_output=True, text=True, timeout=180)
    output = launch.stdout + launch.stderr
    assert launch.returncode == 1, output
    assert "[bringup] perception left unconfigured (--lifecycle unconfigured)" in output
    assert (f"[FATAL] no subscriber on {topics.RGB} after 3 s: nothing played (a managed node subscribes only once "
            "active)") in output
    assert "bag_player exited with code 1" in output and "Traceback" not in output


def test_perception_deactivated_mid_bag_pauses_the_replay_and_its_frames_are_not_lost(graph, tiny_checkpoint,
                                                                                   tmp_path):
    """2 s inactive at half speed would have lost 10 of the 30 frames; the player pauses instead, the launch ends
    with 0 and the outputs hold what an undisturbed replay's do (the frame perception held when deactivated aside)."""
    bag, outputs, log = tmp_path / "input", tmp_path / "outputs", tmp_path / "launch.log"
    write_synthetic_bag(bag, n_frames=N_FRAMES, split="test")
    actions = graph.probe.collect(DrivingAction, topics.NETWORK_ACTION)
    with log.open("w") as output:
        launch = subprocess.Popen(replay(bag, tiny_checkpoint, "--arg", f"record={outputs}", "--arg", "rate=0.5"),
                                  stdout=output, stderr=subprocess.STDOUT)
    try:
        lifecycle = Lifecycle(graph, "perception")
        assert graph.wait_for(lambda: len(actions) >= 5, 120), log.read_text()
        assert lifecycle.set("deactivate")
        time.sleep(2.0)
        assert lifecycle.set("activate")
        assert launch.wait(timeout=120) == 0, log.read_text()
    finally:
        if launch.poll() is None:
            launch.kill()
    text = log.read_text()
    assert "paused at" in text and "resumed" in text, text
    with Reader(outputs) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts["/msfsu/driving_action"] >= N_FRAMES - 3
    assert counts["/msfsu/vehicle_control"] >= N_FRAMES - 3


def start_and_wait_for_playback(command: list[str], log: Path, started_in: Path) -> subprocess.Popen:
    """Start `command` (output into `log`) and return once the bag player logged, in `started_in`, that it plays."""
    with log.open("w") as output:
        process = subprocess.Popen(command, stdout=output, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 120
    while not (started_in.is_file() and STARTED_MESSAGE in started_in.read_text()):
        assert process.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.2)
    return process


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_stopped_launch_leaves_no_node_and_no_shm_file(tiny_checkpoint, tmp_path, stop):
    bag = tmp_path / "input"
    write_synthetic_bag(bag, n_frames=N_FRAMES, split="test")
    present_before = fast_dds_files()
    log = tmp_path / "launch.log"
    launch = start_and_wait_for_playback(replay(bag, tiny_checkpoint, "--arg", "rate=0.1"), log, log)
    nodes = descendants(launch.pid)
    assert len(nodes) >= GRAPH_NODES
    launch.send_signal(stop)
    assert launch.wait(timeout=60) == 0, log.read_text()
    assert not wait_until_gone(nodes, 5.0)
    assert leaked_shm_files(present_before) == set()


def test_a_terminated_evaluation_leaves_no_graph_behind(tiny_checkpoint, tmp_path):
    """msfsu-eval-bag has no SIGTERM handler: the kernel tells its graph (launcher, nodes) to stop."""
    bag, out = tmp_path / "input", tmp_path / "out"
    write_synthetic_bag(bag, n_frames=N_FRAMES, split="test")
    present_before = fast_dds_files()
    evaluation = start_and_wait_for_playback(
        [str(Path(sys.executable).parent / "msfsu-eval-bag"), str(bag), "--checkpoint", str(tiny_checkpoint),
         "--out", str(out), "--rate", "0.1", "--cache-dir", str(tmp_path / "cache")],
        tmp_path / "evaluation.log", out / "replay.log")
    graph = descendants(evaluation.pid)  # the launcher and its nodes
    assert len(graph) >= GRAPH_NODES + 2  # + recorder, + launcher
    evaluation.send_signal(signal.SIGTERM)
    assert evaluation.wait(timeout=30) == -signal.SIGTERM
    left = wait_until_gone(graph, 20.0)  # the bag would play for 30 s more
    for pid in left:  # clean up what a failing run left
        subprocess.run(["kill", "-INT", str(pid)], check=False)
    assert not left
    assert leaked_shm_files(present_before) == set()


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_launch_with_ros2cli_installed_stops_every_node_and_the_recorder_closes_its_bag(tmp_path, stop):
    bag, recorded = tmp_path / "input", tmp_path / "recorded"
    write_synthetic_bag(bag, n_frames=N_FRAMES, split="test")
    profile = tmp_path / "play_and_record.yaml"
    profile.write_text(yaml.safe_dump({"nodes": [
        {"name": "bag_player", "package": "msfsu_bringup", "executable": "bag_player",
         "parameters": {"bag": str(bag), "rate": 0.1, "wait_for": [topics.NAVIGATION_COMMAND], "wait_timeout": 60.0}},
        {"name": "bag_recorder", "package": "msfsu_bringup", "executable": "bag_recorder",
         "parameters": {"output": str(recorded), "topics": [topics.NAVIGATION_COMMAND]}},
    ]}))
    env = ros2cli_environment(tmp_path, "msfsu_bringup", ["bag_player", "bag_recorder"])
    log = tmp_path / "launch.log"
    with log.open("w") as output:
        launch = subprocess.Popen([sys.executable, "-m", "msfsu_bringup", str(profile)], env=env,
                                  stdout=output, stderr=subprocess.STDOUT)
    nodes: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while STARTED_MESSAGE not in log.read_text():  # the player plays once the recorder subscribed
            assert launch.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.2)
        nodes = descendants(launch.pid)
        launch.send_signal(stop)
        assert launch.wait(timeout=60) == 0, log.read_text()
        assert not wait_until_gone(nodes, 5.0)
    finally:
        for pid in alive(nodes):  # what a failing launch left behind
            os.kill(pid, signal.SIGINT)
        wait_until_gone(nodes, 10.0)
    assert (recorded / METADATA_FILE).is_file(), log.read_text()
    with Reader(recorded) as reader:
        assert [c.topic for c in reader.connections] == [topics.NAVIGATION_COMMAND]


@pytest.mark.parametrize("target", ["unconfigured", "inactive"])
def test_the_launcher_brings_its_lifecycle_nodes_to_the_state_asked(graph, tiny_checkpoint, tmp_path, target):
    """`--lifecycle` (default active, as launch_ros's autostart, which every replay above relies on: the player
    waits for perception's camera subscription): `inactive` stops after configure; `unconfigured` leaves the node
    for `ros2 lifecycle set`, which then drives it by hand."""
    profile = tmp_path / "perception.yaml"
    profile.write_text(yaml.safe_dump({"nodes": [{"name": "perception", "package": "msfsu_perception",
                                                  "executable": "perception", "lifecycle": True,
                                                  # torch: no export to ONNX and OpenVINO compile at configure
                                                  "parameters": {"checkpoint": str(tiny_checkpoint),
                                                                 "backend": "torch"}}]}))
    log = tmp_path / "launch.log"
    command = [sys.executable, "-m", "msfsu_bringup", str(profile), "--lifecycle", target]
    with log.open("w") as output:
        launch = subprocess.Popen(command, stdout=output, stderr=subprocess.STDOUT)
    nodes: set[int] = set()
    try:
        lifecycle = Lifecycle(graph, "perception")
        if target != "unconfigured":
            assert graph.wait_for(lambda: f"[bringup] perception: {target}" in log.read_text(), 120), log.read_text()
        assert lifecycle.state() == target
        subscribed = graph.probe.count_subscribers(topics.RGB)
        assert subscribed == (target == "active")
        if target == "unconfigured":  # by hand, as `ros2 lifecycle set /perception configure` / `activate`
            assert "configure done" not in log.read_text()
            assert lifecycle.set("configure") and lifecycle.set("activate")
            assert graph.wait_for(lambda: graph.probe.count_subscribers(topics.RGB) == 1)
        nodes = descendants(launch.pid)
        launch.send_signal(signal.SIGINT)
        assert launch.wait(timeout=60) == 0, log.read_text()
        assert not wait_until_gone(nodes, 5.0)
    finally:
        if launch.poll() is None:
            launch.kill()
        for pid in alive(nodes):
            os.kill(pid, signal.SIGINT)
