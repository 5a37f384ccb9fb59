"""`msfsu-train`: the paper's training recipe (III-B) on rosbag2 MCAP bags.

NAdam (lr 3e-4), ReduceLROnPlateau (factor 0.5, patience 5) on the validation loss, batch 32,
at most 100 epochs, early stop after 20 epochs without improvement; best.pt keeps the best
validation loss, last.pt everything needed to --resume: after every epoch, every --checkpoint-every minutes inside
one, and when the run is stopped (Ctrl-C, SIGINT / SIGTERM; the batch in progress ends first), so a resumed run
continues at the batch where the last one stopped and ends with the weights an unbroken run gets. Presets:
  paper  ResNet-50 V2, 224x224 (exactly the paper);
  cpu    ResNet-18 V2, 128x128 with bf16 autocast where the CPU has bf16 (fp32 elsewhere), same recipe, so a
         model trains on 2 cores; its decoder's
         first layer has 256 filters (the paper's 512 on 2048 features; 512 -> 256 here), which keeps a
         release (fp16) under RELEASE_LIMIT_MB.

    msfsu-train --bags 'data/bags/*' --preset cpu --out runs/cpu
    torchrun --nproc_per_node 2 -m msfsu_perception.train --bags 'data/bags/*' --out runs/ddp

Run directory: best.pt, last.pt, metrics.csv (one row per epoch), loss_curves.png,
balancing.png (paper Fig. 3), args.json. Under torchrun only rank 0 writes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager, closing, nullcontext
from dataclasses import asdict, dataclass, fields
from itertools import islice
from pathlib import Path
from typing import Any, get_args

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader, DistributedSampler, Sampler, Subset
from tqdm import tqdm

from msfsu_common.bag_io import BagError
from msfsu_common.processes import interrupts_deferred, signals_interrupt
from msfsu_common.road_option import RoadOption
from msfsu_perception.augmentation import AugmentationConfig
from msfsu_perception.balancing import BalancingConfig, balance_lane_follow, repeat_focus
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.checkpoint import DEFAULT_SPEED_SCALE_MPS, load_checkpoint, save_checkpoint
from msfsu_perception.dataset import (
    CacheSpaceError,
    CacheSpec,
    DrivingDataset,
    FrameCache,
    expand_bag_paths,
    open_cache,
    split_bags,
    to_device,
)
from msfsu_perception.distributed import DistributedContext, all_reduce_sum, barrier, init_distributed, shutdown
from msfsu_perception.losses import LossConfig, LossTerms, msfsu_loss
from msfsu_perception.model import (PAPER_DECODER_FILTERS, Backbone, DecoderLayout, MSFSUConfig, MSFSUNet, Variant,
                                    build_model)
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_perception.reporting import append_csv_row, plot_balancing_histograms, plot_loss_curves


@dataclass(frozen=True)
class Preset:
    backbone: Backbone
    input_height: int
    input_width: int
    bf16: bool  # on the CPU only where it is native (cpu_bf16_is_native); on a GPU always
    channels_last: bool  # NHWC activations: ~20 % faster bf16 training (AMX Xeon), ~12 % fp32 (AVX2 EPYC)
    decoder_filters: tuple[int, ...] = PAPER_DECODER_FILTERS
    batch_size: int = 32
    learning_rate: float = 3e-4
    max_epochs: int = 100
    plateau_factor: float = 0.5
    plateau_patience: int = 5
    early_stop_patience: int = 20
    # On a CUDA device, unless --batch-size / --learning-rate say otherwise: a batch that keeps the GPU busy and the
    # learning rate scaled with the square root of the batch ratio (the usual rule for Adam-type optimisers); bf16
    # and channels-last are on there for every preset. `--batch-size 32 --learning-rate 3e-4` is the paper's.
    gpu_batch_size: int | None = None
    gpu_learning_rate: float | None = None


    def model_config(self, variant: Variant = "msfsu", decoder_layout: DecoderLayout = MSFSUConfig.decoder_layout
                     ) -> MSFSUConfig:
        """The network this preset trains."""
        return MSFSUConfig(variant, self.backbone, self.input_height, self.input_width,
                           decoder_layout=decoder_layout, decoder_filters=self.decoder_filters)


PRESETS = {
    "paper": Preset("resnet50v2", 224, 224, bf16=False, channels_last=False, gpu_batch_size=256,
                    gpu_learning_rate=round(3e-4 * math.sqrt(256 / 32), 6)),
    "cpu": Preset("resnet18v2", 128, 128, bf16=True, channels_last=True, decoder_filters=(256, 128, 64, 16, 5)),
}
# What a shipped checkpoint (msfsu-release-checkpoint: fp16 storage) of the cpu preset may weigh, in MB (10^6 bytes).
RELEASE_LIMIT_MB = 30.0


def _non_negative(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, not {value}")
    return value


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="msfsu-train", description=__doc__.split("\n")[0])
    data = parser.add_argument_group("data (bag directories or glob patterns)")
    data.add_argument("--bags", nargs="+", default=[], help="bags split by their 'split' metadata")
    data.add_argument("--train-bags", nargs="+", default=[], help="training bags, whatever their metadata")
    data.add_argument("--val-bags", nargs="+", default=[], help="validation bags, whatever their metadata")
    data.add_argument("--cache-dir", type=Path, default=Path("data/cache"), help="decoded sample cache")
    data.add_argument("--evict-caches", action="store_true",
                      help="where the disk cannot hold a new cache, delete the least recently used ones under "
                           "--cache-dir first (they are rebuilt from the bags when asked for again)")
    data.add_argument("--max-samples", type=int, help="use at most this many frames per split (smoke runs)")
    data.add_argument("--topic", action="append", default=[], metavar="FIELD=TOPIC",
                      help=f"override a bag topic; fields: {', '.join(f.name for f in fields(BagTopics))}")
    parser.add_argument("--out", type=Path, required=True, help="run directory")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="cpu")
    parser.add_argument("--variant", choices=("msfsu", "msf", "su"), default="msfsu")
    parser.add_argument("--decoder-layout", choices=get_args(DecoderLayout), default=MSFSUConfig.decoder_layout,
                        help="v2: kernel = stride (default); v1: the paper's kernel 3, as the shipped models "
                             "(to resume or compare with them)")
    parser.add_argument("--epochs", type=int, help="override the preset's maximum number of epochs")
    parser.add_argument("--max-steps", type=int,
                        help="stop after this many optimizer steps in all (a short run: the epoch in progress ends "
                             "early, then validation and checkpoints as after any epoch)")
    parser.add_argument("--batch-size", type=int, help="per process; override the preset's (32; paper preset on a GPU: "
                        "256)")
    parser.add_argument("--learning-rate", type=float, help="override the preset's (3e-4; paper preset on a GPU with "
                        "its batch: 8.5e-4)")
    parser.add_argument("--bf16", action=argparse.BooleanOptionalAction,
                        help="bf16 autocast (default: on a GPU on; on the CPU the preset's where the CPU has bf16, "
                             "avx512_bf16 or AMX: emulated elsewhere, ~12x slower than fp32)")
    parser.add_argument("--channels-last", action=argparse.BooleanOptionalAction,
                        help="NHWC layout (default: preset; on a GPU: on)")
    parser.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    parser.add_argument("--checkpoint-every", type=float, default=10.0, metavar="MINUTES",
                        help="also save last.pt inside an epoch this often (default 10; 0: at epoch ends only); "
                             "single-process runs")
    parser.add_argument("--num-threads", type=int, help="torch intra-op threads per process")
    parser.add_argument("--workers", type=int, help="DataLoader worker processes (default: 0 on the CPU; on a GPU every "
                        "CPU but one, at most 16)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--speed-scale", type=float, default=DEFAULT_SPEED_SCALE_MPS,
                        help="m/s per unit of the speed output (stored in the checkpoint)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--focus-copies", type=_non_negative, default=0, metavar="N",
                        help="N extra copies of every focus frame of on-policy bags (where the network crashed or nearly "
                             "did: dataset.FocusConfig), after balancing; 0: off")
    args = parser.parse_args(argv)
    if not (args.bags or args.train_bags):
        parser.error("give --bags (split by metadata) or --train-bags and --val-bags")
    if args.max_steps is not None and args.max_steps <= 0:
        parser.error(f"--max-steps must be positive, got {args.max_steps}")
    if not args.checkpoint_every >= 0:  # also NaN
        parser.error(f"--checkpoint-every must be >= 0 minutes, got {args.checkpoint_every}")
    try:
        args.topics = BagTopics(**dict(override.split("=", 1) for override in args.topic))
    except (TypeError, ValueError) as error:
        parser.error(f"--topic takes FIELD=TOPIC with a BagTopics field: {error}")
    return args


@dataclass(frozen=True)
class Split:
    cache: FrameCache
    rows: np.ndarray  # cache rows used (balanced training rows repeat)


def _select_bags(args: argparse.Namespace) -> tuple[list[Path], list[Path]]:
    by_metadata = split_bags(expand_bag_paths(args.bags)) if args.bags else {"train": [], "validation": []}
    train = expand_bag_paths(args.train_bags) if args.train_bags else by_metadata["train"]
    validation = expand_bag_paths(args.val_bags) if args.val_bags else by_metadata["validation"]
    if not train or not validation:
        raise SystemExit(f"need training and validation bags, found {len(train)} and {len(validation)}")
    return train, validation


def _open_split(bags: list[Path], preprocess: PreprocessConfig, with_labels: bool, args: argparse.Namespace,
                context: DistributedContext) -> Split:
    """Rank 0 builds the cache while the others wait, then everyone maps it."""
    spec = CacheSpec(tuple(bags), args.topics, preprocess, with_labels)
    if context.is_main:
        open_cache(spec, args.cache_dir, args.evict_caches, log=lambda line: print(f"msfsu-train: {line}", flush=True))
    barrier(context)
    cache = open_cache(spec, args.cache_dir)
    return Split(cache, cache.valid_rows[: args.max_samples])


def _balance(split: Split, seed: int, focus_copies: int = 0) -> Split:
    cache, rows = split.cache, split.rows
    chosen = balance_lane_follow(
        cache.steer[rows], cache.target_speed[rows], cache.command[rows], np.random.default_rng(seed), BalancingConfig()
    )
    return Split(cache, repeat_focus(rows[chosen], cache.focus, focus_copies))


def _lane_follow_distribution(split: Split) -> tuple[np.ndarray, np.ndarray]:
    rows = split.rows[split.cache.command[split.rows] == RoadOption.LANE_FOLLOW]
    return split.cache.steer[rows] * BalancingConfig().steer_to_degrees, split.cache.target_speed[rows]


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

    def means(self, context: DistributedContext, has_scene: bool) -> dict[str, float]:
        sums = all_reduce_sum(self.sums.clone(), context).tolist()
        means = {name: value / max(sums[0], 1) for name, value in zip(LossTerms._fields, sums[1:])}
        if not has_scene:
            means["scene"] = math.nan
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
        progress.meter.sums.copy_(torch.tensor(saved["meter_sums"], dtype=torch.float64))
        progress.timing.update(saved["timing"])
        return progress


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


PROGRESS_EVERY = 50  # batches between progress-bar loss updates (each reads the loss back from the device)


def _batches(iterator: Iterator[Any], device: torch.device, memory_format: torch.memory_format,
             timing: dict[str, float]) -> Iterator[Any]:
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


def _run_epoch(model: torch.nn.Module, loader: DataLoader, optimizer: torch.optim.Optimizer | None,
               autocast: AbstractContextManager[Any] | None, memory_format: torch.memory_format,
               context: DistributedContext, has_scene: bool, description: str,
               max_batches: int | None = None, progress: EpochProgress | None = None,
               rng: dict[str, Any] | None = None,
               after_batch: Callable[[], None] | None = None) -> tuple[dict[str, float], dict[str, float]]:
    """One pass (at most `max_batches` more batches); trains when an optimizer is given. Returns loss means and
    timing of the whole pass.

    `progress` (the caller's, so that it still holds the sums after a stop) starts empty or where a resumed pass
    stopped, with `rng` the random-number states saved with it. Each batch runs whole: a stop signal arriving inside
    one is raised after it (and after `after_batch`, the periodic save)."""
    training = optimizer is not None
    model.train(training)
    progress = progress or EpochProgress.start(context.device)
    meter, timing = progress.meter, progress.timing
    start, wall_before = time.perf_counter(), timing["wall"]
    total = len(loader) if max_batches is None else min(len(loader), max_batches)
    bar = tqdm(total=progress.batches + total, initial=progress.batches, desc=description, disable=not context.is_main,
               leave=False, dynamic_ncols=True)
    iterator = iter(loader)
    if rng is not None:  # after the iterator's start, which draws a seed from torch's generator: a resumed pass
        _set_rng(rng)    # then draws the dropout masks the unbroken pass drew
    with torch.set_grad_enabled(training), closing(bar):
        for batch in islice(_batches(iterator, context.device, memory_format, timing), total):
            with interrupts_deferred():
                with autocast or nullcontext():
                    output = model(batch.inputs, batch.command_index)
                terms = msfsu_loss(output, batch.steer, batch.speed, batch.class_ids if has_scene else None,
                                   LossConfig())
                if training:
                    optimizer.zero_grad(set_to_none=True)
                    terms.total.backward()
                    optimizer.step()
                meter.add(terms, len(batch.steer))
                timing["samples"] += len(batch.steer)
                timing["batches"] += 1
                timing["wall"] = wall_before + time.perf_counter() - start
                if after_batch is not None:
                    after_batch()
            bar.update()
            if timing["batches"] % PROGRESS_EVERY == 1:
                bar.set_postfix(loss=f"{meter.mean_total():.4f}")
    means = meter.means(context, has_scene)  # reads the sums back: the device's work is done after this
    timing["wall"] = wall_before + time.perf_counter() - start
    timing["step"] = timing["wall"] - timing["data"]
    return means, timing


def _rng_state(device: torch.device) -> dict[str, Any]:
    state: dict[str, Any] = {"torch_rng": torch.get_rng_state()}
    if device.type == "cuda":
        state["cuda_rng"] = torch.cuda.get_rng_state_all()
    return state


def _set_rng(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch_rng"])
    if "cuda_rng" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda_rng"])


class Interrupted(Exception):
    """The run was stopped by a signal; the message says what last.pt holds."""


def cpu_bf16_is_native() -> bool:
    """Whether this CPU computes bf16 itself (avx512_bf16 or AMX: backends.cpu_precisions, the inference side's
    test). Without it oneDNN emulates bf16 and autocast slows training down instead of speeding it up (an emulated
    step is many times slower: docs/training.md)."""
    from msfsu_perception.backends import cpu_precisions

    return "bf16" in cpu_precisions()


def resolve_settings(args: argparse.Namespace, preset: Preset, device: torch.device,
                     cpu_bf16: Callable[[], bool] = cpu_bf16_is_native) -> None:
    """Fill in what the command line left open: batch size, learning rate, bf16, channels-last, loader workers.

    The preset's values, and on a CUDA device its GPU batch and learning rate (when the batch size is not given)
    and bf16 + channels-last (when not switched off). A preset's bf16 holds on the CPU only where `cpu_bf16()`
    says the CPU has it; elsewhere it trains in fp32."""
    on_gpu = device.type == "cuda"
    gpu_batch = on_gpu and args.batch_size is None and preset.gpu_batch_size is not None
    args.batch_size = args.batch_size or (preset.gpu_batch_size if gpu_batch else preset.batch_size)
    args.learning_rate = args.learning_rate or (preset.gpu_learning_rate if gpu_batch else preset.learning_rate)
    if args.bf16 is None:
        args.bf16 = on_gpu or (preset.bf16 and cpu_bf16())
    args.channels_last = (preset.channels_last or on_gpu) if args.channels_last is None else args.channels_last
    args.workers = default_workers(device) if args.workers is None else args.workers


def default_workers(device: torch.device, cpus: int | None = None) -> int:
    """Loader worker processes when --workers is not given: none on the CPU (workers would take cores from the
    training step, and a cached sample costs ~1 % of a step there); on a GPU, every CPU but one, at most 16."""
    cpus = cpus or len(os.sched_getaffinity(0))
    return 0 if device.type == "cpu" else max(1, min(16, cpus - 1))


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


def train(args: argparse.Namespace, context: DistributedContext) -> float:
    """Run the recipe; returns the best validation loss."""
    preset = PRESETS[args.preset]
    resolve_settings(args, preset, context.device)  # args.json then records what ran
    batch_size, learning_rate, use_bf16, channels_last = args.batch_size, args.learning_rate, args.bf16, args.channels_last
    if use_bf16 and context.device.type == "cpu" and context.is_main and not cpu_bf16_is_native():
        print("msfsu-train: warning: bf16 on a CPU without bf16 (avx512_bf16 / AMX) is emulated, ~12x slower than "
              "fp32 (--no-bf16)", flush=True)
    max_epochs = args.epochs if args.epochs is not None else preset.max_epochs
    memory_format = torch.channels_last if channels_last else torch.contiguous_format
    model_config = preset.model_config(args.variant, args.decoder_layout)
    preprocess = PreprocessConfig(preset.input_height, preset.input_width, use_depth=args.variant != "su")
    torch.manual_seed(args.seed)

    train_bags, val_bags = _select_bags(args)
    train_split = _open_split(train_bags, preprocess, model_config.has_segmentation, args, context)
    val_split = _open_split(val_bags, preprocess, model_config.has_segmentation, args, context)
    balanced = _balance(train_split, args.seed, args.focus_copies)
    args.out.mkdir(parents=True, exist_ok=True)
    if context.is_main:
        plot_balancing_histograms(_lane_follow_distribution(train_split), _lane_follow_distribution(balanced),
                                  args.out / "balancing.png")
        run_description = {**vars(args), "preset_values": asdict(preset)}
        (args.out / "args.json").write_text(json.dumps(run_description, default=str, indent=1))

    train_set = DrivingDataset(balanced.cache, balanced.rows, args.speed_scale, AugmentationConfig(), args.seed)
    val_set = DrivingDataset(val_split.cache, val_split.rows, args.speed_scale)
    sampler = DistributedSampler(train_set, context.world_size, context.rank, shuffle=True, seed=args.seed,
                                 drop_last=True)
    resumable = ResumableSampler(sampler)
    train_loader = _loader(train_set, batch_size, resumable, args.workers, len(sampler) > batch_size, context.device)
    val_shard = Subset(val_set, range(context.rank, len(val_set), context.world_size))  # exact, no padding
    val_loader = _loader(val_shard, batch_size, None, args.workers, False, context.device)

    network = build_model(model_config).to(context.device, memory_format=memory_format)
    model: torch.nn.Module = DistributedDataParallel(network) if context.enabled else network
    optimizer = torch.optim.NAdam(model.parameters(), lr=learning_rate)
    scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(
        optimizer, mode="min", factor=preset.plateau_factor, patience=preset.plateau_patience
    )
    autocast = torch.autocast(context.device.type, dtype=torch.bfloat16) if use_bf16 else None
    has_scene = model_config.has_segmentation
    state = {"epoch": 0, "best_val": math.inf, "epochs_without_improvement": 0, "steps": 0}
    last_path, best_path = args.out / "last.pt", args.out / "best.pt"
    if args.resume and last_path.exists():
        state = _restore(last_path, network, optimizer, scheduler, model_config, preprocess, context)
    partial = state.pop("partial", None)  # where a run stopped inside state["epoch"]
    training_info = {"preset": args.preset, "seed": args.seed, "train_bags": [str(b) for b in train_bags],
                     "val_bags": [str(b) for b in val_bags], "train_samples": len(train_set), "bf16": use_bf16,
                     "world_size": context.world_size}
    # Inside an epoch only a single process saves: the ranks of a DDP run are stopped at different batches.
    mid_epoch_saves = context.is_main and not context.enabled
    save_every_s = args.checkpoint_every * 60.0

    def save_last(info: dict[str, Any], training_state: dict[str, Any]) -> None:
        training_state = {**training_state, "optimizer": optimizer.state_dict(), "scheduler": scheduler.state_dict(),
                          **_rng_state(context.device)}
        save_checkpoint(last_path, network, preprocess, args.speed_scale, info, training_state)

    try:
        for epoch in range(state["epoch"], max_epochs):
            if state["epochs_without_improvement"] >= preset.early_stop_patience:
                break
            progress = (EpochProgress.start(context.device) if partial is None
                        else EpochProgress.restore(partial, context.device))
            steps_left = None if args.max_steps is None else args.max_steps - state["steps"] - progress.batches
            if steps_left is not None and steps_left <= 0 and partial is None:
                break
            sampler.set_epoch(epoch)
            train_set.set_epoch(epoch)
            resumable.skip = progress.batches * batch_size
            rng = None if partial is None else partial["rng"]
            partial = None
            saved_at = time.monotonic()

            def save_now(epoch: int = epoch, progress: EpochProgress = progress, begun: dict = state,
                         rng: dict[str, Any] | None = None) -> None:
                """last.pt as of the last finished batch (`rng`: the random-number states then, if not now)."""
                save_last({**training_info, "epoch": epoch, "batch": progress.batches,
                           "steps": begun["steps"] + progress.batches},
                          {**begun, "partial": {**progress.state(), "rng": rng or _rng_state(context.device)}})

            def periodic_save() -> None:
                nonlocal saved_at
                if save_every_s > 0 and time.monotonic() - saved_at >= save_every_s:
                    save_now()
                    saved_at = time.monotonic()

            trained_rng = None  # the random-number states at the end of the training pass
            try:
                train_loss, timing = _run_epoch(model, train_loader, optimizer, autocast, memory_format, context,
                                                has_scene, f"epoch {epoch} train",
                                                None if steps_left is None else max(steps_left, 0), progress, rng,
                                                periodic_save if mid_epoch_saves else None)
                trained_rng = _rng_state(context.device)  # validation draws from the generator too
                val_loss, _ = _run_epoch(model, val_loader, None, autocast, memory_format, context, has_scene,
                                         f"epoch {epoch} val")
            except KeyboardInterrupt:
                if mid_epoch_saves:
                    save_now(rng=trained_rng)
                raise Interrupted(_stopped_message(epoch, progress.batches, len(sampler) // batch_size,
                                                   last_path, mid_epoch_saves)) from None
            with interrupts_deferred():  # the epoch's end is recorded whole
                scheduler.step(val_loss["total"])
                improved = val_loss["total"] < state["best_val"]
                state = {
                    "epoch": epoch + 1,
                    "best_val": min(val_loss["total"], state["best_val"]),
                    "epochs_without_improvement": 0 if improved else state["epochs_without_improvement"] + 1,
                    "steps": state["steps"] + timing["batches"],
                }
                if context.is_main:
                    info = {**training_info, "epoch": epoch, "steps": state["steps"], "val_loss": val_loss["total"]}
                    if improved:
                        save_checkpoint(best_path, network, preprocess, args.speed_scale, info)
                    save_last(info, state)
                    _log_epoch(args.out, epoch, optimizer.param_groups[0]["lr"], train_loss, val_loss, timing,
                               context.world_size, improved)
            barrier(context)
    except KeyboardInterrupt:  # between epochs (the epoch's end had been saved)
        if state["epoch"] == 0:
            raise Interrupted("stopped before the first batch: run the same command again") from None
        raise Interrupted(f"stopped after epoch {state['epoch'] - 1}; {last_path} holds it: run again with --resume "
                          "to continue") from None
    finally:  # also when training fails: no worker outlives it
        for loader in (train_loader, val_loader):
            _stop_workers(loader)
    return state["best_val"]


def _stopped_message(epoch: int, batches: int, epoch_batches: int, last_path: Path, saved: bool) -> str:
    if saved:
        return (f"stopped in epoch {epoch} after {batches} of {epoch_batches} batches; {last_path} holds it: run "
                "again with --resume to continue from there")
    return (f"stopped in epoch {epoch}; {last_path} holds the last epoch's end (a DDP run saves at epoch ends "
            f"only): run again with --resume to redo epoch {epoch}")


def _log_epoch(out: Path, epoch: int, lr: float, train_loss: dict[str, float], val_loss: dict[str, float],
               timing: dict[str, float], world_size: int, improved: bool) -> None:
    """metrics.csv row, refreshed loss curves, one console line."""
    samples_per_s = timing["samples"] * world_size / timing["wall"]
    append_csv_row(out / "metrics.csv", {
        "epoch": epoch, "lr": lr,
        **{f"train_{name}": value for name, value in train_loss.items()},
        **{f"val_{name}": value for name, value in val_loss.items()},
        "samples_per_s": samples_per_s, "data_time_s": timing["data"],
        "step_time_s": timing["step"], "epoch_time_s": timing["wall"], "first_batch_s": timing.get("first_batch", 0.0),
    })
    plot_loss_curves(out / "metrics.csv", out / "loss_curves.png")
    tqdm.write(f"epoch {epoch}: train {train_loss['total']:.4f} val {val_loss['total']:.4f} "
               f"({samples_per_s:.1f} samples/s, data {timing['data']:.1f} s, step {timing['step']:.1f} s)"
               f"{' *' if improved else ''}")


def _restore(path: Path, network: MSFSUNet, optimizer: torch.optim.Optimizer, scheduler: Any,
             model_config: MSFSUConfig, preprocess: PreprocessConfig, context: DistributedContext) -> dict[str, Any]:
    loaded = load_checkpoint(path, with_training_state=True)
    if loaded.model.config != model_config or loaded.preprocess != preprocess:
        raise SystemExit(f"{path} was trained as {loaded.model.config}, not {model_config}: use another --out")
    network.load_state_dict(loaded.model.state_dict())
    saved = loaded.training_state or {}
    optimizer.load_state_dict(saved["optimizer"])
    scheduler.load_state_dict(saved["scheduler"])
    torch.set_rng_state(saved["torch_rng"])
    if "cuda_rng" in saved and context.device.type == "cuda":
        torch.cuda.set_rng_state_all(saved["cuda_rng"])
    partial = saved.get("partial")  # saved inside an epoch
    if partial is not None and context.enabled:
        partial = None  # a DDP run redoes that epoch: its ranks stopped at different batches
    if context.is_main:
        where = (f"in epoch {saved['epoch']} after batch {partial['timing']['batches']}" if partial is not None
                 else f"after epoch {saved['epoch'] - 1}")
        tqdm.write(f"resuming {where} (best val {saved['best_val']:.4f})")
    return {**{key: saved[key] for key in ("epoch", "best_val", "epochs_without_improvement")},
            "steps": saved.get("steps", 0),  # runs saved before --max-steps existed counted no steps
            "partial": partial}


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    if args.num_threads:
        torch.set_num_threads(args.num_threads)
    context = init_distributed(args.device)
    try:
        with signals_interrupt():  # SIGTERM, and SIGINT also in a background job: stop after the batch, save, exit 1
            train(args, context)
    except (BagError, CacheSpaceError) as error:  # a path that is no bag, a full disk: one line, exit code 1
        raise SystemExit(f"msfsu-train: {error}") from None
    except Interrupted as stop:
        raise SystemExit(f"msfsu-train: {stop}") from None
    except KeyboardInterrupt:  # before the first epoch started: nothing trained yet
        raise SystemExit(f"msfsu-train: stopped before training started; {args.out} is as it was") from None
    finally:
        shutdown(context)


if __name__ == "__main__":
    main()
