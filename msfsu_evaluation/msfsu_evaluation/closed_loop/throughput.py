"""How fast a run drove: steps per second per worker, episodes per hour, and where a step's time went.

From the episodes' records alone (EpisodeResult.wall_s, steps and timing): the per-worker rate is the run's simulator
steps over the wall seconds its workers spent in episodes (resets included), so it does not depend on how many
workers ran; episodes per hour need the leg's wall time, which only the run knows (cli records it in run.json).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from msfsu_evaluation.closed_loop.episode import STAGES
from msfsu_evaluation.closed_loop.episode_record import EpisodeResult


@dataclass(frozen=True)
class Throughput:
    """Episodes' speed: `steps` simulator steps in `episodes` episodes over `wall_s` worker seconds; per step, the mean
    milliseconds of each stage of the worker's loop (episode.STAGES) and the CPU milliseconds of each process, over
    the `timed_steps` of the episodes whose record has its timing."""

    episodes: int
    steps: int
    wall_s: float
    timed_steps: int
    stage_ms: dict[str, float]
    cpu_ms: dict[str, float]

    @property
    def steps_per_s(self) -> float:
        """Simulator steps per wall second of one worker."""
        return self.steps / self.wall_s if self.wall_s > 0 else float("nan")

    def to_dict(self) -> dict:
        return {"episodes": self.episodes, "steps": self.steps, "wall_s": round(self.wall_s, 1),
                "steps_per_s_per_worker": round(self.steps_per_s, 2), "timed_steps": self.timed_steps,
                "stage_ms_per_step": self.stage_ms, "cpu_ms_per_step": self.cpu_ms}


def throughput(episodes: Iterable[EpisodeResult]) -> Throughput:
    episodes = list(episodes)
    timed = [episode for episode in episodes if episode.timing is not None]
    timed_steps = sum(episode.steps for episode in timed)
    stage_s: dict[str, float] = {}
    cpu_s: dict[str, float] = {}
    for episode in timed:
        for stage, seconds in episode.timing.wall_s.items():
            stage_s[stage] = stage_s.get(stage, 0.0) + seconds
        for process, seconds in episode.timing.cpu_s.items():
            cpu_s[process] = cpu_s.get(process, 0.0) + seconds
    per_step = 1000.0 / max(timed_steps, 1)
    ordered = [stage for stage in STAGES if stage in stage_s] + sorted(set(stage_s) - set(STAGES))
    return Throughput(len(episodes), sum(episode.steps for episode in episodes),
                      sum(episode.wall_s for episode in episodes), timed_steps,
                      {stage: round(stage_s[stage] * per_step, 2) for stage in ordered},
                      {process: round(seconds * per_step, 2) for process, seconds in sorted(cpu_s.items())})


def by_agent(episodes: Iterable[EpisodeResult]) -> dict[str, Throughput]:
    grouped: dict[str, list[EpisodeResult]] = {}
    for episode in episodes:
        grouped.setdefault(episode.agent, []).append(episode)
    return {agent: throughput(grouped[agent]) for agent in sorted(grouped)}


def summary_line(speeds: Mapping[str, Throughput], leg_wall_s: float, workers: int) -> str:
    """The line a run prints at its end: per agent (by_agent), steps/s per worker; for the leg, episodes per hour."""
    if not speeds:
        return "throughput: no episode finished"
    agents = "; ".join(f"{agent} {speed.steps_per_s:.1f} steps/s per worker ({speed.steps} steps, "
                       f"{speed.episodes} episodes)" for agent, speed in speeds.items())
    episodes = sum(speed.episodes for speed in speeds.values())
    per_hour = episodes / leg_wall_s * 3600 if leg_wall_s > 0 else float("nan")
    return f"throughput: {agents}; {per_hour:.0f} episodes/h with {workers} workers"
