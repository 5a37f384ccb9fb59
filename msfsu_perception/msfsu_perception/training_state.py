"""A run's progress as last.pt keeps it, so that a stopped run goes on where it stopped.

At an epoch's end: the run state (epochs done, best validation loss, epochs without improvement, optimizer steps),
the optimizer's and the scheduler's states and torch's random-number states. Inside an epoch (a single process
only: the ranks of a DDP run are stopped at different batches) also the training pass's progress (EpochProgress)
and the random-number states as of its last finished batch, under "partial". A resumed run loads them all and ends
with the weights an unbroken run gets.

A snapshot directory (--snapshots) keeps what survives the loss of the machine in a size a repository takes: after
every epoch last.pt with the weights in fp16, the run state and the scheduler's state (no optimizer state: twice
the weights' size), and best.pt, the best validation loss's weights in fp16. Resumed from it (OUT/last.pt gone), a
run goes on after that epoch with a fresh optimizer at the schedule's learning rate: close to, not exactly, what an
unbroken run gets. The cosine schedule is put at the epoch's rate from the epoch alone (schedules), also from a
state saved under the plateau schedule.
"""

from __future__ import annotations

import math
import os
import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

import torch
from tqdm import tqdm

from msfsu_perception.checkpoint import load_checkpoint, save_checkpoint
from msfsu_perception.distributed import DistributedContext, all_reduce_sum
from msfsu_perception.losses import LossTerms
from msfsu_perception.model import MSFSUConfig, MSFSUNet
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_perception.schedules import Scheduler, restore_scheduler


class RunState(TypedDict):
    """Where a run stands at an epoch's end."""

    epoch: int  # epochs done: the next one to train
    best_val: float
    epochs_without_improvement: int
    steps: int  # optimizer steps in all (--max-steps)


def start_state() -> RunState:
    """The state of a run that has trained nothing yet."""
    return {"epoch": 0, "best_val": math.inf, "epochs_without_improvement": 0, "steps": 0}


def state_after_epoch(state: RunState, epoch: int, val_loss: float, batches: int) -> tuple[RunState, bool]:
    """The state after epoch `epoch` (`batches` optimizer steps, validation loss `val_loss`), and whether that loss
    improved on the best so far."""
    improved = val_loss < state["best_val"]
    return {
        "epoch": epoch + 1,
        "best_val": min(val_loss, state["best_val"]),
        "epochs_without_improvement": 0 if improved else state["epochs_without_improvement"] + 1,
        "steps": state["steps"] + batches,
    }, improved


class LossMeter:
    """Sample-weighted sums of the loss parts, reduced over processes. Accumulated on the device: adding a batch
    never waits for the device (a float() per loss part would synchronise a GPU every step)."""

    def __init__(self, device: torch.device) -> None:
        self.sums = torch.zeros(1 + len(LossTerms._fields), dtype=torch.float64, device=device)
        self._zero = torch.zeros((), dtype=torch.float64, device=device)

    def add(self, parts: Sequence[torch.Tensor | None], batch_size: int) -> None:
        self.sums[0] += batch_size
        self.sums[1:] += torch.stack([self._zero if part is None else part.detach().double() for part in parts]
                                     ) * batch_size

    def mean_total(self) -> float:
        """Mean total loss so far (synchronises the device: for the progress bar now and then)."""
        return float(self.sums[1] / self.sums[0].clamp(min=1))

    def means(self, context: DistributedContext, has_scene: bool, has_stop: bool = False) -> dict[str, float]:
        sums = all_reduce_sum(self.sums.clone(), context).tolist()
        means = {name: value / max(sums[0], 1) for name, value in zip(LossTerms._fields, sums[1:])}
        if not has_scene:
            means["scene"] = math.nan
        if not has_stop:
            means["stop"] = math.nan
        return means


@dataclass
class EpochProgress:
    """How far a training pass is: its loss sums and timing (batches and samples so far, data wait, wall time).
    A mid-epoch checkpoint stores it; restored, the pass goes on and reports the epoch as one unbroken pass."""

    meter: LossMeter
    timing: dict[str, float]

    @classmethod
    def start(cls, device: torch.device) -> EpochProgress:
        return cls(LossMeter(device), {"data": 0.0, "samples": 0, "batches": 0, "wall": 0.0})

    @property
    def batches(self) -> int:
        return int(self.timing["batches"])

    def state(self) -> dict[str, Any]:
        return {"meter_sums": self.meter.sums.tolist(), "timing": dict(self.timing)}

    @classmethod
    def restore(cls, saved: dict[str, Any], device: torch.device) -> EpochProgress:
        progress = cls.start(device)
        sums = saved["meter_sums"]  # a pass saved before a loss part existed has no sum for it: 0 so far
        progress.meter.sums[:len(sums)].copy_(torch.tensor(sums, dtype=torch.float64))
        progress.timing.update(saved["timing"])
        return progress


def rng_state(device: torch.device) -> dict[str, Any]:
    """torch's random-number states: the CPU generator's, and on a CUDA device every GPU's."""
    state: dict[str, Any] = {"torch_rng": torch.get_rng_state()}
    if device.type == "cuda":
        state["cuda_rng"] = torch.cuda.get_rng_state_all()
    return state


def set_rng(state: dict[str, Any]) -> None:
    """Put back states `rng_state` took (the GPUs' wherever this torch has CUDA)."""
    torch.set_rng_state(state["torch_rng"])
    if "cuda_rng" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda_rng"])


@dataclass(frozen=True)
class RunCheckpoints:
    """best.pt (the weights of the best validation loss) and last.pt (everything --resume needs) of a run
    directory, for `network` trained by `optimizer` under `scheduler`."""

    out: Path
    network: MSFSUNet
    optimizer: torch.optim.Optimizer
    scheduler: Scheduler
    preprocess: PreprocessConfig
    speed_scale: float
    device: torch.device
    snapshots: Path | None = None  # --snapshots

    @property
    def last_path(self) -> Path:
        return self.out / "last.pt"

    @property
    def best_path(self) -> Path:
        return self.out / "best.pt"

    def save_best(self, info: Mapping[str, Any]) -> None:
        save_checkpoint(self.best_path, self.network, self.preprocess, self.speed_scale, info)

    def save_last(self, info: Mapping[str, Any], training_state: Mapping[str, Any]) -> None:
        """last.pt: `training_state` with the optimizer's, the scheduler's and the random-number states now."""
        training_state = {**training_state, "optimizer": self.optimizer.state_dict(),
                          "scheduler": self.scheduler.state_dict(), **rng_state(self.device)}
        save_checkpoint(self.last_path, self.network, self.preprocess, self.speed_scale, info, training_state)

    def save_snapshot(self, info: Mapping[str, Any], state: RunState, improved: bool) -> None:
        """The snapshot directory's last.pt after an epoch, best.pt when its validation loss improved, and the run's
        metrics.csv so far."""
        if self.snapshots is None:
            return
        _copy(self.out / "metrics.csv", self.snapshots / "metrics.csv")
        last = self.snapshots / "last.pt"
        save_checkpoint(last, self.network, self.preprocess, self.speed_scale, info,
                        {**state, "scheduler": self.scheduler.state_dict()}, half=True)
        if improved:
            _copy(last, self.snapshots / "best.pt")

    def can_restore(self) -> bool:
        """Whether --resume has something to go on from: last.pt, else the snapshot directory's last.pt."""
        return self.last_path.exists() or (self.snapshots is not None and (self.snapshots / "last.pt").exists())

    def restore_snapshot(self, model_config: MSFSUConfig, context: DistributedContext) -> RunState:
        """Load the snapshot directory's last.pt into the network and the scheduler; the optimizer stays fresh, at
        the scheduler's learning rate. Returns the run state after the snapshot's epoch."""
        assert self.snapshots is not None
        path = self.snapshots / "last.pt"
        seed, saved = self._load_weights(path, model_config, "--snapshots")
        restore_scheduler(self.scheduler, saved.get("scheduler"), saved["epoch"], str(path))
        if context.is_main and (self.snapshots / "metrics.csv").exists():  # the epochs before, as the run logged them
            _copy(self.snapshots / "metrics.csv", self.out / "metrics.csv")
        for group, lr in zip(self.optimizer.param_groups, self.scheduler.get_last_lr()):
            group["lr"] = lr
        torch.manual_seed(seed + saved["epoch"])  # reproducible from here on
        if context.is_main:
            tqdm.write(f"resuming after epoch {saved['epoch'] - 1} from {path} (best val {saved['best_val']:.4f}; "
                       f"fp16 weights, fresh optimizer at lr {self.optimizer.param_groups[0]['lr']:.3g}: "
                       f"{self.last_path} is gone)")
        return _run_state(saved)

    def restore(self, model_config: MSFSUConfig, context: DistributedContext) -> tuple[RunState, dict[str, Any] | None]:
        """Load last.pt into the network, the optimizer, the scheduler and torch's generators (without last.pt: the
        snapshot, restore_snapshot). Returns the run state and, for a last.pt saved inside an epoch, that epoch's
        "partial" progress (None in a DDP run: it redoes the epoch, its ranks stopped at different batches)."""
        if not self.last_path.exists():
            return self.restore_snapshot(model_config, context), None
        path = self.last_path
        _, saved = self._load_weights(path, model_config, "--out")
        self.optimizer.load_state_dict(saved["optimizer"])
        restore_scheduler(self.scheduler, saved.get("scheduler"), saved["epoch"], str(path))
        torch.set_rng_state(saved["torch_rng"])
        if "cuda_rng" in saved and self.device.type == "cuda":
            torch.cuda.set_rng_state_all(saved["cuda_rng"])
        partial = None if context.enabled else saved.get("partial")
        if context.is_main:
            where = (f"in epoch {saved['epoch']} after batch {partial['timing']['batches']}" if partial is not None
                     else f"after epoch {saved['epoch'] - 1}")
            tqdm.write(f"resuming {where} (best val {saved['best_val']:.4f})")
        return _run_state(saved), partial

    def _load_weights(self, path: Path, model_config: MSFSUConfig, option: str) -> tuple[int, dict[str, Any]]:
        """`path`'s weights into the network (a checkpoint of another network or preprocessing: a one-line exit
        naming `option`). Returns the run's seed and the checkpoint's training state."""
        loaded = load_checkpoint(path, with_training_state=True)
        if loaded.model.config != model_config or loaded.preprocess != self.preprocess:
            raise SystemExit(f"{path} was trained as {loaded.model.config}, not {model_config}: use another {option}")
        self.network.load_state_dict(loaded.model.state_dict())
        return int(loaded.training.get("seed", 0)), dict(loaded.training_state or {})


def _run_state(saved: Mapping[str, Any]) -> RunState:
    """The run state a last.pt or a snapshot saved (runs saved before --max-steps existed counted no steps)."""
    return {"epoch": saved["epoch"], "best_val": saved["best_val"],
            "epochs_without_improvement": saved["epochs_without_improvement"], "steps": saved.get("steps", 0)}


def _copy(source: Path, destination: Path) -> None:
    """Copy atomically (temp file + rename): a stopped copy never leaves a torn file."""
    destination.parent.mkdir(parents=True, exist_ok=True)
    temporary = destination.with_name(destination.name + ".tmp")
    shutil.copyfile(source, temporary)
    os.replace(temporary, destination)


class EpochSaves:
    """last.pt inside epoch `epoch` as of its last finished batch: `save_when_due` after every batch (each
    `every_s` seconds; 0: never) and `save` when the run is stopped. `begun`: the run state at the epoch's start."""

    def __init__(self, checkpoints: RunCheckpoints, info: Mapping[str, Any], epoch: int, begun: RunState,
                 progress: EpochProgress, every_s: float) -> None:
        self._checkpoints, self._info, self._epoch = checkpoints, info, epoch
        self._begun, self._progress, self._every_s = begun, progress, every_s
        self._saved_at = time.monotonic()

    def save(self, rng: dict[str, Any] | None = None) -> None:
        """`rng`: the random-number states as of the last finished batch, if not now."""
        progress, begun = self._progress, self._begun
        self._checkpoints.save_last(
            {**self._info, "epoch": self._epoch, "batch": progress.batches, "steps": begun["steps"] + progress.batches},
            {**begun, "partial": {**progress.state(), "rng": rng or rng_state(self._checkpoints.device)}})

    def save_when_due(self) -> None:
        if self._every_s > 0 and time.monotonic() - self._saved_at >= self._every_s:
            self.save()
            self._saved_at = time.monotonic()
