"""carla-ros-bridge recordings written by the tests, as `ros2 bag record -s mcap` would store the bridge's topics.

carla_msgs types are carla_msgs' own definitions (the repository's carla_msgs/msg: CarlaEgoVehicleControl,
CarlaEgoVehicleStatus, CarlaWorldInfo) stored in the MCAP schemas the way rosbag2 writes a complete message
definition (the type's .msg text, then every type it uses after an 80 '=' line and 'MSG: <name>', in sorted order);
the stack never sees them otherwise. Images are what the bridge publishes: bgra8 RGB, 32FC1 depth in metres,
bgra8 CityScapes palette semantic images. Header stamps are CARLA's simulation time; log times are the recorder's
wall clock (recorded without --use-sim-time), and the control command has no stamp, as carla_ad_agent and
carla_manual_control publish it. The ego vehicle drives a straight, a left turn and a straight (`route_point`).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Connection
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from msfsu_common.image_codec import encode_image
from msfsu_common.road_option import RoadOption
from msfsu_common.semantic_classes import CLASS_COLOURS, SemanticClass
from msfsu_perception.synthetic import render_scene

# CARLA's CityScapes palette by tag id (LibCarla/source/carla/image/CityScapesPalette.h, with the tag names of
# LibCarla/source/carla/rpc/ObjectLabel.h): the 23 tags of 0.9.10 - 0.9.13 and the 29 of 0.9.14 - 0.9.15.
PALETTE_0910 = (
    ("None", (0, 0, 0)), ("Buildings", (70, 70, 70)), ("Fences", (100, 40, 40)), ("Other", (55, 90, 80)),
    ("Pedestrians", (220, 20, 60)), ("Poles", (153, 153, 153)), ("RoadLines", (157, 234, 50)),
    ("Roads", (128, 64, 128)), ("Sidewalks", (244, 35, 232)), ("Vegetation", (107, 142, 35)),
    ("Vehicles", (0, 0, 142)), ("Walls", (102, 102, 156)), ("TrafficSigns", (220, 220, 0)), ("Sky", (70, 130, 180)),
    ("Ground", (81, 0, 81)), ("Bridge", (150, 100, 100)), ("RailTrack", (230, 150, 140)),
    ("GuardRail", (180, 165, 180)), ("TrafficLight", (250, 170, 30)), ("Static", (110, 190, 160)),
    ("Dynamic", (170, 120, 50)), ("Water", (45, 60, 150)), ("Terrain", (145, 170, 100)),
)
PALETTE_0914 = (
    ("None", (0, 0, 0)), ("Roads", (128, 64, 128)), ("Sidewalks", (244, 35, 232)), ("Buildings", (70, 70, 70)),
    ("Walls", (102, 102, 156)), ("Fences", (190, 153, 153)), ("Poles", (153, 153, 153)),
    ("TrafficLight", (250, 170, 30)), ("TrafficSigns", (220, 220, 0)), ("Vegetation", (107, 142, 35)),
    ("Terrain", (152, 251, 152)), ("Sky", (70, 130, 180)), ("Pedestrians", (220, 20, 60)), ("Rider", (255, 0, 0)),
    ("Car", (0, 0, 142)), ("Truck", (0, 0, 70)), ("Bus", (0, 60, 100)), ("Train", (0, 80, 100)),
    ("Motorcycle", (0, 0, 230)), ("Bicycle", (119, 11, 32)), ("Static", (110, 190, 160)),
    ("Dynamic", (170, 120, 50)), ("Other", (55, 90, 80)), ("Water", (45, 60, 150)), ("RoadLines", (157, 234, 50)),
    ("Ground", (81, 0, 81)), ("Bridge", (150, 100, 100)), ("RailTrack", (230, 150, 140)),
    ("GuardRail", (180, 165, 180)),
)
PALETTES = {"0.9.10-0.9.13": PALETTE_0910, "0.9.14-0.9.15": PALETTE_0914}
# The paper's five classes by CARLA tag name; every other tag is OTHER.
EXPECTED_CLASS = {"Roads": SemanticClass.ROAD, "RoadLines": SemanticClass.ROAD_LINE,
                  "Sidewalks": SemanticClass.SIDEWALK,
                  **{name: SemanticClass.VEHICLE_OR_PEDESTRIAN for name in (
                      "Pedestrians", "Vehicles", "Rider", "Car", "Truck", "Bus", "Train", "Motorcycle", "Bicycle")}}

# .msg texts: carla_msgs' own files (carla_msgs/msg, as carla-ros-bridge builds them), and the Jazzy types they use
CARLA_MSGS = Path(__file__).resolve().parents[1] / "carla_msgs" / "msg"
CARLA_TYPES = ("CarlaEgoVehicleControl", "CarlaEgoVehicleStatus", "CarlaWorldInfo")
MSG_TEXTS = {
    **{f"carla_msgs/{name}": (CARLA_MSGS / f"{name}.msg").read_text() for name in CARLA_TYPES},
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "geometry_msgs/Accel": "Vector3  linear\nVector3  angular\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
}
_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")  # rosbag2's dependency rule
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
               "int64", "uint64", "string"}


def rosbag2_definition(name: str) -> str:
    """The complete message definition rosbag2 stores for `name` ('carla_msgs/CarlaEgoVehicleStatus')."""
    seen: set[str] = set()

    def text(type_name: str) -> str:
        body = MSG_TEXTS[type_name]
        package = type_name.split("/")[0]
        uses = {used if "/" in used else f"{package}/{used}" for used in _FIELD_TYPE.findall(body)
                if used not in _PRIMITIVES}
        for used in sorted(uses - seen):
            seen.add(used)
            body += "\n" + "=" * 80 + f"\nMSG: {used}\n" + text(used)
        return body

    return text(name)



def bridge_typestore() -> Typestore:
    """Jazzy's types plus carla_msgs from the definitions the recordings hold (the recorder's side only)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for name in CARLA_TYPES:
        types = get_types_from_msg(rosbag2_definition(f"carla_msgs/{name}"), f"carla_msgs/msg/{name}")
        store.register({key: value for key, value in types.items() if key not in store.fielddefs})
    return store


# The route: 30 m east, a left quarter circle of radius 10 m, 30 m north (map frame, metres).
STRAIGHT_M, TURN_RADIUS_M, EXIT_M = 30.0, 10.0, 30.0
SPEED_MPS = 15.0
TURN_STEER = -0.4  # CARLA steer while turning left (negative: left)
SIM_START_NS = 12_300_000_000  # CARLA's simulation time at the first frame
WALL_START_NS = 1_750_000_000_000_000_000  # the recorder's clock
RECEIVE_NS = 3_000_000  # images reach the recorder this long after their tick
CONTROL_LATENCY_NS = 20_000_000  # the agent answers a frame this long after the recorder got it


def route_point(arc_m: float) -> tuple[float, float, float]:
    """(x, y, yaw) at `arc_m` along ROUTE."""
    turn_m = np.pi / 2 * TURN_RADIUS_M
    if arc_m <= STRAIGHT_M:
        return arc_m, 0.0, 0.0
    if arc_m <= STRAIGHT_M + turn_m:
        angle = (arc_m - STRAIGHT_M) / TURN_RADIUS_M
        return STRAIGHT_M + TURN_RADIUS_M * np.sin(angle), TURN_RADIUS_M * (1 - np.cos(angle)), angle
    return STRAIGHT_M + TURN_RADIUS_M, TURN_RADIUS_M + arc_m - STRAIGHT_M - turn_m, np.pi / 2


def on_turn(arc_m: float) -> bool:
    return STRAIGHT_M < arc_m < STRAIGHT_M + np.pi / 2 * TURN_RADIUS_M


@dataclass(frozen=True)
class Recording:
    """What the tests set about a recording; the defaults are the bridge's, as docs/carla.md configures it."""

    frames: int = 40
    rate_hz: float = 10.0
    width: int = 80
    height: int = 60
    role: str = "ego_vehicle"
    depth_encoding: str = "32FC1"
    semantic: str | None = "palette"  # "palette", a PALETTES numbering for raw tags (bgra8, tag in red), None
    palette: str = "0.9.14-0.9.15"  # whose colours a palette image uses
    with_control: bool = True
    control_stamped: bool = False  # False: no header stamp, as carla_ad_agent publishes it
    with_status: bool = True
    with_route: bool = True
    command_topic: str | None = None  # a std_msgs/UInt8 RoadOption topic, published every frame
    stamp_back_at: int | None = None  # this frame's stamp (and the rest) go back by two frame periods
    unknown_colour_frames: tuple[int, ...] = ()  # frames whose semantic image gets one pixel of no CARLA colour
    reverse_frames: tuple[int, ...] = ()
    definitions: bool = True  # False: carla_msgs without a definition in the bag (a recording made without them)
    depth_rows: int | None = None  # a depth camera of this many rows (the bridge's example: smaller than the RGB)


CARLA_DOC = Path(__file__).resolve().parents[1] / "docs" / "carla.md"


def recipe_objects() -> dict[str, Any]:
    """docs/carla.md's sensor definition (its first JSON block), as the recipe saves it in msfsu_objects.json."""
    return json.loads(CARLA_DOC.read_text().split("```json\n", 1)[1].split("```", 1)[0])


def write_objects(path: Path, recording: Recording, **pose: float) -> Path:
    """The recipe's sensor definition with the recording's role and camera size (the tests' images are small), the
    cameras' spawn points updated with `pose`, written to `path`."""
    objects = recipe_objects()
    vehicle = objects["objects"][0]
    vehicle["id"] = recording.role
    for sensor in vehicle["sensors"]:
        if sensor["type"].startswith("sensor.camera"):
            sensor.update(image_size_x=recording.width, image_size_y=recording.height)
            sensor["spawn_point"].update(pose)
    path.write_text(json.dumps(objects))
    return path


@dataclass
class Truth:
    """Per camera frame in recording order, what a correct import makes of it."""

    stamps_ns: list[int] = field(default_factory=list)
    steer: list[float] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)
    arc_m: list[float] = field(default_factory=list)
    class_ids: list[np.ndarray] = field(default_factory=list)

    def add(self, frame: Frame) -> None:
        """`frame`'s sample: its stamp, steer and arc, the drive's speed, its classes."""
        self.stamps_ns.append(frame.stamp_ns)
        self.steer.append(frame.steer)
        self.speed.append(SPEED_MPS)
        self.arc_m.append(frame.arc_m)
        self.class_ids.append(frame.class_ids)


UNKNOWN_COLOUR = (1, 2, 3)


def paint_tags(class_ids: np.ndarray, numbering: str) -> np.ndarray:
    """(H, W) class ids -> (H, W) uint8 CARLA tag ids of `numbering`: every tag of the pixel's class in turn, by
    column, so that each tag of the palette is in the image."""
    palette = PALETTES[numbering]
    tags = np.zeros(class_ids.shape, np.uint8)
    columns = np.broadcast_to(np.arange(class_ids.shape[1]), class_ids.shape)
    for cls in SemanticClass:
        ids = np.array([tag for tag, (name, _) in enumerate(palette)
                        if EXPECTED_CLASS.get(name, SemanticClass.OTHER) is cls], np.uint8)
        mask = class_ids == cls
        tags[mask] = ids[columns[mask] % len(ids)]
    return tags


def semantic_image(class_ids: np.ndarray, semantic: str, palette: str) -> np.ndarray:
    """(H, W, 4) bgra8 semantic image: CityScapes colours of `palette`'s tags, as the bridge publishes it, or for
    `semantic` naming a numbering, CARLA's raw image (the tag in the red channel)."""
    bgra = np.zeros(class_ids.shape + (4,), np.uint8)
    if semantic == "palette":
        colours = np.array([colour for _, colour in PALETTES[palette]], np.uint8)
        bgra[..., :3] = colours[paint_tags(class_ids, palette)][..., ::-1]
    else:
        bgra[..., 2] = paint_tags(class_ids, semantic)
    bgra[..., 3] = 255
    return bgra


class BridgeMessages:
    """The bridge's messages of the ego vehicle `role`, as `store`'s types (its carla_msgs registered)."""

    def __init__(self, store: Typestore, role: str) -> None:
        self.types = store.types
        self.role = role

    def header(self, stamp: int, frame_id: str):
        return self.types["std_msgs/msg/Header"](
            stamp=self.types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9),
            frame_id=frame_id)

    def vector(self, x: float = 0.0):
        return self.types["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0)

    def pose(self, x: float, y: float, yaw: float):
        return self.types["geometry_msgs/msg/Pose"](
            position=self.types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=self.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(yaw / 2),
                                                                   w=np.cos(yaw / 2)))

    def world(self):
        return self.types["carla_msgs/msg/CarlaWorldInfo"](map_name="Town01", opendrive="<OpenDRIVE/>")

    def clock(self, stamp: int):
        return self.types["rosgraph_msgs/msg/Clock"](clock=self.header(stamp, "").stamp)

    def image(self, stamp: int, frame_id: str, pixels: np.ndarray, encoding: str):
        fields = encode_image(pixels, encoding)
        fields["data"] = np.frombuffer(fields["data"], np.uint8)
        return self.types["sensor_msgs/msg/Image"](header=self.header(stamp, f"{self.role}/{frame_id}"), **fields)

    def control(self, stamp: int, steer: float, reverse: bool):
        return self.types["carla_msgs/msg/CarlaEgoVehicleControl"](
            header=self.header(stamp, ""), throttle=0.5, steer=steer, brake=0.0, hand_brake=False, reverse=reverse,
            gear=-1 if reverse else 1, manual_gear_shift=False)

    def odometry(self, stamp: int, arc_m: float):
        types = self.types
        return types["nav_msgs/msg/Odometry"](
            header=self.header(stamp, "map"), child_frame_id=self.role,
            pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(*route_point(arc_m)),
                                                               covariance=np.zeros(36)),
            twist=types["geometry_msgs/msg/TwistWithCovariance"](
                twist=types["geometry_msgs/msg/Twist"](linear=self.vector(SPEED_MPS), angular=self.vector()),
                covariance=np.zeros(36)))

    def status(self, stamp: int, arc_m: float, steer: float, reverse: bool):
        return self.types["carla_msgs/msg/CarlaEgoVehicleStatus"](
            header=self.header(stamp, "map"), velocity=SPEED_MPS,
            acceleration=self.types["geometry_msgs/msg/Accel"](linear=self.vector(), angular=self.vector()),
            orientation=self.pose(*route_point(arc_m)).orientation, control=self.control(stamp, steer, reverse))

    def route(self):
        """The whole route, a pose a metre, as the bridge's waypoints."""
        poses = [self.types["geometry_msgs/msg/PoseStamped"](header=self.header(0, ""), pose=self.pose(*route_point(s)))
                 for s in np.arange(0.0, STRAIGHT_M + np.pi / 2 * TURN_RADIUS_M + EXIT_M, 1.0)]
        return self.types["nav_msgs/msg/Path"](header=self.header(SIM_START_NS, "map"), poses=poses)

    def command(self, arc_m: float):
        value = RoadOption.LEFT if on_turn(arc_m) else RoadOption.LANE_FOLLOW
        return self.types["std_msgs/msg/UInt8"](data=int(value))


def bridge_topics(recording: Recording) -> dict[str, tuple[str, str]]:
    """name -> (topic, message type) of what `recording` holds, in the order of its connections."""
    prefix = f"/carla/{recording.role}"
    topics = {"rgb": (f"{prefix}/rgb_front/image", "sensor_msgs/msg/Image"),
              "depth": (f"{prefix}/depth_front/image", "sensor_msgs/msg/Image"),
              "odometry": (f"{prefix}/odometry", "nav_msgs/msg/Odometry"),
              "world": ("/carla/world_info", "carla_msgs/msg/CarlaWorldInfo"),
              "clock": ("/clock", "rosgraph_msgs/msg/Clock")}
    if recording.semantic is not None:
        # the bridge's example sensor file's id (carla_spawn_objects/config/objects.json)
        topics["semantic"] = (f"{prefix}/semantic_segmentation_front/image", "sensor_msgs/msg/Image")
    if recording.with_control:
        topics["control"] = (f"{prefix}/vehicle_control_cmd", "carla_msgs/msg/CarlaEgoVehicleControl")
    if recording.with_status:
        topics["status"] = (f"{prefix}/vehicle_status", "carla_msgs/msg/CarlaEgoVehicleStatus")
    if recording.with_route:
        topics["route"] = (f"{prefix}/waypoints", "nav_msgs/msg/Path")
    if recording.command_topic:
        topics["command"] = (recording.command_topic, "std_msgs/msg/UInt8")
    return topics


def add_connections(writer: Writer, store: Typestore, topics: dict[str, tuple[str, str]],
                    definitions: bool) -> dict[str, Connection]:
    """A connection per topic: carla_msgs with the definition rosbag2 stores (or none, without `definitions`) and
    their RIHS01 hash; Jazzy's types with rosbags' own text."""
    connections = {}
    for name, (topic, msgtype) in topics.items():
        if msgtype.startswith("carla_msgs/"):
            definition = rosbag2_definition(msgtype.replace("/msg/", "/")) if definitions else ""
            connections[name] = writer.add_connection(topic, msgtype, msgdef=definition,
                                                      rihs01=store.hash_rihs01(msgtype))
        else:
            connections[name] = writer.add_connection(topic, msgtype, typestore=store)
    return connections


@dataclass(frozen=True)
class Frame:
    """One camera frame of the drive."""

    index: int
    stamp_ns: int  # the header stamps: simulation time
    log_ns: int  # when the recorder got the images
    arc_m: float
    steer: float
    reverse: bool
    class_ids: np.ndarray
    depth_m: np.ndarray


def drive_frame(recording: Recording, index: int) -> Frame:
    """Frame `index`: SPEED_MPS along the route, TURN_STEER on the turn; from `stamp_back_at` on, stamps two frame
    periods back."""
    period_ns = round(1e9 / recording.rate_hz)
    back = recording.stamp_back_at is not None and index >= recording.stamp_back_at
    arc = SPEED_MPS * index / recording.rate_hz
    steer = TURN_STEER if on_turn(arc) else 0.0
    class_ids, depth = render_scene(steer, False, recording.height, recording.width)
    return Frame(index=index, stamp_ns=SIM_START_NS + (index - 2 * back) * period_ns,
                 log_ns=WALL_START_NS + index * period_ns + RECEIVE_NS, arc_m=arc, steer=steer,
                 reverse=index in recording.reverse_frames, class_ids=class_ids, depth_m=depth)


def rgb_image(class_ids: np.ndarray) -> np.ndarray:
    """(H, W, 4) bgra8: each class in its stack colour."""
    return np.concatenate([CLASS_COLOURS[class_ids][..., ::-1], np.full(class_ids.shape + (1,), 255, np.uint8)],
                          axis=2)


def depth_image(frame: Frame, encoding: str) -> np.ndarray:
    """The depth camera's pixels in `encoding`: 32FC1 metres, 16UC1 millimetres (65 m at most), or bgra8, CARLA's raw
    encoding (zeros: the bridge converts it, the import refuses it)."""
    if encoding == "16UC1":
        return (np.minimum(frame.depth_m, 65.0) * 1000).astype(np.uint16)
    if encoding == "bgra8":
        return np.zeros(frame.class_ids.shape + (4,), np.uint8)
    return frame.depth_m


Write = Callable[[str, int, Any], None]  # (topic name, log time ns, message)


def write_frame(write: Write, messages: BridgeMessages, recording: Recording, frame: Frame) -> None:
    """Every message of `frame`, in the order the recorder logs them: the clock tick, the cameras, the vehicle,
    the route (latched: the recorder gets it after the first frame), the command, the agent's control."""
    stamp, log = frame.stamp_ns, frame.log_ns
    write("clock", log - RECEIVE_NS, messages.clock(stamp))
    write("rgb", log, messages.image(stamp, "rgb_front", rgb_image(frame.class_ids), "bgra8"))
    depth = depth_image(frame, recording.depth_encoding)[:recording.depth_rows]
    write("depth", log, messages.image(stamp, "depth_front", depth, recording.depth_encoding))
    if recording.semantic is not None:
        painted = semantic_image(frame.class_ids, recording.semantic, recording.palette)
        if frame.index in recording.unknown_colour_frames:
            painted[0, 0, :3] = UNKNOWN_COLOUR[::-1]
        write("semantic", log, messages.image(stamp, "semantic_segmentation_front", painted, "bgra8"))
    write("odometry", log, messages.odometry(stamp, frame.arc_m))
    if recording.with_status:
        write("status", log, messages.status(stamp, frame.arc_m, frame.steer, frame.reverse))
    if recording.with_route and frame.index == 1:
        write("route", log, messages.route())
    if recording.command_topic:
        write("command", log - 1, messages.command(frame.arc_m))
    if recording.with_control:
        control_stamp = stamp if recording.control_stamped else 0
        write("control", log + CONTROL_LATENCY_NS, messages.control(control_stamp, frame.steer, frame.reverse))


def write_recording(path: Path, recording: Recording = Recording()) -> Truth:
    """Write the recording (an MCAP rosbag2 directory) and return what each frame should become."""
    store = bridge_typestore()
    messages = BridgeMessages(store, recording.role)
    truth = Truth()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = add_connections(writer, store, bridge_topics(recording), recording.definitions)

        def write(name: str, log_ns: int, msg: Any) -> None:
            writer.write(connections[name], log_ns, store.serialize_cdr(msg, msg.__msgtype__))

        write("world", WALL_START_NS, messages.world())
        for index in range(recording.frames):
            frame = drive_frame(recording, index)
            truth.add(frame)
            write_frame(write, messages, recording, frame)
    return truth
