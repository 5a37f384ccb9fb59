"""benchmarks/perception.py --quick: the whole benchmark (latency table, gate note, end to end) in a smoke run."""

import subprocess
import sys
from pathlib import Path

from msfsu_evaluation.records.perception import PerceptionRecord
from msfsu_perception.backends import BACKENDS, SUPPORTED_PRECISIONS, is_installed

BENCHMARK = Path(__file__).parents[1] / "benchmarks" / "perception.py"


def test_quick_benchmark_reports_every_backend_and_the_end_to_end_latency(tmp_path):
    out = tmp_path / "table.md"
    completed = subprocess.run([sys.executable, str(BENCHMARK), "--quick", "--work-dir", str(tmp_path / "work"),
                                "--out", str(out), "--json", str(tmp_path / "record.json")],
                               capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0, completed.stderr[-3000:]
    report = out.read_text()
    for backend in BACKENDS:
        for precision in SUPPORTED_PRECISIONS[backend]:
            prefix = f"| cpu preset resnet18v2 128x128 | {backend} {precision}"
            row = next(line for line in report.splitlines() if line.startswith(prefix))
            assert ("not installed" in row) != is_installed(backend), row
    assert "| cpu preset resnet18v2 128x128 | torch fp32 |" in report and "| 1.00x |" in report
    assert "load average" in report and "Accuracy gate: pending" in report
    assert "End to end (camera stamp -> VehicleControl" in report and "of 10 frames dropped" in report
    text = (tmp_path / "record.json").read_text()
    record = PerceptionRecord.from_json(text)
    assert record.to_json() == text and record.iterations == 3 and [run.sent for run in record.end_to_end] == [10]
    [model] = record.models  # random weights: no checkpoint, no verdicts
    assert model.checkpoint is None and model.fastest_gated is None and "torch fp32" in model.paths


def _benchmark_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("perception_benchmark", BENCHMARK)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_the_random_stand_in_of_a_preset_is_that_presets_network(tmp_path):
    from msfsu_perception.checkpoint import load_checkpoint
    from msfsu_perception.training_settings import PRESETS

    checkpoint = _benchmark_module().random_checkpoint(tmp_path, "cpu")
    loaded = load_checkpoint(checkpoint)
    assert loaded.model.config == PRESETS["cpu"].model_config()
    assert (loaded.preprocess.input_height, loaded.preprocess.input_width) == (PRESETS["cpu"].input_height,
                                                                               PRESETS["cpu"].input_width)


def test_the_benchmarks_gate_is_msfsu_gates_and_records_the_benchmarks_command(tiny_checkpoint, tmp_path):
    import shutil

    from msfsu_perception.gate_verdicts import gate_record
    from msfsu_perception.synthetic import write_synthetic_bag

    checkpoint = tmp_path / "tiny.pt"
    shutil.copyfile(tiny_checkpoint, checkpoint)
    write_synthetic_bag(tmp_path / "gate_bag", n_frames=4, split="test")
    args = ["--models", "cpu", "--cpu-checkpoint", str(checkpoint), "--gate-bags", str(tmp_path / "gate_bag"),
            "--record-gate", "--iterations", "0", "--e2e-frames", "0", "--threads", "1",
            "--work-dir", str(tmp_path / "work"), "--out", str(tmp_path / "gate.md")]
    completed = subprocess.run([sys.executable, str(BENCHMARK), *args], capture_output=True, text=True, timeout=300)
    assert completed.returncode == 0, completed.stderr[-3000:]
    record = gate_record(checkpoint)
    assert record["command"] == f"msfsu-gate {checkpoint} --bags {tmp_path / 'gate_bag'} --threads 1"  # its writer
    assert f"Accuracy gate of {checkpoint} on 1 held-out bags" in (tmp_path / "gate.md").read_text()
