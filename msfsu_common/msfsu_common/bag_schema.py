"""What a bag of the stack is: its metadata keys and values, its message types, and the reading interface.

Bag metadata (split, map, weather, ...) is stored in rosbag2's `custom_data` of metadata.yaml (keys prefixed
with `METADATA_PREFIX`, values strings), which `ros2 bag info` and Foxglove leave alone. Message types: ROS 2
Jazzy plus msfsu_interfaces, read from the .msg files. `Bag` is what `open_bag` returns whatever the state of
the files, and `BagError` what it raises for anything that is no bag (one line naming the file and the reason).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from rosbags.interfaces import Connection, MessageDefinitionFormat
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

INTERFACES_PACKAGE = "msfsu_interfaces"
BAG_VERSION = 9
METADATA_PREFIX = "msfsu."
# Keys every dataset bag carries (values are strings).
SPLIT, MAP, WEATHER, TRAFFIC, SEED = "split", "map", "weather", "traffic", "seed"
SPLITS = ("train", "validation", "test")  # values of SPLIT
# A frame's navigation command is logged this long before the frame's images, as a player sends it first (the
# synthetic bags of the tests and the CARLA import write it so)
COMMAND_LEAD_NS = 1_000_000
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
# The front camera of the frames (camera_geometry.FrontCamera's JSON): msfsu-collect's bags and msfsu-import-carla's
# carry it; bags written before it existed lack it (msfsu-collect's then had the simulator's default camera)
CAMERA = "camera"
# Keys of the bags msfsu-import-carla writes (msfsu_sim.carla): where the frames come from and how they were made
SOURCE_BAG = "source_bag"  # absolute path of the carla-ros-bridge recording
SOURCE_INFO = "source_info"  # JSON: the recording's rosbag2 information, topics (type, messages), what was recovered
IMPORT_REPORT = "import_report"  # JSON: frames kept and dropped by reason, where labels, action and command came from
METADATA_FILE = "metadata.yaml"


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
