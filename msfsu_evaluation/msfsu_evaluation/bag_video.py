"""msfsu-bag-video: watch any recorded bag as an MP4 (the drive-video renderer of msfsu_evaluation.video).

    msfsu-bag-video BAG -o drive.mp4
    msfsu-bag-video carla_bag -o drive.mp4 --remap /carla/hero/rgb_front/image:=/carla/ego_vehicle/rgb_front/image

One video frame per camera frame (at the camera's rate unless --fps): the RGB with the network's
segmentation (/msfsu/segmentation; the simulator's ground-truth class ids when the bag has no
prediction), the command, speed, steer, throttle/brake as text, and a top-down inset of the route
(/msfsu/route) and the path driven (odometry). Every other topic is matched to a camera frame by
header stamp (the latest message at or before it); whatever a bag lacks is left out of the picture.
A bag recorded on a car through carla-ros-bridge has the same topic names, or maps them with --remap.
Exit codes: 0 written, 1 failure (one-line reason), 2 usage error.
"""

from __future__ import annotations

import argparse
import math
import resource
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_common import topics
from msfsu_common.image_codec import ImageFormatError, decode_mono8, decode_rgb
from msfsu_common.message_types import stamp_ns, yaw_of
from msfsu_evaluation.usage import UsageError, parse_remap_pairs
from msfsu_evaluation.video import DriveRenderer, DriveState, VideoWriter
from msfsu_perception.preprocessing import PreprocessConfig

# stack topic -> (what it gives the picture, its message type)
SOURCES = {
    topics.RGB: ("rgb", "sensor_msgs/msg/Image"),
    topics.SEGMENTATION: ("segmentation", "sensor_msgs/msg/Image"),
    topics.SEMANTIC_IDS: ("ground_truth", "sensor_msgs/msg/Image"),
    topics.DRIVING_ACTION: ("action", "msfsu_interfaces/msg/DrivingAction"),
    topics.EXPERT_ACTION: ("expert_action", "msfsu_interfaces/msg/DrivingAction"),
    topics.VEHICLE_CONTROL: ("control", "msfsu_interfaces/msg/VehicleControl"),
    topics.ODOMETRY: ("odometry", "nav_msgs/msg/Odometry"),
    topics.ROUTE: ("route", "msfsu_interfaces/msg/Route"),
    topics.NAVIGATION_COMMAND: ("command", "msfsu_interfaces/msg/NavigationCommand"),
}
MAX_AGE_NS = 1_000_000_000  # a message older than this (relative to the camera frame) is not shown


@dataclass
class Series:
    """Values of one source in stamp order; `at(t)` = the latest at or before t (within MAX_AGE_NS)."""

    stamps: list[int] | np.ndarray = field(default_factory=list)  # an array once sorted
    values: list[object] = field(default_factory=list)
    max_age_ns: int | None = MAX_AGE_NS

    def add(self, stamp: int, value: object) -> None:
        self.stamps.append(stamp)  # before sort()
        self.values.append(value)

    def sort(self) -> None:
        order = np.argsort(np.asarray(self.stamps, np.int64), kind="stable")
        self.stamps = np.asarray(self.stamps, np.int64)[order]
        self.values = [self.values[i] for i in order]

    def index_at(self, stamp: int) -> int | None:
        index = int(np.searchsorted(self.stamps, stamp, side="right")) - 1
        if index < 0 or (self.max_age_ns is not None and stamp - self.stamps[index] > self.max_age_ns):
            return None
        return index

    def at(self, stamp: int):
        index = self.index_at(stamp)
        return None if index is None else self.values[index]


def _children_cpu_s() -> float:
    """CPU seconds of this process' finished children (the ffmpeg encoder, once its file is closed)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _count(dropped: dict[str, int], role: str, error: Exception) -> None:
    key = f"{role}: {str(error).splitlines()[0]}"
    dropped[key] = dropped.get(key, 0) + 1


def _decode(role: str, msg):
    """A message -> what the renderer needs from it."""
    if role in ("segmentation", "ground_truth"):
        return np.array(decode_mono8(msg))
    if role in ("action", "expert_action"):
        return float(msg.steer), float(msg.target_speed), int(msg.command)
    if role == "control":
        return float(msg.steer), float(msg.throttle), float(msg.brake)
    if role == "odometry":
        pose, twist = msg.pose.pose, msg.twist.twist
        return (float(pose.position.x), float(pose.position.y), yaw_of(pose.orientation),
                math.hypot(twist.linear.x, twist.linear.y))
    if role == "route":
        return np.array([(p.position.x, p.position.y) for p in msg.poses], np.float64).reshape(-1, 2)
    if role == "command":
        return int(msg.command)
    raise ValueError(role)


@dataclass(frozen=True)
class VideoSummary:
    path: Path
    frames: int
    fps: float
    size: tuple[int, int]
    bytes: int
    render_ms: float  # per frame: overlays drawn (DriveRenderer.render)
    encode_ms: float  # per frame: handed to ffmpeg (blocks while the encoder is behind) + finishing the file
    ffmpeg_cpu_ms: float  # per frame: CPU time of the ffmpeg process (it encodes beside the renderer)
    dropped: dict[str, int]
    sources: list[str]


def parse_remaps(items: Sequence[str], bag_topics: dict[str, str]) -> dict[str, str]:
    """["/bag/topic:=/stack/topic", ...] -> {stack topic: bag topic}."""
    pairs = parse_remap_pairs(items, bag_topics, list(SOURCES), "a topic the video shows", "/stack/topic")
    return {target: source for source, target in pairs}


@dataclass(frozen=True)
class _Sources:
    """What the video reads from a bag: bag topic -> role, and the roles the picture uses."""

    chosen: dict[str, str]  # bag topic -> role (every SOURCES topic the bag has)
    rgb_topic: str
    action_role: str  # "action" (the network's), else "expert_action"
    segmentation_role: str | None  # "segmentation" / "ground_truth" / None (no overlay)

    @property
    def used(self) -> set[str]:
        used = {"rgb", "odometry", "route", "command", "control", self.action_role, self.segmentation_role}
        used.discard(None)
        return used


def _chosen_topics(bag_topics: dict[str, str], remap: dict[str, str]) -> dict[str, str]:
    """Bag topic -> role for each source the bag has (UsageError if one carries another message type)."""
    chosen = {}
    for stack_topic, (role, msgtype) in SOURCES.items():
        topic = remap.get(stack_topic, stack_topic)
        if topic not in bag_topics:
            continue
        if bag_topics[topic] != msgtype:
            raise UsageError(f"{topic} carries {bag_topics[topic]}, the video reads {msgtype} there")
        chosen[topic] = role
    return chosen


def _sources(bag: Path, bag_topics: dict[str, str], remaps: Sequence[str], segmentation: str) -> _Sources:
    """The topics and roles to read; `segmentation` "auto" takes the prediction, else the ground truth, else none."""
    remap = parse_remaps(remaps, bag_topics)
    chosen = _chosen_topics(bag_topics, remap)
    rgb_topic = remap.get(topics.RGB, topics.RGB)
    if rgb_topic not in chosen:
        raise UsageError(f"bag {bag} has no camera topic {rgb_topic} (topics: {', '.join(sorted(bag_topics))}); "
                         "map yours with --remap /bag/topic:=" + topics.RGB)
    roles = set(chosen.values())
    if segmentation == "auto":
        segmentation = ("predicted" if "segmentation" in roles
                        else "ground-truth" if "ground_truth" in roles else "none")
    segmentation_role = {"predicted": "segmentation", "ground-truth": "ground_truth"}.get(segmentation)
    if segmentation_role is not None and segmentation_role not in roles:
        raise UsageError(f"--segmentation {segmentation}: the bag has no {segmentation_role} topic")
    return _Sources(chosen, rgb_topic, "action" if "action" in roles else "expert_action", segmentation_role)


def _read_series(reader: Any, store: Any, sources: _Sources,
                 dropped: dict[str, int]) -> tuple[dict[str, Series], list[int]]:
    """Every used source but the camera decoded into stamp-sorted series, and the camera's stamps (its pixels are
    decoded while rendering); undecodable messages are counted in `dropped`."""
    series = {role: Series(max_age_ns=None if role == "route" else MAX_AGE_NS) for role in sources.used - {"rgb"}}
    rgb_stamps: list[int] = []
    side = [c for c in reader.connections if sources.chosen.get(c.topic) in sources.used]
    for connection, _, raw in reader.messages(connections=side):
        role = sources.chosen[connection.topic]
        try:
            msg = store.deserialize_cdr(raw, connection.msgtype)
            if role == "rgb":
                rgb_stamps.append(stamp_ns(msg.header))
            else:
                series[role].add(stamp_ns(msg.header), _decode(role, msg))
        except (ImageFormatError, ValueError, KeyError) as error:
            _count(dropped, role, error)
    for values in series.values():
        values.sort()
    return series, rgb_stamps


def _camera_fps(rgb_stamps: list[int]) -> float:
    """The camera's rate from its median frame interval, within [1, 60] Hz (10 Hz for a single frame)."""
    steps = np.diff(np.unique(np.asarray(rgb_stamps, np.int64)))
    return float(np.clip(round(1e9 / float(np.median(steps)), 1), 1, 60)) if len(steps) else 10.0


def _render_frames(reader: Any, store: Any, sources: _Sources, series: dict[str, Series], start: int,
                   crop_top: float, writer: VideoWriter, bar: Any, dropped: dict[str, int]) -> tuple[float, float]:
    """Draw and write one video frame per decodable camera frame; returns the seconds spent drawing and writing."""
    renderer = DriveRenderer()
    route_index = None
    render_s = encode_s = 0.0
    for connection, _, raw in reader.messages(connections=[c for c in reader.connections
                                                           if c.topic == sources.rgb_topic]):
        bar.update()
        msg = store.deserialize_cdr(raw, connection.msgtype)
        try:
            rgb = decode_rgb(msg)
        except ImageFormatError as error:
            _count(dropped, "rgb", error)
            continue
        t = stamp_ns(msg.header)
        index = series["route"].index_at(t)
        if index != route_index:
            route_index = index
            renderer.set_route(None if index is None else series["route"].values[index])
        state = _state(t, start, series, sources.action_role, sources.segmentation_role, crop_top)
        started = time.perf_counter()
        frame = renderer.render(rgb, state)
        written = time.perf_counter()
        writer.write(frame)
        render_s += written - started
        encode_s += time.perf_counter() - written
    return render_s, encode_s


def render_bag(bag: Path, output: Path, remaps: Sequence[str] = (), fps: float | None = None,
               segmentation: str = "auto", crop_top: float = PreprocessConfig.crop_top_fraction,
               progress: bool = True) -> VideoSummary:
    """Render `bag` into `output`; UsageError for what the user must change."""
    from rosbags.rosbag2 import Reader
    from tqdm import tqdm

    from msfsu_common.bag_io import msfsu_typestore

    if not (bag / "metadata.yaml").is_file():
        raise UsageError(f"{bag} is not a rosbag2 bag directory (no metadata.yaml)")
    store = msfsu_typestore()
    dropped: dict[str, int] = {}
    with Reader(bag) as reader:
        sources = _sources(bag, {c.topic: c.msgtype for c in reader.connections}, remaps, segmentation)
        series, rgb_stamps = _read_series(reader, store, sources, dropped)
        if not rgb_stamps:
            raise UsageError(f"bag {bag} has no readable camera frame on {sources.rgb_topic}")
        fps = _camera_fps(rgb_stamps) if fps is None else fps
        children_cpu = _children_cpu_s()
        writer = VideoWriter(output, fps)
        with writer, tqdm(total=len(rgb_stamps), unit="frame", disable=not progress, desc="video") as bar:
            render_s, encode_s = _render_frames(reader, store, sources, series, min(rgb_stamps), crop_top, writer,
                                                bar, dropped)
            started = time.perf_counter()
        encode_s += time.perf_counter() - started  # ffmpeg finishing the file
    if writer.frames == 0:
        raise UsageError(f"no camera frame of {sources.rgb_topic} could be decoded ({dropped})")
    frames = writer.frames
    return VideoSummary(output, frames, fps, writer.size, output.stat().st_size, 1e3 * render_s / frames,
                        1e3 * encode_s / frames, 1e3 * (_children_cpu_s() - children_cpu) / frames, dropped,
                        ["rgb"] + sorted(role for role, values in series.items() if len(values.stamps)))


def _state(t: int, start: int, series: dict[str, Series], action_role: str, segmentation_role: str | None,
           crop_top: float) -> DriveState:
    def at(role: str | None):
        return None if role is None or role not in series else series[role].at(t)

    odometry, action, control, command = at("odometry"), at(action_role), at("control"), at("command")
    segmentation = at(segmentation_role)
    return DriveState(
        time_s=(t - start) * 1e-9,  # since the first camera frame
        speed_mps=None if odometry is None else odometry[3],
        command=command if command is not None else (None if action is None else action[2]),
        steer=action[0] if action is not None else (None if control is None else control[0]),
        target_speed_mps=None if action is None else action[1],
        throttle=None if control is None else control[1],
        brake=None if control is None else control[2],
        segmentation=segmentation,
        segmentation_top=crop_top if segmentation_role == "segmentation" else 0.0,
        segmentation_label="predicted" if segmentation_role == "segmentation" else "ground truth",
        pose=None if odometry is None else odometry[:3],
        action_source="" if action_role == "action" or action is None else "expert",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="msfsu-bag-video", description=__doc__.split("\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("bag", type=Path, help="rosbag2 bag directory (MCAP or sqlite3)")
    parser.add_argument("-o", "--output", type=Path, required=True, help="MP4 file to write")
    parser.add_argument("--remap", action="append", default=[], metavar="/bag/topic:=/stack/topic",
                        help="read a stack topic from another bag topic (repeatable)")
    parser.add_argument("--segmentation", choices=["auto", "predicted", "ground-truth", "none"], default="auto",
                        help="overlay: the network's (auto: if recorded, else the ground truth)")
    parser.add_argument("--crop-top", type=float, default=PreprocessConfig.crop_top_fraction,
                        help="share of image rows above what the network saw (its checkpoint's crop_top_fraction)")
    parser.add_argument("--fps", type=float, help="frames per second (default: the camera's rate)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    options = build_parser().parse_args(argv)
    try:
        if options.fps is not None and not 0 < options.fps <= 120:
            raise UsageError("--fps must be in (0, 120]")
        if not 0 <= options.crop_top < 1:
            raise UsageError("--crop-top must be in [0, 1)")
        if options.output.suffix.lower() != ".mp4":
            raise UsageError(f"--output {options.output} must end in .mp4")
        summary = render_bag(options.bag, options.output, options.remap, options.fps, options.segmentation,
                             options.crop_top)
    except UsageError as error:
        print(f"msfsu-bag-video: {error}", file=sys.stderr)
        return 2
    except (OSError, RuntimeError, ValueError) as error:
        print(f"msfsu-bag-video: {str(error).splitlines()[0]}", file=sys.stderr)
        return 1
    dropped = "" if not summary.dropped else "; dropped " + ", ".join(f"{k} x{v}" for k, v in summary.dropped.items())
    print(f"msfsu-bag-video: wrote {summary.path}: {summary.frames} frames at {summary.fps:g} fps "
          f"({summary.frames / summary.fps:.1f} s), {summary.size[0]}x{summary.size[1]} H.264, "
          f"{summary.bytes / 1e6:.2f} MB; per frame: render {summary.render_ms:.1f} ms, hand-off to ffmpeg "
          f"{summary.encode_ms:.1f} ms, ffmpeg CPU {summary.ffmpeg_cpu_ms:.1f} ms; "
          f"shown: {', '.join(summary.sources)}{dropped}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
