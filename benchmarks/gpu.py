"""The perception network on a CUDA GPU: latency per path and per stage, and the accuracy gate of the GPU precisions.

    python benchmarks/gpu.py                         # results beside this file (gpu_results.md / .json)
    python benchmarks/gpu.py --record-gate           # also store the GPU gate verdicts of models/msfsu_default.pt
    python benchmarks/gpu.py --from-record           # anywhere: the report's gate table from the stored verdicts

Two networks: the paper's (ResNet-50 V2 at 224x224, seeded random weights: latency does not depend on them) and the
shipped default model. For each, batch 1, one call = what the perception node asks of its model:
  - eager fp32: the network's kernels launched one by one from Python (torch without a graph);
  - graph fp32 / fp16 / bf16: the same network captured in a CUDA graph (backends.cuda_graph_runner.CudaGraphRunner);
every row with the preprocessed float32 frame coming from the CPU and the outputs going back to it (numpy in, numpy
out), plus the graph's replay alone (input already on the GPU, no copy back: what the GPU does by itself).
End to end per camera frame (800x600 and 1920x1080 RGB + depth): `DrivingModel.prepare` + `predict` as the node
calls them, with the frame preprocessed on the GPU, against `preprocess_frame` on the CPU and the network on the
GPU; stages timed with synchronisation after each.
The gate: the default model's GPU precisions against torch fp32 on the CPU (the reference), on the frames of the
held-out sample bag (bags/sample), scored by `msfsu-gate --device cuda` itself; with --record-gate it stores the
verdicts in the checkpoint's GPU record (<checkpoint>.deploy/<hash>-gate-cuda.json), which precision "auto" reads
on a GPU.
Prints the GPU, torch, CUDA and the load average; exits 2 without a CUDA device.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from msfsu_common.benchmark_run import BenchmarkRun
from msfsu_evaluation.deploy.gate import GPU_PRECISIONS
from msfsu_evaluation.metrics import LatencySummary, latency_summary, time_calls
from msfsu_evaluation.records.gpu import (FRAME_STAGES, WHOLE_CALL, CameraFrame, GpuEnvironment, GpuGate, GpuGatePath,
                                          GpuRecord, Latency, NetworkCall)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = Path(__file__).with_name("gpu_results.md")
DEFAULT_MODEL = ROOT / "models" / "msfsu_default.pt"
SAMPLE_BAGS = [ROOT / "bags" / "sample"]  # one rosbag2 folder
CAMERAS = ((800, 600), (1920, 1080))
PRECISIONS = GPU_PRECISIONS  # timed, and gated against torch fp32 on the CPU


def summary(latency: LatencySummary) -> dict[str, float]:
    """A latency summary as the JSON record keeps it (ms to 3 decimals)."""
    return {key: round(value, 3) if isinstance(value, float) else value for key, value in asdict(latency).items()}


def network_rows(label: str, checkpoint: Path, iterations: int, warmup: int) -> list[NetworkCall]:
    from msfsu_perception.backends.cuda_graph_runner import CudaGraphRunner
    from msfsu_perception.checkpoint import load_checkpoint

    loaded = load_checkpoint(checkpoint)
    preprocess = loaded.preprocess
    rng = np.random.default_rng(0)
    inputs = rng.random((1, preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32)
    command = np.array([2], np.int64)
    rows = []
    for precision, graph in (("fp32", False), *((p, True) for p in PRECISIONS)):
        runner = CudaGraphRunner(loaded.model, precision, preprocess, graph=graph)
        path = f"{'graph' if graph else 'eager'} {precision}"
        whole_call = time_calls(lambda runner=runner: runner(inputs, command), iterations, warmup)
        rows.append(NetworkCall(model=label, path=path, measure=WHOLE_CALL, latency=Latency(**summary(whole_call))))
        if graph:
            def replay(graph=runner.graph) -> None:
                graph.replay()
                torch.cuda.synchronize()

            rows.append(NetworkCall(model=label, path=path, measure="graph replay alone",
                                    latency=Latency(**summary(time_calls(replay, iterations, warmup)))))
    return rows


def end_to_end_rows(label: str, checkpoint: Path, precision: str, iterations: int, warmup: int) -> list[CameraFrame]:
    """Per camera frame: GPU preprocessing (prepare) vs CPU preprocessing, the network on the GPU; stage split."""
    from msfsu_common.road_option import RoadOption
    from msfsu_perception.inference import DrivingModel
    from msfsu_perception.preprocessing import preprocess_frame, sanitize_depth

    model = DrivingModel.from_checkpoint(checkpoint, backend="torch", precision=precision, device="cuda")
    rows = []
    for width, height in CAMERAS:
        rng = np.random.default_rng(1)
        rgb = rng.integers(0, 256, (height, width, 3), np.uint8)
        depth = sanitize_depth(rng.uniform(0.5, 80.0, (height, width)).astype(np.float32))[0]
        for where in ("gpu", "cpu"):
            stages: dict[str, list[float]] = {stage: [] for stage in FRAME_STAGES}

            def frame(where=where, rgb=rgb, depth=depth, stages=stages) -> None:
                started = time.perf_counter()
                if where == "gpu":
                    inputs = model.prepare(rgb, depth)
                    torch.cuda.synchronize()
                else:
                    inputs = preprocess_frame(rgb, depth, model.preprocess)
                prepared = time.perf_counter()
                model.predict(inputs, RoadOption.LANE_FOLLOW)
                done = time.perf_counter()
                stages["preprocess"].append((prepared - started) * 1e3)
                stages["network + outputs back"].append((done - prepared) * 1e3)
                stages["frame"].append((done - started) * 1e3)

            for _ in range(warmup):
                frame()
            for values in stages.values():
                values.clear()
            for _ in range(iterations):
                frame()
            rows.append(CameraFrame(model=label, precision=precision, camera=f"{width}x{height}",
                                    preprocessing_on=where, stages={stage: Latency(**summary(latency_summary(values)))
                                                                    for stage, values in stages.items()}))
    return rows


def gate(checkpoint: Path, record: bool, work_dir: Path) -> GpuGate:
    """The GPU precisions gated by `msfsu-gate --device cuda` (the one writer of verdicts: with `record` it stores
    them in the checkpoint's GPU gate record, with its command)."""
    from msfsu_evaluation.deploy.gate import gate_argv, run_gate

    # paths as seen from here: the command is recorded with the verdicts
    argv = gate_argv(Path(os.path.relpath(checkpoint)), [os.path.relpath(bag) for bag in SAMPLE_BAGS], device="cuda")
    _, run = run_gate(argv, record, work_dir / "gate-cuda.json")
    return gate_summary(run.results, run.held_out, run.recorded)


def recorded_gate(checkpoint: Path) -> GpuGate:
    """The gate table of the checkpoint's stored GPU verdicts (what precision "auto" reads on a GPU)."""
    from msfsu_perception.deploy_files import DeployFiles
    from msfsu_perception.gate_verdicts import gate_record, results_from_record

    record = gate_record(checkpoint, "cuda")
    if not record:
        raise SystemExit(f"benchmarks/gpu.py: {checkpoint} has no GPU gate record (run with --record-gate on a GPU)")
    return gate_summary(results_from_record(record), record["held_out"], DeployFiles(checkpoint).gate_record_of("cuda"))


def gate_summary(results: list, held_out: dict, recorded: Path | None) -> GpuGate:
    """The gate rows for the report; the stored record's path relative to the repository (the committed report does
    not depend on where the checkout was)."""
    from msfsu_evaluation.closed_loop.runs import relative

    return GpuGate(held_out=held_out, recorded=None if recorded is None else relative(recorded), paths=[
        GpuGatePath(path=f"{r.backend}/{r.precision} (cuda)", frames=r.frames,
                    steer_mae_reference=r.reference.steer_mae, steer_mae=r.candidate.steer_mae,
                    steer_mae_rise=r.steer_mae_rise,
                    miou_reference=r.reference.mean_iou, miou=r.candidate.mean_iou,
                    miou_drop_points=r.miou_drop_points, steer_agreement_mae=r.steer_agreement_mae,
                    class_agreement=r.class_agreement, passed=r.passed)
        for r in results])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_MODEL, help="the model gated and timed end to end")
    parser.add_argument("--record-gate", action="store_true")
    parser.add_argument("--no-gate", action="store_true")
    parser.add_argument("--from-record", action="store_true",
                        help="no GPU needed: rewrite the report's gate table from the stored GPU verdicts")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown; the JSON beside it")
    args = parser.parse_args(argv)
    if args.from_record:
        measured = args.out.with_suffix(".json")
        if not measured.is_file():
            print(f"benchmarks/gpu.py: --from-record rewrites the report of an earlier run: no {measured}", file=sys.stderr)
            return 2
        result = GpuRecord.from_json(measured.read_text())
        result.gate = recorded_gate(args.checkpoint)
        return write(result, args.out)
    if not torch.cuda.is_available():
        print("benchmarks/gpu.py: this torch sees no CUDA device", file=sys.stderr)
        return 2
    from msfsu_perception.checkpoint import save_checkpoint
    from msfsu_perception.model import build_model
    from msfsu_perception.preprocessing import PreprocessConfig
    from msfsu_perception.training_settings import PRESETS

    run = BenchmarkRun.start("python benchmarks/gpu.py", argv)
    with tempfile.TemporaryDirectory(prefix="msfsu_gpu_bench_") as work:
        work_dir = Path(work)
        paper = work_dir / "paper.pt"
        preset = PRESETS["paper"]
        torch.manual_seed(0)
        save_checkpoint(paper, build_model(preset.model_config()).eval(),
                        PreprocessConfig(preset.input_height, preset.input_width))
        network = []
        for label, checkpoint in (("paper (R50 V2, 224)", paper), ("default (shipped)", args.checkpoint)):
            print(f"[gpu] network rows: {label}", flush=True)
            network += network_rows(label, checkpoint, args.iterations, args.warmup)
        print("[gpu] end to end", flush=True)
        end_to_end = []
        for precision in ("fp32", "fp16"):
            end_to_end += end_to_end_rows("default (shipped)", args.checkpoint, precision, args.iterations // 2,
                                          args.warmup)
        print("[gpu] gate", flush=True)
        gate_result = None if args.no_gate else gate(args.checkpoint, args.record_gate, work_dir)
    run.end()
    environment = GpuEnvironment(gpu=torch.cuda.get_device_name(), torch=torch.__version__, cuda=torch.version.cuda,
                                 cpus=len(os.sched_getaffinity(0)),
                                 **run.fields({"load_before": "load_start", "load_after": "load_end"}))
    result = GpuRecord(**run.fields({"date": "date_end", "command": "command"}), environment=environment,
                       network=network, end_to_end=end_to_end, gate=gate_result)
    return write(result, args.out)


def write(result: GpuRecord, out: Path) -> int:
    out.with_suffix(".json").write_text(result.to_json())
    page = result.page()
    out.write_text(page)
    print(page, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
