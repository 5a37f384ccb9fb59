"""bag_recorder -> bag -> bag_player round trip, as separate processes (SIGINT flush included); killed
recorders, cut bags and non-bags."""

import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import Pose
from process_hygiene import fast_dds_files, owned_segments, remove_stale_shm_files
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import Image

from msfsu_common.bag_io import msfsu_typestore, open_bag
from msfsu_common.image_codec import decode_rgb, encode_image
from msfsu_control.route_node import ROUTE_QOS
from msfsu_interfaces.msg import DrivingAction, Route
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.synthetic import write_synthetic_bag

BIN = Path(sys.executable).parent
N_FRAMES = 20
PERIOD_S = 0.1
IMAGE_TOPIC, ACTION_TOPIC, ROUTE_TOPIC = "/rt/image", "/rt/action", "/rt/route"


def frame(index: int) -> tuple[Image, DrivingAction]:
    pixels = np.full((12, 16, 3), index, np.uint8)
    image = Image(**encode_image(pixels, "rgb8"))
    image.header.stamp.sec = 100 + index
    action = DrivingAction(steer=index / N_FRAMES, target_speed=float(index), command=4)
    action.header.stamp = image.header.stamp
    return image, action


def route() -> Route:
    poses = [Pose() for _ in range(3)]
    for index, pose in enumerate(poses):
        pose.position.x = float(index)
    return Route(poses=poses, options=[4, 1, 4])


@pytest.fixture
def recorded_bag(graph, tmp_path) -> Path:
    """Record frames published at 10 Hz, stop the recorder with SIGINT; return the bag."""
    bag = tmp_path / "roundtrip"
    recorder = subprocess.Popen([str(BIN / "bag_recorder"), str(bag), "--topics", IMAGE_TOPIC, ACTION_TOPIC, ROUTE_TOPIC])
    try:
        graph.probe.publish(ROUTE_TOPIC, route(), ROUTE_QOS)
        for index in range(N_FRAMES):
            image, action = frame(index)
            graph.probe.publish(IMAGE_TOPIC, image)
            graph.probe.publish(ACTION_TOPIC, action)
            time.sleep(PERIOD_S)
    finally:
        recorder.send_signal(signal.SIGINT)
        assert recorder.wait(timeout=20) == 0
    graph.probe.stop_publishing(ROUTE_TOPIC)  # its latched route would reach the tests' subscribers too
    assert graph.wait_for(lambda: graph.probe.count_publishers(ROUTE_TOPIC) == 0)
    return bag


def recorded_image_span(bag: Path, first: int = 0) -> float:
    """Seconds between the `first` and last recorded image (receive times stored by the recorder)."""
    with Reader(bag) as reader:
        times = [t for c, t, _ in reader.messages() if c.topic == IMAGE_TOPIC]
    return (times[-1] - times[first]) * 1e-9


def test_recorder_flushes_every_message_on_sigint(recorded_bag):
    bag = recorded_bag
    store = msfsu_typestore()
    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts == {IMAGE_TOPIC: N_FRAMES, ACTION_TOPIC: N_FRAMES, ROUTE_TOPIC: 1}
        actions = [store.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages()
                   if c.topic == ACTION_TOPIC]
    assert [a.target_speed for a in actions] == [float(i) for i in range(N_FRAMES)]
    assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap"))


def test_player_replays_everything_with_original_timing(graph, recorded_bag):
    bag = recorded_bag
    images = graph.probe.collect(Image, IMAGE_TOPIC)
    actions = graph.probe.collect(DrivingAction, ACTION_TOPIC)
    routes = graph.probe.collect(Route, ROUTE_TOPIC, ROUTE_QOS)
    received_at: list[float] = []
    graph.probe.create_subscription(Image, IMAGE_TOPIC, lambda _: received_at.append(time.monotonic()), 100)
    player = subprocess.run([str(BIN / "bag_player"), str(bag), "--wait-for", IMAGE_TOPIC, ACTION_TOPIC],
                            timeout=60, capture_output=True, text=True)
    assert player.returncode == 0, player.stderr
    assert graph.wait_for(lambda: len(images) == N_FRAMES and len(actions) == N_FRAMES and len(routes) == 1), (
        len(images), len(actions), len(routes), player.stderr)
    for index, (image, action) in enumerate(zip(images, actions)):
        expected_image, expected_action = frame(index)
        np.testing.assert_array_equal(decode_rgb(image), decode_rgb(expected_image))
        assert image.header.stamp == expected_image.header.stamp
        assert (action.steer, action.target_speed) == (np.float32(expected_action.steer), expected_action.target_speed)
    assert list(routes[0].options) == [4, 1, 4]
    assert 1.5 < recorded_image_span(bag) < 3.0
    # from the second image on: the first one's delivery can wait for the player's writer to finish matching the
    # probe's reader (seen once: 160 ms), which says nothing about the player's timing
    assert received_at[-1] - received_at[1] == pytest.approx(recorded_image_span(bag, first=1), abs=0.1)


def test_player_rate_factor_speeds_up_playback(graph, recorded_bag):
    bag = recorded_bag
    received_at: list[float] = []
    graph.probe.create_subscription(Image, IMAGE_TOPIC, lambda _: received_at.append(time.monotonic()), 100)
    player = subprocess.run([str(BIN / "bag_player"), str(bag), "--rate", "4", "--wait-for", IMAGE_TOPIC],
                            timeout=60, capture_output=True, text=True)
    assert player.returncode == 0, player.stderr
    assert graph.wait_for(lambda: len(received_at) == N_FRAMES)
    assert received_at[-1] - received_at[1] == pytest.approx(recorded_image_span(bag, first=1) / 4, abs=0.1)


def test_recorder_killed_outright_leaves_a_bag_readable_up_to_its_last_flush(graph, tmp_path, caplog):
    bag = tmp_path / "killed"
    present_before = fast_dds_files()
    recorder = subprocess.Popen([str(BIN / "bag_recorder"), str(bag), "--topics", ACTION_TOPIC, "--flush-period", "0.2"])
    try:
        for index in range(N_FRAMES):
            graph.probe.publish(ACTION_TOPIC, frame(index)[1])
            time.sleep(0.02)
        time.sleep(1.0)  # received and past a flush
        owned = owned_segments(recorder.pid)
    finally:
        recorder.kill()  # SIGKILL: no handler, no close(), no metadata.yaml
        recorder.wait(timeout=20)
        # what Fast DDS could not clean up: the recorder's 80 MiB segment, which the probe still maps (it used to
        # stay behind after every run)
        remove_stale_shm_files(fast_dds_files() - present_before)
    assert owned and not {name for name in fast_dds_files() if name.removesuffix("_el") in owned}
    assert not (bag / "metadata.yaml").exists()
    store = msfsu_typestore()
    with caplog.at_level(logging.WARNING), open_bag(bag) as reader:
        actions = [store.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert [a.target_speed for a in actions] == [float(i) for i in range(N_FRAMES)]
    assert "no metadata.yaml" in caplog.text or "no footer" in caplog.text


def player_stderr_lines(bag: Path) -> list[str]:
    player = subprocess.run([str(BIN / "bag_player"), str(bag)], timeout=60, capture_output=True, text=True)
    assert player.returncode == 1
    return player.stderr.strip().splitlines()


def test_player_refuses_what_is_not_a_bag_in_one_line(tmp_path):
    assert player_stderr_lines(tmp_path / "nothing") == [
        f"[FATAL] {tmp_path / 'nothing'}: no such bag (no such file or directory)"]
    noise = tmp_path / "noise"
    write_synthetic_bag(noise, 2, with_clock=False)
    next(noise.glob("*.mcap")).write_bytes(np.random.default_rng(0).bytes(50_000))  # random bytes, real metadata
    assert player_stderr_lines(noise) == [
        f"[FATAL] {next(noise.glob('*.mcap'))}: not an MCAP file (wrong magic bytes at its start)"]


def test_player_plays_every_complete_chunk_of_a_cut_bag(graph, tmp_path):
    bag = tmp_path / "cut"
    write_synthetic_bag(bag, 20, with_clock=False, height=240, width=320)  # ~0.6 MB a frame: 1 MiB chunks
    mcap = next(bag.glob("*.mcap"))
    os.truncate(mcap, int(mcap.stat().st_size * 0.6))
    with open_bag(bag) as reader:
        recovered = {c.topic: c.msgcount for c in reader.connections}
    assert 0 < recovered[BagTopics().rgb] < 20
    images = graph.probe.collect(Image, BagTopics().rgb)
    actions = graph.probe.collect(DrivingAction, BagTopics().expert_action)
    player = subprocess.run([str(BIN / "bag_player"), str(bag), "--rate", "4", "--wait-for", BagTopics().rgb],
                            timeout=60, capture_output=True, text=True)
    assert player.returncode == 0, player.stderr
    assert "damaged bag, recovered what it holds" in player.stderr and "Traceback" not in player.stderr
    assert graph.wait_for(lambda: len(images) == recovered[BagTopics().rgb]
                          and len(actions) == recovered[BagTopics().expert_action])


# --- the player waits for its consumers, before and while playing ------------------------------------------------
def fatal_lines(stderr: str) -> list[str]:
    assert "Traceback" not in stderr, stderr
    return [line for line in stderr.splitlines() if line.startswith("[FATAL]")]


def test_player_with_nobody_to_play_to_ends_non_zero_saying_so_and_plays_nothing(graph, tmp_path):
    bag = tmp_path / "bag"
    write_synthetic_bag(bag, 10, with_clock=False)
    images = graph.probe.collect(Image, BagTopics().rgb)  # a subscriber of what it plays, not of what it waits for
    player = subprocess.run([str(BIN / "bag_player"), str(bag), "--wait-for", "/rt/nobody", "--wait-timeout", "1"],
                            timeout=60, capture_output=True, text=True)
    assert player.returncode == 1
    assert fatal_lines(player.stderr) == ["[FATAL] no subscriber on /rt/nobody after 1 s: nothing played (a managed "
                                          "node subscribes only once active)"]
    time.sleep(0.5)
    assert images == []


class Consumer:
    """A subscriber of the images that goes away and comes back, as a managed node deactivated and activated."""

    def __init__(self, graph) -> None:
        self.graph, self.stamps, self.subscription = graph, [], None

    def subscribe(self) -> None:
        self.subscription = self.graph.probe.create_subscription(
            Image, BagTopics().rgb, lambda image: self.stamps.append(image.header.stamp.sec * 10**9
                                                                     + image.header.stamp.nanosec), 100)

    def leave(self) -> None:
        self.graph.probe.destroy_subscription(self.subscription)


def play_while_the_consumer_leaves(graph, tmp_path: Path, wait_timeout: float, away_s: float | None):
    """Play a 30-frame bag (3 s) to a consumer that leaves after 5 frames and comes back `away_s` later (None: never);
    return the player's exit code and stderr, the consumer, and the bag's truth."""
    bag = tmp_path / "bag"
    truth = write_synthetic_bag(bag, 30, with_clock=False)
    consumer = Consumer(graph)
    consumer.subscribe()
    player = subprocess.Popen([str(BIN / "bag_player"), str(bag), "--wait-for", BagTopics().rgb, "--wait-timeout",
                               str(wait_timeout)], stderr=subprocess.PIPE, text=True)
    try:
        assert graph.wait_for(lambda: len(consumer.stamps) >= 5, 30)
        consumer.leave()
        if away_s is not None:
            time.sleep(away_s)
            consumer.subscribe()
        code = player.wait(timeout=60)
    finally:
        if player.poll() is None:
            player.kill()
    return code, player.stderr.read(), consumer, truth


def test_player_pauses_while_its_consumer_is_gone_and_plays_the_rest_once_it_is_back(graph, tmp_path):
    """Without the pause the 1.5 s away would lose 15 of the 30 frames; with it at most the frame in flight."""
    code, stderr, consumer, truth = play_while_the_consumer_leaves(graph, tmp_path, 30.0, 1.5)
    assert code == 0 and fatal_lines(stderr) == [] and "paused at" in stderr and "resumed" in stderr, stderr
    assert consumer.stamps == sorted(set(consumer.stamps))
    assert set(consumer.stamps) <= set(truth.stamps_ns.tolist()) and len(consumer.stamps) >= len(truth.stamps_ns) - 1


def test_player_whose_consumer_never_comes_back_ends_non_zero_with_what_it_played(graph, tmp_path):
    code, stderr, _, _ = play_while_the_consumer_leaves(graph, tmp_path, 1.0, None)
    assert code == 1
    [fatal] = fatal_lines(stderr)
    assert fatal.startswith(f"[FATAL] no subscriber on {BagTopics().rgb} for 1 s since ")
    played, total = map(int, fatal.split("stopped with ")[1].removesuffix(" messages played").split(" of "))
    with open_bag(tmp_path / "bag") as reader:
        assert total == sum(c.msgcount for c in reader.connections)
    assert 0 < played < total
