"""One benchmark run's context (machine, date, command line, load average at its start and end) and one summary of
timing samples. ROS-free; every benchmark and the evaluation's records take these from here.

Rules:
- The load average is read here only (`load_averages`): a record's 1-minute figure is rounded to 2 decimals
  (`load_1min`), a page's three figures are written with 2 decimals, space-separated (`load_text`).
- A command line is '<program> <arguments>', the arguments being `argv` or, where it is None, `sys.argv[1:]`,
  joined with spaces or shell-quoted (`shlex.join`): each benchmark keeps the form its records always had.
- A run's dates are `machine.utc_stamp()` at its start and at its end, its machine `machine.describe_cpu()`.
- Each record keeps its own key names: `BenchmarkRun.fields` returns the run's values under the keys its caller names.
- A summary of samples (`percentiles`) is numpy's linear-interpolation percentiles, the mean, the count or the
  maximum, rounded to `digits` decimals, under the caller's keys in the caller's order; no samples: {}.
"""

from __future__ import annotations

import os
import shlex
import sys
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from msfsu_common.machine import describe_cpu, utc_stamp

# the summary of a latency: sample count, p50, p95, p99 and maximum (latency_trace's stage rows, the soak)
LATENCY_STATISTICS = ("n", "p50", "p95", "p99", "max")


def load_averages() -> tuple[float, float, float]:
    """The system's 1-, 5- and 15-minute load averages."""
    one, five, fifteen = os.getloadavg()
    return one, five, fifteen


def load_1min() -> float:
    """The 1-minute load average, rounded to 2 decimals (what records keep)."""
    return round(load_averages()[0], 2)


def load_text(loads: Sequence[float] | None = None) -> str:
    """'<1 min> <5 min> <15 min>' with 2 decimals each (of `loads`, by default now's)."""
    return " ".join(f"{load:.2f}" for load in (load_averages() if loads is None else loads))


def command_line(program: str, argv: Sequence[str] | None = None, *, quoted: bool = False) -> str:
    """'<program> <arguments>': `argv` (None: sys.argv[1:]) joined with spaces, or shell-quoted when `quoted` (then
    the space after the program stays when there are no arguments, as those records always had it)."""
    arguments = list(sys.argv[1:] if argv is None else argv)
    return f"{program} {shlex.join(arguments)}" if quoted else " ".join([program, *arguments])


@dataclass
class BenchmarkRun:
    """What a record says about the run that made it; `load_end` and `date_end` are set by `end()`."""

    command: str
    machine: str
    date_start: str
    load_start: float
    date_end: str | None = None
    load_end: float | None = None

    @classmethod
    def start(cls, program: str, argv: Sequence[str] | None = None, *, quoted: bool = False) -> BenchmarkRun:
        """A run starting now: its command line (`command_line`), machine, date and 1-minute load."""
        return cls(command_line(program, argv, quoted=quoted), describe_cpu(), utc_stamp(), load_1min())

    def end(self) -> BenchmarkRun:
        """Record the date and the 1-minute load at the run's end (again: later)."""
        self.date_end, self.load_end = utc_stamp(), load_1min()
        return self

    def fields(self, keys: Mapping[str, str]) -> dict[str, str | float | None]:
        """{record key: value of the attribute it names}, in the order of `keys`, e.g.
        {"date": "date_end", "load_before": "load_start"}."""
        return {key: getattr(self, attribute) for key, attribute in keys.items()}


@contextmanager
def benchmark_run(program: str, argv: Sequence[str] | None = None, *, quoted: bool = False) -> Iterator[BenchmarkRun]:
    """A BenchmarkRun started on entry and ended on a normal exit (an exception leaves it unended)."""
    run = BenchmarkRun.start(program, argv, quoted=quoted)
    yield run
    run.end()


def _statistic(values: np.ndarray, name: str) -> float:
    """'n', 'mean', 'max' or 'p<q>' (numpy's linear-interpolation percentile q) of non-empty `values`."""
    if name == "n":
        return int(values.size)
    if name == "mean":
        return float(values.mean())
    if name == "max":
        return float(values.max())
    if name.startswith("p"):
        return float(np.percentile(values, float(name[1:])))
    raise ValueError(f"unknown statistic {name!r}: n, mean, max or p<percent>")


def percentiles(samples: Sequence[float] | np.ndarray, statistics: Sequence[str] | Mapping[str, str] = LATENCY_STATISTICS,
                *, digits: int = 2) -> dict[str, float]:
    """The `statistics` of `samples` rounded to `digits` (the count as an int): a sequence of names is keyed by
    them, a mapping is {record key: statistic}, e.g. {"p50_ms": "p50", "calls": "n"}. No samples: {}."""
    values = np.asarray(samples, np.float64)
    if values.size == 0:
        return {}
    keys = statistics if isinstance(statistics, Mapping) else {name: name for name in statistics}
    return {key: value if name == "n" else round(value, digits)
            for key, name in keys.items() for value in [_statistic(values, name)]}
