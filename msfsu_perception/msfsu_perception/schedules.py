"""The learning-rate schedules of msfsu-train (--schedule).

plateau  the paper's: the rate halves after `plateau_patience` epochs without a better validation loss (the preset's
         numbers); its state (the best loss, the epochs since) is saved and restored with the run.
cosine   per epoch from the starting rate down a half cosine over the run's --epochs: epoch e of E trains at
         lr * (1 + cos(pi * e / E)) / 2. Its rate depends on the epoch alone, so a resumed run is put at its epoch's
         rate whatever schedule the state it resumes from was saved under (a fixed budget of epochs: model v3).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from typing import Any, Literal, get_args

import torch
from torch.optim.lr_scheduler import LambdaLR, ReduceLROnPlateau

Schedule = Literal["plateau", "cosine"]
SCHEDULES: tuple[str, ...] = get_args(Schedule)
Scheduler = ReduceLROnPlateau | LambdaLR


class ScheduleError(SystemExit):
    """A saved schedule state this run cannot go on from (one line)."""


def cosine_factor(epoch: int, epochs: int) -> float:
    """The share of the starting rate that epoch `epoch` of `epochs` trains at."""
    return 0.5 * (1.0 + math.cos(math.pi * epoch / epochs))


def make_scheduler(schedule: Schedule, optimizer: torch.optim.Optimizer, epochs: int, plateau_factor: float,
                   plateau_patience: int) -> Scheduler:
    """The scheduler of a new run at epoch 0 (the optimizer at the starting rate)."""
    if schedule == "cosine":
        return LambdaLR(optimizer, lambda epoch: cosine_factor(epoch, epochs))
    return ReduceLROnPlateau(optimizer, mode="min", factor=plateau_factor, patience=plateau_patience)


def step_scheduler(scheduler: Scheduler, val_loss: float) -> None:
    """After an epoch: the plateau schedule looks at the validation loss, the cosine one at the epoch count."""
    if isinstance(scheduler, ReduceLROnPlateau):
        scheduler.step(val_loss)
    else:
        scheduler.step()


def restore_scheduler(scheduler: Scheduler, saved: Mapping[str, Any] | None, epochs_done: int, source: str) -> None:
    """Put a new run's `scheduler` where a run saved with `saved` (its scheduler's state_dict, if any) left it after
    `epochs_done` epochs; the optimizer's rate follows. A plateau run cannot go on from a cosine run's state."""
    if isinstance(scheduler, ReduceLROnPlateau):
        if saved is None or "patience" not in saved:
            raise ScheduleError(f"{source} was saved under another schedule than plateau: resume it with "
                                "--schedule cosine")
        scheduler.load_state_dict(dict(saved))
        return
    with warnings.catch_warnings():  # "lr_scheduler.step() before optimizer.step()": nothing is trained here
        warnings.simplefilter("ignore", UserWarning)
        for _ in range(epochs_done - scheduler.last_epoch):
            scheduler.step()
