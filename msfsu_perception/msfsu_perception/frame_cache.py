"""The frame cache: the samples of a set of bags, decoded and preprocessed once into memory-mapped arrays.

Layout (one directory per set of bags, named by a hash of the bags' paths, sizes and mtimes,
the topics and the preprocessing): `rgb.npy` (N, 3, h, w) uint8, exactly `preprocess_frame`'s RGB
* 255; `depth.npy` (N, 1, h, w) float16 in [0, 1]; `class_ids.npy` (N, h, w) uint8; `steer.npy`,
`target_speed.npy` (m/s) float32; `command.npy` uint8 RoadOption values; `stamp_ns.npy`; `focus.npy`
(bag_index.FocusConfig); `valid.npy` (False: depth unusable, row left empty); `manifest.json` (counts of
left-out frames). Which frames, and how they are synchronised: bag_index. Readers open the arrays with
mmap_mode="r", so workers share the page cache.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_common.bag_io import msfsu_typestore, open_bag
from msfsu_common.image_codec import decode_depth, decode_mono8, decode_rgb
from msfsu_common.message_types import stamp_ns
from msfsu_perception.bag_index import FocusConfig, index_bag
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


class CacheSpaceError(OSError):
    """The disk under the cache root cannot hold a new cache (checked before writing, not by a bus error mid-way)."""


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
    indexes = [index_bag(bag, spec.topics, set(spec.image_decoders()), spec.focus) for bag in spec.bags]
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
