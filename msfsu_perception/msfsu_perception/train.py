"""`msfsu-train` runs the recipe (training_settings): the epochs, their checkpoints and their record.

best.pt keeps the best validation loss, last.pt everything needed to --resume: after every epoch, every
--checkpoint-every minutes inside one, and when the run is stopped (Ctrl-C, SIGINT / SIGTERM; the batch in progress
ends first), so a resumed run continues at the batch where the last one stopped and ends with the weights an
unbroken run gets (training_state).

    msfsu-train --bags 'data/bags/*' --preset cpu --out runs/cpu
    torchrun --nproc_per_node 2 -m msfsu_perception.train --bags 'data/bags/*' --out runs/ddp

Run directory: best.pt, last.pt, metrics.csv (one row per epoch), loss_curves.png,
balancing.png (paper Fig. 3), args.json. Under torchrun only rank 0 writes. --snapshots DIR also keeps, after every
epoch, DIR/last.pt and DIR/best.pt in fp16 without the optimizer (a size to commit): --resume goes on from them when
the run directory is gone (a new machine), with a fresh optimizer.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import torch
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from msfsu_common.bag_io import BagError
from msfsu_common.driving import STOP_SPEED_MPS
from msfsu_common.processes import interrupts_deferred, signals_interrupt
from msfsu_perception.checkpoint import CheckpointError, load_checkpoint
from msfsu_perception.distributed import DistributedContext, barrier, init_distributed, shutdown
from msfsu_perception.frame_cache import CacheSpaceError
from msfsu_perception.losses import LossConfig
from msfsu_perception.model import MSFSUConfig, build_model, load_warm_start
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_perception.reporting import append_csv_row, plot_balancing_histograms, plot_loss_curves
from msfsu_perception.schedules import Scheduler, make_scheduler, step_scheduler
from msfsu_perception.training_data import (Loaders, Split, at_most, balance, hold_out, lane_follow_distribution,
                                            open_split, select_bags)
from msfsu_perception.training_pass import PassSettings, run_pass
from msfsu_perception.training_settings import PRESETS, Preset, cpu_bf16_is_native, parse_args, resolve_settings
from msfsu_perception.training_state import (EpochProgress, EpochSaves, RunCheckpoints, RunState, rng_state,
                                             start_state, state_after_epoch)

Losses = dict[str, float]  # loss part -> mean over a pass (LossTerms' fields)
Timing = dict[str, float]  # a pass's seconds and counts (EpochProgress.timing)


class Interrupted(Exception):
    """The run was stopped by a signal; the message says what last.pt holds."""


@dataclass(frozen=True)
class _Run:
    """What the epochs of one run share."""

    args: argparse.Namespace
    preset: Preset
    context: DistributedContext
    loaders: Loaders
    passes: PassSettings
    optimizer: torch.optim.Optimizer
    scheduler: Scheduler
    checkpoints: RunCheckpoints
    info: dict[str, Any]  # what every checkpoint of the run records of it (LoadedCheckpoint.training)

    @property
    def max_epochs(self) -> int:
        return _max_epochs(self.args, self.preset)

    @property
    def saves_inside_epochs(self) -> bool:
        """Inside an epoch only a single process saves: the ranks of a DDP run are stopped at different batches."""
        return self.context.is_main and not self.context.enabled


def _max_epochs(args: argparse.Namespace, preset: Preset) -> int:
    """--epochs, else the preset's maximum (the cosine schedule runs over it)."""
    return args.epochs if args.epochs is not None else preset.max_epochs


def train(args: argparse.Namespace, context: DistributedContext) -> float:
    """Run the recipe; returns the best validation loss."""
    preset = PRESETS[args.preset]
    resolve_settings(args, preset, context.device)  # args.json then records what ran
    if args.bf16 and context.device.type == "cpu" and context.is_main and not cpu_bf16_is_native():
        print("msfsu-train: warning: bf16 on a CPU without bf16 (avx512_bf16 / AMX) is emulated, ~12x slower than "
              "fp32 (--no-bf16)", flush=True)
    model_config = preset.model_config(args.variant, args.decoder_layout, args.stop_output)
    preprocess = PreprocessConfig(preset.input_height, preset.input_width, use_depth=args.variant != "su")
    torch.manual_seed(args.seed)
    warm_start = _warm_start_weights(args, model_config, preprocess)  # checked before any data is read
    bags = select_bags(args)
    balanced, validation = _open_splits(args, bags, preprocess, model_config.has_segmentation, context)
    if context.is_main:
        run_description = {**vars(args), "preset_values": asdict(preset)}
        (args.out / "args.json").write_text(json.dumps(run_description, default=str, indent=1))
    loaders = Loaders.of(balanced, validation, args, context)
    run = _start_run(args, preset, model_config, preprocess, bags, loaders, context)
    state, partial = start_state(), None  # partial: where a stopped run left epoch state["epoch"]
    if args.resume and run.checkpoints.can_restore():
        state, partial = run.checkpoints.restore(model_config, context)
    elif warm_start is not None:
        load_warm_start(run.checkpoints.network, warm_start)
        if context.is_main:
            tqdm.write(f"warm start from {args.init_from} (fresh optimizer and schedule)")
    try:
        state = _train_epochs(run, state, partial)
    finally:  # also when training fails: no worker outlives it
        loaders.stop_workers()
    return state["best_val"]


def _warm_start_weights(args: argparse.Namespace, model_config: MSFSUConfig,
                        preprocess: PreprocessConfig) -> dict[str, torch.Tensor] | None:
    """The --init-from checkpoint's weights (fp32), if one is given; a one-line error when it is not a checkpoint of
    the network and preprocessing this run trains, or was trained with another speed scale."""
    if args.init_from is None:
        return None
    loaded = load_checkpoint(args.init_from)  # CheckpointError: main's one-line error
    # a network without a stop output warm-starts one with it (load_warm_start); the other way would drop it
    if (loaded.model.config not in (model_config, replace(model_config, stop_output=False))
            or loaded.preprocess != preprocess):
        raise CheckpointError(f"--init-from {args.init_from} is {loaded.model.config} with {loaded.preprocess}; this run "
                              f"trains {model_config} with {preprocess} (--preset, --variant, --decoder-layout, "
                              "--stop-output)")
    if loaded.speed_scale != args.speed_scale:
        raise CheckpointError(f"--init-from {args.init_from} was trained with --speed-scale {loaded.speed_scale}, this "
                              f"run has {args.speed_scale}")
    return loaded.model.state_dict()


def _open_splits(args: argparse.Namespace, bags: tuple[list[Path], list[Path]], preprocess: PreprocessConfig,
                 with_labels: bool, context: DistributedContext) -> tuple[Split, Split]:
    """The run's training rows, balanced (balancing.png shows how, in the run directory it makes), and its
    validation rows."""
    train_bags, val_bags = bags
    unbalanced = open_split(train_bags, preprocess, with_labels, args, context)
    if args.val_fraction is None:
        validation = open_split(val_bags, preprocess, with_labels, args, context)
    else:  # validation frames held out of the training bags (select_bags: then there is no validation bag)
        unbalanced, validation = hold_out(unbalanced, args.val_fraction)
        if context.is_main:
            print(f"msfsu-train: --val-fraction {args.val_fraction}: {len(validation.rows)} of "
                  f"{len(unbalanced.rows) + len(validation.rows)} frames held out for validation", flush=True)
    unbalanced, validation = at_most(unbalanced, args.max_samples), at_most(validation, args.max_samples)
    balanced = balance(unbalanced, args.seed, args.focus_copies)
    args.out.mkdir(parents=True, exist_ok=True)
    if context.is_main:
        plot_balancing_histograms(lane_follow_distribution(unbalanced), lane_follow_distribution(balanced),
                                  args.out / "balancing.png")
    return balanced, validation


def _start_run(args: argparse.Namespace, preset: Preset, model_config: MSFSUConfig, preprocess: PreprocessConfig,
               bags: tuple[list[Path], list[Path]], loaders: Loaders, context: DistributedContext) -> _Run:
    """A new network (in DDP under torchrun) with NAdam, its learning-rate schedule (--schedule: schedules) and the
    run's checkpoints."""
    memory_format = torch.channels_last if args.channels_last else torch.contiguous_format
    network = build_model(model_config).to(context.device, memory_format=memory_format)
    model: torch.nn.Module = DistributedDataParallel(network) if context.enabled else network
    optimizer = torch.optim.NAdam(model.parameters(), lr=args.learning_rate)
    scheduler = make_scheduler(args.schedule, optimizer, _max_epochs(args, preset), preset.plateau_factor,
                               preset.plateau_patience)
    autocast = torch.autocast(context.device.type, dtype=torch.bfloat16) if args.bf16 else None
    passes = PassSettings(model, autocast, memory_format, model_config.has_segmentation, context,
                          LossConfig(scene_weight=args.scene_weight, stop_weight=args.stop_weight,
                                     stop_speed_weight=args.stop_speed_weight,
                                     stop_below=STOP_SPEED_MPS / args.speed_scale),
                          has_stop=model_config.stop_output)
    checkpoints = RunCheckpoints(args.out, network, optimizer, scheduler, preprocess, args.speed_scale, context.device,
                                 args.snapshots)
    train_bags, val_bags = bags
    info = {"preset": args.preset, "seed": args.seed, "train_bags": [str(b) for b in train_bags],
            "val_bags": [str(b) for b in val_bags], "val_fraction": args.val_fraction,
            "train_samples": len(loaders.train_set), "bf16": args.bf16,
            "world_size": context.world_size, "init_from": None if args.init_from is None else str(args.init_from),
            "scene_weight": args.scene_weight, "schedule": args.schedule, "stop_output": args.stop_output,
            "stop_weight": args.stop_weight, "stop_speed_weight": args.stop_speed_weight}
    return _Run(args, preset, context, loaders, passes, optimizer, scheduler, checkpoints, info)


def _train_epochs(run: _Run, state: RunState, partial: dict[str, Any] | None) -> RunState:
    """The epochs from state["epoch"] (taken up where `partial` says) to the last, an early stop or the end of the
    --max-steps budget; returns the state after them."""
    device, max_steps = run.context.device, run.args.max_steps
    try:
        for epoch in range(state["epoch"], run.max_epochs):
            if state["epochs_without_improvement"] >= run.preset.early_stop_patience:
                break
            progress = EpochProgress.start(device) if partial is None else EpochProgress.restore(partial, device)
            steps_left = None if max_steps is None else max_steps - state["steps"] - progress.batches
            if steps_left is not None and steps_left <= 0 and partial is None:
                break
            rng = None if partial is None else partial["rng"]
            partial = None
            train_loss, val_loss, timing = _epoch_passes(run, epoch, state, progress, steps_left, rng)
            with interrupts_deferred():  # the epoch's end is recorded whole
                state = _end_epoch(run, epoch, state, train_loss, val_loss, timing)
            barrier(run.context)
    except KeyboardInterrupt:  # between epochs (the epoch's end had been saved)
        raise Interrupted(_stopped_between_epochs(state["epoch"], run.checkpoints.last_path)) from None
    return state


def _epoch_passes(run: _Run, epoch: int, begun: RunState, progress: EpochProgress, steps_left: int | None,
                  rng: dict[str, Any] | None) -> tuple[Losses, Losses, Timing]:
    """Epoch `epoch`'s training pass, on from `progress` (`rng`: the random-number states saved with it), and its
    validation pass. Stopped inside them, the run saves last.pt there (a single process) and raises Interrupted."""
    run.loaders.start_epoch(epoch, progress.batches)
    saves = EpochSaves(run.checkpoints, run.info, epoch, begun, progress, run.args.checkpoint_every * 60.0)
    trained_rng = None  # the random-number states at the end of the training pass
    try:
        train_loss, timing = run_pass(run.passes, run.loaders.train, run.optimizer, f"epoch {epoch} train",
                                      None if steps_left is None else max(steps_left, 0), progress, rng,
                                      saves.save_when_due if run.saves_inside_epochs else None)
        trained_rng = rng_state(run.context.device)  # validation draws from the generator too
        val_loss, _ = run_pass(run.passes, run.loaders.validation, None, f"epoch {epoch} val")
    except KeyboardInterrupt:
        if run.saves_inside_epochs:
            try:  # a second signal (a Ctrl-C a pipeline passes on too) waits for the save, and the stop goes on
                with interrupts_deferred():
                    saves.save(rng=trained_rng)
            except KeyboardInterrupt:
                pass
        raise Interrupted(_stopped_message(epoch, progress.batches, run.loaders.epoch_batches,
                                           run.checkpoints.last_path, run.saves_inside_epochs)) from None
    return train_loss, val_loss, timing


def _end_epoch(run: _Run, epoch: int, state: RunState, train_loss: Losses, val_loss: Losses,
               timing: Timing) -> RunState:
    """The scheduler's step and the state after epoch `epoch`; the main process saves best.pt (when the validation
    loss improved) and last.pt and logs the epoch (at the learning rate it trained at)."""
    lr = run.optimizer.param_groups[0]["lr"]
    step_scheduler(run.scheduler, val_loss["total"])
    state, improved = state_after_epoch(state, epoch, val_loss["total"], int(timing["batches"]))
    if run.context.is_main:
        info = {**run.info, "epoch": epoch, "steps": state["steps"], "val_loss": val_loss["total"]}
        if improved:
            run.checkpoints.save_best(info)
        run.checkpoints.save_last(info, state)
        _log_epoch(run.args.out, epoch, lr, train_loss, val_loss, timing,
                   run.context.world_size, improved, run.info["train_samples"])
        run.checkpoints.save_snapshot(info, state, improved)
    return state


def _stopped_message(epoch: int, batches: int, epoch_batches: int, last_path: Path, saved: bool) -> str:
    if saved:
        return (f"stopped in epoch {epoch} after {batches} of {epoch_batches} batches; {last_path} holds it: run "
                "again with --resume to continue from there")
    return (f"stopped in epoch {epoch}; {last_path} holds the last epoch's end (a DDP run saves at epoch ends "
            f"only): run again with --resume to redo epoch {epoch}")


def _stopped_between_epochs(epochs_done: int, last_path: Path) -> str:
    if epochs_done == 0:
        return "stopped before the first batch: run the same command again"
    return f"stopped after epoch {epochs_done - 1}; {last_path} holds it: run again with --resume to continue"


def _log_epoch(out: Path, epoch: int, lr: float, train_loss: Losses, val_loss: Losses, timing: Timing,
               world_size: int, improved: bool, train_samples: int) -> None:
    """metrics.csv row, refreshed loss curves, one console line. The row counts the training samples the epoch
    drew from (a run resumed on another machine may have bags collected again, not always the same frames)."""
    samples_per_s = timing["samples"] * world_size / timing["wall"]
    append_csv_row(out / "metrics.csv", {
        "epoch": epoch, "lr": lr,
        **{f"train_{name}": value for name, value in train_loss.items()},
        **{f"val_{name}": value for name, value in val_loss.items()},
        "samples_per_s": samples_per_s, "data_time_s": timing["data"],
        "step_time_s": timing["step"], "epoch_time_s": timing["wall"], "first_batch_s": timing.get("first_batch", 0.0),
        "train_samples": train_samples,
    })
    plot_loss_curves(out / "metrics.csv", out / "loss_curves.png")
    tqdm.write(f"epoch {epoch}: train {train_loss['total']:.4f} val {val_loss['total']:.4f} "
               f"({samples_per_s:.1f} samples/s, data {timing['data']:.1f} s, step {timing['step']:.1f} s)"
               f"{' *' if improved else ''}")


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    if args.num_threads:
        torch.set_num_threads(args.num_threads)
    context = init_distributed(args.device)
    try:
        with signals_interrupt():  # SIGTERM, and SIGINT also in a background job: stop after the batch, save, exit 1
            train(args, context)
    except (BagError, CacheSpaceError, CheckpointError) as error:  # no bag, a full disk, a wrong --init-from: one line
        raise SystemExit(f"msfsu-train: {error}") from None
    except Interrupted as stop:
        raise SystemExit(f"msfsu-train: {stop}") from None
    except KeyboardInterrupt:  # before the first epoch started: nothing trained yet
        raise SystemExit(f"msfsu-train: stopped before training started; {args.out} is as it was") from None
    finally:
        shutdown(context)


if __name__ == "__main__":
    main()
