"""The bag's ground truth per camera frame, read the way training reads it.

Reuses msfsu_perception's bag cache: the same synchronisation (images and expert action share the
frame stamp, latest navigation command at or before it), the same left-out rules (incomplete
frames, noise injection, unusable depth) and `preprocess_labels` at the network's input size,
which is the resolution the perception node publishes its segmentation at.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_common.bag_io import open_bag
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.frame_cache import CacheSpec, FrameCache, open_cache
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_sim.carla.recording import CARLA_MSGS


@dataclass(frozen=True)
class GroundTruth:
    """Frames with usable ground truth, in stamp order; images stay memory-mapped in the cache."""

    stamps_ns: np.ndarray  # (N,) int64 camera frame stamps
    steer: np.ndarray  # (N,) float32 expert steer
    target_speed: np.ndarray  # (N,) float32 expert target speed, m/s
    command: np.ndarray  # (N,) uint8 RoadOption values
    has_labels: bool  # the bag has semantic class ids
    camera_frames: int  # RGB messages in the bag
    left_out: dict[str, int]  # frames without usable ground truth, by reason
    cache: FrameCache
    rows: np.ndarray  # (N,) cache rows of the frames

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def class_ids(self, index: int) -> np.ndarray:
        """(h, w) uint8 true class ids of frame `index` at the network input size."""
        if self.cache.class_ids is None:
            raise ValueError("the bag has no semantic class ids")
        return np.asarray(self.cache.class_ids[self.rows[index]])

    def model_rgb(self, index: int) -> np.ndarray:
        """(h, w, 3) uint8: the RGB of frame `index` as the network sees it."""
        return np.asarray(self.cache.rgb[self.rows[index]]).transpose(1, 2, 0)


def topic_message_counts(bag: Path) -> dict[str, int]:
    with open_bag(bag) as reader:
        counts: dict[str, int] = {}
        for connection in reader.connections:
            counts[connection.topic] = counts.get(connection.topic, 0) + connection.msgcount
    return counts


def bridge_recording_topics(bag: Path) -> list[str]:
    """The topics of `bag` whose type is one of carla-ros-bridge's own (carla_msgs), sorted: a bridge recording has
    some (the ego vehicle's control and status, the world info), a bag of the stack's topics none."""
    with open_bag(bag) as reader:
        return sorted({c.topic for c in reader.connections if c.msgtype.startswith(f"{CARLA_MSGS}/")})


def load_ground_truth(bag: Path, topics: BagTopics, preprocess: PreprocessConfig, cache_dir: Path) -> GroundTruth:
    """Decode (or reuse the cached) ground truth of `bag`; ValueError names missing topics or empty results."""
    counts = topic_message_counts(bag)
    required = {"rgb": topics.rgb, "expert action": topics.expert_action,
                "navigation command": topics.navigation_command}
    if preprocess.use_depth:
        required["depth"] = topics.depth
    missing = [f"{role} {topic}" for role, topic in required.items() if topic not in counts]
    if missing:
        bridge = bridge_recording_topics(bag)
        if bridge:
            raise ValueError(f"bag {bag} is a carla-ros-bridge recording ({CARLA_MSGS} on {', '.join(bridge)}), "
                             f"without the stack's ground truth ({', '.join(missing)}): import it first, "
                             f"`msfsu-import-carla {bag} --out DIR --split test`, then evaluate DIR (docs/carla.md)")
        raise ValueError(f"bag {bag} lacks {', '.join(missing)} (topics: {', '.join(sorted(counts))}); "
                         "remap the inputs or name the ground-truth topics")
    with_labels = topics.semantic_ids in counts
    cache = open_cache(CacheSpec(bags=(bag.resolve(),), topics=topics, preprocess=preprocess, with_labels=with_labels),
                       cache_dir)
    left_out = dict(cache.manifest["bags"][0]["dropped"])
    rows = cache.valid_rows
    if len(rows) == 0:
        raise ValueError(f"bag {bag} has no frame with usable ground truth (left out: {left_out})")
    return GroundTruth(
        stamps_ns=cache.stamp_ns[rows],
        steer=cache.steer[rows],
        target_speed=cache.target_speed[rows],
        command=cache.command[rows],
        has_labels=with_labels,
        camera_frames=counts[topics.rgb],
        left_out=left_out,
        cache=cache,
        rows=rows,
    )
