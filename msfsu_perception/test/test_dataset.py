import logging
import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from rosbags.rosbag2 import Reader
from torch.utils.data import default_collate

from msfsu_common.bag_io import BagError, msfsu_typestore
from msfsu_common.image_codec import decode_depth, decode_mono8, decode_rgb
from msfsu_common.road_option import RoadOption
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception import frame_cache, train
from msfsu_perception.bag_paths import expand_bag_paths, split_bags
from msfsu_perception.dataset import DrivingDataset, to_device
from msfsu_perception.frame_cache import CacheSpaceError, CacheSpec, open_cache
from msfsu_perception.preprocessing import PreprocessConfig, preprocess_frame, preprocess_labels
from msfsu_perception.synthetic import write_synthetic_bag

PREPROCESS = PreprocessConfig(input_height=32, input_width=64, max_depth_m=50.0)


def model_inputs(dataset: DrivingDataset, *positions: int):
    """The samples at `positions` as one batch of model inputs, as the trainer makes them (on the CPU here)."""
    return to_device(default_collate([dataset[position] for position in positions]), "cpu")


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    truths = {
        "train_a": write_synthetic_bag(
            root / "train_a", 40, "train", seed=1, noise_period_frames=10, noise_duration_frames=3
        ),
        "train_b": write_synthetic_bag(root / "train_b", 20, "train", seed=2, rgb_encoding="bgra8"),
        "val": write_synthetic_bag(root / "val", 15, "validation", seed=3, with_clock=False),
    }
    return root, truths


def _cache(bag_paths, tmp_path, preprocess=PREPROCESS):
    spec = CacheSpec(tuple(bag_paths), BagTopics(), preprocess, with_labels=True)
    return open_cache(spec, tmp_path / "cache")


def test_bags_are_grouped_by_split_metadata(bags):
    root, _ = bags
    groups = split_bags(expand_bag_paths([str(root / "*")]))
    assert [p.name for p in groups["train"]] == ["train_a", "train_b"]
    assert [p.name for p in groups["validation"]] == ["val"] and groups["test"] == []


def test_samples_are_synchronised_and_noise_frames_removed(bags, tmp_path):
    root, truths = bags
    cache = _cache([root / "train_a", root / "train_b"], tmp_path)
    clean = {name: ~truths[name].noise for name in ("train_a", "train_b")}
    assert clean["train_a"].sum() == 28 and clean["train_b"].sum() == 20
    expected = {
        field: np.concatenate([getattr(truths[name], field)[clean[name]] for name in ("train_a", "train_b")])
        for field in ("stamps_ns", "steer", "target_speed", "command")
    }
    assert len(cache) == 48 and len(cache.valid_rows) == 48
    np.testing.assert_array_equal(cache.stamp_ns, expected["stamps_ns"])
    np.testing.assert_array_equal(cache.steer, expected["steer"])
    np.testing.assert_array_equal(cache.target_speed, expected["target_speed"])
    np.testing.assert_array_equal(cache.command, expected["command"])
    assert set(cache.command) > {RoadOption.LANE_FOLLOW}  # command changes were crossed
    assert cache.manifest["bags"][0]["dropped"]["noise"] == 12


def test_cached_images_equal_the_shared_preprocessing(bags, tmp_path):
    root, truths = bags
    cache = _cache([root / "train_b"], tmp_path)  # bgra8 camera
    store, topics = msfsu_typestore(), BagTopics()
    decoded = {}
    with Reader(root / "train_b") as reader:
        for connection, _, raw in reader.messages():
            msg = store.deserialize_cdr(raw, connection.msgtype)
            if connection.topic in (topics.rgb, topics.depth, topics.semantic_ids) and len(decoded) < 3:
                decoded.setdefault(connection.topic, msg)
    rgb, depth = decode_rgb(decoded[topics.rgb]), decode_depth(decoded[topics.depth])
    expected = preprocess_frame(rgb, depth, PREPROCESS)
    inputs = model_inputs(DrivingDataset(cache, [0], speed_scale=10.0), 0).inputs[0].numpy()
    np.testing.assert_array_equal(inputs[:3], expected[:3])  # RGB survives the uint8 cache exactly
    np.testing.assert_allclose(inputs[3:], expected[3:], atol=1e-3)  # depth is stored as float16
    expected_ids = preprocess_labels(decode_mono8(decoded[topics.semantic_ids]), PREPROCESS)
    np.testing.assert_array_equal(cache.class_ids[0], expected_ids)
    assert cache.depth.dtype == np.float16 and cache.rgb.dtype == np.uint8


def test_cache_is_built_once_and_keyed_by_preprocessing(bags, tmp_path):
    root, _ = bags
    first = _cache([root / "val"], tmp_path)
    manifest_time = (first.directory / "manifest.json").stat().st_mtime_ns
    again = _cache([root / "val"], tmp_path)
    assert again.directory == first.directory
    assert (again.directory / "manifest.json").stat().st_mtime_ns == manifest_time
    other = _cache([root / "val"], tmp_path, PreprocessConfig(input_height=32, input_width=32))
    assert other.directory != first.directory and other.rgb.shape[2:] == (32, 32)


def test_dataset_hands_over_the_stored_sample_and_to_device_makes_model_inputs(bags, tmp_path):
    root, truths = bags
    cache = _cache([root / "val"], tmp_path)
    dataset = DrivingDataset(cache, [2, 2, 5], speed_scale=10.0)
    stored = dataset[1]  # what a loader worker sends: the cache's compact dtypes
    assert len(dataset) == 3
    assert (stored.rgb.dtype, stored.depth.dtype, stored.class_ids.dtype) == (torch.uint8, torch.float16, torch.uint8)
    batch = model_inputs(dataset, 1, 2)
    assert batch.inputs.shape == (2, 4, 32, 64) and 0.0 <= batch.inputs.min() and batch.inputs.max() <= 1.0
    assert batch.inputs.dtype == torch.float32 and batch.class_ids.dtype == torch.long
    assert batch.class_ids.shape == (2, 32, 64) and int(batch.class_ids.max()) <= 4
    np.testing.assert_array_equal(batch.inputs[0, :3].numpy(), cache.rgb[2] * np.float32(1.0 / 255.0))  # as preprocess_frame
    np.testing.assert_array_equal(batch.inputs[0, 3:].numpy(), cache.depth[2].astype(np.float32))
    np.testing.assert_array_equal(batch.class_ids[0].numpy(), cache.class_ids[2])
    assert int(batch.command_index[0]) == RoadOption(int(cache.command[2])).branch_index
    assert float(batch.speed[0]) == pytest.approx(cache.target_speed[2] / 10.0)
    assert float(batch.steer[0]) == cache.steer[2]
    channels_last = to_device(default_collate([dataset[1], dataset[2]]), "cpu", torch.channels_last).inputs
    assert channels_last.is_contiguous(memory_format=torch.channels_last)
    torch.testing.assert_close(channels_last, batch.inputs, rtol=0, atol=0)


def test_cache_travels_to_loader_workers_as_its_directory(bags, tmp_path):
    root, _ = bags
    cache = _cache([root / "val"], tmp_path)
    copy = pickle.loads(pickle.dumps(cache))
    assert isinstance(copy.rgb, np.memmap) and len(pickle.dumps(cache)) < 1000
    np.testing.assert_array_equal(copy.rgb, cache.rgb)


def test_rgb_only_cache_for_the_su_variant(bags, tmp_path):
    root, _ = bags
    cache = _cache([root / "val"], tmp_path, PreprocessConfig(input_height=32, input_width=32, use_depth=False))
    assert cache.depth is None
    batch = model_inputs(DrivingDataset(cache, [0], 10.0), 0)
    assert batch.inputs.shape == (1, 3, 32, 32) and batch.class_ids.shape == (1, 32, 32)


def test_a_bag_without_a_required_topic_is_refused(tmp_path):
    write_synthetic_bag(tmp_path / "bag", 3, topics=BagTopics(semantic_ids="/elsewhere/class_ids"))
    with pytest.raises(ValueError, match="lacks topics.*semantic_front"):
        _cache([tmp_path / "bag"], tmp_path)
    rgb_depth_only = CacheSpec((tmp_path / "bag",), BagTopics(), PREPROCESS, with_labels=False)
    assert len(open_cache(rgb_depth_only, tmp_path / "cache")) == 3  # the MSF variant needs no labels


def test_a_path_that_is_not_a_bag_is_refused(tmp_path):
    with pytest.raises(BagError, match="missing: not a rosbag2 bag directory"):
        expand_bag_paths([str(tmp_path / "missing")])


def test_a_pattern_that_matches_nothing_is_named_as_a_pattern_not_taken_for_a_bag(tmp_path):
    pattern = str(tmp_path / "bags" / "*")
    with pytest.raises(BagError, match=r"^no path matches '.*/bags/\*' \(quote a pattern"):
        expand_bag_paths([pattern])
    (tmp_path / "bags" / "notes").mkdir(parents=True)  # a match that is no bag is named as such
    with pytest.raises(BagError, match="notes: not a rosbag2 bag directory"):
        expand_bag_paths([pattern])


@pytest.mark.parametrize("depth_encoding", ["32FC1", "16UC1"])
def test_frames_of_a_depth_camera_with_holes_are_kept_by_default(tmp_path, depth_encoding):
    bag = tmp_path / "holes"
    write_synthetic_bag(bag, 6, "train", depth_encoding=depth_encoding, depth_hole_fraction=0.03,
                        noise_duration_frames=0)
    cache = open_cache(CacheSpec((bag,), BagTopics(), PREPROCESS, with_labels=True), tmp_path / "cache")
    assert len(cache.valid_rows) == 6 and cache.manifest["bags"][0]["dropped"]["invalid_depth"] == 0
    assert cache.depth[0, 0, -1, 0] == 1.0 and cache.depth[0, 0, -1, -1] < 1.0  # the patch reads as the far clip


def test_training_uses_every_complete_frame_of_a_cut_bag(tmp_path, caplog):
    bag = tmp_path / "cut"
    truth = write_synthetic_bag(bag, 20, "train", height=240, width=320, noise_duration_frames=0)  # ~2 frames a chunk
    mcap = next(bag.glob("*.mcap"))
    os.truncate(mcap, int(mcap.stat().st_size * 0.6))  # the recorder was killed
    with caplog.at_level(logging.WARNING):
        groups = split_bags(expand_bag_paths([str(bag)]))  # its metadata.yaml survived: still a training bag
        cache = open_cache(CacheSpec(tuple(groups["train"]), BagTopics(), PREPROCESS, with_labels=True),
                           tmp_path / "cache")
    assert "damaged bag, recovered what it holds" in caplog.text
    frames = len(cache.valid_rows)
    assert 5 < frames < 20 and cache.manifest["bags"][0]["dropped"]["incomplete"] <= 1
    np.testing.assert_array_equal(cache.stamp_ns, truth.stamps_ns[:frames])
    np.testing.assert_array_equal(cache.steer, truth.steer[:frames])


def _disk_with_free_bytes(monkeypatch, free):
    usage = shutil.disk_usage("/")
    monkeypatch.setattr(frame_cache.shutil, "disk_usage", lambda path: usage._replace(free=free))


def test_a_cache_the_disk_cannot_hold_is_refused_before_writing(bags, tmp_path, monkeypatch):
    root, _ = bags
    _disk_with_free_bytes(monkeypatch, frame_cache.CACHE_SPACE_MARGIN_BYTES)  # the margin alone: no room for images
    with pytest.raises(CacheSpaceError, match=r"needs 0\.0 GB under .*cache, 0\.5 GB free"):
        _cache([root / "val"], tmp_path)
    assert list((tmp_path / "cache").iterdir()) == []  # no half-written cache holds the disk
    monkeypatch.undo()
    assert len(_cache([root / "val"], tmp_path)) == 15


def test_evict_deletes_the_least_recently_used_caches_until_a_new_one_fits(bags, tmp_path, monkeypatch):
    root, _ = bags
    first, second = _cache([root / "train_a"], tmp_path), _cache([root / "train_b"], tmp_path)
    os.utime(first.directory / frame_cache.LAST_USED_FILE, (1, 1))  # used long ago
    os.utime(second.directory / frame_cache.LAST_USED_FILE, (2, 2))
    _cache([root / "train_a"], tmp_path)  # opened again: now the most recently used
    assert frame_cache.complete_caches(tmp_path / "cache") == [second.directory, first.directory]
    sizes = {d: sum(p.stat().st_size for p in d.rglob("*") if p.is_file()) for d in (first.directory, second.directory)}
    # the disk has the margin and exactly one deleted cache's worth more: the new cache fits after one eviction
    usage = shutil.disk_usage("/")
    deleted: list[Path] = []
    monkeypatch.setattr(frame_cache.shutil, "disk_usage", lambda path: usage._replace(
        free=frame_cache.CACHE_SPACE_MARGIN_BYTES + sum(sizes[d] for d in deleted)))
    real_rmtree = frame_cache.shutil.rmtree

    def rmtree(path, *args, **kwargs):
        if Path(path) in sizes:
            deleted.append(Path(path))
        real_rmtree(path, *args, **kwargs)

    monkeypatch.setattr(frame_cache.shutil, "rmtree", rmtree)
    spec = CacheSpec((root / "val",), BagTopics(), PREPROCESS, with_labels=True)
    with pytest.raises(CacheSpaceError, match="msfsu-train --evict-caches does it"):
        open_cache(spec, tmp_path / "cache")  # without evict, nothing is deleted
    assert deleted == []
    logged: list[str] = []
    assert len(open_cache(spec, tmp_path / "cache", evict=True, log=logged.append)) == 15
    assert deleted == [second.directory] and first.directory.is_dir()  # the least recently used one only
    assert len(logged) == 1 and str(second.directory) in logged[0] and "least recently used" in logged[0]


def test_evicting_every_cache_and_still_short_is_refused_before_writing(bags, tmp_path, monkeypatch):
    root, _ = bags
    old = _cache([root / "train_b"], tmp_path)
    _disk_with_free_bytes(monkeypatch, 0)
    with pytest.raises(CacheSpaceError, match="after deleting 1 older caches"):
        _cache_evicting([root / "val"], tmp_path)
    assert not old.directory.exists() and list((tmp_path / "cache").iterdir()) == []


def _cache_evicting(bag_paths, tmp_path):
    return open_cache(CacheSpec(tuple(bag_paths), BagTopics(), PREPROCESS, with_labels=True), tmp_path / "cache",
                      evict=True)


def test_training_on_a_full_disk_is_one_line(bags, tmp_path, monkeypatch):
    root, _ = bags
    _disk_with_free_bytes(monkeypatch, 0)
    argv = ["--train-bags", str(root / "train_b"), "--val-bags", str(root / "val"), "--cache-dir",
            str(tmp_path / "cache"), "--out", str(tmp_path / "run"), "--epochs", "1"]
    one_line = r"^msfsu-train: a frame cache of 20 frames at 128x128 needs .* GB free: free space there"
    with pytest.raises(SystemExit, match=one_line):
        train.main(argv)


@pytest.mark.parametrize("end", ["collision", "arrived"])
def test_focus_frames_are_the_near_misses_and_the_approach_to_a_crash_of_on_policy_bags(bags, tmp_path, end):
    """Near miss: the network drove and asked for >= 2 m/s more than the expert while a car held the expert;
    crash approach: the last 3 s of a bag whose episode ended in a crash. Expert bags have none."""
    root, truths = bags
    bag = tmp_path / f"on_policy_{end}"
    truth = write_synthetic_bag(bag, 120, "train", seed=4, noise_period_frames=1000, noise_duration_frames=0,
                                on_policy_end=end)
    cache = _cache([bag, root / "train_b"], tmp_path)
    near = truth.network & (truth.asked_speed >= truth.target_speed + 2.0) & (truth.limited_by == "vehicle")
    crash = truth.stamps_ns > truth.stamps_ns[-1] - 3_000_000_000 if end == "collision" else np.zeros(120, bool)
    assert near[:-30].sum() >= 3 and near[-30:].any()  # near misses outside the crash window and in it
    np.testing.assert_array_equal(cache.focus, np.concatenate([near | crash, np.zeros(20, bool)]))
    assert cache.manifest["bags"][0]["focus"] == int((near | crash).sum())
