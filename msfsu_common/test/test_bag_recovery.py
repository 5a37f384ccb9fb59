"""bag_recovery: an MCAP file cut at any record boundary (or one byte either side) gives back exactly the messages
of its complete records, and its Recovery counts exactly those records."""

from pathlib import Path

import pytest
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from msfsu_common.bag_io import flush_to_disk, mcap_writer, msfsu_typestore, open_bag
from msfsu_common.bag_recovery import MCAP_MAGIC

MESSAGES = 12


@pytest.fixture(scope="module")
def mcap_file(tmp_path_factory) -> Path:
    """Two topics, a chunk every third message of each (flushed as the recorder does), then the summary."""
    path = tmp_path_factory.mktemp("recovery") / "bag"
    store = msfsu_typestore()
    types = store.types
    with mcap_writer(path, {"split": "test"}) as writer:
        action = writer.add_connection("/test/action", "msfsu_interfaces/msg/DrivingAction", typestore=store)
        text = writer.add_connection("/test/text", "std_msgs/msg/String", typestore=store)
        for index in range(MESSAGES):
            header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=index, nanosec=0),
                                                  frame_id="x" * index)
            message = types["msfsu_interfaces/msg/DrivingAction"](header=header, steer=0.1, target_speed=float(index),
                                                                 command=4)
            writer.write(action, index * 10**9, store.serialize_cdr(message, message.__msgtype__))
            string = types["std_msgs/msg/String"](data="y" * index)
            writer.write(text, index * 10**9 + 5, store.serialize_cdr(string, string.__msgtype__))
            if index % 3 == 2:
                flush_to_disk(writer)
    return next(path.glob("*.mcap"))


def record_ends(mcap: Path) -> list[tuple[int, bool, list[tuple[str, int, bytes]]]]:
    """(end offset, is a chunk, messages (topic, log time, data) in it) of each record of the intact file, in order,
    as the mcap library's streaming reader sees them."""
    records, topics = [], {}
    with mcap.open("rb") as stream:
        for record in StreamReader(stream, emit_chunks=True).records:
            inner = breakup_chunk(record) if isinstance(record, Chunk) else [record]
            topics.update({item.id: item.topic for item in inner if isinstance(item, Channel)})
            messages = [(topics[item.channel_id], item.log_time, bytes(item.data)) for item in inner
                        if isinstance(item, Message)]
            records.append((stream.tell(), isinstance(record, Chunk), messages))
    return records


def cut_points(ends: list[int]) -> list[int]:
    return sorted({point for end in ends for point in (end - 1, end, end + 1) if len(MCAP_MAGIC) <= point < ends[-1]})


def test_every_cut_gives_back_exactly_the_complete_records(mcap_file, tmp_path):
    original = mcap_file.read_bytes()
    records = record_ends(mcap_file)
    assert sum(chunk for _, chunk, _ in records) == MESSAGES // 3
    cut_file = tmp_path / "cut.mcap"
    for cut in cut_points([len(MCAP_MAGIC)] + [end for end, _, _ in records]):
        cut_file.write_bytes(original[:cut])
        complete = [record for record in records if record[0] <= cut]
        expected = sorted((message for _, _, messages in complete for message in messages), key=lambda m: m[1])
        if not expected:
            continue  # nothing to recover: BagError (test_bag_io)
        with open_bag(cut_file, warn=lambda message: None) as bag:
            recovered = [(connection.topic, time, bytes(data)) for connection, time, data in bag.messages()]
            (recovery,) = bag.recoveries
        assert recovered == expected, cut
        assert bag.message_count == len(expected) and recovery.messages == len(expected)
        assert recovery.chunks == sum(chunk for _, chunk, _ in complete)
        assert recovery.readable_bytes == max([len(MCAP_MAGIC)] + [end for end, _, _ in complete])
        assert recovery.damaged_chunks == 0 and recovery.file_bytes == cut and "no footer" in recovery.reason
