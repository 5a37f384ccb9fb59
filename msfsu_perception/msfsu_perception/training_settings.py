"""`msfsu-train`: the paper's training recipe (III-B) on rosbag2 MCAP bags.

What a run is set to: the presets, the command line, and the settings it leaves open (resolve_settings).
The recipe: NAdam (lr 3e-4), ReduceLROnPlateau (factor 0.5, patience 5) on the validation loss, batch 32,
at most 100 epochs, early stop after 20 epochs without improvement. Presets:
  paper  ResNet-50 V2, 224x224 (exactly the paper);
  cpu    ResNet-18 V2, 128x128 with bf16 autocast where the CPU has bf16 (fp32 elsewhere), same recipe, so a
         model trains on 2 cores; its decoder's
         first layer has 256 filters (the paper's 512 on 2048 features; 512 -> 256 here), which keeps a
         release (fp16) under RELEASE_LIMIT_MB.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import get_args

import torch

from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.checkpoint import DEFAULT_SPEED_SCALE_MPS, read_configs
from msfsu_perception.losses import LossConfig
from msfsu_perception.model import PAPER_DECODER_FILTERS, Backbone, DecoderLayout, MSFSUConfig, Variant
from msfsu_perception.schedules import SCHEDULES


@dataclass(frozen=True)
class Preset:
    """A network size and precision with the recipe's numbers."""

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


    def model_config(self, variant: Variant = "msfsu", decoder_layout: DecoderLayout = MSFSUConfig.decoder_layout,
                     stop_output: bool = False) -> MSFSUConfig:
        """The network this preset trains."""
        return MSFSUConfig(variant, self.backbone, self.input_height, self.input_width,
                           decoder_layout=decoder_layout, decoder_filters=self.decoder_filters,
                           stop_output=stop_output)


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
    data.add_argument("--val-fraction", type=float, metavar="F",
                      help="no validation bag (e.g. one recording): hold out about this share of the training bags' "
                           "frames for validation, in blocks of about 10 s spread over each bag")
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
    parser.add_argument("--decoder-layout", choices=get_args(DecoderLayout),
                        help="v2: kernel = stride (default); v1: the paper's kernel 3, as the shipped models "
                             "(to resume or compare with them); with --init-from: the checkpoint's")
    parser.add_argument("--init-from", type=Path, metavar="CHECKPOINT",
                        help="start from these weights (a training or released checkpoint of the same variant, preset "
                             "and decoder layout) with a fresh optimizer and schedule: a warm start; once OUT/last.pt "
                             "exists, --resume continues from it instead")
    parser.add_argument("--scene-weight", type=float, default=LossConfig.scene_weight, metavar="LAMBDA3",
                        help=f"weight of the scene (segmentation) loss in the total (paper: {LossConfig.scene_weight}); "
                             "networks without a decoder have no scene loss")
    parser.add_argument("--stop-output", action="store_true",
                        help="give every branch a stop output, trained as a classification of \"the expert's target "
                             "speed is below the control's stop speed\" (the network then answers 0 m/s where it says "
                             "stop); --init-from a checkpoint without one keeps its other weights")
    parser.add_argument("--stop-weight", type=float, default=LossConfig.stop_weight, metavar="WEIGHT",
                        help="weight of the stop output's cross-entropy in the total "
                             f"(default {LossConfig.stop_weight})")
    parser.add_argument("--stop-speed-weight", type=float, default=LossConfig.stop_speed_weight, metavar="WEIGHT",
                        help="the squared speed error of frames labelled below the stop speed counts this many times "
                             f"in the speed loss (default {LossConfig.stop_speed_weight}: the paper's MSE)")
    parser.add_argument("--epochs", type=int, help="override the preset's maximum number of epochs")
    parser.add_argument("--schedule", choices=SCHEDULES, default="plateau",
                        help="learning rate: plateau (the paper's: halved after the preset's patience without a better "
                             "validation loss) or cosine (per epoch from --learning-rate down a half cosine over "
                             "--epochs; a resumed run is put at its epoch's rate)")
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
    parser.add_argument("--snapshots", type=Path, metavar="DIR",
                        help="after every epoch also write DIR/last.pt (fp16 weights, run and schedule state, no "
                             "optimizer) and DIR/best.pt (fp16): what to commit so that a lost machine costs an epoch; "
                             "--resume without OUT/last.pt goes on from DIR/last.pt with a fresh optimizer")
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
                             "did: bag_index.FocusConfig), after balancing; 0: off")
    args = parser.parse_args(argv)
    if not (args.bags or args.train_bags):
        parser.error("give --bags (split by metadata) or --train-bags and --val-bags")
    if args.val_fraction is not None and not 0 < args.val_fraction < 1:  # also NaN
        parser.error(f"--val-fraction must be between 0 and 1, got {args.val_fraction}")
    if args.max_steps is not None and args.max_steps <= 0:
        parser.error(f"--max-steps must be positive, got {args.max_steps}")
    if not args.scene_weight >= 0:  # also NaN
        parser.error(f"--scene-weight must be >= 0, got {args.scene_weight}")
    if not args.stop_weight >= 0:  # also NaN
        parser.error(f"--stop-weight must be >= 0, got {args.stop_weight}")
    if not args.stop_speed_weight > 0:  # also NaN
        parser.error(f"--stop-speed-weight must be > 0, got {args.stop_speed_weight}")
    if not args.checkpoint_every >= 0:  # also NaN
        parser.error(f"--checkpoint-every must be >= 0 minutes, got {args.checkpoint_every}")
    try:
        args.topics = BagTopics(**dict(override.split("=", 1) for override in args.topic))
    except (TypeError, ValueError) as error:
        parser.error(f"--topic takes FIELD=TOPIC with a BagTopics field: {error}")
    return args


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
    if args.decoder_layout is None:
        # a warm start takes its checkpoint's layout (CheckpointError when it is none: msfsu-train's one-line error)
        args.decoder_layout = (read_configs(args.init_from)[0].decoder_layout if args.init_from
                               else MSFSUConfig.decoder_layout)


def default_workers(device: torch.device, cpus: int | None = None) -> int:
    """Loader worker processes when --workers is not given: none on the CPU (workers would take cores from the
    training step, and a cached sample costs ~1 % of a step there); on a GPU, every CPU but one, at most 16."""
    cpus = cpus or len(os.sched_getaffinity(0))
    return 0 if device.type == "cpu" else max(1, min(16, cpus - 1))
