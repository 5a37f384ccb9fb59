"""rosbag2 bags of the stack, written and read here only (no ROS runtime needed).

One way to write a bag (`mcap_writer`, metadata in custom_data) and one way to read it (`open_bag`) for
replay, training and evaluation. Intact bags (MCAP or sqlite3) are read by rosbags through their indexes. An
MCAP bag whose index is unusable, because the file was cut short (a recorder killed, a full disk), never
finished (no metadata.yaml) or is damaged, is recovered front to back (`bag_recovery`): every complete chunk is
used and a warning says how much was recovered. Anything that is no bag at all raises BagError: one line naming
the file and the reason. The metadata keys, the typestores, `Bag` and `BagError` are defined in `bag_schema`
and importable from here too.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import yaml
from rosbags.interfaces import Connection
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer
from rosbags.typesys.store import Typestore

from msfsu_common.bag_recovery import MAX_CHUNK_BYTES, MCAP_MAGIC, recover
from msfsu_common.bag_schema import (BAG_VERSION, BETA, CAMERA, CRASH_ENDS, DRIVER, DRIVER_DIGEST, END,
                                     EXPERT_DRIVER, EXPERT_LIMITS, IMPORT_REPORT, INTERFACES_PACKAGE, MAP,
                                     METADATA_FILE, METADATA_PREFIX, PARTICIPANT_LIMITS, ROUND, ROUTE_DESTINATION,
                                     ROUTE_JUNCTIONS, ROUTE_LENGTH_M, ROUTE_START, SEED, SIMULATOR_REVISION,
                                     SOURCE_BAG, SOURCE_INFO, SPLIT, SPLITS, TRAFFIC, WEATHER, Bag, BagError,
                                     Recovery, bag_typestore, msfsu_typestore)

__all__ = ["BAG_VERSION", "BETA", "CAMERA", "CRASH_ENDS", "DRIVER", "DRIVER_DIGEST", "END", "EXPERT_DRIVER",
           "EXPERT_LIMITS", "IMPORT_REPORT", "INTERFACES_PACKAGE", "MAP", "MAX_CHUNK_BYTES", "MCAP_MAGIC",
           "METADATA_FILE", "METADATA_PREFIX", "PARTICIPANT_LIMITS", "ROUND", "ROUTE_DESTINATION", "ROUTE_JUNCTIONS",
           "ROUTE_LENGTH_M", "ROUTE_START", "SEED", "SIMULATOR_REVISION", "SOURCE_BAG", "SOURCE_INFO", "SPLIT",
           "SPLITS", "TRAFFIC", "WEATHER", "Bag", "BagError", "Connection", "Recovery", "Typestore", "Writer",
           "bag_typestore", "flush_to_disk", "is_bag", "mcap_writer", "msfsu_typestore", "open_bag",
           "read_bag_information", "read_bag_metadata"]


def mcap_writer(path: Path | str, metadata: Mapping[str, object] | None = None) -> Writer:
    """rosbag2 MCAP writer with `metadata` in custom_data; `with mcap_writer(...) as writer:` opens it.

    MCAP chunks are zstd-compressed (storage-level, as `ros2 bag record --storage-preset-profile
    zstd_fast`): simulator bags shrink several times over and every reader handles it.
    """
    writer = Writer(Path(path), version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    for key, value in (metadata or {}).items():
        writer.set_custom_data(METADATA_PREFIX + key, str(value))
    return writer


def flush_to_disk(writer: Writer) -> None:
    """Close the MCAP chunk being filled and hand the file's bytes to the OS.

    rosbags' MCAP writer keeps messages in memory until a chunk holds 1 MiB, and the file object
    buffers on top: a process killed between two chunks would lose them. After this call every
    message written so far is in complete chunks on disk, which `open_bag` recovers after a SIGKILL
    (not after a power loss: no fsync). Uses rosbags' McapWriter (`close_chunk`, `bio`), pinned in
    requirements.txt and checked by the recorder's kill test.
    """
    storage = writer.storage
    if storage is None:
        raise ValueError("the bag writer is not open")
    if storage.chunk.msgs:
        storage.close_chunk()
    storage.bio.flush()


def read_bag_metadata(path: Path | str) -> dict[str, str]:
    """The stack's metadata of a bag directory ({} for bags recorded elsewhere, e.g. CARLA, or without
    metadata.yaml, e.g. a recording that never finished); BagError if metadata.yaml is unreadable."""
    info = _bag_info(Path(path))
    custom = (info or {}).get("custom_data")
    custom = custom if isinstance(custom, dict) else {}
    return {key[len(METADATA_PREFIX):]: str(value) for key, value in custom.items()
            if isinstance(key, str) and key.startswith(METADATA_PREFIX)}


def read_bag_information(path: Path | str) -> dict:
    """metadata.yaml's rosbag2_bagfile_information of a bag directory ({} without the file); BagError if unreadable."""
    return _bag_info(Path(path)) or {}


def is_bag(path: Path | str) -> bool:
    """A rosbag2 directory: metadata.yaml, or MCAP files of a recording that never wrote it."""
    path = Path(path)
    return path.is_dir() and ((path / METADATA_FILE).is_file() or any(path.glob("*.mcap")))


def _bag_info(path: Path) -> dict | None:
    """metadata.yaml's rosbag2_bagfile_information; None without the file; BagError if unreadable."""
    metadata = path / METADATA_FILE
    if not metadata.is_file():
        return None
    try:
        info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
    except (yaml.YAMLError, UnicodeDecodeError, OSError, TypeError, KeyError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise BagError(f"{metadata}: not rosbag2 metadata ({reason})") from None
    if not isinstance(info, dict):
        raise BagError(f"{metadata}: not rosbag2 metadata (no rosbag2_bagfile_information mapping)")
    return info


class _IndexedBag(Bag):
    """An intact bag (MCAP or sqlite3) through rosbags, which uses the files' indexes."""

    def __init__(self, path: Path, reader: Reader) -> None:
        self.path, self._reader = path, reader
        self.connections = list(reader.connections)
        self.start_time, self.end_time = reader.start_time, reader.end_time
        self.message_count = reader.message_count
        self.recoveries = []

    def messages(self, connections=None, start=None, stop=None):
        connections = None if connections is None else list(connections)
        if connections == []:  # rosbags reads an empty list as "all"; here it means none
            return
        try:
            yield from self._reader.messages(connections=connections or (), start=start, stop=stop)
        except Exception as error:  # noqa: BLE001 - a damaged chunk behind an intact index: rosbags or zstd errors
            reason = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise BagError(f"{self.path}: damaged after {self.path.name}'s index was read ({reason})") from None

    def close(self) -> None:
        self._reader.close()


def open_bag(path: Path | str, warn: Callable[[str], None] | None = None) -> Bag:
    """Open a rosbag2 bag directory (or one .mcap file) for reading; BagError (one line) if it is no bag.

    A damaged or unfinished MCAP bag is recovered (every complete chunk) and `warn` (default: this
    module's logger) hears once per process and file how much was recovered.
    """
    path = Path(path)
    if path.name == METADATA_FILE:
        path = path.parent
    if not path.exists():
        raise BagError(f"{path}: no such bag (no such file or directory)")
    if path.is_file():
        return recover(path, [path], None, {}, warn)
    info = _bag_info(path)
    if info is None:
        files = sorted(path.glob("*.mcap"))
        if not files:
            raise BagError(f"{path}: not a rosbag2 bag (no {METADATA_FILE} and no .mcap file)")
        return recover(path, files, f"no {METADATA_FILE} (the recording did not end cleanly)", {}, warn)
    try:
        reader = Reader(path)
        reader.open()
    except Exception as error:  # noqa: BLE001 - rosbags' ReaderError, or a parser error on damaged bytes
        reason = f"index unreadable: {str(error).splitlines()[0] if str(error) else type(error).__name__}"
    else:
        return _IndexedBag(path, reader)
    names = info.get("relative_file_paths")
    names = [name for name in names if isinstance(name, str)] if isinstance(names, list) else []
    if info.get("storage_identifier") != "mcap" or not names or not all(name.endswith(".mcap") for name in names):
        raise BagError(f"{path}: {reason}")
    missing = [name for name in names if not (path / name).is_file()]
    if missing:
        raise BagError(f"{path / missing[0]}: listed in {METADATA_FILE} but missing")
    return recover(path, [path / name for name in names], reason, _listed_counts(info), warn)


def _listed_counts(info: Mapping) -> dict[str, int]:
    """File name -> message count, as far as metadata.yaml's `files` says (it may be damaged too)."""
    files = info.get("files")
    counts = {}
    for item in files if isinstance(files, list) else []:
        if isinstance(item, dict) and isinstance(item.get("path"), str) and isinstance(item.get("message_count"), int):
            counts[item["path"]] = item["message_count"]
    return counts
