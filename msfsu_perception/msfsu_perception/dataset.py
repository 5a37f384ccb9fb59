"""Training samples from rosbag2 MCAP bags, decoded and preprocessed once into a memory-mapped cache.

Synchronisation: RGB, depth and class ids of a camera frame share its header stamp exactly, and
the expert DrivingAction for the frame carries that stamp too. The navigation command is the
latest NavigationCommand whose header stamp is at or before the frame's. The noise flag
(std_msgs/Bool, no header) is the latest one logged at or before the frame's RGB message. Frames
missing an image or the action, frames before the first command, frames with unusable depth and
noise-injected frames (paper III-A) are left out and counted.

Cache layout (one directory per set of bags, named by a hash of the bags' paths, sizes and mtimes,
the topics and the preprocessing): `rgb.npy` (N, 3, h, w) uint8, exactly `preprocess_frame`'s RGB
* 255; `depth.npy` (N, 1, h, w) float16 in [0, 1]; `class_ids.npy` (N, h, w) uint8; `steer.npy`,
`target_speed.npy` (m/s) float32; `command.npy` uint8 RoadOption values; `stamp_ns.npy`;
`valid.npy` (False: depth unusable, row left empty); `manifest.json` (counts of left-out frames).
Readers open the arrays with mmap_mode="r", so workers share the page cache.
"""

from __future__ import annotations

import bisect
import glob
import hashlib
import json
import shutil
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch.utils.data import Dataset

from msfsu_common.bag_io import (CRASH_ENDS, END, PARTICIPANT_LIMITS, SPLIT, SPLITS, BagError, is_bag,
                                  msfsu_typestore, open_bag, read_bag_metadata)
from msfsu_common.image_codec import decode_depth, decode_mono8, decode_rgb
from msfsu_common.message_types import stamp_ns
from msfsu_common.road_option import RoadOption, branch_indices
from msfsu_perception.augmentation import AugmentationConfig, augment_rgb
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.preprocessing import (
    MAX_INVALID_DEPTH_FRACTION,
    InvalidDepthError,
    PreprocessConfig,
    preprocess_frame,
    preprocess_labels,
    sanitize_depth,
)

CACHE_VERSION = 2  # 2: focus.npy
CACHE_SPACE_MARGIN_BYTES = 512 * 2**20  # left free beside a new cache: the scalars, the manifest, everybody else
LAST_USED_FILE = "last_used"  # touched at every open_cache: which caches --evict-caches deletes first
_KNOWN_COMMANDS = frozenset(option.value for option in RoadOption)


class CacheSpaceError(OSError):
    """The disk under the cache root cannot hold a new cache (checked before writing, not by a bus error mid-way)."""


def expand_bag_paths(patterns: Iterable[str]) -> list[Path]:
    """Bag directories (metadata.yaml, or the MCAP files of an unfinished recording) named by paths or
    glob patterns, sorted; BagError names the first path that is no bag."""
    bags: set[Path] = set()
    for pattern in patterns:
        matches = [Path(match) for match in glob.glob(pattern)] or [Path(pattern)]
        for match in matches:
            if not is_bag(match):
                raise BagError(f"{match}: not a rosbag2 bag directory (no metadata.yaml and no .mcap file)")
            bags.add(match.resolve())
    return sorted(bags)


def split_bags(bags: Iterable[Path]) -> dict[str, list[Path]]:
    """Group bags by their `split` metadata (train / validation / test)."""
    groups: dict[str, list[Path]] = {split: [] for split in SPLITS}
    for bag in bags:
        split = read_bag_metadata(bag).get(SPLIT)
        if split not in groups:
            raise ValueError(f"bag {bag} has split {split!r}, expected one of {SPLITS}")
        groups[split].append(bag)
    return groups


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


def index_bag(bag: Path, spec: CacheSpec) -> BagIndex:
    """First pass: synchronise the small messages and image stamps, without decoding pixels."""
    store, topics = msfsu_typestore(), spec.topics
    image_topics = set(spec.image_decoders())
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
            raise ValueError(f"bag {bag} lacks topics {sorted(missing)}")
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
                and asked[stamp] >= expert_speed + spec.focus.near_miss_mps
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
        focus |= stamps > stamps[-1] - round(spec.focus.crash_window_s * 1e9)
    return BagIndex(
        stamps_ns=stamps,
        steer=np.array(columns[1], np.float32),
        target_speed=np.array(columns[2], np.float32),
        command=np.array(columns[3], np.uint8),
        focus=focus,
        dropped=dropped,
    )


@dataclass(frozen=True)
class CacheSpec:
    """Everything the cached arrays depend on."""

    bags: tuple[Path, ...]
    topics: BagTopics
    preprocess: PreprocessConfig
    with_labels: bool
    max_invalid_depth_fraction: float = MAX_INVALID_DEPTH_FRACTION
    focus: FocusConfig = FocusConfig()

    def image_decoders(self) -> dict[str, Callable[[Any], np.ndarray]]:
        """Image topics a sample needs, with their decoders."""
        decoders = {self.topics.rgb: decode_rgb}
        if self.preprocess.use_depth:
            decoders[self.topics.depth] = decode_depth
        if self.with_labels:
            decoders[self.topics.semantic_ids] = decode_mono8
        return decoders

    def key(self) -> str:
        files = [
            (str(path), path.stat().st_size, path.stat().st_mtime_ns)
            for bag in self.bags
            for path in sorted(bag.iterdir())
            if path.is_file()
        ]
        description = {
            "version": CACHE_VERSION,
            "files": files,
            "topics": asdict(self.topics),
            "preprocess": asdict(self.preprocess),
            "with_labels": self.with_labels,
            "max_invalid_depth_fraction": self.max_invalid_depth_fraction,
            "focus": asdict(self.focus),
        }
        return hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()[:16]


class FrameCache:
    """Read-only memory-mapped arrays of one cache directory."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.manifest: dict[str, Any] = json.loads((directory / "manifest.json").read_text())
        self.preprocess = PreprocessConfig(**self.manifest["preprocess"])

        def load(name: str) -> np.ndarray | None:
            path = directory / f"{name}.npy"
            return np.load(path, mmap_mode="r") if path.is_file() else None

        self.rgb = load("rgb")
        self.depth = load("depth")
        self.class_ids = load("class_ids")
        self.steer = np.load(directory / "steer.npy")
        self.target_speed = np.load(directory / "target_speed.npy")
        self.command = np.load(directory / "command.npy")
        self.stamp_ns = np.load(directory / "stamp_ns.npy")
        self.focus = np.load(directory / "focus.npy")  # FocusConfig
        self.valid_rows = np.flatnonzero(np.load(directory / "valid.npy"))  # rows with usable depth

    def __len__(self) -> int:
        return len(self.steer)

    def __reduce__(self) -> tuple[type[FrameCache], tuple[Path]]:
        """DataLoader workers re-map the files instead of receiving pickled copies of the arrays."""
        return FrameCache, (self.directory,)


def _fill_images(bag: Path, spec: CacheSpec, rows: dict[int, int], arrays: dict[str, np.ndarray]) -> set[int]:
    """Second pass: decode and preprocess the indexed frames into their rows; returns invalid-depth rows."""
    store = msfsu_typestore()
    topics, preprocess = spec.topics, spec.preprocess
    decoders = spec.image_decoders()
    pending: dict[int, dict[str, np.ndarray]] = {}
    invalid: set[int] = set()
    frame = np.empty((preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32)
    with open_bag(bag) as reader:
        connections = [c for c in reader.connections if c.topic in decoders]
        for connection, _, raw in reader.messages(connections):
            msg = store.deserialize_cdr(raw, connection.msgtype)
            row = rows.get(stamp_ns(msg.header))
            if row is None:
                continue
            parts = pending.setdefault(row, {})
            parts[connection.topic] = decoders[connection.topic](msg)
            if len(parts) < len(decoders):
                continue
            del pending[row]
            try:
                depth = parts.get(topics.depth)
                depth = None if depth is None else sanitize_depth(depth, spec.max_invalid_depth_fraction)[0]
            except InvalidDepthError:
                invalid.add(row)
                continue
            preprocess_frame(parts[topics.rgb], depth, preprocess, out=frame)
            arrays["rgb"][row] = np.rint(frame[:3] * 255.0).astype(np.uint8)
            if preprocess.use_depth:
                arrays["depth"][row] = frame[3:].astype(np.float16)
            if spec.with_labels:
                arrays["class_ids"][row] = preprocess_labels(parts[topics.semantic_ids], preprocess)
    return invalid


def _directory_bytes(directory: Path) -> int:
    return sum(path.stat().st_size for path in directory.rglob("*") if path.is_file())


def complete_caches(cache_root: Path) -> list[Path]:
    """The finished caches under `cache_root`, least recently used first (LAST_USED_FILE, else the manifest)."""
    def last_used(directory: Path) -> float:
        stamp = directory / LAST_USED_FILE
        return (stamp if stamp.is_file() else directory / "manifest.json").stat().st_mtime

    found = [d for d in cache_root.iterdir() if not d.name.startswith(".") and (d / "manifest.json").is_file()]
    return sorted(found, key=lambda d: (last_used(d), d.name))


def _make_room(cache_root: Path, needed: int, evict: bool) -> list[tuple[Path, int]]:
    """Free space for `needed` bytes plus the margin; with `evict`, by deleting the least recently used caches (derived
    from bags: rebuilt when asked for again). Returns what was deleted (path, bytes); CacheSpaceError if it still
    does not fit (nothing of the new cache is written then)."""
    evicted: list[tuple[Path, int]] = []
    candidates = complete_caches(cache_root) if evict else []
    while needed + CACHE_SPACE_MARGIN_BYTES > (free := shutil.disk_usage(cache_root).free):
        if not candidates:
            raise CacheSpaceError(
                f"needs {needed / 1e9:.1f} GB under {cache_root}, {free / 1e9:.1f} GB free"
                + (f" after deleting {len(evicted)} older caches" if evicted else "")
                + ": free space there (old caches are safe to delete"
                + ("" if evict else "; msfsu-train --evict-caches does it") + ") or pick another --cache-dir"
            )
        oldest = candidates.pop(0)
        size = _directory_bytes(oldest)
        shutil.rmtree(oldest)
        evicted.append((oldest, size))
    return evicted


def _write_cache(spec: CacheSpec, directory: Path, evict: bool = False) -> list[tuple[Path, int]]:
    """Write the cache into `directory` (a temporary sibling of the finished caches); returns the caches evicted."""
    indexes = [index_bag(bag, spec) for bag in spec.bags]
    count = sum(len(index.stamps_ns) for index in indexes)
    height, width = spec.preprocess.input_height, spec.preprocess.input_width
    shapes = {"rgb": ((count, 3, height, width), np.uint8)}
    if spec.preprocess.use_depth:
        shapes["depth"] = ((count, 1, height, width), np.float16)
    if spec.with_labels:
        shapes["class_ids"] = ((count, height, width), np.uint8)
    needed = sum(int(np.prod(shape)) * np.dtype(dtype).itemsize for shape, dtype in shapes.values())
    try:
        evicted = _make_room(directory.parent, needed, evict)
    except CacheSpaceError as error:
        raise CacheSpaceError(f"a frame cache of {count} frames at {height}x{width} {error}") from None
    arrays = {
        name: np.lib.format.open_memmap(directory / f"{name}.npy", "w+", dtype, shape)
        for name, (shape, dtype) in shapes.items()
    }
    invalid_rows: set[int] = set()
    first_row = 0
    for bag, index in zip(spec.bags, indexes):
        rows = {int(stamp): first_row + offset for offset, stamp in enumerate(index.stamps_ns)}
        invalid_rows |= _fill_images(bag, spec, rows, arrays)
        index.dropped["invalid_depth"] = len(invalid_rows & set(rows.values()))
        first_row += len(rows)
    for array in arrays.values():
        array.flush()
    scalars = {
        "steer": np.concatenate([index.steer for index in indexes]),
        "target_speed": np.concatenate([index.target_speed for index in indexes]),
        "command": np.concatenate([index.command for index in indexes]),
        "stamp_ns": np.concatenate([index.stamps_ns for index in indexes]),
        "focus": np.concatenate([index.focus for index in indexes]),
    }
    scalars["valid"] = np.ones(count, bool)
    scalars["valid"][list(invalid_rows)] = False
    for name, values in scalars.items():
        np.save(directory / f"{name}.npy", values)
    manifest = {
        "version": CACHE_VERSION,
        "count": count,
        "preprocess": asdict(spec.preprocess),
        "topics": asdict(spec.topics),
        "bags": [
            {"path": str(bag), "frames": len(index.stamps_ns), "focus": int(index.focus.sum()), "dropped": index.dropped}
            for bag, index in zip(spec.bags, indexes)
        ],
    }
    (directory / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return evicted


def open_cache(spec: CacheSpec, cache_root: Path, evict: bool = False,
               log: Callable[[str], None] | None = None) -> FrameCache:
    """The cache for `spec`, built on first use (into a temp dir, renamed when complete). `evict`: where the disk
    cannot hold a new cache, the least recently used caches under `cache_root` are deleted first, each one `log`ged
    (a process that still maps one keeps reading it: the kernel frees the files when it unmaps them)."""
    directory = cache_root / spec.key()
    if not (directory / "manifest.json").is_file():
        temporary = cache_root / f".{directory.name}.partial"
        shutil.rmtree(temporary, ignore_errors=True)
        temporary.mkdir(parents=True)
        try:
            evicted = _write_cache(spec, temporary, evict)
        except BaseException:  # a half-written cache is never kept: it would only hold the disk
            shutil.rmtree(temporary, ignore_errors=True)
            raise
        shutil.rmtree(directory, ignore_errors=True)
        temporary.rename(directory)
        for path, size in evicted:
            (log or print)(f"deleted the least recently used frame cache {path} ({size / 1e9:.1f} GB) to make room")
    try:
        (directory / LAST_USED_FILE).touch()
    except OSError:  # a cache on a read-only disk is used all the same, only never ranked for eviction
        pass
    return FrameCache(directory)


class Sample(NamedTuple):
    """A batch as the network takes it (on the training device)."""

    inputs: torch.Tensor  # (B, C, h, w) float32 in [0, 1], R, G, B(, depth)
    command_index: torch.Tensor  # (B,) long, RoadOption.branch_index
    steer: torch.Tensor  # (B,) float32, normalised [-1, 1]
    speed: torch.Tensor  # (B,) float32, target speed / speed_scale
    class_ids: torch.Tensor  # (B, h, w) long; (B, 0) when the cache has no labels


class StoredSample(NamedTuple):
    """One sample as the cache stores it: what loader workers hand over and the host copies to the device (a
    quarter of the bytes of float32 inputs and int64 labels); `to_device` makes a `Sample` of a batch of them."""

    rgb: torch.Tensor  # (3, h, w) uint8: preprocess_frame's RGB * 255 (augmented for training)
    depth: torch.Tensor  # (1, h, w) float16 in [0, 1]; (0,) without depth
    command_index: torch.Tensor  # () long, RoadOption.branch_index
    steer: torch.Tensor  # () float32
    speed: torch.Tensor  # () float32, target speed / speed_scale
    class_ids: torch.Tensor  # (h, w) uint8; (0,) without labels


def to_device(batch: StoredSample, device: torch.device | str,
              memory_format: torch.memory_format = torch.contiguous_format) -> Sample:
    """A collated batch of StoredSamples on `device` as the network's inputs (the conversion runs there, on the GPU
    for a CUDA device). RGB / 255 in float32 exactly as `preprocess_frame` computes it; depth and labels widened."""
    rgb = batch.rgb.to(device, non_blocking=True).float().mul_(1.0 / 255.0)
    depth = batch.depth.to(device, non_blocking=True)
    inputs = torch.cat([rgb, depth.float()], dim=1) if depth.dim() == 4 else rgb
    return Sample(
        inputs=inputs.contiguous(memory_format=memory_format),
        command_index=batch.command_index.to(device, non_blocking=True),
        steer=batch.steer.to(device, non_blocking=True),
        speed=batch.speed.to(device, non_blocking=True),
        class_ids=batch.class_ids.to(device, non_blocking=True).long(),
    )


class DrivingDataset(Dataset[StoredSample]):
    """Samples `rows` of a FrameCache (rows may repeat: balancing duplicates by listing a row twice).

    Augmentation is drawn from a generator seeded by (seed, epoch, position): reproducible,
    independent of the worker that loads it, and resumable. Call `set_epoch` every epoch.
    """

    def __init__(
        self,
        cache: FrameCache,
        rows: Sequence[int] | np.ndarray,
        speed_scale: float,
        augmentation: AugmentationConfig | None = None,
        seed: int = 0,
    ) -> None:
        self.cache = cache
        self.rows = np.asarray(rows, np.int64)
        self.speed_scale = speed_scale
        self.augmentation = augmentation
        self.seed = seed
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, position: int) -> StoredSample:
        cache, row = self.cache, int(self.rows[position])
        rgb = np.array(cache.rgb[row])  # a writable copy of the memory-mapped row
        if self.augmentation is not None:
            rng = np.random.default_rng([self.seed, self.epoch, position])
            rgb = augment_rgb(rgb, rng, self.augmentation).image
        empty = torch.empty(0, dtype=torch.uint8)
        return StoredSample(
            rgb=torch.from_numpy(rgb),
            depth=empty.half() if cache.depth is None else torch.from_numpy(np.array(cache.depth[row])),
            command_index=torch.tensor(branch_indices(cache.command[row])),
            steer=torch.tensor(cache.steer[row]),
            speed=torch.tensor(cache.target_speed[row] / self.speed_scale),
            class_ids=empty if cache.class_ids is None else torch.from_numpy(np.array(cache.class_ids[row])),
        )
