"""A pipeline's stage hours over every invocation, on every machine (written by hand: no pipeline tool keeps them).

A recipe's record directory holds `stages.jsonl` (one `records.stages.StageRecord` line per finished stage) and
`clock/<name>/<an invocation's start, epoch s>`, each holding the last second its invocation was seen alive. The clock
beats every `beat_s` while the stage runs, so a machine lost mid-stage leaves its hours but the last beat; committed
with the stage's progress, the hours spent on a lost machine count. A stage's hours are its clock's, summed over its
invocations (`records.stages.clock_hours`), written into its line when it ends.
"""

from __future__ import annotations

import os
import platform
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from msfsu_evaluation.records.stages import CLOCK_DIR, STAGES_FILE, StageRecord, clock_hours, read_stages

BEAT_S = 30


def machine() -> str:
    """This machine as a stage line names it: the CPU's model and the CPUs this process may use."""
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo") as stream:
            cpu = next((line.split(":", 1)[1].strip() for line in stream if line.startswith("model name")), cpu)
    except OSError:
        pass
    return f"{cpu}, {len(os.sched_getaffinity(0))} CPUs"


def code_commit() -> str:
    """The commit the checkout is at (short), as a stage line names the code it ran."""
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()


def _write_atomic(path: Path, seconds: int) -> None:
    partial = path.with_name(path.name + ".new")
    partial.write_text(f"{seconds}\n")
    os.replace(partial, path)


class Recording:
    """A recipe's record directory: its finished stages and their clocks.

    `lock` is held while a clock beats and while a progress commit takes the clocks (and the hours' blocks made from
    them), so that what is committed is what the files say."""

    def __init__(self, directory: Path, lock: threading.Lock | None = None, beat_s: float = BEAT_S) -> None:
        self.directory = directory
        self.stages_file = directory / STAGES_FILE
        self.clocks = directory / CLOCK_DIR
        self.lock = lock or threading.Lock()
        self.beat_s = beat_s

    def done(self, stage: str) -> bool:
        return any(record.stage == stage for record in read_stages(self.stages_file))

    @contextmanager
    def clock(self, name: str) -> Iterator[Path]:
        """One invocation of clock `name`, beating until the block ends (however it ends)."""
        started = int(time.time())
        path = self.clocks / name / str(started)
        path.parent.mkdir(parents=True, exist_ok=True)
        with self.lock:
            _write_atomic(path, started)
        stop = threading.Event()

        def beat() -> None:
            while not stop.wait(self.beat_s):
                with self.lock:
                    _write_atomic(path, int(time.time()))

        beating = threading.Thread(target=beat, name=f"clock {name}", daemon=True)
        beating.start()
        try:
            yield path
        finally:
            stop.set()
            beating.join()
            with self.lock:
                _write_atomic(path, int(time.time()))

    def finish(self, stage: str) -> StageRecord | None:
        """The stage's line, from its clock's invocations, appended unless it is there (the first measurement stays
        the record); None when it was."""
        if self.done(stage):
            return None
        directory = self.clocks / stage
        runs = {int(path.name): int(path.read_text()) for path in directory.iterdir() if path.name.isdigit()}
        record = StageRecord(stage=stage, started_utc=min(runs), ended_utc=max(runs.values()), invocations=len(runs),
                             hours=round(clock_hours(directory), 3), machine=machine(), code=code_commit())
        self.directory.mkdir(parents=True, exist_ok=True)
        with open(self.stages_file, "a") as stream:
            stream.write(record.to_line() + "\n")
        return record
