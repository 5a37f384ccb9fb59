"""Closed-loop statistics (ROS-free): Wilson intervals for success rates and a leaderboard-style driving score.

- Success rate per cell with the Wilson score interval (95 %): unlike the normal approximation it stays
  inside [0, 1] and is honest at 0/n and n/n, where small benchmark cells live.
- Driving score as CARLA leaderboard 1.0 defines it: per episode, route completion x infraction penalty,
  the penalty being the product of one coefficient per infraction (pedestrian 0.50, vehicle 0.60, static
  object 0.65). MetaDrive ends an episode at its first collision, so an episode has at most one; leaving
  the road ends it too and, like the leaderboard's route deviation, costs only the route not completed.
- Infractions per km driven: collisions by type (the static layout, kerb or building, as "static"),
  off-road ends and solid-line crossings over the distance actually driven (route completion x route
  length), summed over the cell. Static-layout strikes and solid-line crossings are recorded since routes
  v3 (`recorded_infractions`): a v2 report has no such columns rather than zeros it never measured.
- Two agents on the same routes (the ablation): the pairs tell more than two separate intervals, because
  only the routes where exactly one of them succeeded say which is better. The exact McNemar test (a
  two-sided binomial test of those discordant routes at 1/2) and the Newcombe (1998) method-10 interval
  of the paired difference of success rates (Wilson intervals of both rates, combined with their phi
  correlation) are reported; a pooled comparison over many routes separates agents that no 10-route
  cell can.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from msfsu_evaluation.closed_loop.episode_record import EpisodeResult

Z_95 = 1.959963984540054  # two-sided 95 % normal quantile
# leaderboard 1.0 coefficients; the static layout (kerb, boundary, guardrail: "sidewalk"; "building") is a
# static-object collision there (0.65)
COLLISION_PENALTY = {"pedestrian": 0.50, "vehicle": 0.60, "object": 0.65, "sidewalk": 0.65, "building": 0.65}
INFRACTIONS = ("pedestrian", "vehicle", "object", "static", "off_road", "solid_line")
STATIC_LAYOUT = ("sidewalk", "building")  # collision types that count as "static"
FIRST_RECORDED = {"static": 3, "solid_line": 3}  # routes version whose records first hold these


def recorded_infractions(routes_version: int) -> tuple[str, ...]:
    """The INFRACTIONS that records of this routes version hold."""
    return tuple(name for name in INFRACTIONS if FIRST_RECORDED.get(name, 0) <= routes_version)


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
        return "static" if collision_type in STATIC_LAYOUT else collision_type
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


def _count_infractions(episodes: Sequence[EpisodeResult], infractions_recorded: Sequence[str]) -> dict[str, int]:
    """Infractions of `infractions_recorded` over the episodes; ValueError where a record holds another kind, or
    solid_line is counted and a record has no solid_line_crossings."""
    infractions = dict.fromkeys(infractions_recorded, 0)
    for episode in episodes:
        if (kind := infraction_of(episode.status, episode.collision_type)) is not None:
            if kind not in infractions:
                raise ValueError(f"{episode.route}: a {kind} infraction in records said not to hold it")
            infractions[kind] += 1
        if "solid_line" in infractions:
            if episode.solid_line_crossings is None:
                raise ValueError(f"{episode.route}: no solid_line_crossings in records said to hold them")
            infractions["solid_line"] += episode.solid_line_crossings
    return infractions


def cell_statistics(episodes: Sequence[EpisodeResult], route_length_m: dict[str, float],
                    infractions_recorded: Sequence[str] = INFRACTIONS) -> CellStatistics:
    """Statistics of one cell's episodes."""
    if not episodes:
        raise ValueError("a cell needs at least one episode")
    successes = sum(e.success for e in episodes)
    km = sum(e.route_completion * route_length_m[e.route] for e in episodes) / 1000.0
    return CellStatistics(
        episodes=len(episodes), successes=successes, success=wilson_interval(successes, len(episodes)),
        route_completion=sum(e.route_completion for e in episodes) / len(episodes),
        driving_score=sum(driving_score(e.route_completion, e.collision_type) for e in episodes) / len(episodes),
        km_driven=km, infractions=_count_infractions(episodes, infractions_recorded))


@dataclass(frozen=True)
class PairedComparison:
    """Agents a and b on the same routes."""

    routes: int
    a_successes: int
    b_successes: int
    only_a: int  # routes a finished and b did not
    only_b: int
    difference: float  # success rate a - b
    difference_ci95: Interval  # Newcombe method 10
    p_value: float  # exact McNemar, two-sided


def mcnemar_exact_p(only_a: int, only_b: int) -> float:
    """Two-sided exact McNemar p: the binomial probability of a split of the discordant pairs at least this uneven."""
    if only_a < 0 or only_b < 0:
        raise ValueError(f"discordant counts must be >= 0, got {only_a} and {only_b}")
    n = only_a + only_b
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, k) for k in range(min(only_a, only_b) + 1)) / 2.0 ** n
    return min(1.0, 2.0 * tail)


def paired_difference_interval(both: int, only_a: int, only_b: int, neither: int, z: float = Z_95) -> Interval:
    """95 % interval of the paired difference of success rates (a - b), Newcombe (1998) method 10."""
    n = both + only_a + only_b + neither
    if min(both, only_a, only_b, neither) < 0 or n == 0:
        raise ValueError(f"need non-negative counts and at least one pair, got {(both, only_a, only_b, neither)}")
    p1, p2 = (both + only_a) / n, (both + only_b) / n
    w1, w2 = wilson_interval(both + only_a, n, z), wilson_interval(both + only_b, n, z)
    margins = (both + only_a) * (only_b + neither) * (both + only_b) * (only_a + neither)
    phi = 0.0
    if margins > 0:  # phi with Newcombe's continuity correction of the cross product
        cross = both * neither - only_a * only_b
        corrected = cross - n / 2 if cross > n / 2 else (cross if cross < 0 else 0.0)
        phi = corrected / math.sqrt(margins)
    d1, u1 = p1 - w1.low, w1.high - p1
    d2, u2 = p2 - w2.low, w2.high - p2
    delta = math.sqrt(max(0.0, d1 * d1 - 2 * phi * d1 * u2 + u2 * u2))
    epsilon = math.sqrt(max(0.0, u1 * u1 - 2 * phi * u1 * d2 + d2 * d2))
    return Interval(max(-1.0, p1 - p2 - delta), min(1.0, p1 - p2 + epsilon))


def paired_comparison(a: Mapping[str, bool], b: Mapping[str, bool]) -> PairedComparison | None:
    """Success of a and b per route key; the routes both drove are compared (None if there are none)."""
    common = sorted(a.keys() & b.keys())
    if not common:
        return None
    both = sum(a[k] and b[k] for k in common)
    only_a = sum(a[k] and not b[k] for k in common)
    only_b = sum(b[k] and not a[k] for k in common)
    n = len(common)
    return PairedComparison(
        routes=n, a_successes=both + only_a, b_successes=both + only_b, only_a=only_a, only_b=only_b,
        difference=(only_a - only_b) / n,
        difference_ci95=paired_difference_interval(both, only_a, only_b, n - both - only_a - only_b),
        p_value=mcnemar_exact_p(only_a, only_b))
