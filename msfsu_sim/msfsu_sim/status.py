"""Live status of a simulator run (ROS-free; the sim_bridge node logs its lines).

A line every `period_s` of simulated time: episode, sim time, route progress / length, speed, command,
steps taken in lockstep vs after a control timeout (free-running: with the control of their frame vs an
older one), simulator frames per wall second. One line when an
episode ends (outcome, time to goal when it arrived) and a summary when the run ends.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

from msfsu_sim.environment import Observation


def outcome_of(obs: Observation) -> str:
    if obs.arrived:
        return "arrived"
    if obs.collision:
        return f"collision ({obs.collision_type})" if obs.collision_type else "collision"
    return "out of road" if obs.out_of_road else "running"


@dataclass
class _Steps:
    lockstep: int = 0  # free-running: with the control of their own frame
    timeout: int = 0  # free-running: with an older control (or none)
    free_running: bool = False

    def __str__(self) -> str:
        if self.free_running:
            return f"steps {self.lockstep} with their frame's control / {self.timeout} with an older one"
        return f"steps {self.lockstep} lockstep / {self.timeout} timeout"


class RunStatus:
    """Feed it every episode start, step and end; it returns the lines to log (None: nothing due)."""

    def __init__(self, period_s: float = 5.0, episodes: int = 0, clock: Callable[[], float] = time.monotonic,
                 free_running: bool = False) -> None:
        self.period_s, self.episodes, self.clock, self.free_running = period_s, episodes, clock, free_running
        self.episode = -1
        self.route_length_m = 0.0
        self.outcomes: Counter[str] = Counter()
        self.times_to_goal: list[float] = []
        self.total = _Steps(free_running=free_running)
        self.started: float | None = None  # wall time of the first episode's first frame

    @property
    def finished(self) -> bool:
        """All the episodes asked for have ended (never, when `episodes` is 0)."""
        return 0 < self.episodes <= sum(self.outcomes.values())

    def start_episode(self, route_length_m: float) -> None:
        self.episode += 1
        self.route_length_m = route_length_m
        if self.started is None:
            self.started = self.clock()
        self.steps = _Steps(free_running=self.free_running)
        self._next_line_s = self.period_s
        self._window = (self.clock(), 0)  # wall time and steps at the last line

    def step(self, obs: Observation, lockstep: bool) -> str | None:
        """Count one simulator step (answered in lockstep, or after the control timeout); a status line when due."""
        for steps in (self.steps, self.total):
            if lockstep:
                steps.lockstep += 1
            else:
                steps.timeout += 1
        if self.period_s <= 0 or obs.time_s + 1e-9 < self._next_line_s or obs.done:
            return None
        while self._next_line_s <= obs.time_s + 1e-9:
            self._next_line_s += self.period_s
        return self._line(obs)

    def end_episode(self, obs: Observation) -> str:
        outcome = outcome_of(obs)
        self.outcomes[outcome] += 1
        result = f"{outcome}, time to goal {obs.time_s:.1f} s" if obs.arrived else f"{outcome} at {obs.time_s:.1f} s"
        if obs.arrived:
            self.times_to_goal.append(obs.time_s)
        return f"{self._line(obs)} | ended: {result}"

    def summary(self) -> str:
        count = sum(self.outcomes.values())
        outcomes = ", ".join(f"{n} {name}" for name, n in self.outcomes.most_common()) or "none ended"
        goal = (f", mean time to goal {sum(self.times_to_goal) / len(self.times_to_goal):.1f} s"
                if self.times_to_goal else "")
        steps = self.total.lockstep + self.total.timeout
        rate = steps / max(self.clock() - (self.started or 0.0), 1e-9)
        return (f"{count} episode{'s' if count != 1 else ''}: {outcomes}{goal}; {self.total}, "
                f"{rate:.1f} frames/s overall (resets included)")

    def _line(self, obs: Observation) -> str:
        now, steps = self.clock(), self.steps.lockstep + self.steps.timeout
        then, steps_then = self._window
        self._window = (now, steps)
        rate = (steps - steps_then) / max(now - then, 1e-9)
        return (f"episode {self.episode} | {obs.time_s:6.1f} s | route {obs.route_progress_m:4.0f}/"
                f"{self.route_length_m:.0f} m | {obs.odometry.speed:4.1f} m/s | {obs.command.name} | "
                f"{self.steps} | {rate:.1f} frames/s")
