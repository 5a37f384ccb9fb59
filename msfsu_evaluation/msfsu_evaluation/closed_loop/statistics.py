"""Closed-loop statistics (ROS-free): Wilson intervals for success rates and a leaderboard-style driving score.

- Success rate per cell with the Wilson score interval (95 %): unlike the normal approximation it stays
  inside [0, 1] and is honest at 0/n and n/n, where small benchmark cells live.
- Driving score as CARLA leaderboard 1.0 defines it: per episode, route completion x infraction penalty,
  the penalty being the product of one coefficient per infraction (pedestrian 0.50, vehicle 0.60, static
  object 0.65). MetaDrive ends an episode at its first collision, so an episode has at most one; leaving
  the road ends it too and, like the leaderboard's route deviation, costs only the route not completed.
- Infractions per km driven: collisions by type and off-road ends over the distance actually driven
  (route completion x route length), summed over the cell.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

Z_95 = 1.959963984540054  # two-sided 95 % normal quantile
COLLISION_PENALTY = {"pedestrian": 0.50, "vehicle": 0.60, "object": 0.65}  # leaderboard 1.0 coefficients
INFRACTIONS = ("pedestrian", "vehicle", "object", "off_road")


@dataclass(frozen=True)
class Interval:
    low: float
    high: float

    def overlaps(self, other: Interval) -> bool:
        return self.low <= other.high and other.low <= self.high


def wilson_interval(successes: int, trials: int, z: float = Z_95) -> Interval:
    """Wilson score interval of a binomial proportion; ValueError for impossible counts."""
    if trials <= 0 or not 0 <= successes <= trials:
        raise ValueError(f"need 0 <= successes <= trials and trials > 0, got {successes}/{trials}")
    p = successes / trials
    denominator = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denominator
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denominator
    # Clamp rounding noise: at 0/n and n/n one bound is exactly 0 or 1.
    return Interval(max(0.0, centre - half) if successes else 0.0, min(1.0, centre + half) if successes < trials else 1.0)


def infraction_penalty(collision_type: str) -> float:
    """Leaderboard penalty coefficient of an episode's collision ("" = none: 1.0)."""
    if not collision_type:
        return 1.0
    if collision_type not in COLLISION_PENALTY:
        raise ValueError(f"unknown collision type {collision_type!r}; known: {', '.join(COLLISION_PENALTY)}")
    return COLLISION_PENALTY[collision_type]


def driving_score(route_completion: float, collision_type: str) -> float:
    """Route completion (0..1) x infraction penalty of one episode, 0..1."""
    return min(max(route_completion, 0.0), 1.0) * infraction_penalty(collision_type)


def infraction_of(status: str, collision_type: str) -> str | None:
    """The infraction an episode ended with (INFRACTIONS), or None."""
    if status == "collision":
        return collision_type
    if status == "off_road":
        return "off_road"
    return None


@dataclass(frozen=True)
class CellStatistics:
    episodes: int
    successes: int
    success: Interval
    route_completion: float  # mean over episodes, 0..1
    driving_score: float  # mean over episodes, 0..1
    km_driven: float
    infractions: dict[str, int]  # INFRACTIONS -> count

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes

    def infractions_per_km(self) -> dict[str, float | None]:
        """None where nothing was driven (rate undefined)."""
        return {name: (count / self.km_driven if self.km_driven > 0 else None)
                for name, count in self.infractions.items()}


def cell_statistics(episodes: Sequence[dict], route_length_m: dict[str, float]) -> CellStatistics:
    """Statistics of one cell's episodes (episode records: success, status, collision_type, route_completion)."""
    if not episodes:
        raise ValueError("a cell needs at least one episode")
    successes = sum(bool(e["success"]) for e in episodes)
    infractions = dict.fromkeys(INFRACTIONS, 0)
    for episode in episodes:
        if (kind := infraction_of(episode["status"], episode["collision_type"])) is not None:
            infractions[kind] += 1
    km = sum(e["route_completion"] * route_length_m[e["route"]] for e in episodes) / 1000.0
    return CellStatistics(
        episodes=len(episodes), successes=successes, success=wilson_interval(successes, len(episodes)),
        route_completion=sum(e["route_completion"] for e in episodes) / len(episodes),
        driving_score=sum(driving_score(e["route_completion"], e["collision_type"]) for e in episodes) / len(episodes),
        km_driven=km, infractions=infractions)
