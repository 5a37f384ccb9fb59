"""benchmarks/soak.py in a few seconds (marked slow: `make test-all`); the 10-minute run is a benchmark, not a test."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

SOAK = Path(__file__).parents[1] / "benchmarks" / "soak.py"


@pytest.mark.slow
def test_short_soak_writes_its_results(tmp_path, tiny_checkpoint):
    completed = subprocess.run([sys.executable, str(SOAK), "--minutes", "0.2", "--window-s", "6", "--rate", "10",
                                "--checkpoint", str(tiny_checkpoint), "--out-dir", str(tmp_path)],
                               capture_output=True, text=True, timeout=300)
    assert completed.returncode == 0, completed.stdout[-3000:] + completed.stderr[-3000:]
    result = json.loads((tmp_path / "soak_results.json").read_text())
    assert len(result["windows"]) == 2 and result["totals"]["answered"] > 0
    assert set(result["totals"]["rss_mb_end"]) == {"perception", "control"}
    assert (tmp_path / "soak_results.png").stat().st_size > 0 and "| perception |" in (tmp_path / "soak_results.md").read_text()
