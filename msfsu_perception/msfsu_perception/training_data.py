"""A run's data: its training and validation bags, their frame caches (rank 0 builds them), the training rows
balanced, and the loaders, whose training order a resumed epoch takes up at the batch where it stopped."""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterator
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, DistributedSampler, Sampler, Subset

from msfsu_common.road_option import RoadOption
from msfsu_perception.augmentation import AugmentationConfig
from msfsu_perception.bag_paths import expand_bag_paths, split_bags
from msfsu_perception.balancing import BalancingConfig, balance_lane_follow, repeat_focus
from msfsu_perception.dataset import DrivingDataset
from msfsu_perception.distributed import DistributedContext, barrier
from msfsu_perception.frame_cache import CacheSpec, FrameCache, open_cache
from msfsu_perception.preprocessing import PreprocessConfig


@dataclass(frozen=True)
class Split:
    """Rows of a frame cache that one split of a run uses."""

    cache: FrameCache
    rows: np.ndarray  # cache rows used (balanced training rows repeat)


VAL_BLOCK_S = 10.0  # --val-fraction holds out whole blocks of about this length (neighbouring frames look alike)


def select_bags(args: argparse.Namespace) -> tuple[list[Path], list[Path]]:
    """Training and validation bags: --train-bags / --val-bags where given, else --bags by their split metadata.
    With --val-fraction there are no validation bags: the validation frames are held out of the training bags."""
    by_metadata = split_bags(expand_bag_paths(args.bags)) if args.bags else {"train": [], "validation": []}
    train = expand_bag_paths(args.train_bags) if args.train_bags else by_metadata["train"]
    validation = expand_bag_paths(args.val_bags) if args.val_bags else by_metadata["validation"]
    if not train:
        raise SystemExit(f"msfsu-train: no training bag (split 'train' of --bags, or --train-bags); found "
                         f"{len(validation)} validation bags")
    if args.val_fraction is not None and validation:
        raise SystemExit(f"msfsu-train: --val-fraction holds validation frames out of the training bags, but there "
                         f"are {len(validation)} validation bags too: give one or the other")
    if args.val_fraction is None and not validation:
        raise SystemExit(f"msfsu-train: need validation bags, found {len(train)} training and 0 validation bags: "
                         "import or collect one with split 'validation' (or name it with --val-bags), or hold out a "
                         "share of the training bags' frames, e.g. --val-fraction 0.2")
    return train, validation


def open_split(bags: list[Path], preprocess: PreprocessConfig, with_labels: bool, args: argparse.Namespace,
               context: DistributedContext) -> Split:
    """Every usable row of the bags' cache; rank 0 builds the cache while the others wait, then everyone maps it."""
    spec = CacheSpec(tuple(bags), args.topics, preprocess, with_labels)
    if context.is_main:
        open_cache(spec, args.cache_dir, args.evict_caches, log=lambda line: print(f"msfsu-train: {line}", flush=True))
    barrier(context)
    cache = open_cache(spec, args.cache_dir)
    return Split(cache, cache.valid_rows)


def at_most(split: Split, max_samples: int | None) -> Split:
    """The split's first `max_samples` rows (--max-samples; None: all)."""
    return Split(split.cache, split.rows[:max_samples])


def validation_blocks(stamps_ns: np.ndarray, bag_of_row: np.ndarray, fraction: float,
                      block_s: float = VAL_BLOCK_S) -> np.ndarray:
    """(N,) bool: the rows held out for validation. Each bag's time span is cut into equal blocks, about `block_s`
    long and at least 1 / `fraction` of them; block b is held out where floor((b + 1) * fraction) > floor(b *
    fraction), so about `fraction` of the blocks are, spread evenly over the bag (its last block always)."""
    held_out = np.zeros(len(stamps_ns), bool)
    for bag in np.unique(bag_of_row):
        rows = np.flatnonzero(bag_of_row == bag)
        stamps = stamps_ns[rows].astype(np.float64)
        start, span = stamps.min(), stamps.max() - stamps.min()
        blocks = max(math.ceil(span * 1e-9 / block_s), math.ceil(1 / fraction))
        position = (stamps - start) / span if span > 0 else np.zeros(len(rows))  # 0 to 1 through the bag
        block = np.minimum(position * blocks, blocks - 1).astype(int)
        held_out[rows] = np.floor((block + 1) * fraction) > np.floor(block * fraction)
    return held_out


def hold_out(split: Split, fraction: float) -> tuple[Split, Split]:
    """(training, validation) rows of one cache: `validation_blocks` of each of its bags held out."""
    cache = split.cache
    bag_of_row = np.repeat(np.arange(len(cache.manifest["bags"])), [bag["frames"] for bag in cache.manifest["bags"]])
    held_out = validation_blocks(cache.stamp_ns, bag_of_row, fraction)[split.rows]
    train, validation = split.rows[~held_out], split.rows[held_out]
    if not len(train) or not len(validation):
        raise SystemExit(f"msfsu-train: --val-fraction {fraction} leaves {len(train)} training and {len(validation)} "
                         f"validation frames of {len(split.rows)}: record longer bags or give a validation bag")
    return Split(cache, train), Split(cache, validation)


def balance(split: Split, seed: int, focus_copies: int = 0) -> Split:
    """The rows that balancing keeps (lane following thinned, paper Fig. 3), each focus frame `focus_copies` more
    times."""
    cache, rows = split.cache, split.rows
    chosen = balance_lane_follow(
        cache.steer[rows], cache.target_speed[rows], cache.command[rows], np.random.default_rng(seed), BalancingConfig()
    )
    return Split(cache, repeat_focus(rows[chosen], cache.focus, focus_copies))


def lane_follow_distribution(split: Split) -> tuple[np.ndarray, np.ndarray]:
    """Steer (degrees) and target speed (m/s) of the split's lane-following rows."""
    rows = split.rows[split.cache.command[split.rows] == RoadOption.LANE_FOLLOW]
    return split.cache.steer[rows] * BalancingConfig().steer_to_degrees, split.cache.target_speed[rows]


class ResumableSampler(Sampler[int]):
    """A sampler's order from position `skip` on: an epoch resumed after k batches draws the indices an unbroken
    run would have drawn from batch k on (the order depends on the seed and epoch alone)."""

    def __init__(self, sampler: DistributedSampler) -> None:
        self.sampler = sampler
        self.skip = 0

    def set_epoch(self, epoch: int) -> None:
        self.sampler.set_epoch(epoch)

    def __iter__(self) -> Iterator[int]:
        return islice(iter(self.sampler), self.skip, None)

    def __len__(self) -> int:
        return max(0, len(self.sampler) - self.skip)

@dataclass(frozen=True)
class Loaders:
    """The training loader (shuffled per epoch, sharded over the processes, resumable inside an epoch) and the
    validation loader (each process its exact share of the frames, no padding)."""

    train_set: DrivingDataset
    sampler: DistributedSampler
    resumable: ResumableSampler
    batch_size: int
    train: DataLoader
    validation: DataLoader

    @classmethod
    def of(cls, balanced: Split, validation: Split, args: argparse.Namespace, context: DistributedContext) -> Loaders:
        """Loaders of --batch-size batches from --workers processes; training samples augmented."""
        train_set = DrivingDataset(balanced.cache, balanced.rows, args.speed_scale, AugmentationConfig(), args.seed)
        val_set = DrivingDataset(validation.cache, validation.rows, args.speed_scale)
        sampler = DistributedSampler(train_set, context.world_size, context.rank, shuffle=True, seed=args.seed,
                                     drop_last=True)
        resumable = ResumableSampler(sampler)
        batch_size = args.batch_size
        train_loader = _loader(train_set, batch_size, resumable, args.workers, len(sampler) > batch_size,
                               context.device)
        val_shard = Subset(val_set, range(context.rank, len(val_set), context.world_size))  # exact, no padding
        val_loader = _loader(val_shard, batch_size, None, args.workers, False, context.device)
        return cls(train_set, sampler, resumable, batch_size, train_loader, val_loader)

    @property
    def epoch_batches(self) -> int:
        """Training batches an epoch has on this process."""
        return len(self.sampler) // self.batch_size

    def start_epoch(self, epoch: int, batches_done: int) -> None:
        """Epoch `epoch`'s order and augmentation, from batch `batches_done` on."""
        self.sampler.set_epoch(epoch)
        self.train_set.set_epoch(epoch)
        self.resumable.skip = batches_done * self.batch_size

    def stop_workers(self) -> None:
        for loader in (self.train, self.validation):
            _stop_workers(loader)


def _loader(dataset: torch.utils.data.Dataset, batch_size: int, sampler: Any, workers: int,
            drop_last: bool, device: torch.device) -> DataLoader:
    """Workers live across epochs; on a GPU batches land in pinned memory, so the copies to the device overlap."""
    return DataLoader(dataset, batch_size=batch_size, sampler=sampler, num_workers=workers, drop_last=drop_last,
                      persistent_workers=workers > 0, pin_memory=device.type == "cuda")


def _stop_workers(loader: DataLoader) -> None:
    """End a loader's persistent workers now. Left to the interpreter's exit, the workers of a loader stopped
    mid-epoch (--max-steps) with pinned memory can hang the process after its work is done (docs/decisions.md,
    "loader workers stopped by training itself"); dropping the iterator runs its shutdown."""
    iterator = getattr(loader, "_iterator", None)
    if iterator is not None:
        iterator._shutdown_workers()
        loader._iterator = None
