"""benchmarks/perception.py --quick: the whole benchmark (latency table, gate note, end to end) in a smoke run."""

import subprocess
import sys
from pathlib import Path

from msfsu_perception.backends import BACKENDS, SUPPORTED_PRECISIONS, is_installed

BENCHMARK = Path(__file__).parents[1] / "benchmarks" / "perception.py"


def test_quick_benchmark_reports_every_backend_and_the_end_to_end_latency(tmp_path):
    out = tmp_path / "table.md"
    completed = subprocess.run([sys.executable, str(BENCHMARK), "--quick", "--work-dir", str(tmp_path / "work"),
                                "--out", str(out)], capture_output=True, text=True, timeout=120)
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


def _benchmark_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("perception_benchmark", BENCHMARK)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_the_random_stand_in_of_a_preset_is_that_presets_network(tmp_path):
    from msfsu_perception.checkpoint import load_checkpoint
    from msfsu_perception.train import PRESETS

    checkpoint = _benchmark_module().random_checkpoint(tmp_path, "cpu")
    loaded = load_checkpoint(checkpoint)
    assert loaded.model.config == PRESETS["cpu"].model_config()
    assert (loaded.preprocess.input_height, loaded.preprocess.input_width) == (PRESETS["cpu"].input_height,
                                                                               PRESETS["cpu"].input_width)
