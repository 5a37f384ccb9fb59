"""Episodes in parallel worker processes, each with its own simulator and ROS domain; resumable.

A worker owns one SimEnvironment (one MetaDrive engine per process, ~5.5 GB) and, while it drives a
network, that network's node graph (GraphAgent) in a ROS domain reserved for the worker
(domain_coordinator), so workers never hear each other. Every finished episode is appended to
`episodes.jsonl` (its trajectory to `trajectories/`) by the parent at once: an interrupted run resumes
by skipping the (agent, route) pairs already there. A run resumed on another CPU drives again, beside the agents
still to run on a route, that route's episodes driven elsewhere (pending): a network's episodes differ between CPUs,
so a route's agents are compared on one machine (a later record of a route replaces the earlier one). Jobs are
ordered by agent and town so a worker rarely restarts a graph or rebuilds a town. With `Settings.video`, the worker films the episodes
(`videos/<agent>/<route>.mp4`): all of them, or only the failed ones.

Two watchdogs, both ending in a restart: the parent stops all workers (SIGKILL for those that ignore
SIGTERM) and runs the unfinished episodes again in fresh ones (fresh graphs, fresh DDS participants), at
most `Settings.restarts` times. (1) Every worker stamps a shared heartbeat at each simulator step, graph
start and episode; one silent for `Settings.stall_s` is hung. (2) A graph that answers none of
graph_agent.MAX_SILENT_FRAMES frames in a row is stuck (GraphStalled; seen twice: both workers' graphs
went silent at once after hundreds of episodes while the simulators kept stepping on the control
timeout). An episode is recorded only when it finished, so a restart loses the episodes in flight, nothing
else; an episode cut by a stall is driven again from its start.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import queue
import resource
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.suites import BenchmarkRoute

EPISODES_FILE = "episodes.jsonl"
RUN_FILE = "run.json"  # what a run directory holds: route-file version, agents, shard
EXPERT = "expert"
POLL_S = 5.0
STOP_GRACE_S = 60.0  # a stopped worker closes its graph (<= 30 s) and simulator; then it is killed
VIDEO_CHOICES = ("none", "failures", "all")


class BenchmarkError(RuntimeError):
    """A worker could not run its episodes (graph did not start, simulator failed); message says why."""


class WorkerStalled(BenchmarkError):
    """A worker made no progress for Settings.stall_s (and was stopped with the others)."""


@dataclass(frozen=True)
class Agent:
    name: str
    checkpoint: Path | None = None  # None: the in-process expert
    backend: str = "auto"  # the perception node's `backend` parameter (auto: the node's default)
    precision: str = "auto"  # the perception node's `precision` parameter (auto: the node's default)
    aeb: bool = False  # the emergency brake (aeb node) between perception and control
    aeb_crossing: bool = False  # ... which also acts on obstacles moving into its corridor (predict_crossing)
    aeb_parameters: tuple[tuple[str, Any], ...] = ()  # ... and these of its parameters (sorted by name), else defaults


@dataclass(frozen=True)
class Settings:
    control_timeout_s: float = 5.0  # wall time to wait for the graph's control of a frame
    blocked_s: float = 20.0  # rules.EpisodeRules.blocked_s
    video: str = "none"  # VIDEO_CHOICES: which episodes are kept as MP4
    stall_s: float = 300.0  # a worker silent this long hangs (graph start <= 180 s, a town build < 60 s)
    restarts: int = 3  # fresh workers after a stall, at most this many times per run
    real_time_factor: float | None = None  # networks drive free-running at this factor (msfsu_sim.pacing); None: lockstep
    expert_labels: bool = True  # a network's telemetry holds the expert's action in the same state (episode.run_episode)


@dataclass(frozen=True)
class Job:
    agent: Agent
    route: BenchmarkRoute


def trajectory_path(out: Path, agent: str, route_key: str) -> Path:
    return out / "trajectories" / agent / f"{route_key.replace('/', '__')}.npy"


def telemetry_path(out: Path, agent: str, route_key: str) -> Path:
    """closed_loop.telemetry's archive of an episode, beside its trajectory."""
    return out / "telemetry" / agent / f"{route_key.replace('/', '__')}.npz"


def video_path(out: Path, agent: str, route_key: str) -> Path:
    return out / "videos" / agent / f"{route_key.replace('/', '__')}.mp4"


def drives_networks(info: dict) -> bool:
    """Whether a run directory's run.json names a network agent (a checkpoint: it drove through the node graph)."""
    return any(path is not None for path in info.get("agents", {}).values())


@dataclass(frozen=True)
class RunInfo:
    """What a run directory's run.json says its episodes were made with, a missing key read as what runs made before
    it was recorded used: the one place both resuming a run (cli) and merging runs (report) read these from."""

    routes_version: int | None
    simulator_revision: int
    graph_revision: int | None  # None: no network drove (the expert drives without the node graph)
    real_time_factor: float | None  # None: lockstep
    shard: str

    @classmethod
    def of(cls, info: dict) -> RunInfo:
        from msfsu_bringup import UNRECORDED_GRAPH_REVISION
        from msfsu_sim import UNRECORDED_REVISION

        return cls(info.get("routes_version"), info.get("simulator_revision", UNRECORDED_REVISION),
                   info.get("graph_revision", UNRECORDED_GRAPH_REVISION) if drives_networks(info) else None,
                   info.get("real_time_factor"), info.get("shard", "1/1"))


def read_episodes(out: Path) -> list[EpisodeResult]:
    """Finished episodes; a line cut off by an interruption is ignored (that episode runs again)."""
    path = out / EPISODES_FILE
    episodes = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            episodes.append(EpisodeResult.from_dict(record))
    return episodes


@dataclass(frozen=True)
class Shard:
    """Shard `index` (1-based) of `count`: a deterministic 1/count of a suite's jobs (cluster array jobs)."""

    index: int = 1
    count: int = 1

    @classmethod
    def parse(cls, text: str) -> Shard:
        """'K/N' with 1 <= K <= N; ValueError otherwise."""
        index, separator, count = text.partition("/")
        try:
            shard = cls(int(index), int(count))
        except ValueError:
            raise ValueError(f"shard must be K/N, got {text!r}") from None
        if not separator or not 1 <= shard.index <= shard.count:
            raise ValueError(f"shard must be K/N with 1 <= K <= N, got {text!r}")
        return shard

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"

    def select(self, jobs: Sequence[Job]) -> list[Job]:
        """Every count-th job of the suite in a fixed order (agent, route key), from the index-th on.

        Independent of what is done already and of the order given, so N shards are disjoint and together
        cover the suite; round-robin spreads the towns and the slow traffic tasks evenly over the shards.
        """
        ordered = sorted(jobs, key=lambda job: (job.agent.name, job.route.key))
        return ordered[self.index - 1 :: self.count]


def episode_machine(episode: EpisodeResult, run_machines: Sequence[str]) -> str | None:
    """The CPU that drove an episode: its record's, else (recorded before it was kept) its run's first machine
    (run.json "machines"); None where neither is known."""
    return episode.machine or (run_machines[0] if run_machines else None)


def pending(out: Path, jobs: Sequence[Job], machine: str | None = None,
            run_machines: Sequence[str] = ()) -> list[Job]:
    """The jobs to run: those not finished and, where `machine` (this CPU) is given, the finished jobs of every route
    that has a job to run whose episode was driven on another CPU (or one not known): they are driven again beside
    it, so each route's agents are compared on one machine. `run_machines`: run.json's "machines" (episode_machine)."""
    done = {(episode.agent, episode.route): episode_machine(episode, run_machines) for episode in read_episodes(out)}
    todo = [job for job in jobs if (job.agent.name, job.route.key) not in done]
    if machine is not None:
        routes = {job.route.key for job in todo}
        todo += [job for job in jobs if job.route.key in routes
                 and done.get((job.agent.name, job.route.key), machine) != machine]
    return sorted(todo, key=lambda job: (job.agent.name != EXPERT, job.agent.name, job.route.town, job.route.key))


def _worker(jobs: multiprocessing.Queue, results: multiprocessing.Queue, out: Path, settings: Settings,
            parent: int, heartbeat) -> None:
    """Worker process: run jobs until the None sentinel; report ("episode", EpisodeResult), ("stalled", text) or
    ("error", text).

    `heartbeat` (a shared double) gets time.monotonic() whenever the worker makes progress.

    It gets SIGTERM when the parent ends, however it ends, and then closes its graph, whose processes would
    die with it anyway.
    """
    from msfsu_common.processes import interrupt_on_signals, tie_to_parent

    tie_to_parent(parent)
    interrupt_on_signals()  # the parent's terminate(): close the graph and rclpy cleanly (no /dev/shm left)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from domain_coordinator import domain_id

    from msfsu_common.machine import describe_cpu
    from msfsu_common.ros_env import configure_ros_environment
    from msfsu_evaluation.closed_loop.episode import EpisodeVideo, ExpertDriver, run_episode
    from msfsu_evaluation.closed_loop.graph_agent import GraphAgent, GraphError, GraphStalled
    from msfsu_sim.environment import SimConfig, SimEnvironment

    def beat() -> None:
        heartbeat.value = time.monotonic()

    configure_ros_environment()
    machine = describe_cpu()
    graph: GraphAgent | None = None
    with domain_id() as domain:
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        environment = SimEnvironment(SimConfig(labels=False))  # driving needs RGB + depth only
        expert = ExpertDriver()
        ran = 0  # episodes this worker ran before the current one (recorded: an episode's history can be replayed)
        try:
            while (job := jobs.get()) is not None:
                beat()
                agent = job.agent
                video = None if settings.video == "none" else EpisodeVideo(video_path(out, agent.name, job.route.key))
                try:
                    if agent.checkpoint is not None and (graph is None or graph.name != agent.name):
                        if graph is not None:
                            graph.close()
                            graph = None
                        graph = GraphAgent(agent.name, agent.checkpoint, environment,
                                           out / "logs" / f"{agent.name}_domain{domain}.log", settings.control_timeout_s,
                                           settings.real_time_factor, backend=agent.backend,
                                           precision=agent.precision, aeb=agent.aeb,
                                           aeb_crossing=agent.aeb_crossing, aeb_parameters=dict(agent.aeb_parameters))
                        beat()
                    result, output = run_episode(environment, job.route, graph if agent.checkpoint else expert,
                                                 settings.blocked_s, video, on_step=beat,
                                                 expert_labels=settings.expert_labels)
                except BaseException as error:
                    if video is not None:
                        video.discard()
                    if not isinstance(error, GraphError):
                        raise
                    kind = "stalled" if isinstance(error, GraphStalled) else "error"
                    results.put((kind, f"{agent.name} on {job.route.key}: {error}"))
                    return
                if video is not None and (settings.video == "all" or not result.success):
                    video.close()
                elif video is not None:
                    video.discard()
                path = trajectory_path(out, agent.name, job.route.key)
                path.parent.mkdir(parents=True, exist_ok=True)
                np.save(path, output.trajectory.astype(np.float32))
                output.telemetry.save(telemetry_path(out, agent.name, job.route.key))
                peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # the simulator's process
                results.put(("episode", result.stamped(round(peak_rss_mb), domain, ran, machine)))
                ran += 1
        except KeyboardInterrupt:
            pass  # stopped by the parent (or Ctrl-C): what finished is recorded, the rest resumes later
        finally:
            if graph is not None:
                graph.close()
            environment.close()


def run_jobs(jobs: Sequence[Job], out: Path, workers: int, settings: Settings,
             target: Callable[..., None] = _worker) -> Iterator[EpisodeResult]:
    """Run the jobs (spread over `workers` processes) and yield each finished episode's result.

    A stalled worker (see the module doc) stops the workers; the jobs not finished run again in fresh
    workers, up to settings.restarts times, then WorkerStalled is raised. `target` is the worker function.
    """
    if not jobs:
        return
    out.mkdir(parents=True, exist_ok=True)
    todo = list(jobs)
    for restart in range(settings.restarts + 1):
        try:
            yield from _run_workers(todo, out, workers, settings, target)
            return
        except WorkerStalled as error:
            todo = pending(out, jobs)
            if restart == settings.restarts:
                raise WorkerStalled(f"{error}; gave up after {settings.restarts} restarts, "
                                    f"{len(todo)} episodes left (re-run to resume)") from None
            print(f"msfsu-benchmark: {error}; restarting the workers for the {len(todo)} episodes left "
                  f"({restart + 1} of {settings.restarts})", file=sys.stderr, flush=True)


def _run_workers(jobs: Sequence[Job], out: Path, workers: int, settings: Settings,
                 target: Callable[..., None]) -> Iterator[EpisodeResult]:
    context = multiprocessing.get_context("spawn")  # no inherited GL or DDS state
    job_queue, results = context.Queue(), context.Queue()
    workers = max(1, min(workers, len(jobs)))
    for job in jobs:
        job_queue.put(job)
    for _ in range(workers):
        job_queue.put(None)
    heartbeats = [context.RawValue("d", time.monotonic()) for _ in range(workers)]
    processes = [context.Process(target=target, args=(job_queue, results, out, settings, os.getpid(), heartbeat),
                                 daemon=False) for heartbeat in heartbeats]
    for process in processes:
        process.start()
    received = 0
    poll_s = min(POLL_S, settings.stall_s / 4)
    try:
        with (out / EPISODES_FILE).open("a") as log:
            while received < len(jobs):
                _check_progress(processes, heartbeats, settings.stall_s, received)
                try:
                    kind, payload = results.get(timeout=poll_s)
                except queue.Empty:
                    if not any(process.is_alive() for process in processes):
                        raise BenchmarkError(f"all workers exited with {len(jobs) - received} episodes left "
                                             f"(exit codes {[p.exitcode for p in processes]})") from None
                    continue
                if kind == "stalled":
                    raise WorkerStalled(payload)
                if kind == "error":
                    raise BenchmarkError(payload)
                log.write(json.dumps(payload.to_dict()) + "\n")
                log.flush()
                received += 1
                yield payload
    finally:  # also on KeyboardInterrupt / SIGTERM in the parent (cli.py turns SIGTERM into KeyboardInterrupt)
        for process in processes:
            if process.is_alive() and received < len(jobs):
                process.terminate()  # SIGTERM: the launcher it started gets SIGTERM too (PDEATHSIG) and stops
        for process in processes:
            process.join(STOP_GRACE_S)
            if process.is_alive():  # blocked in C code, where the SIGTERM handler never runs
                process.kill()
                process.join()
        # Jobs nobody took are still in the queue's pipe: without this the process cannot exit (its feeder thread
        # waits at exit for a reader to take them; seen with 136 jobs left). pending() finds them again on resume.
        job_queue.cancel_join_thread()


def _check_progress(processes: Sequence, heartbeats: Sequence, stall_s: float, received: int) -> None:
    now = time.monotonic()
    for index, (process, heartbeat) in enumerate(zip(processes, heartbeats)):
        if process.is_alive() and now - heartbeat.value > stall_s:
            raise WorkerStalled(f"worker {index + 1} made no progress for {now - heartbeat.value:.0f} s "
                                f"({received} episodes finished in this start)")
