"""What the tests of a benchmark's committed report share: `--from-record` rewrites it from its JSON record."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path


def run_benchmark(benchmark: Path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(benchmark), *args], capture_output=True, text=True, timeout=timeout)


def assert_from_record_rewrites(benchmark: Path, report: Path, tmp_path: Path) -> Path:
    """`benchmark --from-record` on a copy of `report`'s JSON writes `report` exactly; returns the copy's markdown."""
    out = tmp_path / report.name
    shutil.copy(report.with_suffix(".json"), out.with_suffix(".json"))
    completed = run_benchmark(benchmark, "--from-record", "--out", str(out))
    assert completed.returncode == 0, completed.stderr[-3000:]
    assert out.read_text() == report.read_text()
    return out
