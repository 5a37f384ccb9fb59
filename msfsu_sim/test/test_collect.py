import json

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from msfsu_common import topics
from msfsu_common.bag_io import msfsu_typestore, read_bag_metadata
from msfsu_common.image_codec import decode_depth, decode_mono8, decode_rgb
from msfsu_common.road_option import RoadOption
from msfsu_sim.collect import (DROPPED_LOG, MAX_ROUTE_M, SPAWN_ROOM_M, Episode, bag_path, collection_routes, draw_route,
                               episode_route, pending, plan, record_episode)
from msfsu_sim.environment import SPAWN_LONGITUDE_M
from msfsu_sim.route_catalog import RoadRoute


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


# ----- routes -----
def _route(junctions, length_m=200.0, start_road_m=40.0, end="x"):
    return RoadRoute(("a", "b", "c", end), tuple(junctions), length_m, start_road_m)


def test_collection_routes_cross_a_junction_leave_room_to_spawn_and_are_not_too_long():
    fits = _route([RoadOption.LEFT])
    longest = _route([RoadOption.RIGHT], length_m=SPAWN_LONGITUDE_M + MAX_ROUTE_M)
    routes = [fits, _route([]), longest, _route([RoadOption.STRAIGHT], length_m=SPAWN_LONGITUDE_M + MAX_ROUTE_M + 1),
              _route([RoadOption.LEFT], start_road_m=SPAWN_LONGITUDE_M + SPAWN_ROOM_M - 0.1)]
    assert collection_routes(routes) == [fits, longest]


def test_a_route_is_drawn_by_the_seed():
    routes = [_route([RoadOption.LEFT], end=str(i)) for i in range(50)]
    drawn = [draw_route(routes, seed) for seed in range(40)]
    assert drawn == [draw_route(routes, seed) for seed in range(40)]
    assert len(set(drawn)) > 20
    with pytest.raises(ValueError):
        draw_route([], 0)


def test_episode_routes_come_from_the_town_catalog_by_seed(sim):
    """Episodes of one town get the catalog's routes (the benchmark's), a route per seed, its junctions varied."""
    episodes = plan("train", ["town_a"], ["clear_noon"], ["empty"], 6, base_seed=0)
    routes = [episode_route(sim, episode) for episode in episodes]
    assert routes == [episode_route(sim, episode) for episode in episodes]  # the same seed, the same route
    assert len(set(routes)) == 6  # six seeds, six routes
    catalog = sim.road_routes()
    pool = collection_routes(catalog)
    assert all(route in pool for route in routes) and len(pool) > 50
    assert {RoadOption.LEFT, RoadOption.RIGHT, RoadOption.STRAIGHT} <= {j for route in pool for j in route.junctions}
    assert len({route.checkpoints[:2] for route in pool}) > 10  # many start roads, not the map's one


def test_recorded_bag_reads_back(sim, tmp_path):
    episode = Episode("train", "town_a", "wet_cloudy", "regular", 0, seed=42)
    result = record_episode(sim, episode, tmp_path, max_steps=12, noise=True)
    assert result.kept and result.reason == "timeout" and result.steps == 12
    assert list(sim._env.agent.navigation.checkpoints) == list(result.route)  # it drove the route the bag names
    path = bag_path(tmp_path, episode)
    metadata = read_bag_metadata(path)
    assert metadata == {"split": "train", "map": "town_a", "weather": "wet_cloudy", "traffic": "regular",
                        "seed": "42", "route_start": json.dumps(list(result.route[:2])),
                        "route_destination": result.route[-1], "route_junctions": metadata["route_junctions"],
                        "route_length_m": metadata["route_length_m"]}
    route = next(route for route in sim.road_routes() if route.checkpoints == result.route)
    assert metadata["route_junctions"] == ",".join(option.name for option in route.junctions) != ""
    assert float(metadata["route_length_m"]) == pytest.approx(route.length_m - SPAWN_LONGITUDE_M, abs=0.05)
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
