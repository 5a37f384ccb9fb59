"""Training samples: a torch Dataset over rows of a frame cache, and the batches the network takes."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import torch
from torch.utils.data import Dataset

from msfsu_common.road_option import branch_indices
from msfsu_perception.augmentation import AugmentationConfig, augment_rgb
from msfsu_perception.frame_cache import FrameCache


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
