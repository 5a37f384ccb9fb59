"""Fuzz (hypothesis) of what the stack reads from outside: sensor_msgs/Image fields and bytes, navigation
command values, bag files. Only the documented errors may come out: ImageFormatError,
ValueError for an unknown command, BagError for a bag; never another exception, never a hang."""

import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sensor_msgs.msg import Image

from msfsu_common.bag_io import BagError, flush_to_disk, mcap_writer, msfsu_typestore, open_bag
from msfsu_common.image_codec import ENCODINGS, ImageFormatError, decode_depth, decode_mono8, decode_rgb
from msfsu_common.road_option import RoadOption, parse_road_option

UINT32 = st.integers(0, 2**32 - 1)
ENCODING = st.one_of(st.sampled_from(sorted(ENCODINGS)), st.text(max_size=12))


@st.composite
def images(draw) -> Image:
    """Mostly well-formed sizes (so decoding gets far), with any field able to be hostile."""
    encoding = draw(ENCODING)
    dtype, channels = ENCODINGS.get(encoding, (np.dtype(np.uint8), 1))
    height = draw(st.one_of(st.integers(0, 12), UINT32))
    width = draw(st.one_of(st.integers(0, 12), UINT32))
    row_bytes = min(width, 64) * channels * dtype.itemsize
    step = draw(st.one_of(st.integers(row_bytes, row_bytes + 5), UINT32))
    size = min(height, 64) * min(step, 4096)
    data = draw(st.one_of(st.binary(min_size=size, max_size=size), st.binary(max_size=600)))
    return Image(height=height, width=width, encoding=encoding, is_bigendian=draw(st.integers(0, 255)), step=step,
                 data=data)


@settings(max_examples=200)
@given(images())
def test_image_decoding_gives_pixels_or_an_image_format_error(msg):
    for decode, channels in ((decode_rgb, 3), (decode_depth, None), (decode_mono8, None)):
        try:
            pixels = decode(msg)
        except ImageFormatError:
            continue
        assert pixels.shape[:2] == (msg.height, msg.width) and (channels is None or pixels.shape[2] == channels)


@settings(max_examples=100)
@given(st.integers(0, 255))
def test_navigation_command_values_parse_or_name_the_accepted_ones(value):
    try:
        option = parse_road_option(value)
    except ValueError as error:
        assert value not in {o.value for o in RoadOption} and "accepted: 1=LEFT" in str(error)
    else:
        assert option.value == value


# --- bags ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_bag(tmp_path_factory) -> tuple[Path, bytes]:
    """A valid bag of 12 chunks (one per message): its metadata.yaml and its MCAP bytes."""
    path = tmp_path_factory.mktemp("fuzz") / "bag"
    store = msfsu_typestore()
    types = store.types
    with mcap_writer(path, {"split": "test"}) as writer:
        connection = writer.add_connection("/fuzz/action", "msfsu_interfaces/msg/DrivingAction", typestore=store)
        for index in range(12):
            action = types["msfsu_interfaces/msg/DrivingAction"](
                header=types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=index, nanosec=0),
                                                    frame_id="x" * index),
                steer=0.1, target_speed=float(index), command=4)
            writer.write(connection, index * 10**9, store.serialize_cdr(action, action.__msgtype__))
            flush_to_disk(writer)
    return path, next(path.glob("*.mcap")).read_bytes()


def read_everything(directory: Path) -> None:
    """What player, training and evaluation do with a bag: open, list, iterate. Only BagError may escape."""
    try:
        with open_bag(directory, warn=lambda message: None) as bag:
            messages = [(connection.topic, time, bytes(raw)) for connection, time, raw in bag.messages()]
            assert all(connection.msgcount >= 0 for connection in bag.connections)
    except BagError as error:
        assert "\n" not in str(error) and str(directory) in str(error)
        return
    if bag.recoveries:
        assert len(messages) == bag.message_count


@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.binary(min_size=1, max_size=16)), max_size=6),
       st.one_of(st.none(), st.floats(0, 1)))
def test_damaged_bags_are_read_or_refused_with_a_bag_error(small_bag, mutations, cut):
    """Bytes overwritten anywhere (headers, chunk lengths, compressed data, summary) and the file cut anywhere."""
    source, original = small_bag
    data = bytearray(original)
    for position, replacement in mutations:
        start = int(position * len(data))
        data[start:start + len(replacement)] = replacement
    if cut is not None:
        del data[int(cut * len(data)):]
    with tempfile.TemporaryDirectory() as directory:
        bag = Path(directory) / "bag"
        shutil.copytree(source, bag)
        next(bag.glob("*.mcap")).write_bytes(bytes(data))
        read_everything(bag)


@settings(max_examples=60)
@given(st.binary(max_size=4000), st.one_of(st.none(), st.text(max_size=200)))
def test_random_bytes_and_random_metadata_are_refused_with_a_bag_error(content, metadata):
    with tempfile.TemporaryDirectory() as directory:
        bag = Path(directory) / "bag"
        bag.mkdir()
        (bag / "bag.mcap").write_bytes(content)
        if metadata is not None:
            (bag / "metadata.yaml").write_text(metadata)
        read_everything(bag)
        read_everything(bag / "bag.mcap")
