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
