"""Where an int8 model's time goes: OpenVINO's per-layer counters for a checkpoint's int8 model, exported as
deployed (msfsu_perception.export.deploy_graph) and as the torch network is, side by side in one run.

    python benchmarks/int8_profile.py runs/paper_short/best.pt models/msfsu_default.pt \
        --out benchmarks/int8_profile_results.md --json benchmarks/int8_profile_results.json

Both graphs of a checkpoint are quantised the way the node quantises (its calibration frames and int8 recipe,
NNCF) and compiled the way the node compiles (OpenVINO CPU, latency hint, one stream, --threads threads). Per
graph: the wall time per inference (p50 of --iterations, counters off), and with counters on (PERF_COUNT) the
layers' time per inference split by layer type x kernel (a kernel named `..._I8` runs int8, `..._f32` float) and
the slowest layers. The 1-minute load average is printed: numbers taken under load are not comparable.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from msfsu_common.benchmark_run import BenchmarkRun, load_1min
from msfsu_evaluation.metrics import time_calls
from msfsu_evaluation.records.int8_profile import (AS_IN_TORCH, DEPLOYED, GraphProfile, Int8Profile, KindTime,
                                                   LayerTime, ProfiledModel)
from msfsu_perception.backends import OpenVinoRunner, ensure_openvino_telemetry_off, nncf_quantize, openvino_core
from msfsu_perception.checkpoint import load_checkpoint
from msfsu_perception.deploy_files import CalibrationSet, calibration_path, file_digest
from msfsu_perception.export import export_onnx
from msfsu_perception.int8_recipe import graph_layers, load_recipe, openvino_layer_names

GRAPHS = {DEPLOYED: True, AS_IN_TORCH: False}  # name: export_onnx(rewrite=...)
TOP_LAYERS = 6
WARMUP = 10  # untimed inferences before each measurement


def profile_graph(checkpoint: Path, rewrite: bool, threads: int, iterations: int, work_dir: Path) -> GraphProfile:
    """The int8 model of `checkpoint` exported with or without the deploy rewrites: wall p50 and layer times."""
    import onnx

    loaded = load_checkpoint(checkpoint)
    onnx_path = work_dir / f"{file_digest(checkpoint)}-{rewrite}.onnx"
    export_onnx(loaded.model, onnx_path, class_ids=True, rewrite=rewrite)
    float_model = openvino_core().read_model(str(onnx_path))
    layer_of = openvino_layer_names(float_model, graph_layers(onnx.load(str(onnx_path))))
    quantised = nncf_quantize(float_model, CalibrationSet.load(calibration_path(checkpoint)), load_recipe(checkpoint),
                              onnx_path)
    config = loaded.model.config
    inputs = np.random.default_rng(0).random((1, config.in_channels, config.input_height, config.input_width),
                                             np.float32)
    command = np.zeros(1, np.int64)

    runner = OpenVinoRunner(quantised, "int8", threads, None)  # compiled as the node compiles it
    wall = time_calls(lambda: runner(inputs, command), iterations, WARMUP)

    runner = OpenVinoRunner(quantised, "int8", threads, None, perf_count=True)
    for _ in range(WARMUP):
        runner(inputs, command)
    by_kind: Counter[str] = Counter()
    by_layer: Counter[tuple[str, str]] = Counter()
    for _ in range(iterations):
        runner(inputs, command)
        for info in runner.request.profiling_info:
            milliseconds = info.real_time.total_seconds() * 1e3 / iterations
            by_kind[f"{info.node_type} ({info.exec_type})"] += milliseconds
            name = layer_of.get(info.node_name) or layer_of.get(info.node_name.split("/")[0]) or info.node_name
            by_layer[(name, f"{info.node_type} ({info.exec_type})")] += milliseconds
    return GraphProfile(
        wall_p50_ms=round(wall.p50_ms, 3), layers_ms=round(sum(by_kind.values()), 3),
        by_kind=[KindTime(kind=kind, ms=round(ms, 3)) for kind, ms in by_kind.most_common() if ms >= 0.005],
        top_layers=[LayerTime(layer=name, kind=kind, ms=round(ms, 3))
                    for (name, kind), ms in by_layer.most_common(TOP_LAYERS)])


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", type=Path)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--out", type=Path, help="markdown report")
    parser.add_argument("--json", type=Path, help="the record")
    args = parser.parse_args(argv)
    missing = [str(path) for path in args.checkpoints if not calibration_path(path).is_file()]
    if missing:
        parser.error(f"no calibration frames beside {', '.join(missing)}: msfsu-calibrate <checkpoint> first")
    ensure_openvino_telemetry_off()
    run = BenchmarkRun.start("python benchmarks/int8_profile.py", argv, quoted=True)
    record = Int8Profile(**run.fields({"date": "date_start", "command": "command", "machine": "machine"}),
                         threads=args.threads, iterations=args.iterations, models=[])
    with tempfile.TemporaryDirectory() as work, tqdm(total=len(args.checkpoints) * len(GRAPHS), unit="graph") as bar:
        for checkpoint in args.checkpoints:
            model = ProfiledModel(checkpoint=str(checkpoint), checkpoint_digest=file_digest(checkpoint),
                                  load_before=load_1min(), graphs={})
            for name, rewrite in GRAPHS.items():
                model.graphs[name] = profile_graph(checkpoint, rewrite, args.threads, args.iterations, Path(work))
                bar.update()
            record.models.append(model)
    report = record.page()
    print(report)
    if args.out:
        args.out.write_text(report)
    if args.json:
        args.json.write_text(record.to_json())
    return 0


if __name__ == "__main__":
    sys.exit(main())
