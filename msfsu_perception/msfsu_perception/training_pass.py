"""One pass of a training run over a loader: each batch through the network and the paper's loss, with an optimizer
step when training; the loss means, the timing, and a progress bar on the main process."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, closing, nullcontext
from dataclasses import dataclass
from itertools import islice
from typing import Any

import torch
from torch.utils.data import DataLoader
from tqdm import tqdm

from msfsu_common.processes import interrupts_deferred
from msfsu_perception.dataset import Sample, to_device
from msfsu_perception.distributed import DistributedContext
from msfsu_perception.losses import LossConfig, LossTerms, msfsu_loss
from msfsu_perception.training_state import EpochProgress, set_rng

PROGRESS_EVERY = 50  # batches between progress-bar loss updates (each reads the loss back from the device)


@dataclass(frozen=True)
class PassSettings:
    """What every pass of a run shares: the model (in DDP under torchrun), the bf16 autocast (None: fp32), the
    activations' memory format, whether the loss has its scene term, the loss's weights, and whether it has its stop
    term."""

    model: torch.nn.Module
    autocast: AbstractContextManager[Any] | None
    memory_format: torch.memory_format
    has_scene: bool
    context: DistributedContext
    loss: LossConfig = LossConfig()
    has_stop: bool = False  # the network has a stop output (MSFSUConfig.stop_output): the loss has its stop term


def _batches(iterator: Iterator[Any], device: torch.device, memory_format: torch.memory_format,
             timing: dict[str, float]) -> Iterator[Sample]:
    """Yield the loader iterator's batches on `device` (dataset.to_device), adding the time spent waiting for each
    to timing['data']."""
    while True:
        start = time.perf_counter()
        try:
            batch = next(iterator)
        except StopIteration:
            return
        batch = to_device(batch, device, memory_format)
        waited = time.perf_counter() - start
        timing["data"] += waited
        timing.setdefault("first_batch", waited)  # the loader's start (its workers' first batches) is in it
        yield batch


def _step(settings: PassSettings, batch: Sample, optimizer: torch.optim.Optimizer | None) -> LossTerms:
    """The batch's loss terms; with an optimizer, after its step on them."""
    with settings.autocast or nullcontext():
        output = settings.model(batch.inputs, batch.command_index)
    terms = msfsu_loss(output, batch.steer, batch.speed, batch.class_ids if settings.has_scene else None,
                       settings.loss)
    if optimizer is not None:
        optimizer.zero_grad(set_to_none=True)
        terms.total.backward()
        optimizer.step()
    return terms


def run_pass(settings: PassSettings, loader: DataLoader, optimizer: torch.optim.Optimizer | None, description: str,
             max_batches: int | None = None, progress: EpochProgress | None = None,
             rng: dict[str, Any] | None = None,
             after_batch: Callable[[], None] | None = None) -> tuple[dict[str, float], dict[str, float]]:
    """One pass (at most `max_batches` more batches); trains when an optimizer is given. Returns loss means and
    timing of the whole pass.

    `progress` (the caller's, so that it still holds the sums after a stop) starts empty or where a resumed pass
    stopped, with `rng` the random-number states saved with it. Each batch runs whole: a stop signal arriving inside
    one is raised after it (and after `after_batch`, the periodic save)."""
    context = settings.context
    training = optimizer is not None
    settings.model.train(training)
    progress = progress or EpochProgress.start(context.device)
    meter, timing = progress.meter, progress.timing
    start, wall_before = time.perf_counter(), timing["wall"]
    total = len(loader) if max_batches is None else min(len(loader), max_batches)
    bar = tqdm(total=progress.batches + total, initial=progress.batches, desc=description, disable=not context.is_main,
               leave=False, dynamic_ncols=True)
    iterator = iter(loader)
    if rng is not None:  # after the iterator's start, which draws a seed from torch's generator: a resumed pass
        set_rng(rng)    # then draws the dropout masks the unbroken pass drew
    with torch.set_grad_enabled(training), closing(bar):
        for batch in islice(_batches(iterator, context.device, settings.memory_format, timing), total):
            with interrupts_deferred():
                meter.add(_step(settings, batch, optimizer), len(batch.steer))
                timing["samples"] += len(batch.steer)
                timing["batches"] += 1
                timing["wall"] = wall_before + time.perf_counter() - start
                if after_batch is not None:
                    after_batch()
            bar.update()
            if timing["batches"] % PROGRESS_EVERY == 1:
                bar.set_postfix(loss=f"{meter.mean_total():.4f}")
    # reads the sums back: the device's work is done after this
    means = meter.means(context, settings.has_scene, settings.has_stop)
    timing["wall"] = wall_before + time.perf_counter() - start
    timing["step"] = timing["wall"] - timing["data"]
    return means, timing
