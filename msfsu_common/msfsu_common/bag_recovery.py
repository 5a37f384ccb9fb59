"""Salvage of MCAP files whose index cannot be used: cut short, never finished, or damaged.

A file is read front to back like `ros2 bag reindex` / `mcap recover` do: every complete record is used, a
damaged one is skipped, and the reading stops where the file is cut short. The mcap library parses each record
(`StreamReader` over the record's bytes, `breakup_chunk` for a chunk's content, checksums checked); the framing
(opcode and length of each record, and where it starts) is read here, because the library's readers cannot
salvage: `StreamReader` / `NonSeekingReader` stop at the first record they cannot parse instead of skipping it,
bound a record's length by a fixed limit (4 GiB) rather than by the bytes left in the file, so a damaged length
makes them read to the end of the file, and do not say where a record starts, which the log-time merge below
needs to read a chunk only when it gets there (NonSeekingReader's log-time order holds the whole file in memory).
"""

from __future__ import annotations

import heapq
import logging
import struct
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import BinaryIO

from mcap.opcode import Opcode
from mcap.records import Channel as McapChannel
from mcap.records import Chunk as McapChunk
from mcap.records import Message as McapMessage
from mcap.records import McapRecord
from mcap.records import Schema as McapSchema
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.interfaces import Connection, ConnectionExtRosbag2, MessageDefinition, MessageDefinitionFormat, Qos
from rosbags.rosbag2.metadata import parse_qos

from msfsu_common.bag_schema import Bag, BagError, Recovery

MCAP_MAGIC = b"\x89MCAP0\r\n"
MAX_CHUNK_BYTES = 1 << 30  # a chunk claiming more (uncompressed) is damaged, not decompressed
CONTENT_OPCODES = frozenset({Opcode.CHUNK, Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL})  # records that are parsed

log = logging.getLogger("msfsu_common.bag_io")  # warnings come under the name of the module bags are opened through


_MSGDEF_FORMAT = {"ros2msg": MessageDefinitionFormat.MSG, "ros2idl": MessageDefinitionFormat.IDL,
                  "omgidl": MessageDefinitionFormat.IDL}


class _CutShort(Exception):
    """The record at this position does not end within the file."""


@dataclass(frozen=True)
class _Block:
    """A record that holds messages: a chunk, or a message written outside chunks."""

    file: int  # index into the bag's files
    offset: int  # of the record in the file
    start_time: int  # earliest log time in it
    channels: frozenset[int]  # channel ids with messages in it


@dataclass
class _FileScan:
    """What a front-to-back scan of one MCAP file learned, without keeping any message."""

    schemas: dict[int, McapSchema] = field(default_factory=dict)
    channels: dict[int, McapChannel] = field(default_factory=dict)
    counts: Counter[int] = field(default_factory=Counter)
    blocks: list[_Block] = field(default_factory=list)
    chunks: int = 0
    damaged_chunks: int = 0
    start_time: int = 2**63 - 1
    end_time: int = -1
    readable_bytes: int = 0
    problem: str | None = None  # why the scan stopped before the footer; None: read to the end


def _read_record(handle: BinaryIO, file_size: int) -> tuple[int, bytes]:
    """(opcode, the whole record: opcode, length, body) at the handle's position; _CutShort if it runs past the
    file's end (so a damaged length never makes a read run past the file)."""
    position = handle.tell()
    head = handle.read(9)  # opcode (1) + body length (8)
    if len(head) < 9:
        raise _CutShort(position)
    opcode, length = struct.unpack("<BQ", head)
    if length > file_size - position - 9:
        raise _CutShort(position)
    return opcode, head + handle.read(length)


def _messages_of(opcode: int, record: bytes) -> list[McapRecord]:
    """Records in a chunk (schemas, channels, messages) or a lone schema, channel or message, parsed by the mcap
    library; [] for any other record (indexes, statistics, attachments are not needed to recover messages).

    Raises whatever a damaged record makes the parser raise; the callers treat that as "damaged".
    """
    if opcode not in CONTENT_OPCODES:
        return []
    parsed = next(StreamReader(BytesIO(record), skip_magic=True, emit_chunks=True).records)
    if not isinstance(parsed, McapChunk):
        return [parsed]
    if parsed.uncompressed_size > MAX_CHUNK_BYTES:
        raise ValueError(f"chunk claims {parsed.uncompressed_size} bytes")
    return breakup_chunk(parsed, validate_crc=True)


def _scan_mcap(file: Path, index: int) -> _FileScan:
    """Walk one MCAP file record by record up to its footer, or up to where it is cut short."""
    scan = _FileScan()
    size = file.stat().st_size
    with file.open("rb") as handle:
        magic = handle.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            reason = "an empty file" if not magic else "not an MCAP file (wrong magic bytes at its start)"
            raise BagError(f"{file}: {reason}")
        scan.readable_bytes = handle.tell()
        while True:
            offset = handle.tell()
            try:
                opcode, body = _read_record(handle, size)
            except _CutShort:
                scan.problem = (f"no footer: the file ends {'inside the record at' if offset < size else 'at'} byte "
                                f"{offset} (cut short, or the recording did not end cleanly)")
                break
            if opcode == Opcode.FOOTER:
                scan.readable_bytes = size
                break
            try:
                records = _messages_of(opcode, body)
            except Exception:  # noqa: BLE001 - damaged bytes make the parsers fail in many ways; all mean "damaged"
                scan.damaged_chunks += opcode == Opcode.CHUNK
                continue
            scan.readable_bytes = handle.tell()
            times, channels = [], set()
            for record in records:
                if isinstance(record, McapSchema):
                    scan.schemas[record.id] = record
                elif isinstance(record, McapChannel):
                    scan.channels[record.id] = record
                elif isinstance(record, McapMessage) and record.channel_id in scan.channels:
                    scan.counts[record.channel_id] += 1
                    times.append(record.log_time)
                    channels.add(record.channel_id)
            scan.chunks += opcode == Opcode.CHUNK
            if times:
                scan.blocks.append(_Block(index, offset, min(times), frozenset(channels)))
                scan.start_time, scan.end_time = min(scan.start_time, min(times)), max(scan.end_time, max(times))
    return scan


def _offered_qos(metadata: Mapping[str, str]) -> list[Qos]:
    try:
        return parse_qos(metadata.get("offered_qos_profiles", ""))
    except Exception:  # noqa: BLE001 - an unreadable profile is no reason to lose the messages
        return []


class _RecoveredBag(Bag):
    """MCAP files read front to back, every complete chunk of them (`ros2 bag reindex`, `mcap recover`).

    Framing (opcode, length) is checked here against the file size, so a damaged length never makes a
    read run past the end of the file; the records are parsed by the mcap library. Messages are merged
    in log-time order, a chunk being read only when the merge reaches its first log time.
    """

    def __init__(self, path: Path, files: list[Path], reason: str | None, expected: Mapping[str, int]) -> None:
        self.path, self._files = path, files
        scans = [_scan_mcap(file, index) for index, file in enumerate(files)]
        connections: dict[tuple[str, str], Connection] = {}
        counts: Counter[tuple[str, str]] = Counter()
        key_of: dict[tuple[int, int], tuple[str, str]] = {}
        for index, scan in enumerate(scans):
            for channel_id, channel in scan.channels.items():
                schema = scan.schemas.get(channel.schema_id)
                if schema is None:  # a schemaless channel has no ROS type
                    continue
                key = key_of[(index, channel_id)] = (channel.topic, schema.name)
                counts[key] += scan.counts[channel_id]
                connections.setdefault(key, Connection(
                    id=len(connections) + 1, topic=channel.topic, msgtype=schema.name,
                    msgdef=MessageDefinition(_MSGDEF_FORMAT.get(schema.encoding, MessageDefinitionFormat.NONE),
                                             schema.data.decode(errors="replace")),
                    digest="", msgcount=0,
                    ext=ConnectionExtRosbag2(channel.message_encoding, _offered_qos(channel.metadata)), owner=None))
        self.connections = [connection._replace(msgcount=counts[key]) for key, connection in connections.items()]
        by_key = dict(zip(connections, self.connections))
        self._connection_of = {place: by_key[key] for place, key in key_of.items()}
        self._blocks = [block for scan in scans for block in scan.blocks]
        self.message_count = sum(counts.values())
        self.start_time = min((scan.start_time for scan in scans), default=2**63 - 1)
        self.end_time = max((scan.end_time + 1 for scan in scans), default=0)
        self.recoveries = []
        for file, scan in zip(files, scans):
            if scan.problem is None and reason is None and not scan.damaged_chunks:
                continue
            messages = sum(scan.counts.values())
            self.recoveries.append(Recovery(
                file=file, reason=scan.problem or reason or "damaged chunks", messages=messages, chunks=scan.chunks,
                damaged_chunks=scan.damaged_chunks, readable_bytes=scan.readable_bytes, file_bytes=file.stat().st_size,
                expected_messages=expected.get(file.name), span_ns=scan.end_time - scan.start_time if messages else 0))
        if not self.message_count:
            problem = "; ".join(recovery.reason for recovery in self.recoveries) or "no messages"
            raise BagError(f"{path}: {problem}; no complete chunk with messages, nothing to recover")

    def messages(self, connections=None, start=None, stop=None):
        wanted = None if connections is None else {connection.id for connection in connections}

        def keep(block: _Block) -> bool:
            return wanted is None or any(self._connection_of.get((block.file, channel), _NO_CONNECTION).id in wanted
                                         for channel in block.channels)

        handles = [file.open("rb") for file in self._files]
        sizes = [file.stat().st_size for file in self._files]

        def block_messages(block: _Block) -> Iterator[tuple[int, Connection | None, bytes]]:
            yield block.start_time, None, b""  # ordering key only: the block is read when the merge gets here
            handle = handles[block.file]
            handle.seek(block.offset)
            found = []
            for record in _messages_of(*_read_record(handle, sizes[block.file])):
                if not isinstance(record, McapMessage):
                    continue
                connection = self._connection_of.get((block.file, record.channel_id))
                if connection is None or (wanted is not None and connection.id not in wanted):
                    continue
                if (start is None or record.log_time >= start) and (stop is None or record.log_time < stop):
                    found.append((record.log_time, connection, record.data))
            found.sort(key=lambda item: item[0])
            yield from found

        try:
            merged = heapq.merge(*(block_messages(block) for block in self._blocks if keep(block)),
                                 key=lambda item: item[0])
            for log_time, connection, data in merged:
                if connection is not None:
                    yield connection, log_time, data
        finally:
            for handle in handles:
                handle.close()


_NO_CONNECTION = Connection(0, "", "", MessageDefinition(MessageDefinitionFormat.NONE, ""), "", 0,
                            ConnectionExtRosbag2("", []), None)
_warned: set[tuple[str, int, int]] = set()


def recover(path: Path, files: list[Path], reason: str | None, expected: Mapping[str, int],
            warn: Callable[[str], None] | None) -> Bag:
    """The messages of the MCAP `files` of bag `path` that can be salvaged; BagError (one line) if none.

    `reason`: why the index was not used (None: a lone .mcap file, scanned as it is); `expected`: file name ->
    message count from metadata.yaml. `warn` (default: the logger) hears once per process and file version
    (path, size, mtime) how much of each damaged file was recovered.
    """
    bag = _RecoveredBag(path, files, reason, expected)
    for recovery in bag.recoveries:
        stat = recovery.file.stat()
        key = (str(recovery.file.resolve()), stat.st_size, stat.st_mtime_ns)
        if key not in _warned:
            _warned.add(key)
            (warn or log.warning)(f"damaged bag, recovered what it holds: {recovery.describe()}")
    return bag
