"""Recording the pending episodes of a plan, in this process or in a pool of simulator processes.

Each worker process owns one simulator (MetaDrive runs one engine per process) and the driver's network, both
kept across its episodes. Episodes that are not kept are appended to DROPPED_LOG, so a resumed run skips them.
"""

from __future__ import annotations

import json
import multiprocessing
import os
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path

from msfsu_common.processes import tie_to_parent
from msfsu_sim.collection_plan import DROPPED_LOG, Episode, pending
from msfsu_sim.environment import Quality, SimConfig, SimEnvironment
from msfsu_sim.episode_driver import EXPERT, Driver, driver_network
from msfsu_sim.episode_recording import EpisodeResult, record_episode

# (episode, output, max_steps, noise, driver, record_from, light_meshes): one episode for a worker
Job = tuple[Episode, Path, int, bool, Driver, int, bool]

_environment: SimEnvironment | None = None  # this process's simulator


def _worker_init(parent: int) -> None:
    """A pool worker dies with the parent, however the parent ends (PDEATHSIG), and only the parent takes a stop:
    the worker leaves the terminal's process group, so Ctrl-C reaches the parent alone, which then ends the pool
    (SIGTERM, on which a worker ends at once; the bag it was writing stays in .partial and is re-recorded on resume).
    In the terminal's group, each worker would die of its own KeyboardInterrupt with a traceback, and a pool that
    lost a worker's job would wait for it forever."""
    tie_to_parent(parent)
    os.setpgrp()
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def _run(job: Job) -> EpisodeResult:
    """Worker entry: one simulator (and the driver's network) per process, kept across episodes."""
    global _environment
    if _environment is None:
        _environment = SimEnvironment(SimConfig(labels=True, quality=Quality(light_meshes=job[6])))
    return record_episode(_environment, *job[:5], network=driver_network(job[4]), record_from=job[5])


def collect(output: Path, planned: list[Episode], workers: int, max_steps: int, noise: bool,
            driver: Driver = EXPERT, record_from: int = 0, light_meshes: bool = True) -> Iterator[EpisodeResult]:
    """Record the pending episodes (in `workers` processes) and yield each result as it finishes."""
    jobs = [(episode, output, max_steps, noise, driver, record_from, light_meshes)
            for episode in pending(output, planned)]
    output.mkdir(parents=True, exist_ok=True)
    if workers <= 1:
        yield from _log_dropped(output, map(_run, jobs))
        return
    # spawn: each worker owns one MetaDrive engine (one per process) and no inherited GL state.
    with multiprocessing.get_context("spawn").Pool(workers, initializer=_worker_init,
                                                    initargs=(os.getpid(),)) as pool:
        yield from _log_dropped(output, pool.imap_unordered(_run, jobs, chunksize=1))


def _log_dropped(output: Path, results: Iterator[EpisodeResult]) -> Iterator[EpisodeResult]:
    for result in results:
        if not result.kept:
            with (output / DROPPED_LOG).open("a") as log:
                log.write(json.dumps({"episode": asdict(result.episode), "reason": result.reason,
                                      "steps": result.steps}) + "\n")
        yield result
