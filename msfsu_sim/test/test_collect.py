import json
import zlib
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from msfsu_common import bag_io, topics
from msfsu_common.bag_io import EXPERT_LIMITS, msfsu_typestore, read_bag_metadata
from msfsu_common.camera_geometry import FrontCamera
from msfsu_control.aeb_node import AebCamera
from msfsu_common.image_codec import decode_depth, decode_mono8, decode_rgb
from msfsu_common.road_option import RoadOption
from msfsu_control.pid import ActionController
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.bag_paths import split_bags
from msfsu_perception.frame_cache import CacheSpec, open_cache
from msfsu_perception.deploy_files import file_digest
from msfsu_perception.frame_inference import infer_frame
from msfsu_perception.preprocessing import InvalidDepthError, PreprocessConfig
from msfsu_sim import SIMULATOR_REVISION
from msfsu_sim.collect import main, summary
from msfsu_sim.collection_plan import DROPPED_LOG, Episode, bag_path, pending, plan
from msfsu_sim.collection_routes import SPAWN_ROOM_M, collection_routes, draw_route, episode_route
from msfsu_sim.episode_driver import EXPERT, Driver, Pilot, load_network
from msfsu_sim.episode_recording import CRASH_TRIM_S, EpisodeResult, record_episode
from msfsu_sim.environment import SPAWN_LONGITUDE_M, STEP_S
from msfsu_sim.route_catalog import MAX_ROUTE_M, RoadRoute

CRUISE_MPS = 3.0  # the on-policy test network's speed: neither the expert's cruise (8) nor its junction speed (5)
TRIM_STEPS = round(CRASH_TRIM_S / STEP_S)


def read_frames(path) -> dict[str, list[tuple[int, object]]]:
    """topic -> [(log time ns, decoded message)] in log order."""
    store = msfsu_typestore()
    frames: dict[str, list[tuple[int, object]]] = {}
    with Reader(path) as reader:
        for connection, timestamp, raw in reader.messages():
            frames.setdefault(connection.topic, []).append((timestamp, store.deserialize_cdr(raw, connection.msgtype)))
    return frames


def values(frames, topic, read):
    return np.array([read(message) for _, message in frames[topic]])


def replayed_controls(targets, speeds, steers) -> np.ndarray:
    """(throttle, brake, steer) per frame from the control node's controller fed these targets and speeds."""
    controller = ActionController()
    return np.array([tuple(vars(controller.step(steer, target, speed, STEP_S)).values())
                     for target, speed, steer in zip(targets, speeds, steers)])


# ----- planning -----
def test_plan_is_deterministic_and_seeds_differ_per_episode():
    first = plan("train", ["town_a", "town_b"], ["clear_noon"], ["empty", "dense"], 2, base_seed=0)
    assert first == plan("train", ["town_a", "town_b"], ["clear_noon"], ["empty", "dense"], 2, base_seed=0)
    assert len(first) == 8 and len({e.seed for e in first}) == 8
    assert [e.town for e in first] == ["town_a"] * 4 + ["town_b"] * 4
    # round 0 keeps the names and seeds of collections made before rounds existed
    assert first[0].name == "town_a_clear_noon_empty_000"
    assert first[0].seed == zlib.crc32(b"0/train/town_a/clear_noon/empty/0") % 2**31


def test_each_round_has_its_own_names_and_seeds():
    rounds = [plan("train", ["town_a"], ["clear_noon"], ["empty"], 3, base_seed=0, round_index=r) for r in (0, 1, 2)]
    assert [e.name for e in rounds[1]] == [f"town_a_clear_noon_empty_{i:03d}_r1" for i in range(3)]
    assert len({e.name for episodes in rounds for e in episodes}) == 9
    assert len({e.seed for episodes in rounds for e in episodes}) == 9


def test_pending_skips_written_and_dropped_episodes(tmp_path):
    episodes = plan("test", ["town_h1"], ["foggy_day"], ["empty"], 4, base_seed=1)
    bag_path(tmp_path, episodes[0]).mkdir(parents=True)
    dropped = {"episode": episodes[1].__dict__, "reason": "collision", "steps": 10}
    old = {k: v for k, v in episodes[2].__dict__.items() if k != "round"}  # a log written before rounds existed
    lines = [json.dumps(dropped), json.dumps({"episode": old, "reason": "out_of_road", "steps": 5})]
    (tmp_path / DROPPED_LOG).write_text("\n".join(lines) + "\n")
    assert pending(tmp_path, episodes) == [episodes[3]]


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


# ----- expert episodes -----
@pytest.fixture(scope="module")
def expert_episode(sim, tmp_path_factory):
    episode = Episode("train", "town_a", "wet_cloudy", "regular", 0, seed=42)
    output = tmp_path_factory.mktemp("expert")
    result = record_episode(sim, episode, output, max_steps=12, noise=True)
    return episode, result, bag_path(output, episode), list(sim._env.agent.navigation.checkpoints)


def test_recorded_bag_reads_back(expert_episode):
    episode, result, path, driven = expert_episode
    assert result.kept and result.reason == "timeout" and result.steps == 12 and result.frames == 12
    assert result.network_frames == 0
    assert driven == list(result.route)  # the simulator drove the route the bag names
    metadata = read_bag_metadata(path)
    # the camera the frames were rendered with, on the car as it stood at the start: the emergency brake's defaults
    camera, brake = FrontCamera.from_json(metadata.pop("camera")), AebCamera()
    assert (camera.width, camera.height, camera.fov_deg, camera.forward_m, camera.right_m, camera.pitch_deg) == (
        brake.camera_width_px, brake.camera_height_px, brake.camera_fov_deg, brake.camera_forward_m,
        brake.camera_right_m, brake.camera_pitch_deg)
    assert camera.up_m == pytest.approx(brake.camera_height_m, abs=1e-3)
    assert metadata == {"split": "train", "map": "town_a", "weather": "wet_cloudy", "traffic": "regular",
                        "seed": "42", "route_start": json.dumps(list(result.route[:2])),
                        "route_destination": result.route[-1], "route_junctions": metadata["route_junctions"],
                        "route_length_m": metadata["route_length_m"], "driver": "expert", "beta": "1.0", "round": "0",
                        "simulator_revision": str(SIMULATOR_REVISION), "end": "timeout"}
    frames = read_frames(path)
    counts = {topic: len(messages) for topic, messages in frames.items()}
    assert counts.pop(topics.ROUTE) == 1
    assert set(counts.values()) == {12}
    stamps = {}
    for topic, messages in frames.items():
        for timestamp, _ in messages:
            stamps.setdefault(timestamp, set()).add(topic)
    assert len(stamps) == 12  # every message of a step shares the frame's stamp
    first = {topic: messages[0][1] for topic, messages in frames.items()}
    assert decode_rgb(first[topics.RGB]).shape == (300, 400, 3)
    assert first[topics.DEPTH].encoding == "32FC1" and np.isfinite(decode_depth(first[topics.DEPTH])).all()
    assert decode_mono8(first[topics.SEMANTIC_IDS]).max() <= 4
    route = first[topics.ROUTE]
    assert len(route.poses) == len(route.options) > 10
    assert not values(frames, topics.NETWORK_DRIVING, lambda m: m.data).any()
    assert {message.data for _, message in frames[topics.EXPERT_LIMITED_BY]} <= set(EXPERT_LIMITS)
    # the expert's target speed went through the control node's PID (no noise burst within 1.2 s)
    labels = values(frames, topics.EXPERT_ACTION, lambda m: (m.steer, m.target_speed))
    speeds = values(frames, topics.ODOMETRY, lambda m: m.twist.twist.linear.x)
    controls = values(frames, topics.VEHICLE_CONTROL, lambda m: (m.throttle, m.brake, m.steer))
    assert (labels[:, 1] >= 0).all() and controls[:, 0].max() > 0  # it drove off
    np.testing.assert_allclose(controls, replayed_controls(labels[:, 1], speeds, labels[:, 0]), atol=1e-6)


def test_record_from_drives_the_first_steps_without_recording_them(sim, expert_episode, tmp_path):
    """The same episode from step 5: the full recording's last 7 frames (the simulator repeats an episode to
    ~1e-6 m), the route first."""
    episode, _, full_path, _ = expert_episode
    result = record_episode(sim, episode, tmp_path, max_steps=12, noise=True, record_from=5)
    assert result.kept and result.steps == 12 and result.frames == 7
    frames, full = read_frames(bag_path(tmp_path, episode)), read_frames(full_path)
    assert [stamp for stamp, _ in frames.pop(topics.ROUTE)] == [full[topics.ODOMETRY][5][0]]
    assert {t: [s for s, _ in m] for t, m in frames.items()} == {t: [s for s, _ in m][5:] for t, m in full.items()
                                                                 if t != topics.ROUTE}
    for topic, read in ((topics.EXPERT_ACTION, lambda m: (m.steer, m.target_speed)),
                        (topics.ODOMETRY, lambda m: (m.pose.pose.position.x, m.pose.pose.position.y)),
                        (topics.NOISE_INJECTION, lambda m: m.data)):
        np.testing.assert_allclose(values(frames, topic, read), values(full, topic, read)[5:], atol=1e-4)


def test_the_bag_names_a_route_of_the_catalog(sim, expert_episode):
    _, result, path, _ = expert_episode
    metadata = read_bag_metadata(path)
    route = next(route for route in sim.road_routes() if route.checkpoints == result.route)
    assert metadata["route_junctions"] == ",".join(option.name for option in route.junctions) != ""
    assert float(metadata["route_length_m"]) == pytest.approx(route.length_m - SPAWN_LONGITUDE_M, abs=0.05)


def test_with_beta_1_a_network_driver_collects_what_the_expert_does(sim, expert_episode, tmp_path,
                                                                    constant_policy_checkpoint):
    """B = 1 is plain expert collection: same route, same frames, labels and controls (the simulator repeats an
    episode to ~1e-6 m, not bit for bit), no frame by the network; the metadata names the driver and B."""
    episode, expert_result, expert_path, _ = expert_episode
    checkpoint = constant_policy_checkpoint(0.0, CRUISE_MPS)
    driver = Driver(str(checkpoint), 1.0, file_digest(checkpoint), "torch", "fp32")
    result = record_episode(sim, episode, tmp_path, max_steps=12, noise=True, driver=driver,
                            network=load_network(driver))
    assert (result.kept, result.frames, result.network_frames, result.route) == (True, 12, 0, expert_result.route)
    metadata, expert_metadata = read_bag_metadata(bag_path(tmp_path, episode)), read_bag_metadata(expert_path)
    assert metadata.pop("driver") == str(checkpoint) and metadata.pop("driver_digest") == driver.digest
    assert expert_metadata.pop("driver") == "expert" and metadata == expert_metadata
    frames, expert_frames = read_frames(bag_path(tmp_path, episode)), read_frames(expert_path)
    assert {t: [s for s, _ in m] for t, m in frames.items()} == {t: [s for s, _ in m] for t, m in expert_frames.items()}
    for topic, read in ((topics.EXPERT_ACTION, lambda m: (m.steer, m.target_speed)),
                        (topics.VEHICLE_CONTROL, lambda m: (m.throttle, m.brake, m.steer)),
                        (topics.ODOMETRY, lambda m: (m.pose.pose.position.x, m.pose.pose.position.y)),
                        (topics.NAVIGATION_COMMAND, lambda m: m.command),
                        (topics.NOISE_INJECTION, lambda m: m.data), (topics.NETWORK_DRIVING, lambda m: m.data)):
        np.testing.assert_allclose(values(frames, topic, read), values(expert_frames, topic, read), atol=1e-4)


# ----- on-policy episodes -----
@pytest.fixture(scope="module")
def dagger_episode(sim, tmp_path_factory, constant_policy_checkpoint):
    """B = 0 with a network that always answers steer 0 and CRUISE_MPS; 6 s, noise on (a burst is due at 5 s)."""
    checkpoint = constant_policy_checkpoint(0.0, CRUISE_MPS)
    driver = Driver(str(checkpoint), 0.0, file_digest(checkpoint), "torch", "fp32")
    episode = plan("train", ["town_a"], ["clear_noon"], ["empty"], 1, base_seed=0, round_index=1)[0]
    output = tmp_path_factory.mktemp("dagger")
    result = record_episode(sim, episode, output, max_steps=60, noise=True, driver=driver, network=load_network(driver))
    return driver, result, bag_path(output, episode)


def test_with_beta_0_the_network_drives_and_the_expert_labels(dagger_episode):
    driver, result, path = dagger_episode
    assert result.kept and result.reason == "timeout" and result.frames == result.network_frames == 60
    assert result.noisy_steps == 0  # no steering noise on frames the network drives
    metadata = read_bag_metadata(path)
    assert (metadata["driver"], metadata["driver_digest"], metadata["beta"], metadata["round"]) == (
        driver.checkpoint, driver.digest, "0.0", "1")
    frames = read_frames(path)
    assert values(frames, topics.NETWORK_DRIVING, lambda m: m.data).all()
    assert not values(frames, topics.NOISE_INJECTION, lambda m: m.data).any()
    asked = values(frames, topics.DRIVING_ACTION, lambda m: (m.steer, m.target_speed))  # the network's own action
    np.testing.assert_allclose(asked, np.tile([0.0, CRUISE_MPS], (60, 1)), atol=1e-3)
    assert metadata["end"] == "timeout"
    speeds = values(frames, topics.ODOMETRY, lambda m: m.twist.twist.linear.x)
    labels = values(frames, topics.EXPERT_ACTION, lambda m: (m.steer, m.target_speed))
    controls = values(frames, topics.VEHICLE_CONTROL, lambda m: (m.throttle, m.brake, m.steer))
    # the car went to the network's speed, through the control node's PID, with the network's steer ...
    assert abs(speeds[-10:].mean() - CRUISE_MPS) < 0.15 * CRUISE_MPS and speeds.max() < 1.15 * CRUISE_MPS
    np.testing.assert_allclose(controls, replayed_controls(np.full(60, CRUISE_MPS), speeds, np.zeros(60)), atol=1e-6)
    # ... while the labels are the expert's for the states reached: its free-road speed, its steering corrections
    assert (labels[:, 1] >= 5.0).all()
    assert np.abs(labels[:, 0]).max() > 0.05


def test_on_policy_bags_train_like_expert_bags(dagger_episode, expert_episode, tmp_path):
    """The training cache reads the new bags (flag topic, route and driver metadata) and keeps the frames the
    network drove, labelled by the expert."""
    _, result, path = dagger_episode
    _, _, expert_path, _ = expert_episode
    assert split_bags([path, expert_path])["train"] == [path, expert_path]
    spec = CacheSpec((path, expert_path), BagTopics(), PreprocessConfig(input_height=64, input_width=64), True)
    cache = open_cache(spec, tmp_path / "cache")
    assert len(cache) == 60 + 12 and len(cache.valid_rows) == 72
    labels = values(read_frames(path), topics.EXPERT_ACTION, lambda m: (m.steer, m.target_speed))
    np.testing.assert_array_equal(cache.steer[:60], labels[:, 0].astype(np.float32))
    np.testing.assert_array_equal(cache.target_speed[:60], labels[:, 1].astype(np.float32))
    assert [bag["dropped"]["noise"] for bag in cache.manifest["bags"]] == [0, 0]


def test_an_on_policy_crash_is_kept_without_its_last_second(sim, tmp_path, constant_policy_checkpoint):
    """A network steering hard right leaves the road: DAgger keeps the states that led there, not the last second."""
    checkpoint = constant_policy_checkpoint(1.0, 4.0)
    driver = Driver(str(checkpoint), 0.0, file_digest(checkpoint), "torch", "fp32")
    episode = plan("train", ["town_a"], ["clear_noon"], ["empty"], 2, base_seed=0, round_index=1)[1]
    result = record_episode(sim, episode, tmp_path, max_steps=80, noise=False, driver=driver,
                            network=load_network(driver))
    assert result.reason in ("out_of_road", "collision") and result.steps < 80
    assert result.kept and result.frames == result.network_frames == result.steps - TRIM_STEPS > 0
    frames = read_frames(bag_path(tmp_path, episode))
    stamps = [stamp for stamp, _ in frames[topics.EXPERT_ACTION]]
    assert stamps == [round(step * STEP_S * 1e9) for step in range(result.frames)]
    assert (values(frames, topics.VEHICLE_CONTROL, lambda m: m.steer) == 1.0).all()
    assert read_bag_metadata(bag_path(tmp_path, episode))["end"] == result.reason


def test_pilot_draws_the_driver_of_each_step_by_the_seed(tiny_checkpoint):
    network = load_network(Driver(str(tiny_checkpoint), 0.5, "", "torch", "fp32"))

    def draws(seed, beta, steps=2000):
        pilot = Pilot(seed, beta, network)
        return np.array([pilot.network_drives() for _ in range(steps)])

    half = draws(7, 0.5)
    assert abs(half.mean() - 0.5) < 0.05 and (half == draws(7, 0.5)).all() and (half != draws(8, 0.5)).any()
    assert abs(draws(7, 0.75).mean() - 0.25) < 0.05
    assert not draws(7, 1.0).any() and draws(7, 0.0).all()
    assert not Pilot(7, 1.0).network_drives()  # the expert alone needs no network
    with pytest.raises(ValueError):
        Pilot(7, 0.5)


def test_the_pilots_network_predicts_by_the_perception_nodes_per_frame_rules(tiny_checkpoint):
    """Pilot.network_action is infer_frame at the node's default max_invalid_depth_fraction: the same prediction,
    a covered depth camera or a depth of another size rejected as the node drops them."""
    network = load_network(Driver(str(tiny_checkpoint), 0.0, "", "torch", "fp32"))
    pilot = Pilot(7, 0.0, network)
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    depth = rng.uniform(1.0, 60.0, (48, 64)).astype(np.float32)
    depth[:12] = np.nan  # a quarter of the pixels without a return: read as far, as the node does
    obs = SimpleNamespace(rgb=rgb, depth=depth, command=RoadOption.LEFT)
    asked, node = pilot.network_action(obs), infer_frame(network, rgb, depth, RoadOption.LEFT).prediction
    assert (asked.steer, asked.target_speed) == (node.steer, node.target_speed)
    assert (asked.class_ids == node.class_ids).all()
    with pytest.raises(InvalidDepthError):
        pilot.network_action(SimpleNamespace(rgb=rgb, depth=np.full_like(depth, np.nan), command=RoadOption.LEFT))
    with pytest.raises(ValueError, match="does not match rgb"):
        pilot.network_action(SimpleNamespace(rgb=rgb, depth=depth[20:], command=RoadOption.LEFT))


def test_summary_counts_stopping_and_network_frames_per_traffic_level():
    episode = Episode("train", "town_a", "clear_noon", "dense", 0, 1)
    results = [EpisodeResult(episode, True, "timeout", 100, 0.5, 0, 100, 40, 25),
               EpisodeResult(episode, False, "collision", 30, 0.1, 0),
               EpisodeResult(Episode("train", "town_a", "clear_noon", "empty", 0, 2), True, "arrived", 50, 1, 0, 50)]
    assert summary(results).splitlines()[1:] == ["empty | 1/1 | 50 | 0 (0.0 %) | 0 (0.0 %)",
                                                 "dense | 1/2 | 100 | 25 (25.0 %) | 40 (40.0 %)"]


# ----- the command line -----
@pytest.mark.parametrize("arguments, message", [
    (["--beta", "1.5"], "--beta 1.5 is not a probability"),
    (["--beta", "0.5"], "name it with --driver"),
    (["--driver", "{checkpoint}"], "give it --round N"),
    (["--driver", "{missing}", "--round", "1"], "cannot drive with"),
    (["--driver", "{checkpoint}", "--round", "1", "--precision", "int8"], "cannot drive with"),
    (["--episodes", "0"], "--episodes"),
    (["--max-steps", "12", "--record-from", "12"], "--record-from"),
])
def test_bad_options_get_one_line_and_exit_code_2(tmp_path, capsys, tiny_checkpoint, arguments, message):
    arguments = [a.format(checkpoint=tiny_checkpoint, missing=tmp_path / "none.pt") for a in arguments]
    code = main(["--output", str(tmp_path / "data"), "--split", "train", "--towns", "town_a", *arguments])
    error = capsys.readouterr().err
    assert code == 2 and error.startswith("msfsu-collect: ") and message in error and error.count("\n") == 1
    assert not (tmp_path / "data").exists()  # refused before anything ran


def test_resuming_a_round_with_another_driver_is_refused(tmp_path, capsys, tiny_checkpoint):
    episode = plan("train", ["town_a"], ["clear_noon"], ["empty"], 1, base_seed=0, round_index=1)[0]
    metadata = {**EXPERT.metadata(), bag_io.SPLIT: "train", bag_io.SIMULATOR_REVISION: SIMULATOR_REVISION}
    with bag_io.mcap_writer(bag_path(tmp_path, episode), metadata):
        pass
    code = main(["--output", str(tmp_path), "--split", "train", "--towns", "town_a", "--weathers", "clear_noon",
                 "--traffic", "empty", "--round", "1", "--driver", str(tiny_checkpoint), "--backend", "torch"])
    error = capsys.readouterr().err
    assert code == 2 and "was driven by expert with beta 1.0" in error and "another --round" in error


def test_resuming_bags_of_another_simulator_revision_is_refused(tmp_path, capsys):
    """Bags without the key are revision 1 (pedestrians placed by the map's seed): never mixed with newer ones."""
    episode = plan("train", ["town_a"], ["clear_noon"], ["empty"], 1, base_seed=0)[0]
    with bag_io.mcap_writer(bag_path(tmp_path, episode), {**EXPERT.metadata(), bag_io.SPLIT: "train"}):
        pass
    code = main(["--output", str(tmp_path), "--split", "train", "--towns", "town_a", "--weathers", "clear_noon",
                 "--traffic", "empty"])
    error = capsys.readouterr().err
    assert code == 2 and f"simulator revision 1, this code is revision {SIMULATOR_REVISION}" in error


@pytest.mark.slow
def test_noise_flags_in_a_bag_follow_the_schedule(sim, tmp_path):
    episode = Episode("train", "town_a", "clear_noon", "empty", 0, seed=7)
    result = record_episode(sim, episode, tmp_path, max_steps=110, noise=True)
    assert result.noisy_steps == 10 * 2  # bursts at 5 s and 10 s, 1 s each at 10 Hz
