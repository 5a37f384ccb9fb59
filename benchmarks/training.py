"""Training throughput: msfsu-train's samples/s against the model-only ceiling, in one run, on one device.

    python benchmarks/training.py                                    # cpu preset on the CPU, results beside this file
    python benchmarks/training.py --preset paper --device cuda       # the paper preset on a GPU (its GPU defaults)
    python benchmarks/training.py --preset paper --device cuda --batch-size 32 --learning-rate 3e-4   # the paper's batch
    python benchmarks/training.py --from-record                      # rewrite the markdown from its JSON record

Both on the same synthetic bags (msfsu_perception.synthetic, the preset's input size), the same model and settings
(msfsu_perception.training_settings.resolve_settings: batch, bf16, channels-last, loader workers):
  - trainer: `msfsu-train --max-steps` as a user runs it (cache built before timing; loader, augmentation,
    host -> device copy and conversion, forward, backward, optimizer step; samples/s, data wait and step time from
    its metrics.csv), run twice: N and 2N steps. The 2N-step run is the "whole run" (its start included: the loader's
    workers, the first pinned buffers, the first steps); the difference of the two runs is the steady state, the N
    steps a long epoch is made of (what starting costs, both runs pay alike and the difference cancels);
  - ceiling: N steps on one batch that already sits on the device, nothing else: what the device does alone.
The ratios say how much of the device the trainer's data path leaves unused. The load average is printed.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from msfsu_evaluation.records.training import TrainingResults, TrainingRun

if TYPE_CHECKING:
    from msfsu_perception.training_settings import Preset

DEFAULT_OUT = Path(__file__).with_name("training_results.md")


def ceiling(model: torch.nn.Module, batch, optimizer: torch.optim.Optimizer, autocast, steps: int, device) -> float:
    """Samples/s of forward + loss + backward + step on one resident batch (after 3 warm-up steps)."""
    from msfsu_perception.losses import LossConfig, msfsu_loss

    has_scene = batch.class_ids.dim() == 3

    def step() -> None:
        with autocast or nullcontext():
            output = model(batch.inputs, batch.command_index)
        terms = msfsu_loss(output, batch.steer, batch.speed, batch.class_ids if has_scene else None, LossConfig())
        optimizer.zero_grad(set_to_none=True)
        terms.total.backward()
        optimizer.step()

    model.train()
    for _ in range(3):
        step()
    if device.type == "cuda":
        torch.cuda.synchronize()
    started = time.perf_counter()
    for _ in range(steps):
        step()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return steps * len(batch.steer) / (time.perf_counter() - started)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=("cpu", "paper"), default="cpu")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument("--steps", type=int, default=30,
                        help="N: optimizer steps of the ceiling and of the steady state (the trainer runs N and 2N)")
    parser.add_argument("--batch-size", type=int)
    parser.add_argument("--learning-rate", type=float)
    parser.add_argument("--workers", type=int)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown; the JSON beside it")
    parser.add_argument("--from-record", action="store_true",
                        help="measure nothing: rewrite the markdown from the JSON beside it")
    return parser


def train_options(args: argparse.Namespace) -> list[str]:
    """The msfsu-train options of the measured settings (the preset's defaults where none is given)."""
    options = ["--preset", args.preset, "--device", args.device]
    for flag, value in (("--batch-size", args.batch_size), ("--learning-rate", args.learning_rate),
                        ("--workers", args.workers)):
        if value is not None:
            options += [flag, str(value)]
    return options


def write_bags(work: Path, preset: Preset, batch_size: int, steps: int) -> None:
    """Synthetic train bag for the 2N-step run (and a few batches more), one validation batch."""
    from msfsu_perception.synthetic import write_synthetic_bag

    frames = max(batch_size * (2 * steps + 4), 64)
    print(f"[training] {frames} synthetic frames at {preset.input_width}x{preset.input_height} ...", flush=True)
    size = {"height": preset.input_height * 2, "width": preset.input_width}  # the crop keeps the lower half
    write_synthetic_bag(work / "bags" / "train", frames, "train", seed=1, **size)
    write_synthetic_bag(work / "bags" / "validation", batch_size, "validation", seed=2, **size)


def trainer_rows(common: list[str], work: Path, steps: int) -> tuple[dict[str, str], dict[str, str]]:
    """The metrics.csv rows of msfsu-train runs of N and 2N steps."""
    import csv

    from msfsu_perception.train import main as train_main

    rows = {}
    for max_steps in (steps, 2 * steps):
        train_main([*common, "--out", str(work / f"run{max_steps}"), "--max-steps", str(max_steps)])
        with (work / f"run{max_steps}" / "metrics.csv").open() as stream:
            rows[max_steps] = next(csv.DictReader(stream))
    return rows[steps], rows[2 * steps]


def model_ceiling(work: Path, preset: Preset, probe: argparse.Namespace, device: torch.device, steps: int) -> float:
    """The ceiling's samples/s on the first batch of the cached train bag, with the trainer's model and settings."""
    from torch.utils.data import default_collate

    from msfsu_perception.bag_topics import BagTopics
    from msfsu_perception.dataset import DrivingDataset, to_device
    from msfsu_perception.frame_cache import CacheSpec, open_cache
    from msfsu_perception.model import build_model
    from msfsu_perception.preprocessing import PreprocessConfig

    preprocess = PreprocessConfig(preset.input_height, preset.input_width)
    cache = open_cache(CacheSpec((work / "bags" / "train",), BagTopics(), preprocess, True), work / "cache")
    dataset = DrivingDataset(cache, cache.valid_rows, 10.0)
    memory_format = torch.channels_last if probe.channels_last else torch.contiguous_format
    batch = to_device(default_collate([dataset[i] for i in range(probe.batch_size)]), device, memory_format)
    model = build_model(preset.model_config()).to(device, memory_format=memory_format)
    optimizer = torch.optim.NAdam(model.parameters(), lr=probe.learning_rate)
    autocast = torch.autocast(device.type, dtype=torch.bfloat16) if probe.bf16 else None
    return ceiling(model, batch, optimizer, autocast, steps, device)


def steady_state(steps: int, batch_size: int, short: dict[str, str], row: dict[str, str],
                 model_only: float) -> dict[str, float]:
    """The last N steps of the 2N-step run less the N-step run (the start both pay); empty, with a warning, when
    the difference is not positive."""
    steady_wall = float(row["epoch_time_s"]) - float(short["epoch_time_s"])
    if steady_wall <= 0:  # noise larger than N steps: a busy machine, or N too small
        print(f"[training] the {2 * steps}-step run took no longer than the {steps}-step one: no steady "
              "state measured (a busy machine, or too few --steps)", file=sys.stderr)
        return {}
    rate = steps * batch_size / steady_wall
    return {"steady_samples_per_s": round(rate, 1),
            "steady_data_wait_share": round((float(row["data_time_s"]) - float(short["data_time_s"])) / steady_wall, 3),
            "steady_share_of_ceiling": round(rate / model_only, 3)}


def device_name(device: torch.device) -> str:
    """The machine part of a row's key: the CUDA device's name, or the CPU model with its numeric flags (the flags
    decide the kernels and the cpu preset's bf16, so two CPUs of one model name but other flags are two machines)."""
    from msfsu_common.machine import cpu_model

    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    return "{} ({})".format(*cpu_model())


def measure(args: argparse.Namespace, argv: list[str] | None) -> TrainingRun:
    """Trainer runs of N and 2N steps and the ceiling, on fresh synthetic bags, as one record row."""
    from msfsu_common.benchmark_run import BenchmarkRun
    from msfsu_perception.train import main as train_main
    from msfsu_perception.training_settings import PRESETS, parse_args, resolve_settings

    preset, device, options = PRESETS[args.preset], torch.device(args.device), train_options(args)
    with tempfile.TemporaryDirectory(prefix="msfsu_training_bench_") as work:
        work = Path(work)
        probe = parse_args(["--bags", "x", "--out", "y", *options])
        resolve_settings(probe, preset, device)
        write_bags(work, preset, probe.batch_size, args.steps)
        common = ["--bags", str(work / "bags" / "*"), "--cache-dir", str(work / "cache"), *options]
        train_main([*common, "--out", str(work / "warm"), "--max-steps", "2"])  # builds the caches, warms up
        run = BenchmarkRun.start("python benchmarks/training.py", argv)
        short, row = trainer_rows(common, work, args.steps)
        model_only = model_ceiling(work, preset, probe, device, args.steps)
    trainer, wall = float(row["samples_per_s"]), float(row["epoch_time_s"])
    steady = steady_state(args.steps, probe.batch_size, short, row, model_only)
    run.end()
    return TrainingRun.from_dict({
        "date": run.date_end, "preset": args.preset, "device": args.device,
        "device_name": device_name(device),
        "cpus": len(os.sched_getaffinity(0)), "torch": torch.__version__, "batch_size": probe.batch_size,
        "learning_rate": probe.learning_rate, "bf16": probe.bf16, "channels_last": probe.channels_last,
        "workers": probe.workers, "steps": args.steps, "trainer_samples_per_s": round(trainer, 1),
        "trainer_data_wait_share": round(float(row["data_time_s"]) / wall, 3),
        "ceiling_samples_per_s": round(model_only, 1), "trainer_share_of_ceiling": round(trainer / model_only, 3),
        # waiting for the loader's first batch: its workers starting
        "first_batch_s": round(float(row["first_batch_s"]), 2), **steady,
        **run.fields({"load_before": "load_start", "load_after": "load_end", "command": "command"}),
    })


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    path = args.out.with_suffix(".json")
    if args.from_record:
        if not path.exists():
            print(f"benchmarks/training.py: --from-record needs {path}, an earlier run's record", file=sys.stderr)
            return 2
        write_report(TrainingResults.from_json(path.read_text()), args.out)
        return 0
    if args.device == "cuda" and not torch.cuda.is_available():
        print("benchmarks/training.py: --device cuda, but this torch has no CUDA device", file=sys.stderr)
        return 2
    result = measure(args, argv)
    path.parent.mkdir(parents=True, exist_ok=True)
    earlier = TrainingResults.from_json(path.read_text()) if path.exists() else TrainingResults([])
    records = earlier.replacing(result)  # a row per preset, device, machine and batch size
    path.write_text(records.to_json())
    write_report(records, args.out)
    return 0


def write_report(records: TrainingResults, out: Path) -> None:
    """The page of `records` (a row each) at `out`, printed too."""
    text = records.page()
    out.write_text(text)
    print(text, end="")


if __name__ == "__main__":
    sys.exit(main())
