"""The benchmark harness: command lines in both forms, a run's start and end under the caller's keys, the one load
average reading, and the summary of samples every benchmark writes."""

import re
import sys

import numpy as np
import pytest

from msfsu_common import benchmark_run
from msfsu_common.benchmark_run import BenchmarkRun, benchmark_run as run_of, command_line, load_text, percentiles


@pytest.fixture
def loads(monkeypatch):
    """os.getloadavg as the harness sees it: a queue of readings."""
    readings = [(0.504, 0.6, 0.7), (1.256, 1.1, 1.0)]
    monkeypatch.setattr(benchmark_run.os, "getloadavg", lambda: readings.pop(0))
    return readings


def test_command_lines_keep_each_records_form(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["x.py", "--out", "a b.md"])
    assert command_line("python benchmarks/gpu.py") == "python benchmarks/gpu.py --out a b.md"
    assert command_line("python benchmarks/gpu.py", ["--n", "1"]) == "python benchmarks/gpu.py --n 1"
    assert command_line("python p.py", quoted=True) == "python p.py --out 'a b.md'"
    assert command_line("python p.py", [], quoted=True) == "python p.py "  # as those records always had it
    assert command_line("python p.py", []) == "python p.py"


def test_a_run_records_the_load_at_both_ends_under_the_callers_keys(loads):
    with run_of("python b.py", ["--x"]) as run:
        assert (run.load_start, run.load_end, run.date_end) == (0.5, None, None)
    assert run.command == "python b.py --x" and run.load_end == 1.26
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC", run.date_start) and run.date_end is not None
    assert list(run.fields({"load_before": "load_start", "load_after": "load_end", "command": "command"}).items()) == [
        ("load_before", 0.5), ("load_after", 1.26), ("command", "python b.py --x")]


def test_a_run_left_by_an_exception_has_no_end(loads):
    with pytest.raises(RuntimeError), run_of("python b.py", []) as run:
        raise RuntimeError
    assert run.load_end is None and len(loads) == 1


def test_load_text_is_three_figures_with_two_decimals(loads):
    assert load_text() == "0.50 0.60 0.70"
    assert load_text((1.0, 2.345, 3)) == "1.00 2.35 3.00"


def test_a_started_run_names_this_machine(loads):
    from msfsu_common.machine import describe_cpu

    assert BenchmarkRun.start("p", []).machine == describe_cpu()


def test_percentiles_are_numpys_rounded_under_the_callers_keys_in_its_order():
    samples = [4.0, 1.0, 3.0, 2.0, 10.0]
    assert list(percentiles(samples).items()) == [("n", 5), ("p50", 3.0), ("p95", 8.8), ("p99", 9.76), ("max", 10.0)]
    assert percentiles(samples, ("mean", "p50", "p95")) == {"mean": 4.0, "p50": 3.0, "p95": 8.8}
    assert list(percentiles(samples, {"p90_ms": "p90", "calls": "n"}, digits=1).items()) == [("p90_ms", 7.6),
                                                                                              ("calls", 5)]
    assert percentiles(np.array([])) == {}
    with pytest.raises(ValueError, match="unknown statistic"):
        percentiles(samples, ("median",))
