"""Which bags a run reads: bag directories named by paths or glob patterns, grouped by their `split` metadata."""

from __future__ import annotations

import glob
from collections.abc import Iterable
from pathlib import Path

from msfsu_common.bag_io import SPLIT, SPLITS, BagError, is_bag, read_bag_metadata


def expand_bag_paths(patterns: Iterable[str]) -> list[Path]:
    """Bag directories (metadata.yaml, or the MCAP files of an unfinished recording) named by paths or
    glob patterns, sorted; BagError names the first path that is no bag, or a pattern that matches nothing."""
    bags: set[Path] = set()
    for pattern in patterns:
        matches = [Path(match) for match in glob.glob(pattern)] or [Path(pattern)]
        if glob.has_magic(pattern) and not Path(pattern).exists() and matches == [Path(pattern)]:
            raise BagError(f"no path matches {pattern!r} (quote a pattern so the shell leaves it to the tool)")
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
