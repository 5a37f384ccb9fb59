"""open_bag: intact bags through their index, damaged MCAP bags chunk by chunk, non-bags in one line."""

import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import NonSeekingReader

from msfsu_common.bag_io import BagError, mcap_writer, msfsu_typestore, open_bag, read_bag_metadata

FRAMES = 24
IMAGE_TOPIC, ACTION_TOPIC = "/test/image", "/test/action"


def write_bag(path: Path, frames: int = FRAMES) -> None:
    """Images of ~1.1 MB (rosbags closes a chunk past 1 MiB: about one chunk per frame) and small actions."""
    store = msfsu_typestore()
    types = store.types
    rng = np.random.default_rng(0)
    with mcap_writer(path, {"split": "test"}) as writer:
        image_connection = writer.add_connection(IMAGE_TOPIC, "sensor_msgs/msg/Image", typestore=store)
        action_connection = writer.add_connection(ACTION_TOPIC, "msfsu_interfaces/msg/DrivingAction", typestore=store)
        for index in range(frames):
            stamp = types["builtin_interfaces/msg/Time"](sec=index, nanosec=0)
            header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="camera")
            pixels = np.full((1000, 1100), index, np.uint8)
            pixels[:100] = rng.integers(0, 256, (100, 1100), np.uint8)  # 110 kB that do not compress
            image = types["sensor_msgs/msg/Image"](header=header, height=1000, width=1100, encoding="mono8",
                                                   is_bigendian=0, step=1100, data=pixels.reshape(-1))
            action = types["msfsu_interfaces/msg/DrivingAction"](header=header, steer=index / frames,
                                                                target_speed=1.0, command=4)
            writer.write(image_connection, index * 10**9, store.serialize_cdr(image, image.__msgtype__))
            writer.write(action_connection, index * 10**9 + 1, store.serialize_cdr(action, action.__msgtype__))


@pytest.fixture(scope="module")
def intact(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "intact"
    write_bag(path)
    return path


def contents(bag) -> list[tuple[str, int, bytes]]:
    return [(connection.topic, time, bytes(raw)) for connection, time, raw in bag.messages()]


def cut_copy(intact: Path, directory: Path, share: float) -> Path:
    """The bag with its MCAP file cut after `share` of its bytes (a recorder killed, a full disk)."""
    bag = directory / f"cut_{share}"
    shutil.copytree(intact, bag)
    mcap = next(bag.glob("*.mcap"))
    os.truncate(mcap, int(mcap.stat().st_size * share))
    return bag


def complete_chunk_messages(mcap: Path) -> list[tuple[str, int, bytes]]:
    """The oracle: what the mcap library's streaming reader yields before it meets the cut."""
    found = []
    with mcap.open("rb") as stream:
        try:
            for _, channel, message in NonSeekingReader(stream).iter_messages(log_time_order=False):
                found.append((channel.topic, message.log_time, bytes(message.data)))
        except Exception:  # noqa: BLE001 - the cut: the streaming reader stops there one way or another
            pass
    return sorted(found, key=lambda item: item[1])


def test_intact_bag_is_read_through_its_index(intact):
    with open_bag(intact) as bag:
        assert bag.recoveries == [] and bag.message_count == 2 * FRAMES
        assert {c.topic: c.msgcount for c in bag.connections} == {IMAGE_TOPIC: FRAMES, ACTION_TOPIC: FRAMES}
        messages = contents(bag)
    assert [time for _, time, _ in messages] == sorted(time for _, time, _ in messages)
    assert read_bag_metadata(intact) == {"split": "test"}


def test_cut_bag_yields_every_complete_chunk_with_a_warning(intact, tmp_path, caplog):
    with open_bag(intact) as bag:
        everything = contents(bag)
    cut = cut_copy(intact, tmp_path, 0.6)
    expected = complete_chunk_messages(next(cut.glob("*.mcap")))
    assert FRAMES < len(expected) < 2 * FRAMES * 0.6  # the oracle sees complete chunks only
    with caplog.at_level(logging.WARNING), open_bag(cut) as bag:
        recovered = contents(bag)
        assert bag.message_count == len(recovered) and bag.start_time == 0
        counts = {c.topic: c.msgcount for c in bag.connections}
        later = [(c.topic, time) for c, time, _ in bag.messages([c for c in bag.connections if c.topic == ACTION_TOPIC],
                                                                start=5 * 10**9)]
    assert recovered == expected and recovered == everything[:len(recovered)]
    assert counts == {IMAGE_TOPIC: sum(t == IMAGE_TOPIC for t, _, _ in expected),
                      ACTION_TOPIC: sum(t == ACTION_TOPIC for t, _, _ in expected)}
    assert later == [(ACTION_TOPIC, i * 10**9 + 1) for i in range(5, counts[ACTION_TOPIC])]
    (warning,) = [r.getMessage() for r in caplog.records if "recovered" in r.getMessage()]
    assert f"recovered {len(expected)} messages of {2 * FRAMES}" in warning and "no footer" in warning
    assert read_bag_metadata(cut) == {"split": "test"}  # metadata.yaml survived the cut


def test_unfinished_recording_without_metadata_is_reindexed(intact, tmp_path, caplog):
    bag_dir = cut_copy(intact, tmp_path, 0.3)
    (bag_dir / "metadata.yaml").unlink()  # a recorder killed before close() never writes it
    with caplog.at_level(logging.WARNING), open_bag(bag_dir) as bag:
        recovered = contents(bag)
    assert recovered == complete_chunk_messages(next(bag_dir.glob("*.mcap"))) and recovered
    assert "no footer" in caplog.text and read_bag_metadata(bag_dir) == {}
    with open_bag(next(bag_dir.glob("*.mcap"))) as single_file:  # the .mcap file alone is a bag too
        assert contents(single_file) == recovered


def one_line_error(path: Path) -> str:
    with pytest.raises(BagError) as error:
        open_bag(path)
    message = str(error.value)
    assert "\n" not in message
    return message


def test_what_is_not_a_bag_gets_one_line_naming_the_file(intact, tmp_path):
    random_bytes = np.random.default_rng(0).bytes(100_000)
    (tmp_path / "noise.mcap").write_bytes(random_bytes)
    assert one_line_error(tmp_path / "noise.mcap") == f"{tmp_path / 'noise.mcap'}: not an MCAP file (wrong magic bytes at its start)"
    assert one_line_error(tmp_path / "missing") == f"{tmp_path / 'missing'}: no such bag (no such file or directory)"
    (tmp_path / "empty").mkdir()
    assert "not a rosbag2 bag (no metadata.yaml and no .mcap file)" in one_line_error(tmp_path / "empty")

    fake = tmp_path / "fake"  # a real bag's metadata.yaml over random bytes
    shutil.copytree(intact, fake)
    next(fake.glob("*.mcap")).write_bytes(random_bytes)
    assert one_line_error(fake) == f"{next(fake.glob('*.mcap'))}: not an MCAP file (wrong magic bytes at its start)"
    (fake / "metadata.yaml").write_text("{not: [yaml")
    assert one_line_error(fake).startswith(f"{fake / 'metadata.yaml'}: not rosbag2 metadata (")

    header_only = cut_copy(intact, tmp_path, 0.001)  # magic and header, no complete chunk
    assert "nothing to recover" in one_line_error(header_only)
    listed = yaml.safe_load((intact / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["relative_file_paths"]
    gone = cut_copy(intact, tmp_path, 0.5)
    (gone / listed[0]).unlink()
    (gone / "other.mcap").write_bytes(b"")
    assert one_line_error(gone) == f"{gone / listed[0]}: listed in metadata.yaml but missing"
