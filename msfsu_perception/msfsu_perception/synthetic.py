"""Small, learnable rosbag2 MCAP bags shaped like the simulator's recordings (tests, bag replay).

Each camera frame has an RGB image (rgb8 or bgra8), metric depth (32FC1) and class ids (mono8)
sharing one header stamp, and an expert DrivingAction with that stamp. The road leans with the
steering and a vehicle appears when the expert stops, so images and labels are consistent.
NavigationCommand messages have their own stamps (sent just before a change and again between
frames); the std_msgs/Bool noise flag (no header) is logged when it changes, the std_msgs/String of what
limits the expert (`topics.EXPERT_LIMITED_BY`: "vehicle" while it stops, else "free") every frame. Log times are the
stamps plus a small recording delay. The returned `SyntheticTruth` is what a correct reader
must recover per frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from msfsu_common import topics as topic_names
from msfsu_common.bag_io import END, MAP, SEED, SPLIT, TRAFFIC, WEATHER, mcap_writer, msfsu_typestore
from msfsu_common.bag_schema import COMMAND_LEAD_NS
from msfsu_common.image_codec import encode_image
from msfsu_common.road_option import RoadOption
from msfsu_common.semantic_classes import CLASS_COLOURS
from msfsu_perception.bag_topics import BagTopics

# RGB of the five classes: road, road line, sidewalk, vehicle or pedestrian, other.
FAR_DEPTH_M = 1000.0
VEHICLE_DEPTH_M = 8.0
CRUISE_SPEED_MPS = 8.0
RECORDING_DELAY_NS = 5_000_000
TURN_COMMANDS = (RoadOption.LEFT, RoadOption.RIGHT, RoadOption.STRAIGHT)


@dataclass(frozen=True)
class SyntheticTruth:
    """Per camera frame, in stamp order."""

    stamps_ns: np.ndarray  # (N,) int64 header stamps
    steer: np.ndarray  # (N,) float32
    target_speed: np.ndarray  # (N,) float32 m/s
    command: np.ndarray  # (N,) uint8 RoadOption values
    noise: np.ndarray  # (N,) bool, noise injection active
    limited_by: np.ndarray  # (N,) str, what holds the expert's label below cruise (bag_io.EXPERT_LIMITS)
    network: np.ndarray | None = None  # (N,) bool, the network drove (on-policy bags)
    asked_speed: np.ndarray | None = None  # (N,) float32, the target speed the network asked for where it drove


def _trajectory(n_frames: int, rng: np.random.Generator, noise_period: int, noise_duration: int) -> SyntheticTruth:
    """Mostly straight driving with sharp turns now and then, stops, command changes, noise windows."""
    frames = np.arange(n_frames)
    phase = rng.uniform(0, 2 * np.pi)
    steer = 0.8 * np.sin(2 * np.pi * frames / 37.0 + phase) ** 7 + rng.normal(0, 0.01, n_frames)
    target_speed = np.where((frames // 13) % 4 == 3, 0.0, CRUISE_SPEED_MPS) + rng.uniform(-0.5, 0.5, n_frames)
    command = np.full(n_frames, RoadOption.LANE_FOLLOW, np.uint8)
    turn_window = (frames // 8) % 3 == 2
    command[turn_window] = np.array(TURN_COMMANDS, np.uint8)[(frames[turn_window] // 24) % len(TURN_COMMANDS)]
    noise = frames % noise_period >= noise_period - noise_duration
    target_speed = np.clip(target_speed, 0, None).astype(np.float32)
    return SyntheticTruth(
        stamps_ns=np.zeros(n_frames, np.int64),
        steer=np.clip(steer, -1, 1).astype(np.float32),
        target_speed=target_speed,
        command=command,
        noise=noise,
        limited_by=np.where(target_speed < 1.0, "vehicle", "free"),  # render_scene draws the car it stops for
    )


def render_scene(steer: float, stopped: bool, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) uint8 class ids and (H, W) float32 depth: a road leaning with the steering."""
    rows = np.arange(height, dtype=np.float32)[:, None]
    cols = np.arange(width, dtype=np.float32)[None, :]
    horizon = height / 2
    nearness = np.clip((rows - horizon) / (height - horizon), 0, 1)  # 0 at the horizon, 1 at the bottom
    centre = width / 2 + steer * (width / 2) * (1 - nearness)
    half_width = width * (0.05 + 0.35 * nearness)
    offset = np.abs(cols - centre)
    below = rows >= horizon
    class_ids = np.full((height, width), 4, np.uint8)
    class_ids[below & (offset < half_width + width * 0.08)] = 2
    class_ids[below & (offset < half_width)] = 0
    class_ids[below & (offset < 1.0)] = 1
    row_depth = np.where(below, 1.5 * height / np.maximum(rows - horizon, 1.0), FAR_DEPTH_M)
    depth = np.broadcast_to(row_depth, (height, width)).astype(np.float32)
    if stopped:
        vehicle = below & (nearness < 0.3) & (offset < half_width * 0.8)
        class_ids[vehicle] = 3
        depth[vehicle] = VEHICLE_DEPTH_M
    return class_ids, depth


@dataclass(frozen=True)
class _FrameFormat:
    """How the camera frames are drawn and encoded."""

    height: int
    width: int
    rgb_encoding: str  # rgb8 / bgr8 / rgba8 / bgra8
    depth_encoding: str  # 32FC1 metres / 16UC1 millimetres
    depth_hole_fraction: float  # one no-return patch at the bottom left of each depth frame


def _camera_rgb(class_ids: np.ndarray, rng: np.random.Generator, encoding: str) -> np.ndarray:
    """The class colours with pixel noise, in `encoding`'s channel order (alpha 255)."""
    rgb = np.clip(CLASS_COLOURS[class_ids].astype(np.int16) + rng.integers(-12, 13, class_ids.shape + (3,)), 0, 255)
    rgb = rgb.astype(np.uint8)
    if encoding in ("bgra8", "rgba8"):
        rgb = np.concatenate([rgb, np.full(class_ids.shape + (1,), 255, np.uint8)], axis=2)
    if encoding.startswith("bgr"):
        rgb[..., :3] = rgb[..., 2::-1]
    return rgb


def _camera_depth(depth: np.ndarray, frame: _FrameFormat) -> np.ndarray:
    """Metric depth with its no-return patch (NaN in 32FC1, 0 in 16UC1), in the frame's depth encoding."""
    height, width, holes = frame.height, frame.width, frame.depth_hole_fraction
    if holes:
        patch_rows = max(1, round(height * holes))
        depth[height - patch_rows:, :round(width * holes * height / patch_rows)] = np.nan
    if frame.depth_encoding == "16UC1":
        depth = np.nan_to_num(np.minimum(depth, 65.535) * 1000.0, nan=0.0).round().astype(np.uint16)
    return depth


class _SyntheticBagWriter:
    """Builds the bag's messages and writes them on its connections, named by role."""

    def __init__(self, writer: object, topics: BagTopics, with_clock: bool, on_policy: bool) -> None:
        self.store = msfsu_typestore()
        self.types = self.store.types
        self._writer = writer
        self._connections = {
            name: writer.add_connection(topic, msgtype, typestore=self.store)
            for name, topic, msgtype in (
                ("rgb", topics.rgb, "sensor_msgs/msg/Image"),
                ("depth", topics.depth, "sensor_msgs/msg/Image"),
                ("ids", topics.semantic_ids, "sensor_msgs/msg/Image"),
                ("action", topics.expert_action, "msfsu_interfaces/msg/DrivingAction"),
                ("command", topics.navigation_command, "msfsu_interfaces/msg/NavigationCommand"),
                ("noise", topics.noise_injection, "std_msgs/msg/Bool"),
                ("limited_by", topic_names.EXPERT_LIMITED_BY, "std_msgs/msg/String"),
                ("network", topic_names.NETWORK_DRIVING, "std_msgs/msg/Bool"),
                ("asked", topic_names.DRIVING_ACTION, "msfsu_interfaces/msg/DrivingAction"),
                ("clock", topics.clock, "rosgraph_msgs/msg/Clock"),
            )
            if (with_clock or name != "clock") and (on_policy or name not in ("network", "asked"))
        }

    def write(self, name: str, log_ns: int, msg: object) -> None:
        self._writer.write(self._connections[name], log_ns, self.store.serialize_cdr(msg, msg.__msgtype__))

    def header(self, stamp_ns: int, frame_id: str) -> object:
        stamp = self.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def image(self, stamp_ns: int, pixels: np.ndarray, encoding: str) -> object:
        fields = encode_image(pixels, encoding)
        fields["data"] = np.frombuffer(fields["data"], np.uint8)
        return self.types["sensor_msgs/msg/Image"](header=self.header(stamp_ns, "camera_front"), **fields)

    def command(self, stamp_ns: int, value: int) -> object:
        return self.types["msfsu_interfaces/msg/NavigationCommand"](header=self.header(stamp_ns, "map"), command=value)

    def action(self, stamp_ns: int, steer: float, target_speed: float, command: int) -> object:
        return self.types["msfsu_interfaces/msg/DrivingAction"](
            header=self.header(stamp_ns, "base_link"), steer=steer, target_speed=target_speed, command=command)

    def flag(self, value: bool) -> object:
        return self.types["std_msgs/msg/Bool"](data=value)


def _write_frame(bag: _SyntheticBagWriter, truth: SyntheticTruth, index: int, rng: np.random.Generator,
                 frame: _FrameFormat) -> None:
    """The camera images, the expert's label, what limits it and (on-policy) the network's flag and action of one
    frame, logged RECORDING_DELAY_NS after its stamp (the labels one delay later)."""
    stamp, command = int(truth.stamps_ns[index]), int(truth.command[index])
    class_ids, depth = render_scene(float(truth.steer[index]), truth.target_speed[index] < 1.0, frame.height,
                                    frame.width)
    log = stamp + RECORDING_DELAY_NS
    bag.write("rgb", log, bag.image(stamp, _camera_rgb(class_ids, rng, frame.rgb_encoding), frame.rgb_encoding))
    bag.write("depth", log, bag.image(stamp, _camera_depth(depth, frame), frame.depth_encoding))
    bag.write("ids", log, bag.image(stamp, class_ids, "mono8"))
    steer = float(truth.steer[index])
    bag.write("action", log + RECORDING_DELAY_NS, bag.action(stamp, steer, float(truth.target_speed[index]), command))
    bag.write("limited_by", log, bag.types["std_msgs/msg/String"](data=str(truth.limited_by[index])))
    if truth.network is not None:
        bag.write("network", log, bag.flag(bool(truth.network[index])))
        if truth.network[index]:
            bag.write("asked", log + RECORDING_DELAY_NS,
                      bag.action(stamp, steer, float(truth.asked_speed[index]), command))


def _write_frames(bag: _SyntheticBagWriter, truth: SyntheticTruth, rng: np.random.Generator, frame: _FrameFormat,
                  period_ns: int, with_clock: bool) -> None:
    """Every frame in stamp order: the clock, a command and a noise flag where they change, the frame, and the
    command again half a period later."""
    previous_command, previous_noise = None, None
    for index in range(len(truth.stamps_ns)):
        stamp = int(truth.stamps_ns[index])
        command, noise = int(truth.command[index]), bool(truth.noise[index])
        if with_clock:
            bag.write("clock", stamp, bag.types["rosgraph_msgs/msg/Clock"](clock=bag.header(stamp, "").stamp))
        if command != previous_command:
            bag.write("command", stamp - COMMAND_LEAD_NS, bag.command(stamp - COMMAND_LEAD_NS, command))
        if noise != previous_noise:
            bag.write("noise", stamp, bag.flag(noise))
        previous_command, previous_noise = command, noise
        _write_frame(bag, truth, index, rng, frame)
        bag.write("command", stamp + period_ns // 2, bag.command(stamp + period_ns // 2, command))


def write_synthetic_bag(
    path: Path | str,
    n_frames: int,
    split: str = "train",
    seed: int = 0,
    height: int = 60,
    width: int = 80,
    frame_rate_hz: float = 10.0,
    rgb_encoding: str = "rgb8",
    noise_period_frames: int = 50,
    noise_duration_frames: int = 10,
    with_clock: bool = True,
    topics: BagTopics = BagTopics(),
    start_ns: int = 1_000_000_000,
    depth_encoding: str = "32FC1",
    depth_hole_fraction: float = 0.0,
    on_policy_end: str | None = None,
) -> SyntheticTruth:
    """Write a bag directory at `path` (must not exist) and return the per-frame truth.

    Noise is injected for `noise_duration_frames` of every `noise_period_frames` (paper: 1 s in 5 s).
    Depth is 32FC1 metres or 16UC1 millimetres; `depth_hole_fraction` of each depth frame, one patch at
    the bottom left, reports no return the way real cameras do (NaN in 32FC1, 0 in 16UC1).
    With `on_policy_end` (an END value: "collision", "arrived", ...) the bag is an on-policy one that ended so: the
    network drives every other 10 frames, asking for 3 m/s more than the expert's label (a near miss where the
    expert stops for a car), with the std_msgs/Bool network flag and its DrivingAction on their topics.
    """
    rng = np.random.default_rng(seed)  # draws the trajectory, then each frame's pixel noise
    truth = _trajectory(n_frames, rng, noise_period_frames, noise_duration_frames)
    period_ns = int(round(1e9 / frame_rate_hz))
    truth.stamps_ns[:] = start_ns + np.arange(n_frames, dtype=np.int64) * period_ns
    if on_policy_end is not None:
        network = (np.arange(n_frames) // 10) % 2 == 1
        truth = replace(truth, network=network, asked_speed=(truth.target_speed + 3.0).astype(np.float32))
    metadata = {SPLIT: split, MAP: "synthetic", WEATHER: "0", TRAFFIC: "none", SEED: seed}
    if on_policy_end is not None:
        metadata[END] = on_policy_end
    frame = _FrameFormat(height, width, rgb_encoding, depth_encoding, depth_hole_fraction)
    with mcap_writer(path, metadata) as writer:
        bag = _SyntheticBagWriter(writer, topics, with_clock, on_policy=truth.network is not None)
        _write_frames(bag, truth, rng, frame, period_ns, with_clock)
    return truth
