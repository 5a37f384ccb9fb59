"""benchmarks/network.py: the committed parameter and FLOP counts (the table of docs/training.md) are what the code builds."""

import json
import subprocess
import sys
from pathlib import Path

BENCHMARK = Path(__file__).parents[1] / "benchmarks" / "network.py"
RECORD = BENCHMARK.with_name("network_results.json")


def test_sizes_of_both_decoder_layouts_match_the_committed_record_and_a_smoke_timing_runs(tmp_path):
    out = tmp_path / "network.md"
    completed = subprocess.run([sys.executable, str(BENCHMARK), "--iterations", "2", "--rounds", "1", "--warmup", "1",
                                "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert completed.returncode == 0, completed.stderr[-3000:]
    measured = json.loads(out.with_suffix(".json").read_text())
    assert measured["size"] == json.loads(RECORD.read_text())["size"]
    by_layout = {(row["preset"], row["decoder_layout"]): row for row in measured["size"]}
    assert by_layout[("paper", "v1")]["decoder_kernels"] == [3, 3, 3, 3, 3]
    assert by_layout[("paper", "v2")]["decoder_kernels"] == [4, 2, 2, 2, 3]
    assert set(measured["latency"]["presets"]["cpu"]) == {"v1 network", "v1 decoder", "v2 network", "v2 decoder"}
    assert "load average" in measured["latency"]["uptime_before"] and "| cpu | v2 decoder |" in out.read_text()
