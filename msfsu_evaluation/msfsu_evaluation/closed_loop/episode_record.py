"""One closed-loop episode as its run directory's episodes.jsonl holds it: one JSON line per finished episode.

The benchmark writes EpisodeResult.to_dict(), json.dumps'd; every reader takes a line back with from_dict. A line
holds the fields of the record shape it was written in: a field added later reads as None, "not recorded", which
is never a recorded value:
- solid_line_crossings: None in records before routes v3 (the v2 runs, the free-running runs on v2).
- solid_lines: None in records before each crossing's start was kept; () an episode that kept them and crossed none.
- metres_by_command, metres_by_place: None in records before the progress by command and place was kept (the
  per-command and per-place rates leave those episodes out: lateral.solid_line_summary).
- free_running: None for an episode driven in lockstep.
- aeb: the emergency brake's interventions (brakes, caps, false brakes, false caps), for agents that drive with it;
  its false_caps None in records before caps were judged (the first brake's runs).
- collision_actor: who the car collided with (msfsu_sim.environment.actor_name: "crosser 1", "traffic car 7", a
  scenario's role), for collisions with a vehicle or pedestrian; None in records before it was kept.
- timing: where the episode's wall time went in the worker (stages of closed_loop.episode.STAGES, seconds) and the CPU
  seconds each process of the episode used (the worker, and each node of a network's graph); None in records before
  it was kept (closed_loop.throughput reads it).
- worker_peak_rss_mb, worker, worker_episode, machine: stamped by the worker that drove the episode (runner); worker
  and worker_episode None in records before they were kept; machine (msfsu_common.machine.describe_cpu) None in records
  before it was kept, which all ran on their run's first machine (run.json "machines"; runner.episode_machine).
A None field is not written, so to_dict gives back the line the record was read from, key for key and in order.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class SolidLineCrossing:
    """Where a solid-line crossing began (episode.RouteDistances)."""

    time_s: float
    progress_m: float  # route progress since the episode's start
    command: str  # the RoadOption name in force
    where: str  # one of lateral.SOLID_LINE_PLACES


@dataclass(frozen=True)
class FreeRunning:
    """An episode's free-running figures (msfsu_sim.pacing.RealTimePacer.record)."""

    real_time_factor: float
    achieved_real_time_factor: float
    steps: int
    late_steps: int
    steps_without_control: int
    control_age_steps: dict[str, int]  # control age in steps (str) -> steps it was applied at that age


@dataclass(frozen=True)
class AebInterventions:
    """The emergency brake's interventions in an episode (closed_loop.episode.AebCount)."""

    brakes: int  # times it started braking
    caps: int  # times it started capping the target speed
    false_brakes: int  # brakes with no vehicle or pedestrian within 15 m of the car's path ahead (ground truth)
    false_caps: int | None = None  # caps likewise; None: recorded before caps were judged (the first brake's runs)


@dataclass(frozen=True)
class EpisodeTiming:
    """Where an episode's time went (closed_loop.episode.run_episode): wall seconds per stage of the worker's loop, and
    CPU seconds (user + system) per process: "worker" (the simulator's process) and each node of the graph by name."""

    wall_s: dict[str, float]
    cpu_s: dict[str, float]


@dataclass(frozen=True)
class EpisodeResult:
    agent: str
    route: str  # BenchmarkRoute.key
    status: str
    success: bool
    time_s: float
    steps: int
    route_completion: float
    collision_type: str
    distance_to_goal_m: float
    timeout_s: float
    wall_s: float
    unanswered_frames: int  # frames the driver did not answer in time (stepped with its last control)
    free_running: FreeRunning | None = None  # None: lockstep
    solid_line_crossings: int | None = None  # times the car started touching a solid lane line (routes v3)
    solid_lines: tuple[SolidLineCrossing, ...] | None = None  # each crossing's start
    metres_by_command: dict[str, float] | None = None  # route progress driven under each command (RoadOption name)
    metres_by_place: dict[str, float] | None = None  # route progress driven in each of lateral.SOLID_LINE_PLACES
    worker_peak_rss_mb: int | None = None  # the worker process's peak resident memory when the episode ended
    worker: int | None = None  # the worker's ROS domain
    worker_episode: int | None = None  # episodes the worker drove before this one
    collision_actor: str | None = None  # who it collided with (vehicle and pedestrian collisions), "" for no one
    aeb: AebInterventions | None = None  # the emergency brake's interventions; None: the driver had none
    machine: str | None = None  # the CPU that drove it (describe_cpu); None: recorded before it was kept
    timing: EpisodeTiming | None = None  # where its wall and CPU time went; None: recorded before it was kept

    @classmethod
    def from_dict(cls, record: Mapping[str, Any]) -> EpisodeResult:
        """A line of episodes.jsonl of any record shape (module doc); TypeError: a field missing or unknown."""
        fields = dict(record)
        if (free_running := fields.get("free_running")) is not None:
            fields["free_running"] = FreeRunning(**free_running)
        if (crossings := fields.get("solid_lines")) is not None:
            fields["solid_lines"] = tuple(SolidLineCrossing(**crossing) for crossing in crossings)
        if (aeb := fields.get("aeb")) is not None:
            fields["aeb"] = AebInterventions(**aeb)
        if (timing := fields.get("timing")) is not None:
            fields["timing"] = EpisodeTiming(**timing)
        return cls(**fields)

    def to_dict(self) -> dict[str, Any]:
        """The episodes.jsonl line: every recorded field in field order, None (not recorded) left out."""
        line = {name: value for name, value in asdict(self).items() if value is not None}
        if "aeb" in line:
            line["aeb"] = {name: value for name, value in line["aeb"].items() if value is not None}
        return line

    def stamped(self, peak_rss_mb: int, worker: int, worker_episode: int, machine: str) -> EpisodeResult:
        """The record with the worker that drove it and its machine."""
        return dataclasses.replace(self, worker_peak_rss_mb=peak_rss_mb, worker=worker, worker_episode=worker_episode,
                                   machine=machine)
