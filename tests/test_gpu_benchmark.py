"""benchmarks/gpu.py without a GPU: --from-record rebuilds the committed report from its records, and says in one
line what is missing instead of a traceback; a measuring run on a CPU-only torch stops with one line."""

import json
from pathlib import Path

import pytest
import torch
from benchmark_reports import assert_from_record_rewrites, run_benchmark

BENCHMARK = Path(__file__).parents[1] / "benchmarks" / "gpu.py"
REPORT = BENCHMARK.with_name("gpu_results.md")


def _run(*args: str):
    return run_benchmark(BENCHMARK, *args)


def test_from_record_rewrites_the_committed_report_unchanged(tmp_path):
    out = assert_from_record_rewrites(BENCHMARK, REPORT, tmp_path)
    committed = json.loads(REPORT.with_suffix(".json").read_text())
    assert json.loads(out.with_suffix(".json").read_text())["gate"] == committed["gate"]
    assert not Path(committed["gate"]["recorded"]).is_absolute()  # the same in every checkout


def test_from_record_without_an_earlier_run_is_one_line(tmp_path):
    completed = _run("--from-record", "--out", str(tmp_path / "nowhere.md"))
    assert completed.returncode == 2
    assert completed.stderr.strip().count("\n") == 0 and "nowhere.json" in completed.stderr
    assert "Traceback" not in completed.stderr


@pytest.mark.skipif(torch.cuda.is_available(), reason="measures for real where torch sees a GPU")
def test_measuring_without_cuda_is_one_line(tmp_path):
    completed = _run("--out", str(tmp_path / "gpu.md"))
    assert completed.returncode == 2
    assert completed.stderr.strip() == "benchmarks/gpu.py: this torch sees no CUDA device"
    assert not (tmp_path / "gpu.md").exists()
