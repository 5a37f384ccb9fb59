"""When a closed-loop episode ends and how it is scored (ROS-free, one call per simulator step).

- success: within `goal_m` of the destination, or MetaDrive's own arrival (on the final road, within
  5 m of its end: MetaDrive ends the episode there, so the goal distance is 5 m, not CoRL's 2 m);
- collision (by type: vehicle, pedestrian, object, and since routes v3 the static layout: sidewalk for the
  kerb, road boundary or guardrail, building) and off-road end the episode as failures. MetaDrive ends an
  episode at any collision with a vehicle, pedestrian or object, so CoRL2017 tasks count a collision as a
  failure too (stricter than CoRL2017, equal to NoCrash; the leaderboard penalises static-layout
  collisions with 0.65, statistics.py);
- solid lane lines (routes v3): every time the car starts touching a solid yellow or white line counts as
  one crossing, an infraction recorded with the episode (reported per km driven), not a failure, as the
  leaderboard counts lane invasions;
- timeout as the original benchmarks set it: CoRL2017 route_km / (10 km/h) + 10 s, NoCrash
  route_km / (5 km/h) + 20 s;
- blocked: no route progress for `blocked_s` of simulation time *without a reason to wait*. A car that
  stands behind a stopped or slow lead, or for a pedestrian on its path, or for cross traffic about to
  pass, is waiting legitimately (StepState.waiting_for, from msfsu_sim.scene on the simulator's ground
  truth): that time does not count, and only the timeout ends such an episode. Not in the paper: it ends
  an episode that could only time out (a car stopped with nothing in its way) early, to save wall time.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass



def timeout_s(route_length_m: float, speed_kmh: float, margin_s: float) -> float:
    """The time to drive the route at `speed_kmh`, plus a margin (CoRL2017: 10 km/h + 10 s, NoCrash: 5 + 20)."""
    return route_length_m / 1000.0 / speed_kmh * 3600.0 + margin_s


@dataclass(frozen=True)
class EpisodeRules:
    route_length_m: float  # from the spawn position to the destination
    timeout_s: float
    goal_m: float = 5.0
    blocked_s: float = 20.0
    progress_m: float = 1.0  # progress below this within blocked_s counts as none


@dataclass(frozen=True)
class StepState:
    """What the judge needs from one simulator step."""

    time_s: float  # since the start of the episode
    distance_to_goal_m: float
    route_progress_m: float  # along the route, from the spawn position
    collision_type: str = ""  # "" = none
    out_of_road: bool = False
    arrived: bool = False  # MetaDrive's arrival
    waiting_for: str = ""  # what the car legitimately waits for ("vehicle", "pedestrian"), "" = nothing
    static_collision: str = ""  # "sidewalk" / "building": the car strikes the static layout
    solid_line: bool = False  # the car touches a solid lane line


@dataclass(frozen=True)
class Outcome:
    status: str  # success / collision / off_road / timeout / blocked
    time_s: float
    route_completion: float  # share of the route driven, 0..1
    collision_type: str = ""
    solid_line_crossings: int = 0

    @property
    def success(self) -> bool:
        return self.status == "success"


class EpisodeJudge:
    """Feed every step to `update`; it returns the Outcome at the step that ends the episode, else None."""

    def __init__(self, rules: EpisodeRules) -> None:
        self.rules = rules
        self._best_progress = -math.inf
        self._idle_s = 0.0  # time without progress and without a reason to wait
        self._last_time: float | None = None
        self._on_solid_line = False
        self.solid_line_crossings = 0

    def update(self, step: StepState) -> Outcome | None:
        if step.solid_line and not self._on_solid_line:
            self.solid_line_crossings += 1
        self._on_solid_line = step.solid_line
        outcome = self._judge(step)
        return None if outcome is None else dataclasses.replace(outcome, solid_line_crossings=self.solid_line_crossings)

    def _judge(self, step: StepState) -> Outcome | None:
        rules = self.rules
        elapsed = 0.0 if self._last_time is None else step.time_s - self._last_time
        self._last_time = step.time_s
        if step.route_progress_m >= self._best_progress + rules.progress_m:
            self._best_progress, self._idle_s = step.route_progress_m, 0.0
        elif not step.waiting_for:
            self._idle_s += elapsed
        completion = min(max(step.route_progress_m / max(rules.route_length_m, 1e-9), 0.0), 1.0)
        if step.collision_type or step.static_collision:
            return Outcome("collision", step.time_s, completion, step.collision_type or step.static_collision)
        if step.out_of_road:
            return Outcome("off_road", step.time_s, completion)
        if step.arrived or step.distance_to_goal_m <= rules.goal_m:
            return Outcome("success", step.time_s, 1.0)
        if step.time_s >= rules.timeout_s:
            return Outcome("timeout", step.time_s, completion)
        if self._idle_s >= rules.blocked_s - 1e-9:
            return Outcome("blocked", step.time_s, completion)
        return None
