"""Size and speed of the network per training preset and decoder layout: parameters, GFLOP/frame, torch latency.

    python benchmarks/network.py                          # writes benchmarks/network_results.{md,json}
    python benchmarks/network.py --latency-presets cpu paper --iterations 200 --out /tmp/network.md

MSFSU variant, batch 1. Parameters and FLOPs are exact for the architecture (`torch.utils.flop_counter`:
2 FLOPs per multiply-add of the convolutions, transposed convolutions and linear layers; BN, ReLU and
pooling are not counted). Latency: torch eager fp32 on the CPU, random weights (seed 0) in eval mode under
inference_mode, `--threads` intra-op threads, of the whole network and of the decoder alone (on the
encoder's features); the layouts are timed in alternating rounds, so load from other work on the machine
falls on both alike. `uptime` is recorded before and after the timing: on a
shared machine the latencies are noisy, compare them only within one run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path
from typing import get_args

import torch
from torch.utils.flop_counter import FlopCounterMode

from msfsu_common.benchmark_run import BenchmarkRun, percentiles
from msfsu_evaluation.records.network import NetworkLatency, NetworkRecord, NetworkSize
from msfsu_perception.checkpoint import save_checkpoint
from msfsu_perception.model import DecoderLayout, MSFSUNet, build_model
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_perception.training_settings import PRESETS, RELEASE_LIMIT_MB

DEFAULT_OUT = Path(__file__).with_name("network_results.md")
LATENCY_STATISTICS = {"p50_ms": "p50", "p90_ms": "p90", "mean_ms": "mean", "calls": "n"}  # per layout
LAYOUTS: tuple[DecoderLayout, ...] = get_args(DecoderLayout)


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True, check=True).stdout.strip()


def build(preset: str, layout: DecoderLayout) -> MSFSUNet:
    torch.manual_seed(0)
    return build_model(PRESETS[preset].model_config("msfsu", layout)).eval()


def example_inputs(network: MSFSUNet) -> tuple[torch.Tensor, torch.Tensor]:
    config = network.config
    return torch.rand(1, config.in_channels, config.input_height, config.input_width), torch.tensor([0])


def release_mb(network: MSFSUNet) -> float:
    """MB (10^6 bytes) of the network's release file (msfsu-release-checkpoint: fp16 storage)."""
    config = network.config
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "release.pt"
        save_checkpoint(path, network, PreprocessConfig(config.input_height, config.input_width), half=True)
        return path.stat().st_size / 1e6


def size(preset: str, layout: DecoderLayout) -> dict:
    network = build(preset, layout)
    with torch.inference_mode(), FlopCounterMode(display=False) as counter:
        network(*example_inputs(network))
    flops = {module: sum(by_op.values()) for module, by_op in counter.get_flop_counts().items()}
    config = network.config
    return {
        "preset": preset, "backbone": config.backbone, "input": f"{config.input_height}x{config.input_width}",
        "decoder_layout": layout,
        "decoder_filters": list(config.decoder_filters),
        "decoder_kernels": [layer.kernel_size[0] for layer in network.decoder.layers
                            if isinstance(layer, torch.nn.ConvTranspose2d)],
        "params_m": round(sum(p.numel() for p in network.parameters()) / 1e6, 2),
        "decoder_params_m": round(sum(p.numel() for p in network.decoder.parameters()) / 1e6, 2),
        "gflop": round(counter.get_total_flops() / 1e9, 2),
        "decoder_gflop": round(flops["MSFSUNet.decoder"] / 1e9, 2),
        "release_mb": round(release_mb(network), 1),
    }


def latencies(preset: str, threads: int, iterations: int, rounds: int, warmup: int) -> dict[str, dict]:
    """p50 / p90 / mean ms per layout of the whole network and of its decoder alone (on the encoder's
    features), timed in `rounds` alternating rounds of iterations / rounds calls each."""
    torch.set_num_threads(threads)
    calls = {}
    for layout in LAYOUTS:
        network = build(preset, layout)
        inputs = example_inputs(network)
        with torch.inference_mode():
            features = network.encoder(inputs[0])
        calls[f"{layout} network"] = lambda network=network, inputs=inputs: network(*inputs)
        calls[f"{layout} decoder"] = lambda decoder=network.decoder, features=features: decoder(features)
    samples: dict[str, list[float]] = {name: [] for name in calls}
    with torch.inference_mode():
        for call in calls.values():
            for _ in range(warmup):
                call()
        for _ in range(rounds):
            for name, call in calls.items():
                for _ in range(max(1, iterations // rounds)):
                    started = time.perf_counter()
                    call()
                    samples[name].append((time.perf_counter() - started) * 1e3)
    return {name: percentiles(ms, LATENCY_STATISTICS) for name, ms in samples.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latency-presets", nargs="*", choices=sorted(PRESETS), default=["cpu"],
                        help="presets to time (none: sizes only)")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch intra-op threads for the timing (1: steadier when other work shares the cores)")
    parser.add_argument("--iterations", type=int, default=200, help="timed calls per layout")
    parser.add_argument("--rounds", type=int, default=10, help="alternating rounds the calls are split into")
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown; JSON beside it")
    args = parser.parse_args(argv)
    run = BenchmarkRun.start("python benchmarks/network.py", argv or [])  # the command line: argv's arguments only
    sizes = [size(preset, layout) for preset in sorted(PRESETS) for layout in LAYOUTS]
    for row in sizes:
        print(json.dumps(row), flush=True)
    before = uptime()
    print(before, flush=True)
    timed = {preset: latencies(preset, args.threads, args.iterations, args.rounds, args.warmup)
             for preset in args.latency_presets}
    after = uptime()
    print(json.dumps(timed), flush=True)
    print(after, flush=True)
    record = NetworkRecord(**run.end().fields({"measured_at": "date_end", "command": "command"}),
                           torch=torch.__version__, size=[NetworkSize.from_dict(row) for row in sizes],
                           latency=NetworkLatency(threads=args.threads, rounds=args.rounds, uptime_before=before,
                                                  uptime_after=after, presets=timed))
    args.out.write_text(record.page(RELEASE_LIMIT_MB))
    args.out.with_suffix(".json").write_text(record.to_json())
    print(f"wrote {args.out} and {args.out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
