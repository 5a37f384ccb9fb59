"""Wall time per named stage of the simulator loop (render, physics, read-back, messages, ...).

Always on: a `perf_counter` pair per stage costs ~1 µs against steps of tens of milliseconds. The simulator
benchmark and the live bridge read it to say where a step's time goes.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager


class StageClock:
    def __init__(self) -> None:
        self.seconds: defaultdict[str, float] = defaultdict(float)
        self.calls: defaultdict[str, int] = defaultdict(int)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - start)

    def add(self, name: str, seconds: float) -> None:
        self.seconds[name] += seconds
        self.calls[name] += 1

    def clear(self) -> None:
        self.seconds.clear()
        self.calls.clear()

    def ms_per(self, count: int) -> dict[str, float]:
        """Milliseconds of each stage per `count` (e.g. per step), in the order the stages first ran."""
        return {name: 1000.0 * seconds / max(count, 1) for name, seconds in self.seconds.items()}


class TimedTaskManager:
    """Stands in for MetaDrive's `engine.task_manager`: its `step()` (which renders the frame) is timed."""

    def __init__(self, task_manager: object, clock: StageClock, stage: str = "render") -> None:
        self._task_manager, self._clock, self._stage = task_manager, clock, stage

    def step(self) -> None:
        with self._clock.stage(self._stage):
            self._task_manager.step()

    def __getattr__(self, name: str) -> object:
        return getattr(self._task_manager, name)
