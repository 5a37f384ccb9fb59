import json

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from msfsu_common import topics
from msfsu_common.bag_io import msfsu_typestore, read_bag_metadata
from msfsu_common.image_codec import decode_depth, decode_mono8, decode_rgb
from msfsu_sim.collect import DROPPED_LOG, Episode, bag_path, pending, plan, record_episode


def test_plan_is_deterministic_and_seeds_differ_per_episode():
    first = plan("train", ["town_a", "town_b"], ["clear_noon"], ["empty", "dense"], 2, base_seed=0)
    assert first == plan("train", ["town_a", "town_b"], ["clear_noon"], ["empty", "dense"], 2, base_seed=0)
    assert len(first) == 8 and len({e.seed for e in first}) == 8
    assert [e.town for e in first] == ["town_a"] * 4 + ["town_b"] * 4


def test_pending_skips_written_and_dropped_episodes(tmp_path):
    episodes = plan("test", ["town_h1"], ["foggy_day"], ["empty"], 3, base_seed=1)
    bag_path(tmp_path, episodes[0]).mkdir(parents=True)
    dropped = {"episode": episodes[1].__dict__, "reason": "collision", "steps": 10}
    (tmp_path / DROPPED_LOG).write_text(json.dumps(dropped) + "\n")
    assert pending(tmp_path, episodes) == [episodes[2]]


def test_recorded_bag_reads_back(sim, tmp_path):
    episode = Episode("train", "town_a", "wet_cloudy", "regular", 0, seed=42)
    result = record_episode(sim, episode, tmp_path, max_steps=12, noise=True)
    assert result.kept and result.reason == "timeout" and result.steps == 12
    path = bag_path(tmp_path, episode)
    assert read_bag_metadata(path) == {"split": "train", "map": "town_a", "weather": "wet_cloudy",
                                       "traffic": "regular", "seed": "42"}
    store = msfsu_typestore()
    with Reader(path) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        decoded = {}
        stamps = {}
        for connection, timestamp, raw in reader.messages():
            message = store.deserialize_cdr(raw, connection.msgtype)
            decoded.setdefault(connection.topic, message)
            stamps.setdefault(timestamp, set()).add(connection.topic)
    assert counts.pop(topics.ROUTE) == 1
    assert set(counts.values()) == {12}
    assert len(stamps) == 12  # every message of a step shares the frame's stamp
    assert decode_rgb(decoded[topics.RGB]).shape == (300, 400, 3)
    assert decoded[topics.DEPTH].encoding == "32FC1" and np.isfinite(decode_depth(decoded[topics.DEPTH])).all()
    assert decode_mono8(decoded[topics.SEMANTIC_IDS]).max() <= 4
    route = decoded[topics.ROUTE]
    assert len(route.poses) == len(route.options) > 10
    assert decoded[topics.EXPERT_ACTION].target_speed >= 0
    assert -1.0 <= decoded[topics.VEHICLE_CONTROL].steer <= 1.0


@pytest.mark.slow
def test_noise_flags_in_a_bag_follow_the_schedule(sim, tmp_path):
    episode = Episode("train", "town_a", "clear_noon", "empty", 0, seed=7)
    result = record_episode(sim, episode, tmp_path, max_steps=110, noise=True)
    assert result.noisy_steps == 10 * 2  # bursts at 5 s and 10 s, 1 s each at 10 Hz
