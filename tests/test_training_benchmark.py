"""benchmarks/training.py: --from-record rebuilds the committed report from its record, a missing record or a missing
CUDA device is one line and exit 2, and (slow) a real run on the CPU replaces its own row and keeps the others."""

import json
from pathlib import Path

import pytest
import torch
from benchmark_reports import assert_from_record_rewrites, run_benchmark

BENCHMARK = Path(__file__).parents[1] / "benchmarks" / "training.py"
REPORT = BENCHMARK.with_name("training_results.md")


def _run(*args: str, timeout: float = 120):
    return run_benchmark(BENCHMARK, *args, timeout=timeout)


def test_from_record_rewrites_the_committed_report_unchanged(tmp_path):
    assert_from_record_rewrites(BENCHMARK, REPORT, tmp_path)


def test_from_record_without_a_record_is_one_line(tmp_path):
    completed = _run("--from-record", "--out", str(tmp_path / "none.md"))
    assert completed.returncode == 2
    assert "Traceback" not in completed.stderr
    assert completed.stderr.strip().splitlines() == [
        f"benchmarks/training.py: --from-record needs {tmp_path / 'none.json'}, an earlier run's record"]


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is there")
def test_cuda_without_a_device_is_one_line(tmp_path):
    completed = _run("--preset", "paper", "--device", "cuda", "--out", str(tmp_path / "r.md"))
    assert completed.returncode == 2
    assert completed.stderr.strip().splitlines() == [
        "benchmarks/training.py: --device cuda, but this torch has no CUDA device"]
    assert not (tmp_path / "r.json").exists()


@pytest.mark.slow
def test_a_cpu_run_replaces_its_row_and_keeps_the_others(tmp_path):
    out = tmp_path / "sub" / "training_results.md"  # a folder that does not exist yet
    out.parent.mkdir()
    committed = json.loads(REPORT.with_suffix(".json").read_text())
    out.with_suffix(".json").write_text(json.dumps(committed))
    completed = _run("--steps", "2", "--out", str(out), timeout=900)
    assert completed.returncode == 0, completed.stderr[-3000:]
    records = json.loads(out.with_suffix(".json").read_text())
    keys = [(r["preset"], r["device"], r["batch_size"]) for r in records]
    assert sorted(keys) == sorted((r["preset"], r["device"], r["batch_size"]) for r in committed)
    mine = records[-1]
    assert (mine["preset"], mine["device"], mine["steps"]) == ("cpu", "cpu", 2)
    assert mine["trainer_samples_per_s"] > 0 and mine["ceiling_samples_per_s"] > 0
    if "steady_samples_per_s" in mine:  # left out, with a warning, when the 2N-step run was not the slower
        assert mine["steady_samples_per_s"] > 0
        assert mine["steady_share_of_ceiling"] == pytest.approx(
            mine["steady_samples_per_s"] / mine["ceiling_samples_per_s"], rel=0.01)  # of rounded figures
    else:
        assert "no steady state measured" in completed.stderr
    assert [r for r in records if r is not mine] == [r for r in committed if r["device"] != "cpu"]
    assert out.read_text().count("\n| ") == len(records) + 2  # header, rule and one row per record
