"""benchmarks/training.py: --from-record rebuilds the committed report from its record, a missing record or a missing
CUDA device is one line and exit 2, and (slow) a real run on the CPU replaces the row of its key (preset, device,
this machine's CPU, batch size) and keeps every other row, whichever machine runs it."""

import json
from pathlib import Path

import pytest
import torch
from benchmark_reports import assert_from_record_rewrites, run_benchmark

from msfsu_perception.training_settings import PRESETS

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


# the record rounds samples/s to 0.1 and shares to 0.001, each share computed from the unrounded figures
SAMPLES_PER_S_STEP, SHARE_STEP = 0.1, 0.001


def _ratio_bounds(numerator: float, denominator: float, step: float) -> tuple[float, float]:
    """The range of the ratio of two unrounded figures that round to `numerator` and `denominator` (> 0) on `step`:
    at a few samples/s (a slow or busy CPU) the rounding alone moves it by several per cent."""
    half = step / 2
    return (numerator - half) / (denominator + half), (numerator + half) / (denominator - half)


def _benchmark_module():
    """benchmarks/training.py as a module (it is a script, not a package)."""
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location("training_benchmark", BENCHMARK)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _record_around_this_machines_row(committed: list[dict], machine: str) -> tuple[list[dict], list[dict]]:
    """(the record a cpu preset run on `machine` starts from, the rows it must keep). The kept rows: the committed
    ones less any of the run's key, and for each field of the key a row that differs from the run's in that field
    only. Between them, second, a stale row of the run's key: the run's row must take its place, last. A merge keyed
    on fewer fields drops a kept row; one keyed on more, or appending, keeps the stale row."""
    batch = PRESETS["cpu"].batch_size
    key = {"preset": "cpu", "device": "cpu", "device_name": machine, "batch_size": batch}
    stale = {**committed[0], **key, "steps": 30, "date": "stale"}
    neighbours = [{**stale, field: other, "date": "kept"} for field, other in (
        ("preset", "paper"), ("device", "cuda"), ("device_name", f"not {machine}"), ("batch_size", 2 * batch))]
    kept = [row for row in committed if {field: row[field] for field in key} != key] + neighbours
    return kept[:1] + [stale] + kept[1:], kept


@pytest.mark.slow
def test_a_cpu_run_replaces_its_machines_row_and_keeps_the_others(tmp_path):
    out = tmp_path / "sub" / "training_results.md"  # a folder that does not exist yet
    out.parent.mkdir()
    machine = _benchmark_module().device_name(torch.device("cpu"))
    start, kept = _record_around_this_machines_row(json.loads(REPORT.with_suffix(".json").read_text()), machine)
    out.with_suffix(".json").write_text(json.dumps(start))
    completed = _run("--steps", "2", "--out", str(out), timeout=900)
    assert completed.returncode == 0, completed.stderr[-3000:]
    records = json.loads(out.with_suffix(".json").read_text())
    *others, mine = records
    assert others == kept  # in their order, unchanged; the stale row gone
    assert ((mine["preset"], mine["device"], mine["device_name"], mine["batch_size"], mine["steps"])
            == ("cpu", "cpu", machine, PRESETS["cpu"].batch_size, 2))
    assert mine["trainer_samples_per_s"] > 0 and mine["ceiling_samples_per_s"] > 0
    if "steady_samples_per_s" in mine:  # left out, with a warning, when the 2N-step run was not the slower
        assert mine["steady_samples_per_s"] > 0
        low, high = _ratio_bounds(mine["steady_samples_per_s"], mine["ceiling_samples_per_s"], SAMPLES_PER_S_STEP)
        assert low - SHARE_STEP / 2 <= mine["steady_share_of_ceiling"] <= high + SHARE_STEP / 2
    else:
        assert "no steady state measured" in completed.stderr
    assert out.read_text().count("\n| ") == len(start) + 2  # header, rule and one row per record
