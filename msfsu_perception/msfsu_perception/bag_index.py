"""The frames of one rosbag2 MCAP bag that make training samples, found without decoding a pixel.

Synchronisation: RGB, depth and class ids of a camera frame share its header stamp exactly, and
the expert DrivingAction for the frame carries that stamp too. The navigation command is the
latest NavigationCommand whose header stamp is at or before the frame's. The noise flag
(std_msgs/Bool, no header) is the latest one logged at or before the frame's RGB message. Frames
missing an image or the action, frames before the first command, frames with unusable depth and
noise-injected frames (paper III-A) are left out and counted (unusable depth by the frame cache, which decodes).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_common.bag_io import (CRASH_ENDS, END, PARTICIPANT_LIMITS, BagError, msfsu_typestore, open_bag,
                                  read_bag_metadata)
from msfsu_common.message_types import stamp_ns
from msfsu_common.road_option import RoadOption
from msfsu_perception.bag_topics import BagTopics

_KNOWN_COMMANDS = frozenset(option.value for option in RoadOption)


@dataclass
class BagIndex:
    """Frames of one bag that make samples, in stamp order, and why the others were left out."""

    stamps_ns: np.ndarray
    steer: np.ndarray
    target_speed: np.ndarray
    command: np.ndarray
    focus: np.ndarray  # (N,) bool, FocusConfig
    dropped: dict[str, int]


@dataclass(frozen=True)
class FocusConfig:
    """Frames of on-policy bags where the network failed or nearly did (`msfsu-train --focus-copies` repeats them).

    - crash approach: the last `crash_window_s` of a bag whose episode ended in a crash (bag_io.END; msfsu-collect
      has already cut the last second, from which the crash could no longer be avoided);
    - near miss: a frame the network drove, asking for at least `near_miss_mps` more than the expert's target speed
      while the expert was held by a vehicle or a pedestrian (`topics.EXPERT_LIMITED_BY`).
    Bags without these topics or metadata (expert data, older bags) have no focus frames.
    """

    crash_window_s: float = 3.0
    near_miss_mps: float = 2.0


def _latest_at_or_before(times: list[int], values: list[Any], time: int) -> Any:
    position = bisect.bisect_right(times, time)
    return values[position - 1] if position else None


def _sorted_pairs(pairs: list[tuple[int, Any]]) -> tuple[list[int], list[Any]]:
    pairs.sort(key=lambda pair: pair[0])
    return [time for time, _ in pairs], [value for _, value in pairs]


def missing_topics_message(bag: Path, missing: set[str], topics: BagTopics, present: set[str]) -> str:
    """One line: what a bag lacks of what samples need, what it holds, and what to do without class ids."""
    message = f"bag {bag} lacks topics {sorted(missing)} (topics: {', '.join(sorted(present)) or 'none'})"
    if topics.semantic_ids in missing:
        message += ("; the msfsu and su variants learn segmentation from its class ids: train --variant msf, which "
                    "needs none, or record (import) the bag with its semantic camera")
    return message


def index_bag(bag: Path, topics: BagTopics, image_topics: set[str], focus_config: FocusConfig) -> BagIndex:
    """Synchronise the small messages with the stamps of `image_topics` (each a sample needs), without decoding
    pixels; `focus_config` says which are focus frames."""
    store = msfsu_typestore()
    wanted = image_topics | {topics.expert_action, topics.navigation_command, topics.noise_injection,
                             topics.network_driving, topics.network_action, topics.expert_limited_by}
    image_stamps: dict[str, set[int]] = {topic: set() for topic in image_topics}
    rgb_log_ns: dict[int, int] = {}
    actions: dict[int, tuple[float, float]] = {}
    commands: list[tuple[int, int]] = []
    noise: list[tuple[int, bool]] = []
    network: list[tuple[int, bool]] = []  # (log time, the network drove)
    asked: dict[int, float] = {}  # stamp -> target speed the network asked for
    held_by: list[tuple[int, str]] = []  # (log time, what held the expert)
    with open_bag(bag) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        required = image_topics | {topics.expert_action, topics.navigation_command}
        missing = required - {c.topic for c in connections}
        if missing:
            raise BagError(missing_topics_message(bag, missing, topics, {c.topic for c in reader.connections}))
        for connection, log_ns, raw in reader.messages(connections):
            msg = store.deserialize_cdr(raw, connection.msgtype)
            if connection.topic in image_topics:
                stamp = stamp_ns(msg.header)
                image_stamps[connection.topic].add(stamp)
                if connection.topic == topics.rgb:
                    rgb_log_ns[stamp] = log_ns
            elif connection.topic == topics.expert_action:
                actions[stamp_ns(msg.header)] = (float(msg.steer), float(msg.target_speed))
            elif connection.topic == topics.navigation_command:
                commands.append((stamp_ns(msg.header), int(msg.command)))
            elif connection.topic == topics.noise_injection:
                noise.append((log_ns, bool(msg.data)))
            elif connection.topic == topics.network_driving:
                network.append((log_ns, bool(msg.data)))
            elif connection.topic == topics.network_action:
                asked[stamp_ns(msg.header)] = float(msg.target_speed)
            else:
                held_by.append((log_ns, str(msg.data)))
    command_times, command_values = _sorted_pairs(commands)
    noise_times, noise_values = _sorted_pairs(noise)
    network_times, network_values = _sorted_pairs(network)
    held_times, held_values = _sorted_pairs(held_by)

    def near_miss(stamp: int, expert_speed: float) -> bool:
        log_ns = rgb_log_ns[stamp]
        return (bool(_latest_at_or_before(network_times, network_values, log_ns)) and stamp in asked
                and asked[stamp] >= expert_speed + focus_config.near_miss_mps
                and _latest_at_or_before(held_times, held_values, log_ns) in PARTICIPANT_LIMITS)
    complete = set.intersection(*image_stamps.values())
    incomplete = len(set.union(*image_stamps.values()) - complete)
    dropped = {"incomplete": incomplete, "no_action": 0, "no_command": 0, "unknown_command": 0, "noise": 0}
    kept: list[tuple[int, float, float, int]] = []
    for stamp in sorted(complete):
        command = _latest_at_or_before(command_times, command_values, stamp)
        if stamp not in actions:
            dropped["no_action"] += 1
        elif command is None:
            dropped["no_command"] += 1
        elif command not in _KNOWN_COMMANDS:
            dropped["unknown_command"] += 1
        elif _latest_at_or_before(noise_times, noise_values, rgb_log_ns[stamp]):
            dropped["noise"] += 1
        else:
            kept.append((stamp, *actions[stamp], command, near_miss(stamp, actions[stamp][1])))
    columns = list(zip(*kept)) if kept else [(), (), (), (), ()]
    stamps = np.array(columns[0], np.int64)
    focus = np.array(columns[4], bool)
    if len(stamps) and read_bag_metadata(bag).get(END) in CRASH_ENDS:
        focus |= stamps > stamps[-1] - round(focus_config.crash_window_s * 1e9)
    return BagIndex(
        stamps_ns=stamps,
        steer=np.array(columns[1], np.float32),
        target_speed=np.array(columns[2], np.float32),
        command=np.array(columns[3], np.uint8),
        focus=focus,
        dropped=dropped,
    )
