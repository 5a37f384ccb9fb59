"""msfsu-import-carla: a carla-ros-bridge recording -> one bag the stack trains and evaluates on (ROS-free core).

    msfsu-import-carla BAG --out DIR [--split train] [--role ego_vehicle] [--tolerance 0.05] [--raw-tags NUMBERING]
                       [--objects msfsu_objects.json] [--no-labels] [--force]

One bag in, one bag out. The recording's carla_msgs types are read from the message definitions the bag holds
(`bag_io.bag_typestore`): the import needs no carla_msgs installed. The source is read through `bag_io.open_bag`, so a
recording cut short is recovered as every bag tool of the stack recovers it (one warning says what was kept).

Rules, per camera frame (each RGB image; its header stamp is the frame's stamp in every output message):
- a frame whose stamp is not after the previous frame's (stamps out of order, a clock reset) is dropped;
- depth and semantic images pair with it by header stamp, the nearest within the tolerance;
- labels: the semantic image's CityScapes colours (or, with `--raw-tags`, its red channel's raw tags) through
  `msfsu_sim.carla.labels.CARLA_TAGS`; a frame with a pixel that is no CARLA tag is dropped, its colours reported;
- steer: `steer` of the CarlaEgoVehicleControl nearest in time (CarlaEgoVehicleStatus' `control` with
  `--control-topic .../vehicle_status`: the control CARLA applied, e.g. its autopilot's). CARLA's normalised steer
  (-1 full left, +1 full right) is the stack's DrivingAction.steer unchanged, clipped to [-1, 1] as CARLA clamps
  it when it applies a control; a frame driven in reverse is dropped (the stack drives forwards only);
- target speed: the vehicle's measured speed nearest in time, CarlaEgoVehicleStatus `velocity` (m/s), or the
  odometry's twist length without a status topic;
- navigation command: the latest RoadOption message at or before the frame (`--command-topic`, or the stack's
  NavigationCommand topic when the recording has it; CARLA's CHANGELANELEFT / CHANGELANERIGHT are LANE_FOLLOW,
  VOID and other values drop the frame), else derived from the route (`msfsu_sim.carla.route`: turns from the
  nav_msgs/Path's shape, the route tracker's look-ahead at the odometry position);
- time: header stamps; a topic whose messages all have a zero stamp (carla_ad_agent and carla_manual_control publish
  CarlaEgoVehicleControl without one) is placed by its log time, matched against the frames' log times.
A frame that misses any of these is dropped and counted by reason. A recording without the semantic camera is
refused unless `--no-labels` says that no labels are wanted (msfsu-eval-bag and `msfsu-train --variant msf` need
none); `--force` replaces an output bag that exists. The output holds the stack's topics
(`BagTopics` defaults, odometry on `topics.ODOMETRY`) with log times on the frames' clock, the split, the map
(from /carla/world_info), the camera (bag_io CAMERA: the RGB camera's size, lens and mount in the sensor definition
the recording was spawned with, `--objects`, checked against the recorded images; msfsu_sim.carla.sensors) and where
everything came from (bag_io SOURCE_BAG, SOURCE_INFO, IMPORT_REPORT).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_common import topics as stack_topics
from msfsu_common.bag_io import (CAMERA, IMPORT_REPORT, MAP, METADATA_PREFIX, SOURCE_BAG, SOURCE_INFO, SPLIT, SPLITS,
                                  Bag, is_bag, mcap_writer, msfsu_typestore, open_bag, read_bag_information)
from msfsu_common.bag_schema import COMMAND_LEAD_NS
from msfsu_common.camera_geometry import FrontCamera
from msfsu_common.image_codec import decode_rgb, encode_image, image_to_array
from msfsu_common.message_types import stamp_ns
from msfsu_control.route_tracker import RouteTrackerConfig
from msfsu_perception.bag_topics import BagTopics
from msfsu_sim.carla.frames import Frame, ImportSettings, Plan, plan_frames
from msfsu_sim.carla.labels import (TAG_SETS, Labels, is_palette_image, looks_like_raw_tags, palette_labels,
                                    tag_labels)
from msfsu_sim.carla.recording import (NAVIGATION_COMMAND_TYPE, CarlaImportError, Series, Sources, SourceTopics,
                                       check_images, pick_sources, read_series)
from msfsu_sim.carla.sensors import RECIPE_OBJECTS, front_camera, sensor_id, vehicle_sensors

PROGRAM = "msfsu-import-carla"


def _labels_of(msg: Any, raw_tags: str | None, topic: str) -> Labels:
    if raw_tags is None:
        return palette_labels(decode_rgb(msg))
    if msg.encoding == "mono8":
        return tag_labels(np.ascontiguousarray(image_to_array(msg, ("mono8",))), raw_tags)
    rgb = decode_rgb(msg)
    labels = tag_labels(np.ascontiguousarray(rgb[..., 0]), raw_tags)
    if labels.unknown and is_palette_image(rgb):
        example = tuple(int(value) for value in rgb[np.nonzero(rgb[..., 1:].any(axis=-1))][0])
        raise CarlaImportError(f"--raw-tags {raw_tags}: {topic} holds CityScapes palette colours (e.g. {example}), "
                               "not raw tags in the red channel: import it without --raw-tags")
    return labels


class _Output:
    """The output bag's connections and one frame's messages written into it."""

    def __init__(self, writer: Any, with_depth: bool, with_labels: bool) -> None:
        self.store = msfsu_typestore()
        self.types = self.store.types
        self.names = BagTopics()
        wanted = {"rgb": (self.names.rgb, "sensor_msgs/msg/Image"),
                  "action": (self.names.expert_action, "msfsu_interfaces/msg/DrivingAction"),
                  "command": (self.names.navigation_command, NAVIGATION_COMMAND_TYPE),
                  "odometry": (stack_topics.ODOMETRY, "nav_msgs/msg/Odometry")}
        if with_depth:
            wanted["depth"] = (self.names.depth, "sensor_msgs/msg/Image")
        if with_labels:
            wanted["ids"] = (self.names.semantic_ids, "sensor_msgs/msg/Image")
        self.writer = writer
        self.connections = {name: writer.add_connection(topic, msgtype, typestore=self.store)
                            for name, (topic, msgtype) in wanted.items()}

    def header(self, stamp: int, frame_id: str) -> Any:
        time = self.types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
        return self.types["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def write(self, name: str, log_ns: int, msg: Any) -> None:
        self.writer.write(self.connections[name], log_ns, self.store.serialize_cdr(msg, msg.__msgtype__))

    def write_raw(self, name: str, log_ns: int, raw: bytes) -> None:
        self.writer.write(self.connections[name], log_ns, raw)

    def frame(self, frame: Frame, parts: dict[str, Any], labels: Labels | None) -> None:
        """The frame's command first, then its images and expert action, all stamped (and logged) at its stamp."""
        stamp = frame.stamp_ns
        self.write("command", stamp - COMMAND_LEAD_NS, self.types[NAVIGATION_COMMAND_TYPE](
            header=self.header(stamp, "map"), command=frame.command))
        self.write_raw("rgb", stamp, parts["rgb"][0])
        if frame.depth is not None:
            raw, depth = parts["depth"]
            if stamp_ns(depth.header) == stamp:
                self.write_raw("depth", stamp, raw)
            else:  # re-stamped with the frame's stamp: the stack pairs a frame's images by equal stamps
                self.write("depth", stamp, replace(depth, header=self.header(stamp, depth.header.frame_id)))
        if labels is not None:
            fields = encode_image(labels.class_ids, "mono8")
            fields["data"] = np.frombuffer(fields["data"], np.uint8)
            self.write("ids", stamp, self.types["sensor_msgs/msg/Image"](
                header=self.header(stamp, parts["semantic"][1].header.frame_id), **fields))
        self.write("action", stamp, self.types["msfsu_interfaces/msg/DrivingAction"](
            header=self.header(stamp, parts["rgb"][1].header.frame_id), steer=frame.steer,
            target_speed=frame.target_speed, command=frame.command))


@dataclass
class WriteResult:
    written: int = 0
    unknown_label_frames: int = 0
    unknown_labels: Counter = field(default_factory=Counter)  # colour (r, g, b) or raw tag -> pixels


def write_frames(bag: Bag, sources: Sources, plan: Plan, series: dict[str, Series], writer: Any,
                 raw_tags: str | None) -> WriteResult:
    """Pass 2: each planned frame once its images are read (frames with a pixel that is no tag are left out), and
    the odometry as recorded, every message logged at its header stamp (its log time without one)."""
    output = _Output(writer, plan.frames[0].depth is not None, plan.frames[0].semantic is not None)
    needed: dict[str, dict[int, list[int]]] = {"rgb": {}, "depth": {}, "semantic": {}}
    for number, frame in enumerate(plan.frames):
        for role in needed:
            index = getattr(frame, role)
            if index is not None:
                needed[role].setdefault(index, []).append(number)
    roles = {sources.connections[role].id: role for role in (*needed, "odometry")
             if sources.connections[role] is not None}
    parts_of: dict[int, dict[str, tuple[bytes, Any]]] = {}
    seen: Counter[str] = Counter()
    result = WriteResult()
    chosen = [sources.connections[role] for role in roles.values()]
    for connection, log_ns, raw in bag.messages(chosen):
        role = roles[connection.id]
        index, seen[role] = seen[role], seen[role] + 1
        if role == "odometry":
            stamp = series["odometry"].stamps[index]
            output.write_raw("odometry", stamp or log_ns, bytes(raw))
            continue
        for number in needed[role].get(index, ()):
            parts = parts_of.setdefault(number, {})
            parts[role] = (bytes(raw), sources.store.deserialize_cdr(raw, connection.msgtype))
            frame = plan.frames[number]
            if len(parts) < 1 + (frame.depth is not None) + (frame.semantic is not None):
                continue
            del parts_of[number]
            labels = (None if frame.semantic is None
                      else _labels_of(parts["semantic"][1], raw_tags, sources.connections["semantic"].topic))
            if labels is not None and labels.unknown:
                result.unknown_label_frames += 1
                result.unknown_labels.update(labels.unknown)
                continue
            output.frame(frame, parts, labels)
            result.written += 1
    return result


# --- the whole import --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImportReport:
    source: Path
    output: Path
    camera_frames: int
    frames: int
    dropped: dict[str, int]
    sources: dict[str, str]
    unknown_labels: dict[str, int]  # the most frequent colours / tags that are no CARLA tag -> pixels
    unknown_colours: tuple[Any, ...] = ()  # those colours (r, g, b) / tags as read

    def lines(self) -> list[str]:
        dropped = ", ".join(f"{count} {reason}" for reason, count in self.dropped.items() if count) or "none"
        lines = [f"{self.source} -> {self.output}: {self.frames} of {self.camera_frames} camera frames "
                 f"(dropped: {dropped})"]
        lines += [f"  {name}: {source}" for name, source in self.sources.items()]
        if self.unknown_labels:
            lines.append(f"  {self.dropped['unknown_label']} frames hold colours that are no CARLA tag, most "
                         f"frequent (pixels): {', '.join(f'{c} {n}' for c, n in self.unknown_labels.items())}"
                         f"{raw_tags_hint(self.unknown_colours)}")
        if self.sources["labels"].startswith("none"):  # --no-labels: asked for
            lines.append("  imported for evaluation only: msfsu-eval-bag scores steer and speed, not segmentation; "
                         "msfsu-train needs the semantic camera for the msfsu and su variants (--variant msf trains "
                         "without)")
        return lines


def raw_tags_hint(unknown: tuple[Any, ...]) -> str:
    """A hint for colours that are a raw semantic image read as a palette (the tag in red, green and blue 0)."""
    if unknown and all(isinstance(colour, tuple) for colour in unknown) and looks_like_raw_tags(unknown):
        return f"; they look like raw tags in the red channel: --raw-tags {' or --raw-tags '.join(TAG_SETS)}"
    return ""


def _source_info(bag: Bag) -> dict[str, Any]:
    """What the recording says of itself, for the output's metadata."""
    information = read_bag_information(bag.path) if bag.path.is_dir() else {}
    kept = ("storage_identifier", "ros_distro", "starting_time", "duration", "message_count", "custom_data")
    info = {key: information[key] for key in kept if key in information}
    info["topics"] = {c.topic: {"type": c.msgtype, "messages": c.msgcount} for c in bag.connections}
    info["recovered"] = [recovery.describe() for recovery in bag.recoveries]
    return info


def recording_camera(series: dict[str, Series], sources: Sources, objects: Path, role: str) -> FrontCamera:
    """The RGB camera of vehicle `role` in the sensor definition `objects`, checked against the recording: its image
    size, and the depth camera at its pose with its lens (the stack pairs their pixels)."""
    rgb_topic, depth_topic = sources.topic("rgb"), sources.topic("depth")
    sensors = vehicle_sensors(objects, role)
    camera = front_camera(objects, role, sensor_id(rgb_topic), sensors)
    width, height = series["rgb"].values[0][1:]
    if (camera.width, camera.height) != (width, height):
        raise CarlaImportError(f"{rgb_topic} is {width}x{height}, camera {sensor_id(rgb_topic)!r} of {objects} "
                               f"{camera.width}x{camera.height}: give the sensor definition the recording was spawned "
                               "with (--objects FILE)")
    if depth_topic is not None and sensor_id(depth_topic) in sensors:  # none named: nothing to check it against
        depth = front_camera(objects, role, sensor_id(depth_topic), sensors)
        if depth != camera:
            raise CarlaImportError(f"{objects}: the depth camera {sensor_id(depth_topic)!r} is not at the RGB camera's "
                                   f"pose with its lens ({depth} against {camera}); the stack pairs their pixels")
    return camera


def check_output(output: Path, force: bool) -> None:
    """An output that exists is refused, or with `force` taken to be replaced if it is a bag (nothing else is)."""
    if not output.exists() and not output.is_symlink():
        return
    if not force:
        raise CarlaImportError(f"{output} exists; the import writes a new bag directory (--force replaces it)")
    if output.is_symlink() or not output.is_dir() or not is_bag(output):
        raise CarlaImportError(f"{output} exists and is no bag directory: --force replaces only a bag")


def require_labels(sources: Sources, settings: ImportSettings) -> None:
    """Labels wanted and no semantic camera: refused, saying where it was looked for and how to go without."""
    if settings.labels and sources.connections["semantic"] is None:
        raise CarlaImportError(
            f"no semantic camera on {sources.looked_for['semantic']} (topics: {sources.present}): the labels "
            "msfsu-train needs for the msfsu and su variants; name it with --semantic-topic, or import without labels "
            "with --no-labels (for msfsu-eval-bag and msfsu-train --variant msf)")


def import_carla_bag(source: Path, output: Path, topics: SourceTopics, settings: ImportSettings,
                     warn: Callable[[str], None] | None = None, objects: Path = RECIPE_OBJECTS,
                     role: str = stack_topics.ROLE, force: bool = False) -> ImportReport:
    """Import one recording into a new bag directory `output` (written whole, or not at all; `force`: replacing the
    bag there); its camera is the one of vehicle `role` in the sensor definition `objects` (the file its sensors were
    spawned with)."""
    if settings.split not in SPLITS:
        raise CarlaImportError(f"split {settings.split!r} is none of {', '.join(SPLITS)}")
    if settings.raw_tags is not None and settings.raw_tags not in TAG_SETS:
        raise CarlaImportError(f"--raw-tags {settings.raw_tags!r} is none of {', '.join(TAG_SETS)}")
    check_output(output, force)
    with open_bag(source, warn) as bag:
        sources = pick_sources(bag, topics)
        if not settings.labels:
            sources.connections["semantic"] = None
        require_labels(sources, settings)
        series = read_series(bag, sources)
        check_images(series, sources, settings.raw_tags)
        camera = recording_camera(series, sources, objects, role)
        plan = plan_frames(series, sources, settings)
        if not plan.frames:
            raise CarlaImportError(f"{source}: none of {plan.camera_frames} camera frames has everything a sample "
                                   f"needs (dropped: {dict(plan.dropped)})")
        world = series["world"].values
        metadata: dict[str, object] = {SPLIT: settings.split, SOURCE_BAG: str(bag.path.resolve()),
                                       SOURCE_INFO: json.dumps(_source_info(bag), sort_keys=True),
                                       CAMERA: camera.to_json()}
        if world:
            metadata[MAP] = world[-1]
        staging = output.with_name(f".{output.name}.partial")  # the bag is written whole in here, then moved
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir(parents=True)
        partial = staging / output.name  # the MCAP file is named after its directory
        try:
            with mcap_writer(partial, metadata) as writer:
                result = write_frames(bag, sources, plan, series, writer, settings.raw_tags)
                dropped = {**plan.dropped, "unknown_label": result.unknown_label_frames}
                common = dict(result.unknown_labels.most_common(5))
                report = ImportReport(source, output, plan.camera_frames, result.written, dropped, plan.sources,
                                      {str(key): count for key, count in common.items()}, tuple(common))
                writer.set_custom_data(METADATA_PREFIX + IMPORT_REPORT, json.dumps(_report_metadata(report, settings)))
            if not result.written:
                raise CarlaImportError(f"{source}: every frame's semantic image holds colours that are no CARLA tag "
                                       f"(most frequent, pixels: {report.unknown_labels}); a compressed or re-coloured "
                                       f"semantic camera cannot be read as labels{raw_tags_hint(tuple(common))}")
            if output.exists():  # --force, checked above: the old bag goes only once the new one is whole
                shutil.rmtree(output)
            partial.rename(output)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    return report


def _report_metadata(report: ImportReport, settings: ImportSettings) -> dict[str, Any]:
    return {"tool": PROGRAM, "camera_frames": report.camera_frames, "frames": report.frames,
            "dropped": report.dropped, "sources": report.sources, "unknown_labels": report.unknown_labels,
            "settings": {**asdict(settings), "route": asdict(settings.route)}}


# --- command line ------------------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROGRAM, description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("bag", type=Path, help="carla-ros-bridge recording (rosbag2 directory, MCAP or sqlite3)")
    parser.add_argument("--out", type=Path, required=True, help="output bag directory (must not exist, or --force)")
    parser.add_argument("--force", action="store_true", help="replace the output bag directory if it exists")
    parser.add_argument("--no-labels", dest="labels", action="store_false",
                        help="import without the semantic camera's labels (for msfsu-eval-bag and msfsu-train "
                             "--variant msf); without it a recording that has no semantic camera is refused")
    parser.add_argument("--split", choices=SPLITS, default=ImportSettings.split, help="split metadata of the output")
    parser.add_argument("--role", default=stack_topics.ROLE, help="the ego vehicle's role_name in the bridge's topics")
    parser.add_argument("--tolerance", type=float, default=ImportSettings.tolerance_s, metavar="S",
                        help="nearest-in-time matches further apart than this are no match")
    parser.add_argument("--raw-tags", choices=TAG_SETS, help="the semantic camera gives raw tags (red channel) "
                        "numbered as in these CARLA versions, not CityScapes palette colours")
    parser.add_argument("--lookahead", type=float, default=RouteTrackerConfig.lookahead_m, metavar="M",
                        help="route-derived commands: announce a turn this far ahead (the route node's lookahead)")
    parser.add_argument("--objects", type=Path, default=RECIPE_OBJECTS, metavar="FILE",
                        help="the carla_spawn_objects definition the recording's sensors were spawned with: the RGB "
                             "camera's size, lens and mount go into the output's metadata (the emergency brake "
                             "of msfsu-eval-bag places pixels with them)")
    names = parser.add_argument_group("topics (defaults: the bridge's names for --role)")
    for role in ("rgb", "depth", "semantic", "control", "status", "odometry", "route"):
        names.add_argument(f"--{role}-topic", metavar="TOPIC")
    names.add_argument("--command-topic", metavar="TOPIC", help=f"RoadOption values ({NAVIGATION_COMMAND_TYPE} or a "
                       f"std_msgs integer); default: {stack_topics.NAVIGATION_COMMAND} where recorded, else derived "
                       "from the route")
    return parser


def run(options: argparse.Namespace) -> ImportReport:
    if not options.tolerance > 0 or not options.lookahead >= 0:
        raise CarlaImportError(f"--tolerance must be positive and --lookahead not negative, got {options.tolerance} "
                               f"and {options.lookahead}")
    topics = SourceTopics.of_role(options.role, **{role: getattr(options, f"{role}_topic") for role in (
        "rgb", "depth", "semantic", "control", "status", "odometry", "route", "command")})
    settings = ImportSettings(split=options.split, tolerance_s=options.tolerance, raw_tags=options.raw_tags,
                              labels=options.labels, route=RouteTrackerConfig(lookahead_m=options.lookahead))
    return import_carla_bag(options.bag, options.out, topics, settings, warn=_complain, objects=options.objects,
                            role=options.role, force=options.force)


def _complain(message: str) -> None:
    print(f"{PROGRAM}: {message}", file=sys.stderr, flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    options = build_parser().parse_args(argv)
    try:
        report = run(options)
    except (ValueError, OSError) as error:  # CarlaImportError, BagError, ImageFormatError: one line each
        _complain(str(error))
        return 1
    print("\n".join(report.lines()), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
