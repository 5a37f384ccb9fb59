"""rosbag2 bags of the stack, written and read here only (no ROS runtime needed).

One typestore (Jazzy + msfsu_interfaces), one place that knows how bag metadata (split, map,
weather, ...) is stored: rosbag2's `custom_data` in metadata.yaml, which `ros2 bag info` and
Foxglove leave alone, and one way to read a bag (`open_bag`) for replay, training and evaluation.

Intact bags (MCAP or sqlite3) are read by rosbags through their indexes. An MCAP bag whose index is
unusable, because the file was cut short (a recorder killed, a full disk), never finished (no
metadata.yaml) or is damaged, is read front to back like `ros2 bag reindex` / `mcap recover` do:
every complete chunk is used and a warning says how much was recovered. Anything that is no bag at
all raises BagError: one line naming the file and the reason.
"""

from __future__ import annotations

import heapq
import logging
import os
import struct
import sys
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from functools import cache
from io import BytesIO
from pathlib import Path

import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel as McapChannel
from mcap.records import Chunk as McapChunk
from mcap.records import Message as McapMessage
from mcap.records import McapRecord
from mcap.records import Schema as McapSchema
from mcap.stream_reader import breakup_chunk
from rosbags.interfaces import Connection, ConnectionExtRosbag2, MessageDefinition, MessageDefinitionFormat, Qos
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

INTERFACES_PACKAGE = "msfsu_interfaces"
BAG_VERSION = 9
METADATA_PREFIX = "msfsu."
# Keys every dataset bag carries (values are strings).
SPLIT, MAP, WEATHER, TRAFFIC, SEED = "split", "map", "weather", "traffic", "seed"
SPLITS = ("train", "validation", "test")  # values of SPLIT
# Keys of the bags msfsu-collect writes; bags written before they existed lack them (and then drove
# MetaDrive's default route of the map, with the expert at the wheel).
ROUTE_START = "route_start"  # the start road: JSON list of its two MetaDrive nodes, '["1S0_0_", "2C0_0_"]'
ROUTE_DESTINATION = "route_destination"  # the destination node
ROUTE_JUNCTIONS = "route_junctions"  # RoadOption names of the route's junction crossings in order, "LEFT,STRAIGHT"
ROUTE_LENGTH_M = "route_length_m"  # metres from the spawn position to the destination
DRIVER = "driver"  # who drove: EXPERT_DRIVER, or the path of the network's checkpoint
DRIVER_DIGEST = "driver_digest"  # content hash of that checkpoint (deploy_files.file_digest); absent for the expert
BETA = "beta"  # probability that the expert drives a step ("1.0": expert only); per-frame: topics.NETWORK_DRIVING
ROUND = "round"  # collection round: 0 expert data, 1, 2, ... on-policy (DAgger) rounds
SIMULATOR_REVISION = "simulator_revision"  # msfsu_sim.SIMULATOR_REVISION of the collecting code; absent: revision 1
END = "end"  # how the episode ended: arrived, timeout, collision, out_of_road (a crashed bag lacks its last second)
CRASH_ENDS = ("collision", "out_of_road")  # values of END that are a crash
# values of topics.EXPERT_LIMITED_BY: a free road; a car or a walker ahead (PARTICIPANT_LIMITS); waiting to cross
EXPERT_LIMITS = ("free", "vehicle", "pedestrian", "junction")
PARTICIPANT_LIMITS = ("vehicle", "pedestrian")
EXPERT_DRIVER = "expert"  # value of DRIVER
# Keys of the bags msfsu-import-carla writes (msfsu_sim.carla): where the frames come from and how they were made
SOURCE_BAG = "source_bag"  # absolute path of the carla-ros-bridge recording
SOURCE_INFO = "source_info"  # JSON: the recording's rosbag2 information, topics (type, messages), what was recovered
IMPORT_REPORT = "import_report"  # JSON: frames kept and dropped by reason, where labels, action and command came from
METADATA_FILE = "metadata.yaml"
MCAP_MAGIC = b"\x89MCAP0\r\n"
MAX_CHUNK_BYTES = 1 << 30  # a chunk claiming more (uncompressed) is damaged, not decompressed

log = logging.getLogger(__name__)


def _interface_dirs() -> list[Path]:
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    source_tree = Path(__file__).resolve().parents[2] / INTERFACES_PACKAGE
    return [Path(prefix) / "share" / INTERFACES_PACKAGE for prefix in prefixes] + [source_tree]


def _stack_typestore() -> Typestore:
    """A new typestore: ROS 2 Jazzy types plus the project's messages (read from the .msg files)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    msg_dir = next((d / "msg" for d in _interface_dirs() if (d / "msg").is_dir()), None)
    if msg_dir is None:
        raise FileNotFoundError(f"{INTERFACES_PACKAGE}/msg not found (run the setup)")
    types = {}
    for msg_file in sorted(msg_dir.glob("*.msg")):
        types.update(get_types_from_msg(msg_file.read_text(), f"{INTERFACES_PACKAGE}/msg/{msg_file.stem}"))
    store.register(types)
    return store


@cache
def msfsu_typestore() -> Typestore:
    """ROS 2 Jazzy types plus the project's messages (one shared store: never register more types into it)."""
    return _stack_typestore()


def bag_typestore(connections: Iterable[Connection]) -> Typestore:
    """A new typestore that reads these connections: the stack's types plus each type only the bag knows.

    rosbag2 stores every topic's complete message definition in the bag (MCAP schemas; ros2msg text: the type's
    .msg first, then each type it uses). A type the stack lacks (carla_msgs in a carla-ros-bridge recording) is
    registered from that text, with the types it brings; types the stack has keep the stack's definition. No
    package is installed or imported. BagError (one line) names a connection whose type the bag does not define.
    """
    store = _stack_typestore()
    for connection in connections:
        if connection.msgtype in store.fielddefs:
            continue
        definition = connection.msgdef
        if not definition.data.strip():
            raise BagError(f"{connection.topic}: type {connection.msgtype} is not installed and the bag does not "
                           "define it (record with ros2 bag record -s mcap)")
        if definition.format is not MessageDefinitionFormat.MSG:  # rosbag2 writes IDL only for types without .msg
            raise BagError(f"{connection.topic}: type {connection.msgtype} is not installed and the bag defines it in "
                           f"{definition.format.name}, which is not read here (only .msg definitions)")
        try:
            types = get_types_from_msg(definition.data, connection.msgtype)
            store.register({name: fields for name, fields in types.items() if name not in store.fielddefs})
        except Exception as error:  # noqa: BLE001 - rosbags' parser and code generator fail in many ways
            reason = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise BagError(f"{connection.topic}: type {connection.msgtype} is not installed and the bag's own "
                           f"definition of it is unusable ({reason})") from None
    return store


def mcap_writer(path: Path | str, metadata: Mapping[str, object] | None = None) -> Writer:
    """rosbag2 MCAP writer with `metadata` in custom_data; `with mcap_writer(...) as writer:` opens it.

    MCAP chunks are zstd-compressed (storage-level, as `ros2 bag record --storage-preset-profile
    zstd_fast`): simulator bags shrink ~5x (144 MB -> 27 MB for 150 frames) and every reader handles it.
    """
    writer = Writer(Path(path), version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    for key, value in (metadata or {}).items():
        writer.set_custom_data(METADATA_PREFIX + key, str(value))
    return writer


def flush_to_disk(writer: Writer) -> None:
    """Close the MCAP chunk being filled and hand the file's bytes to the OS.

    rosbags' MCAP writer keeps messages in memory until a chunk holds 1 MiB, and the file object
    buffers on top: a process killed between two chunks would lose them. After this call every
    message written so far is in complete chunks on disk, which `open_bag` recovers after a SIGKILL
    (not after a power loss: no fsync). Uses rosbags' McapWriter (`close_chunk`, `bio`), pinned in
    requirements.txt and checked by the recorder's kill test.
    """
    storage = writer.storage
    if storage is None:
        raise ValueError("the bag writer is not open")
    if storage.chunk.msgs:
        storage.close_chunk()
    storage.bio.flush()


def read_bag_metadata(path: Path | str) -> dict[str, str]:
    """The stack's metadata of a bag directory ({} for bags recorded elsewhere, e.g. CARLA, or without
    metadata.yaml, e.g. a recording that never finished); BagError if metadata.yaml is unreadable."""
    info = _bag_info(Path(path))
    custom = (info or {}).get("custom_data")
    custom = custom if isinstance(custom, dict) else {}
    return {key[len(METADATA_PREFIX):]: str(value) for key, value in custom.items()
            if isinstance(key, str) and key.startswith(METADATA_PREFIX)}


def read_bag_information(path: Path | str) -> dict:
    """metadata.yaml's rosbag2_bagfile_information of a bag directory ({} without the file); BagError if unreadable."""
    return _bag_info(Path(path)) or {}


def is_bag(path: Path | str) -> bool:
    """A rosbag2 directory: metadata.yaml, or MCAP files of a recording that never wrote it."""
    path = Path(path)
    return path.is_dir() and ((path / METADATA_FILE).is_file() or any(path.glob("*.mcap")))


def _bag_info(path: Path) -> dict | None:
    """metadata.yaml's rosbag2_bagfile_information; None without the file; BagError if unreadable."""
    metadata = path / METADATA_FILE
    if not metadata.is_file():
        return None
    try:
        info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
    except (yaml.YAMLError, UnicodeDecodeError, OSError, TypeError, KeyError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise BagError(f"{metadata}: not rosbag2 metadata ({reason})") from None
    if not isinstance(info, dict):
        raise BagError(f"{metadata}: not rosbag2 metadata (no rosbag2_bagfile_information mapping)")
    return info


# --- reading ------------------------------------------------------------------------------------
class BagError(ValueError):
    """Not a readable rosbag2 bag; the message is one line that names the file and the reason."""


@dataclass(frozen=True)
class Recovery:
    """What was read from one MCAP file whose index could not be used (cut short, unfinished, damaged)."""

    file: Path
    reason: str  # why the file was scanned instead of read through its index
    messages: int  # messages recovered
    chunks: int  # complete chunks read
    damaged_chunks: int  # chunks present in full but unreadable (checksum, compression): skipped
    readable_bytes: int  # up to the end of the last complete record
    file_bytes: int
    expected_messages: int | None  # what metadata.yaml says the file held, when it says
    span_ns: int  # log time from the first to the last recovered message

    def describe(self) -> str:
        share = (f" of {self.expected_messages} ({self.messages / self.expected_messages:.0%})"
                 if self.expected_messages else "")
        damaged = f", {self.damaged_chunks} damaged chunks skipped" if self.damaged_chunks else ""
        return (f"{self.file}: {self.reason}; recovered {self.messages} messages{share} from {self.chunks} complete "
                f"chunks ({self.span_ns * 1e-9:.1f} s of log time, {self.readable_bytes / 2**20:.1f} of "
                f"{self.file_bytes / 2**20:.1f} MiB of the file){damaged}")


class Bag:
    """An open bag, read the same way whatever its state: `connections`, `messages()`, times and counts.

    Messages come as (connection, log time ns, serialized CDR) in log-time order, of the given
    connections (None: all; an empty list: none), from `start` up to `stop` (ns); `connections` are
    rosbags `Connection`s (topic, msgtype, msgcount, ext.offered_qos_profiles). `recoveries` lists the
    files that were scanned instead of read through their index (empty for an intact bag).
    """

    path: Path
    connections: list[Connection]
    start_time: int  # ns, first message; 2**63 - 1 without messages
    end_time: int  # ns, one past the last message
    message_count: int
    recoveries: list[Recovery]

    @property
    def duration(self) -> int:
        return max(0, self.end_time - self.start_time)

    def messages(self, connections: Iterable[Connection] | None = None, start: int | None = None,
                 stop: int | None = None) -> Iterator[tuple[Connection, int, bytes | memoryview]]:
        raise NotImplementedError

    def close(self) -> None:
        """Release the files (also done by `with open_bag(...) as bag:`)."""

    def __enter__(self) -> Bag:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class _IndexedBag(Bag):
    """An intact bag (MCAP or sqlite3) through rosbags, which uses the files' indexes."""

    def __init__(self, path: Path, reader: Reader) -> None:
        self.path, self._reader = path, reader
        self.connections = list(reader.connections)
        self.start_time, self.end_time = reader.start_time, reader.end_time
        self.message_count = reader.message_count
        self.recoveries = []

    def messages(self, connections=None, start=None, stop=None):
        connections = None if connections is None else list(connections)
        if connections == []:  # rosbags reads an empty list as "all"; here it means none
            return
        try:
            yield from self._reader.messages(connections=connections or (), start=start, stop=stop)
        except Exception as error:  # noqa: BLE001 - a damaged chunk behind an intact index: rosbags or zstd errors
            reason = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise BagError(f"{self.path}: damaged after {self.path.name}'s index was read ({reason})") from None

    def close(self) -> None:
        self._reader.close()


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


def _read_record(handle, file_size: int) -> tuple[int, bytes]:
    """(opcode, body) of the record at the handle's position; _CutShort if it runs past the file's end."""
    position = handle.tell()
    head = handle.read(9)  # opcode (1) + body length (8)
    if len(head) < 9:
        raise _CutShort(position)
    opcode, length = struct.unpack("<BQ", head)
    if length > file_size - position - 9:
        raise _CutShort(position)
    return opcode, handle.read(length)


def _messages_of(opcode: int, body: bytes) -> list[McapRecord]:
    """Records in a chunk (schemas, channels, messages) or a lone record, parsed by the mcap library.

    Raises whatever a damaged record makes the parser raise; the callers treat that as "damaged".
    """
    if opcode == Opcode.CHUNK:
        chunk = McapChunk.read(ReadDataStream(BytesIO(body)))
        if chunk.uncompressed_size > MAX_CHUNK_BYTES:
            raise ValueError(f"chunk claims {chunk.uncompressed_size} bytes")
        return breakup_chunk(chunk, validate_crc=True)
    if opcode == Opcode.MESSAGE:
        return [McapMessage.read(ReadDataStream(BytesIO(body)), len(body))]
    if opcode == Opcode.SCHEMA:
        return [McapSchema.read(ReadDataStream(BytesIO(body)))]
    if opcode == Opcode.CHANNEL:
        return [McapChannel.read(ReadDataStream(BytesIO(body)))]
    return []


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


def open_bag(path: Path | str, warn: Callable[[str], None] | None = None) -> Bag:
    """Open a rosbag2 bag directory (or one .mcap file) for reading; BagError (one line) if it is no bag.

    A damaged or unfinished MCAP bag is recovered (every complete chunk) and `warn` (default: this
    module's logger) hears once per process and file how much was recovered.
    """
    path = Path(path)
    if path.name == METADATA_FILE:
        path = path.parent
    if not path.exists():
        raise BagError(f"{path}: no such bag (no such file or directory)")
    if path.is_file():
        return _recover(path, [path], None, {}, warn)
    info = _bag_info(path)
    if info is None:
        files = sorted(path.glob("*.mcap"))
        if not files:
            raise BagError(f"{path}: not a rosbag2 bag (no {METADATA_FILE} and no .mcap file)")
        return _recover(path, files, f"no {METADATA_FILE} (the recording did not end cleanly)", {}, warn)
    try:
        reader = Reader(path)
        reader.open()
    except Exception as error:  # noqa: BLE001 - rosbags' ReaderError, or a parser error on damaged bytes
        reason = f"index unreadable: {str(error).splitlines()[0] if str(error) else type(error).__name__}"
    else:
        return _IndexedBag(path, reader)
    names = info.get("relative_file_paths")
    names = [name for name in names if isinstance(name, str)] if isinstance(names, list) else []
    if info.get("storage_identifier") != "mcap" or not names or not all(name.endswith(".mcap") for name in names):
        raise BagError(f"{path}: {reason}")
    missing = [name for name in names if not (path / name).is_file()]
    if missing:
        raise BagError(f"{path / missing[0]}: listed in {METADATA_FILE} but missing")
    return _recover(path, [path / name for name in names], reason, _listed_counts(info), warn)


def _listed_counts(info: Mapping) -> dict[str, int]:
    """File name -> message count, as far as metadata.yaml's `files` says (it may be damaged too)."""
    files = info.get("files")
    counts = {}
    for item in files if isinstance(files, list) else []:
        if isinstance(item, dict) and isinstance(item.get("path"), str) and isinstance(item.get("message_count"), int):
            counts[item["path"]] = item["message_count"]
    return counts


def _recover(path: Path, files: list[Path], reason: str | None, expected: Mapping[str, int],
             warn: Callable[[str], None] | None) -> Bag:
    bag = _RecoveredBag(path, files, reason, expected)
    for recovery in bag.recoveries:
        stat = recovery.file.stat()
        key = (str(recovery.file.resolve()), stat.st_size, stat.st_mtime_ns)
        if key not in _warned:
            _warned.add(key)
            (warn or log.warning)(f"damaged bag, recovered what it holds: {recovery.describe()}")
    return bag
