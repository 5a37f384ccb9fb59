"""The carla-ros-bridge recording as the import reads it: which topic holds what, and pass 1 over its messages.

Each role (rgb, depth, semantic, control, speed, odometry, route, command, world) is read from one topic of the
recording, of the types `READERS` accepts; the carla_msgs types come from the definitions the bag holds
(`bag_io.bag_typestore`). Pass 1 keeps of every message its header stamp, its log time and a small value (an
image's encoding and size, never its pixels).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from msfsu_common import topics as stack_topics
from msfsu_common.bag_io import Bag, Connection, Typestore, bag_typestore
from msfsu_common.image_codec import DEPTH_ENCODINGS, RGB_ENCODINGS
from msfsu_common.message_types import stamp_ns

WORLD_INFO_TOPIC = "/carla/world_info"  # carla_msgs/CarlaWorldInfo: map_name
NAVIGATION_COMMAND_TYPE = "msfsu_interfaces/msg/NavigationCommand"
INTEGER_COMMAND_TYPES = tuple(f"std_msgs/msg/{name}" for name in
                              ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64"))
# the recording's own types: decoded from the definitions it holds (bag_io.bag_typestore), never a dependency
CARLA_MSGS = "carla_msgs"
CONTROL_TYPE = f"{CARLA_MSGS}/msg/CarlaEgoVehicleControl"
STATUS_TYPE = f"{CARLA_MSGS}/msg/CarlaEgoVehicleStatus"
WORLD_INFO_TYPE = f"{CARLA_MSGS}/msg/CarlaWorldInfo"


class CarlaImportError(ValueError):
    """The recording cannot be imported; the message is one line that says why and what was looked for."""


@dataclass(frozen=True)
class SourceTopics:
    """Where the recording holds what the import reads (carla-ros-bridge names for one ego vehicle role)."""

    rgb: str
    depth: str
    semantic: str
    control: str  # CarlaEgoVehicleControl (or CarlaEgoVehicleStatus: its applied control)
    status: str  # CarlaEgoVehicleStatus: the speed
    odometry: str  # nav_msgs/Odometry: the position (and the speed without a status topic)
    route: str  # nav_msgs/Path from carla_waypoint_publisher
    command: str | None = None  # a RoadOption topic; None: the stack's NavigationCommand topic where recorded
    named: tuple[str, ...] = ()  # the roles whose topic the user named (--<role>-topic): the recording must hold it

    @classmethod
    def of_role(cls, role: str = stack_topics.ROLE, **overrides: str | None) -> SourceTopics:
        """The bridge's topics of ego vehicle `role`, with the sensor ids of the bridge's example sensor file
        (msfsu_common.topics); overrides win and must be in the recording."""
        names = {"rgb": f"{stack_topics.RGB_SENSOR}/image", "depth": f"{stack_topics.DEPTH_SENSOR}/image",
                 "semantic": f"{stack_topics.SEMANTIC_SENSOR}/image", "control": "vehicle_control_cmd",
                 "status": "vehicle_status", "odometry": "odometry", "route": "waypoints"}
        given = {name: value for name, value in overrides.items() if value is not None}
        defaults = {name: stack_topics.carla_topic(topic, role) for name, topic in names.items()}
        return cls(**{**defaults, **given}, named=tuple(given))


@dataclass
class Series:
    """The messages of one topic in log order: header stamp (0 without one), log time, and what was kept of each."""

    stamps: list[int] = field(default_factory=list)
    logs: list[int] = field(default_factory=list)
    values: list[Any] = field(default_factory=list)

    @property
    def by_log_time(self) -> bool:
        """No message carries a stamp: the topic is placed by log time."""
        return not any(self.stamps)

    def times(self) -> np.ndarray:
        return np.array(self.logs if self.by_log_time else self.stamps, np.int64)


def _image_shape(msg: Any) -> tuple[str, int, int]:
    return str(msg.encoding), int(msg.width), int(msg.height)


def _control(msg: Any) -> tuple[float, bool]:
    """(steer, reverse) of a CarlaEgoVehicleControl, or of the applied control in a CarlaEgoVehicleStatus."""
    control = getattr(msg, "control", msg)
    return float(control.steer), bool(control.reverse)


def _speed(msg: Any) -> float:
    """m/s: CarlaEgoVehicleStatus velocity, or the length of an Odometry's linear twist."""
    if hasattr(msg, "velocity"):
        return float(msg.velocity)
    linear = msg.twist.twist.linear
    return float(np.linalg.norm([linear.x, linear.y, linear.z]))


def _position(msg: Any) -> tuple[float, float]:
    return float(msg.pose.pose.position.x), float(msg.pose.pose.position.y)


def _route_points(msg: Any) -> np.ndarray:
    return np.array([(pose.pose.position.x, pose.pose.position.y) for pose in msg.poses], np.float64).reshape(-1, 2)


def _command_value(msg: Any) -> int:
    return int(msg.command) if hasattr(msg, "command") else int(msg.data)


# role -> (accepted types, what is kept of each message); types are checked before a message is read
READERS: dict[str, tuple[tuple[str, ...], Callable[[Any], Any]]] = {
    "rgb": (("sensor_msgs/msg/Image",), _image_shape),
    "depth": (("sensor_msgs/msg/Image",), _image_shape),
    "semantic": (("sensor_msgs/msg/Image",), _image_shape),
    "control": ((CONTROL_TYPE, STATUS_TYPE), _control),
    "speed": ((STATUS_TYPE, "nav_msgs/msg/Odometry"), _speed),
    "odometry": (("nav_msgs/msg/Odometry",), _position),
    "route": (("nav_msgs/msg/Path",), _route_points),
    "command": ((NAVIGATION_COMMAND_TYPE, *INTEGER_COMMAND_TYPES), _command_value),
    "world": ((WORLD_INFO_TYPE,), lambda msg: str(msg.map_name)),
}


@dataclass(frozen=True)
class Sources:
    """The connection each role reads (None: the recording lacks it), the topic looked for, and the store that
    decodes them."""

    connections: dict[str, Connection | None]
    looked_for: dict[str, str]
    store: Typestore
    present: str  # the recording's topics, sorted, for messages that name what it holds

    def topic(self, role: str) -> str | None:
        connection = self.connections.get(role)
        return None if connection is None else connection.topic


def pick_sources(bag: Bag, source: SourceTopics) -> Sources:
    """The recording's connection for each role; CarlaImportError for a missing required topic or a wrong type."""
    by_topic = {connection.topic: connection for connection in bag.connections}
    present = ", ".join(sorted(by_topic)) or "none"
    speed_topic = source.status if source.status in by_topic else source.odometry
    command_topic = source.command or stack_topics.NAVIGATION_COMMAND
    wanted = {"rgb": source.rgb, "depth": source.depth, "semantic": source.semantic, "control": source.control,
              "speed": speed_topic, "odometry": source.odometry, "route": source.route, "command": command_topic,
              "world": WORLD_INFO_TOPIC}
    for role in source.named:  # a topic the user named that is not there is a typo, never "import without it"
        if getattr(source, role) not in by_topic:
            raise CarlaImportError(f"{bag.path}: no --{role}-topic {getattr(source, role)} (topics: {present})")
    if source.rgb not in by_topic:
        raise CarlaImportError(f"{bag.path}: no RGB camera on {source.rgb} (topics: {present}); name it with "
                               "--rgb-topic or --role")
    if source.control not in by_topic:
        raise CarlaImportError(
            f"{bag.path}: no {source.control} (CarlaEgoVehicleControl): no expert action, nothing to learn from; "
            f"for a drive by CARLA's autopilot take the control it applied: --control-topic {source.status}")
    if speed_topic not in by_topic:
        raise CarlaImportError(f"{bag.path}: no vehicle speed: neither {source.status} (CarlaEgoVehicleStatus) nor "
                               f"{source.odometry} (nav_msgs/Odometry)")
    if command_topic not in by_topic and not {source.route, source.odometry} <= set(by_topic):
        raise CarlaImportError(
            f"{bag.path}: no navigation command: no RoadOption topic (--command-topic; {command_topic} absent) and no "
            f"route to derive it from ({source.route} nav_msgs/Path from carla_waypoint_publisher, with "
            f"{source.odometry})")
    connections = {role: by_topic.get(topic) for role, topic in wanted.items()}
    if connections["command"] is not None:  # a recorded command: the route is not needed
        connections["route"] = None
    if connections["world"] is not None and connections["world"].msgtype not in READERS["world"][0]:
        connections["world"] = None  # only the map's name, for the metadata
    for role, connection in connections.items():
        if connection is not None and connection.msgtype not in READERS[role][0]:
            raise CarlaImportError(f"{connection.topic} is {connection.msgtype}; {role} is read from "
                                   f"{' or '.join(READERS[role][0])}")
    used = [connection for connection in connections.values() if connection is not None]
    return Sources(connections, wanted, bag_typestore(used), present)


def read_series(bag: Bag, sources: Sources) -> dict[str, Series]:
    """Pass 1: every message of every role's topic, kept small (images: encoding and size only)."""
    roles: dict[int, list[str]] = {}
    for role, connection in sources.connections.items():
        if connection is not None:
            roles.setdefault(connection.id, []).append(role)
    series = {role: Series() for role in sources.connections}
    chosen = [connection for connection in sources.connections.values() if connection is not None]
    for connection, log_ns, raw in bag.messages(list({c.id: c for c in chosen}.values())):
        msg = sources.store.deserialize_cdr(raw, connection.msgtype)
        header = getattr(msg, "header", None)
        for role in roles[connection.id]:
            entry = series[role]
            entry.stamps.append(0 if header is None else stamp_ns(header))
            entry.logs.append(log_ns)
            entry.values.append(READERS[role][1](msg))
    return series


def check_images(series: dict[str, Series], sources: Sources, raw_tags: str | None) -> None:
    """Every image in an encoding the stack reads, all of the RGB camera's size; CarlaImportError otherwise."""
    accepted = {"rgb": RGB_ENCODINGS, "depth": DEPTH_ENCODINGS,
                "semantic": RGB_ENCODINGS + (("mono8",) if raw_tags else ())}
    reads = {"rgb": "colour images: rgb8, bgr8, rgba8 or bgra8 (carla-ros-bridge publishes bgra8)",
             "depth": "depth as 32FC1 metres (as carla-ros-bridge publishes it) or 16UC1 millimetres",
             "semantic": "CityScapes palette colours: rgb8, bgr8, rgba8 or bgra8 (carla-ros-bridge publishes bgra8)"
                         + ("; raw tags also as mono8" if raw_tags else "")}
    if not series["rgb"].values:
        raise CarlaImportError(f"{sources.topic('rgb')} holds no message")
    size = series["rgb"].values[0][1:]
    for role, encodings in accepted.items():
        for encoding, width, height in dict.fromkeys(series[role].values):
            topic = sources.topic(role)
            if encoding not in encodings:
                raise CarlaImportError(f"{topic} is {encoding}: the import reads {reads[role]}")
            if (width, height) != size:
                raise CarlaImportError(f"{topic} is {width}x{height}, the RGB camera {size[0]}x{size[1]}: the stack "
                                       "pairs their pixels; give the cameras one size")


