"""benchmarks/soak.py in a few seconds (marked slow: `make test-all`); the 10-minute runs are benchmarks, not tests."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

SOAK = Path(__file__).parents[1] / "benchmarks" / "soak.py"


@pytest.mark.slow
def test_short_soak_traces_every_stage_and_writes_its_results(tmp_path, tiny_checkpoint):
    completed = subprocess.run([sys.executable, str(SOAK), "--minutes", "0.2", "--window-s", "6", "--rate", "10",
                                "--size", "320x240", "--checkpoint", str(tiny_checkpoint), "--out-dir", str(tmp_path)],
                               capture_output=True, text=True, timeout=300)
    assert completed.returncode == 0, completed.stdout[-3000:] + completed.stderr[-3000:]
    result = json.loads((tmp_path / "320x240_10hz.json").read_text())
    totals = result["totals"]
    assert re.fullmatch(r"cpu \w+/\w+", result["inference"]), result["inference"]  # as the node configured it
    assert totals["published"] == 120 and totals["answered"] + totals["skipped"] >= 0.9 * totals["published"]
    assert len(result["windows"]) == 2 and totals["watchdog_brakes_driving"] == 0
    stages = {row["stage"]: row for row in result["stages"]}
    for name in ("DDS: rgb to perception", "perception: network", "control: waits for its executor",
                 "since the camera stamp: VehicleControl at the measurer (end to end)"):
        assert stages[name]["n"] == totals["answered"] and stages[name]["p50"] >= 0.0, name
    assert stages["since the camera stamp: VehicleControl at the measurer (end to end)"]["max"] == totals["end_to_end_ms"]["max"]
    assert (tmp_path / "320x240_10hz.png").stat().st_size > 0
    assert "| perception: network |" in (tmp_path / "320x240_10hz.md").read_text()
