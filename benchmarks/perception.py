"""Perception speed on this CPU: every backend x precision side by side, the accuracy gate, end to end.

    python benchmarks/perception.py --out perception_benchmark.md            # random weights
    python benchmarks/perception.py --checkpoint runs/paper/best.pt --cpu-checkpoint models/msfsu_default.pt \
        --gate-bags 'data/gate/test/*' --calibration-bags 'data/sim/train/*' --record-gate \
        --out benchmarks/perception_results.md --json benchmarks/perception_results.json
    python benchmarks/perception.py --models cpu --cpu-checkpoint models/msfsu_default.pt \
        --gate-bags 'data/gate/test/*' --record-gate --iterations 0 --e2e-frames 0   # gate only, no timing
    python benchmarks/perception.py --quick                                   # smoke run (< 1 min)

1. Latency of `DrivingModel.predict` (batch 1, `--threads` intra-op threads) for the paper model
   (ResNet-50 V2, 224x224) and the `cpu` training preset (ResNet-18 V2, 128x128): p50/p95 ms, Hz and
   the speed-up over torch eager fp32 measured in the same run. Without checkpoints the weights are
   random (seed 0) and int8 is calibrated on random frames: right for speed, meaningless for accuracy.
   int8 is built the way the node builds it: the checkpoint's calibration frames and int8 recipe
   (layers kept in float: msfsu-int8-recipe).
2. The accuracy gate of every fast path when a checkpoint and held-out bags are given, run by `msfsu-gate` (the
   one writer of verdicts; frames pooled from all the bags decide, each bag's own numbers are printed beside them;
   --record-gate lets it store the verdicts, with its command, for the node's precision "auto"). Without gate
   bags, the verdicts recorded for the checkpoint are used.
3. Per model: the fastest path that passed the gate, its Hz and its speed-up over torch eager fp32 of this run.
4. End to end through DDS: a 10 Hz camera publisher (RGB + metric depth + odometry), the perception and
   control nodes in this process on a private ROS domain (LOCALHOST discovery), camera stamp ->
   VehicleControl received: p50/p95 and dropped frames.
The 1-minute load average is printed before every section: numbers taken under load are not comparable.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from msfsu_common.benchmark_run import BenchmarkRun, load_averages, load_text
from msfsu_common.road_option import RoadOption
from msfsu_evaluation.end_to_end import EndToEnd, end_to_end, end_to_end_lines
from msfsu_evaluation.metrics import LatencySummary, time_calls
from msfsu_evaluation.records.perception import (EndToEndRun, GatedPath, PathLatency, PerceptionModel,
                                                 PerceptionRecord)
from msfsu_perception.backends import SUPPORTED_PRECISIONS, Backend, BackendUnavailableError, Precision, is_installed
from msfsu_perception.calibration import DEFAULT_FRAMES as CALIBRATION_FRAMES
from msfsu_perception.deploy_files import DeployFiles, calibration_path, file_digest
from msfsu_perception.checkpoint import load_checkpoint, save_checkpoint
from msfsu_perception.gate_verdicts import REFERENCE as GATE_REFERENCE
from msfsu_perception.inference import DrivingModel
from msfsu_perception.model import build_model
from msfsu_perception.preprocessing import PreprocessConfig, preprocess_frame

# (role, training preset of the random stand-in): the paper's network and the `cpu` preset
PAPER_MODEL = ("paper", "paper")
CPU_PRESET_MODEL = ("cpu preset", "cpu")
RANDOM_CALIBRATION_FRAMES = 16


@dataclass(frozen=True)
class InferencePath:
    backend: Backend
    precision: Precision
    channels_last: bool = False

    @property
    def label(self) -> str:
        return f"{self.backend} {self.precision}" + (" channels_last" if self.channels_last else "")


REFERENCE = InferencePath(*GATE_REFERENCE)  # the gate's reference path
PATHS = (REFERENCE, InferencePath("torch", "fp32", True), InferencePath("torch", "bf16", True)) + tuple(
    InferencePath(backend, precision)
    for backend in ("onnxruntime", "openvino")
    for precision in SUPPORTED_PRECISIONS[backend]
)


def model_label(role: str, checkpoint: Path) -> str:
    config = load_checkpoint(checkpoint).model.config
    return f"{role} {config.backbone} {config.input_height}x{config.input_width}"


def load_average() -> str:
    return "load average (1/5/15 min): " + load_text()


def random_checkpoint(work_dir: Path, preset_name: str) -> Path:
    """A seeded random network of a training preset (training_settings.PRESETS), written once per network configuration
    (same file next run: cached exports stay valid)."""
    from msfsu_perception.training_settings import PRESETS

    preset = PRESETS[preset_name]
    config = preset.model_config()
    filters = "-".join(str(count) for count in config.decoder_filters)
    path = work_dir / f"random-{config.backbone}-{config.input_height}x{config.input_width}-decoder{filters}.pt"
    if not path.is_file():
        torch.manual_seed(0)
        save_checkpoint(path, build_model(config), PreprocessConfig(preset.input_height, preset.input_width))
    return path


def ensure_calibration(checkpoint: Path, bags: Sequence[str], work_dir: Path) -> None:
    """<checkpoint>.calibration.npz from the training split of `bags` as msfsu-gate's first step makes it (its
    freshness rule: kept while newer than the checkpoint); without bags, the file there, else random frames."""
    from msfsu_evaluation.deploy.gate import ensure_calibration as gate_calibration

    if bags:
        print(gate_calibration(checkpoint, bags, work_dir / "cache", CALIBRATION_FRAMES), flush=True)
        return
    path = calibration_path(checkpoint)
    if path.is_file():
        return
    preprocess = load_checkpoint(checkpoint).preprocess
    rng = np.random.default_rng(0)
    frames, height, width = RANDOM_CALIBRATION_FRAMES, preprocess.input_height, preprocess.input_width
    arrays = {"rgb": rng.integers(0, 256, (frames, 3, height, width), np.uint8),
              "command_index": np.arange(frames, dtype=np.int64) % len(RoadOption)}
    if preprocess.use_depth:
        arrays["depth"] = rng.random((frames, 1, height, width)).astype(np.float16)
    np.savez(path, **arrays)


@dataclass(frozen=True)
class LatencyRow:
    model: str
    path: InferencePath
    latency: LatencySummary | None
    note: str = ""


def measure_model(label: str, checkpoint: Path, threads: int, iterations: int, warmup: int) -> list[LatencyRow]:
    rows = []
    for path in PATHS:
        if not is_installed(path.backend):
            rows.append(LatencyRow(label, path, None, "not installed"))
            continue
        try:
            model = DrivingModel.from_checkpoint(
                checkpoint, threads, path.backend, path.precision, channels_last=path.channels_last)
        except BackendUnavailableError as error:
            rows.append(LatencyRow(label, path, None, str(error)))
            continue
        preprocess = model.preprocess
        inputs = np.random.default_rng(0).random(
            (preprocess.channels, preprocess.input_height, preprocess.input_width), dtype=np.float32)
        latency = time_calls(lambda: model.predict(inputs, RoadOption.LANE_FOLLOW), iterations, warmup)
        rows.append(LatencyRow(label, path, latency))
        print(f"  {label:14s} {path.label:28s} p50 {latency.p50_ms:7.1f} ms  p95 {latency.p95_ms:7.1f} ms",
              flush=True)
    return rows


def latency_table(rows: list[LatencyRow]) -> list[str]:
    lines = ["| model | backend / precision | p50 ms | p95 ms | Hz (p50) | speed-up vs torch fp32 |",
             "|---|---|---:|---:|---:|---:|"]
    reference = {row.model: row.latency.p50_ms for row in rows if row.path == REFERENCE and row.latency}
    for row in rows:
        if row.latency is None:
            lines.append(f"| {row.model} | {row.path.label} | - | - | - | {row.note} |")
            continue
        p50 = row.latency.p50_ms
        speedup = f"{reference[row.model] / p50:.2f}x" if row.model in reference else "-"
        lines.append(f"| {row.model} | {row.path.label} | {p50:.1f} | {row.latency.p95_ms:.1f} | "
                     f"{1e3 / p50:.1f} | {speedup} |")
    return lines


def preprocess_line(camera: tuple[int, int], sizes: Sequence[int], iterations: int) -> list[str]:
    """preprocess_frame (crop + resize + scale, RGB + depth) from camera resolution, into a reused buffer."""
    width, height = camera
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (height, width, 3), np.uint8)
    depth = rng.uniform(1.0, 80.0, (height, width)).astype(np.float32)
    parts = []
    for size in sizes:
        config = PreprocessConfig(size, size)
        out = np.empty((config.channels, size, size), np.float32)
        summary = time_calls(lambda: preprocess_frame(rgb, depth, config, out=out), iterations, 3)
        parts.append(f"{width}x{height} -> {size}x{size}: p50 {summary.p50_ms:.2f} ms, p95 {summary.p95_ms:.2f} ms")
    return ["preprocess_frame " + "; ".join(parts)]


def recorded_verdicts(checkpoint: Path) -> dict[tuple[str, str], bool]:
    """The checkpoint's recorded verdicts that hold for its files now (int8: same calibration + recipe)."""
    from msfsu_perception.backends import int8_build
    from msfsu_perception.gate_verdicts import gate_verdicts, gated_precisions

    build = int8_build(checkpoint)
    verdicts = {}
    for (backend, precision), entry in gate_verdicts(checkpoint).items():
        verdicts[(backend, precision)] = precision in gated_precisions(checkpoint, backend, build)
    return verdicts


@dataclass(frozen=True)
class FastestGated:
    model: str
    reference_p50_ms: float
    path: tuple[str, str] | None
    p50_ms: float | None
    verdicts: str  # where the verdicts came from


def fastest_gated(label: str, rows: list[LatencyRow], verdicts: dict[tuple[str, str], bool], source: str
                  ) -> FastestGated | None:
    from msfsu_perception.gate_verdicts import fastest_passing

    p50 = {(row.path.backend, row.path.precision): row.latency.p50_ms for row in rows
           if row.model == label and row.latency is not None and not row.path.channels_last}
    if (REFERENCE.backend, REFERENCE.precision) not in p50:
        return None
    path = fastest_passing(p50, verdicts)
    return FastestGated(label, p50[("torch", "fp32")], path, p50[path] if path else None, source)


def fastest_gated_lines(entries: list[FastestGated]) -> list[str]:
    lines = ["| model | torch fp32 (eager) | fastest path that passed the gate | p50 ms | Hz (p50) | "
             "speed-up vs torch fp32 | verdicts |", "|---|---|---|---:|---:|---:|---|"]
    for entry in entries:
        reference = f"{entry.reference_p50_ms:.1f} ms ({1e3 / entry.reference_p50_ms:.1f} Hz)"
        backend, precision = entry.path
        lines.append(f"| {entry.model} | {reference} | {backend} {precision} | {entry.p50_ms:.1f} | "
                     f"{1e3 / entry.p50_ms:.1f} | {entry.reference_p50_ms / entry.p50_ms:.2f}x | {entry.verdicts} |")
    return lines


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", type=Path, help="paper model (R50 224) checkpoint; default random weights")
    parser.add_argument("--cpu-checkpoint", type=Path, help="`cpu` preset checkpoint; default random weights")
    parser.add_argument("--gate-bags", "--held-out-bag", nargs="+", default=[],
                        help="held-out bags/globs (with class ids) the accuracy gate pools (scripts/gate_bags.sh)")
    parser.add_argument("--calibration-bags", nargs="+", default=[],
                        help="bags/globs whose 'train' split calibrates int8 (when no calibration file exists)")
    parser.add_argument("--record-gate", action="store_true", help="store gate verdicts next to the checkpoint")
    parser.add_argument("--gate-frames", type=int, help="at most this many frames per gate bag, evenly spaced "
                        "(default all)")
    parser.add_argument("--json", type=Path, help="also write the timings and gate summary as JSON here "
                        "(msfsu-results-blocks reads benchmarks/perception_results.json)")
    parser.add_argument("--threads", type=int, default=2, help="intra-op threads")
    parser.add_argument("--iterations", type=int, default=40, help="timed calls per path (0: no timing)")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--camera", default="800x600", help="end-to-end camera resolution WxH")
    parser.add_argument("--e2e-frames", type=int, default=100, help="frames sent in the end-to-end run (0: skip)")
    parser.add_argument("--e2e-rate", type=float, default=10.0, help="camera rate, Hz")
    parser.add_argument("--e2e-backend", default="auto")
    parser.add_argument("--e2e-precision", nargs="+", default=["auto"], help="one end-to-end run per precision")
    parser.add_argument("--work-dir", type=Path, default=Path(tempfile.gettempdir()) / "msfsu-benchmark",
                        help="random checkpoints, their exported models and frame caches")
    parser.add_argument("--out", type=Path, help="also write the report as markdown here")
    parser.add_argument("--models", nargs="+", choices=("paper", "cpu"), default=["paper", "cpu"],
                        help="which networks to time (and gate, when their checkpoint is given)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: cpu preset only, 3 iterations, 10 end-to-end frames at 224x224")
    args = parser.parse_args(argv)
    if args.quick:
        args.iterations, args.warmup, args.e2e_frames, args.camera = 3, 3, min(args.e2e_frames, 10), "224x224"
        args.models = ["cpu"]
    args.camera = tuple(int(value) for value in args.camera.lower().split("x"))
    return args


def gated_path(entry: FastestGated | None) -> GatedPath | None:
    """The record's fastest gated path; None without one (random weights, nothing timed)."""
    if entry is None or entry.path is None:
        return None
    return GatedPath(path=" ".join(entry.path), p50_ms=round(entry.p50_ms, 3), hz=round(1e3 / entry.p50_ms, 1),
                     speedup_vs_torch_fp32=round(entry.reference_p50_ms / entry.p50_ms, 2))


def model_record(label: str, checkpoint: Path, given: bool, rows: list[LatencyRow], load: tuple[float, ...],
                 best: FastestGated | None, verdicts: tuple[dict, str]) -> PerceptionModel:
    """One model's timings and verdicts as the record keeps them (ms to 3 decimals)."""
    passed, source = verdicts
    return PerceptionModel(
        model=label, checkpoint=str(checkpoint) if given else None,
        checkpoint_digest=file_digest(checkpoint) if given else None,
        load_average_before=[round(value, 2) for value in load],
        paths={row.path.label: PathLatency(p50_ms=round(row.latency.p50_ms, 3), p95_ms=round(row.latency.p95_ms, 3))
               for row in rows if row.model == label and row.latency is not None},
        verdicts={f"{backend} {precision}": ok for (backend, precision), ok in sorted(passed.items())},
        verdict_source=source, fastest_gated=gated_path(best))


def end_to_end_record(result: EndToEnd) -> EndToEndRun:
    latency = result.latency
    return EndToEndRun(backend=result.backend, precision=result.precision, sent=result.sent, dropped=result.dropped,
                       p50_ms=None if latency is None else round(latency.p50_ms, 2),
                       p95_ms=None if latency is None else round(latency.p95_ms, 2))


def json_record(run: BenchmarkRun, args: argparse.Namespace, models: list, rows: list[LatencyRow],
                loads: dict[str, tuple[float, ...]], fastest: list[FastestGated],
                verdicts: dict[str, tuple[dict, str]], e2e: list[EndToEnd]) -> PerceptionRecord:
    entries = []
    for label, checkpoint, given in models:
        best = next((entry for entry in fastest if entry.model == label), None)
        found = verdicts.get(label, ({}, "random weights: no verdicts"))
        entries.append(model_record(label, checkpoint, given, rows, loads[label], best, found))
    return PerceptionRecord(**run.fields({"date": "date_end", "command": "command", "machine": "machine"}),
                            threads=args.threads, iterations=args.iterations, torch=torch.__version__, models=entries,
                            end_to_end=[end_to_end_record(result) for result in e2e])


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    run = BenchmarkRun.start("python benchmarks/perception.py", argv, quoted=True)
    command = run.command
    args.work_dir.mkdir(parents=True, exist_ok=True)
    report = [f"# Perception benchmark {run.date_start}", "",
              f"Made by `{command}`", "",
              f"{run.machine}, {args.threads} intra-op threads, "
              f"torch {torch.__version__}, python {sys.version.split()[0]}", ""]
    print("\n".join(report), flush=True)
    roles = [(PAPER_MODEL, args.checkpoint)] if "paper" in args.models else []
    roles += [(CPU_PRESET_MODEL, args.cpu_checkpoint)] if "cpu" in args.models else []
    models = [(model_label(role, checkpoint), checkpoint, given is not None) for (role, preset), given in roles
              for checkpoint in [given or random_checkpoint(args.work_dir, preset)]]
    rows: list[LatencyRow] = []
    loads: dict[str, tuple[float, ...]] = {}
    for label, checkpoint, given in models:
        ensure_calibration(checkpoint, args.calibration_bags, args.work_dir)
        loads[label] = load_averages()
        print(load_average(), flush=True)
        report.append(f"{label}: {checkpoint if given else 'random weights'}; {load_average()}")
        if args.iterations > 0:
            rows += measure_model(label, checkpoint, args.threads, args.iterations, args.warmup)
    if rows:
        sizes = sorted({load_checkpoint(checkpoint).preprocess.input_height for _, checkpoint, _ in models})
        report += ["", *latency_table(rows), "", *preprocess_line(args.camera, sizes, 20)]
    verdicts: dict[str, tuple[dict, str]] = {}
    for label, checkpoint, given in models:
        if not given:
            continue
        if args.gate_bags:
            from msfsu_evaluation.deploy.gate import gate_argv, run_gate

            lines, gate_run = run_gate(gate_argv(checkpoint, args.gate_bags, threads=args.threads,
                                                 frames_per_bag=args.gate_frames),
                                       args.record_gate, args.work_dir / f"gate-{label.replace(' ', '_')}.json")
            results = gate_run.results
            report += ["", load_average(), *lines]
            verdicts[label] = ({(r.backend, r.precision): r.passed for r in results}, "this run")
        else:
            recorded = recorded_verdicts(checkpoint)
            verdicts[label] = (recorded, f"recorded ({DeployFiles(checkpoint).gate_record.name})" if recorded
                               else "none recorded")
    if not verdicts:
        report += ["", "Accuracy gate: pending (needs --checkpoint/--cpu-checkpoint; --gate-bags or recorded verdicts)."]
    fastest = [entry for label, _, given in models if given  # random weights have no verdicts
               for entry in [fastest_gated(label, rows, *verdicts[label])] if entry is not None]
    if fastest:
        report += ["", "Fastest path that passed the accuracy gate (torch fp32 is the reference and always counts), "
                       "timed in this run:", "", *fastest_gated_lines(fastest)]
    label, checkpoint, _ = models[0]
    e2e = []
    for precision in args.e2e_precision if args.e2e_frames else []:
        report += ["", f"{load_average()} (before end to end, {label})"]
        e2e.append(end_to_end(checkpoint, args.e2e_backend, precision, args.threads, args.camera,
                              args.e2e_frames, args.e2e_rate))
        report += end_to_end_lines(e2e[-1], args.camera, args.e2e_rate)
    report += ["", load_average() + " (at the end)"]
    text = "\n".join(report) + "\n"
    print("\n" + text)
    if args.out is not None:
        args.out.write_text(text)
    if args.json is not None:
        args.json.write_text(json_record(run.end(), args, models, rows, loads, fastest, verdicts, e2e).to_json())


if __name__ == "__main__":
    main()
