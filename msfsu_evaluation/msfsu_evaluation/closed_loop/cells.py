"""The typed records of a closed-loop report and their Markdown: a cell's summary, every cell of a report, a paired row.

A record holds exactly what results.json holds (its numbers rounded as written there), `to_json` writes it and
`from_json` reads it back unchanged; the Markdown is made from these rounded values, so a page made from
results.json (msfsu_evaluation.reports) says what the report's own page says.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar, Self

from msfsu_evaluation.closed_loop.statistics import CellStatistics, Interval, PairedComparison

CELL_DIGITS = 4  # rates, route completion, driving score, interval bounds
KM_DIGITS = 3  # km driven, infractions per km
DASH = "–"  # a table entry without a value


def percent(value: float | None, digits: int = 0) -> str:
    """A 0..1 value in percent (DASH: none)."""
    return DASH if value is None else f"{100 * value:.{digits}f}"


def metres(value: float | None) -> str:
    return DASH if value is None else f"{value:.3f}"


def _interval(bounds: Sequence[float]) -> Interval:
    low, high = bounds
    return Interval(low, high)


def _rounded(interval: Interval) -> Interval:
    return Interval(round(interval.low, CELL_DIGITS), round(interval.high, CELL_DIGITS))


class JsonRecord:
    """A dataclass record as results.json holds it: its fields in order, each Interval named in INTERVALS as
    [low, high], every other field as it is."""

    INTERVALS: ClassVar[tuple[str, ...]] = ()

    def to_json(self) -> dict[str, Any]:
        bounds = {name: [getattr(self, name).low, getattr(self, name).high] for name in self.INTERVALS}
        return {**asdict(self), **bounds}  # every subclass is a dataclass

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Self:
        return cls(**{**data, **{name: _interval(data[name]) for name in cls.INTERVALS}})


@dataclass(frozen=True)
class SummaryCell(JsonRecord):
    """One agent's episodes of one suite, task and condition (results.json results[agent][suite][task][condition])."""

    episodes: int
    successes: int
    success_rate: float
    success_ci95: Interval  # Wilson 95 %
    route_completion: float  # mean, 0..1
    driving_score: float  # mean, 0..1
    km_driven: float
    infractions: dict[str, int]  # statistics.recorded_infractions -> count
    infractions_per_km: dict[str, float | None]  # None: nothing driven
    outcomes: dict[str, int]  # episode status -> count
    collisions: dict[str, int]  # collision type -> count
    wall_s_per_episode: float
    rmse_m: float | None  # against the expert's trajectory, over the routes both finished; None: no such route
    path_rmse_m: float | None
    rmse_episodes: int

    INTERVALS: ClassVar[tuple[str, ...]] = ("success_ci95",)

    @classmethod
    def of(cls, stats: CellStatistics, outcomes: Mapping[str, int], collisions: Mapping[str, int], wall_s: float,
           rmse_m: float | None, path_rmse_m: float | None, rmse_episodes: int) -> SummaryCell:
        """The cell of a cell's statistics, rounded as results.json holds it."""
        return cls(
            episodes=stats.episodes, successes=stats.successes, success_rate=stats.success_rate,
            success_ci95=_rounded(stats.success), route_completion=round(stats.route_completion, CELL_DIGITS),
            driving_score=round(stats.driving_score, CELL_DIGITS), km_driven=round(stats.km_driven, KM_DIGITS),
            infractions=dict(stats.infractions),
            infractions_per_km={kind: None if rate is None else round(rate, KM_DIGITS)
                                for kind, rate in stats.infractions_per_km().items()},
            outcomes=dict(outcomes), collisions=dict(collisions), wall_s_per_episode=round(wall_s, 1),
            rmse_m=rmse_m, path_rmse_m=path_rmse_m, rmse_episodes=rmse_episodes)

    def count_text(self) -> str:
        """Successes/episodes: "7/10"."""
        return f"{self.successes}/{self.episodes}"

    def success_text(self) -> str:
        """Successes/episodes (rate %; Wilson interval %): "7/10 (70; 40-89)"."""
        low, high = self.success_ci95.low, self.success_ci95.high
        return f"{self.count_text()} ({percent(self.success_rate)}; {percent(low)}-{percent(high)})"

    def score_text(self) -> str:
        return f"DS {percent(self.driving_score, 1)}, RC {percent(self.route_completion, 1)}"

    def outcomes_text(self) -> str:
        """Outcome counts by name, then the collisions by type where there were any."""
        text = ", ".join(f"{name} {count}" for name, count in sorted(self.outcomes.items()))
        if self.collisions:
            text += " (collisions: " + ", ".join(f"{kind} {n}" for kind, n in sorted(self.collisions.items())) + ")"
        return text

    def rmse_text(self) -> str:
        return f"{metres(self.rmse_m)} (path {metres(self.path_rmse_m)}, n={self.rmse_episodes})"


def separation_text(a: SummaryCell | None, b: SummaryCell | None, names: tuple[str, str]) -> str:
    """Whether two cells' success intervals overlap ("overlap"), else which agent is higher (DASH: one is missing)."""
    if not a or not b:
        return DASH
    if a.success_ci95.overlaps(b.success_ci95):
        return "overlap"
    return f"{names[0] if a.success_ci95.low > b.success_ci95.high else names[1]} higher"


Cells = dict[str, dict[str, dict[str, dict[str, SummaryCell]]]]  # agent -> suite -> task -> condition -> cell


@dataclass(frozen=True)
class Results:
    """Every cell of a report (results.json "results"), agents in the report's order."""

    cells: Cells

    def cell(self, agent: str, suite: str, task: str, condition: str) -> SummaryCell | None:
        return self.cells.get(agent, {}).get(suite, {}).get(task, {}).get(condition)

    def of_agent(self, agent: str) -> Iterator[tuple[str, str, str, SummaryCell]]:
        """(suite, task, condition, cell) of every cell of the agent, in the report's order."""
        for suite, tasks in self.cells.get(agent, {}).items():
            for task, conditions in tasks.items():
                for condition, cell in conditions.items():
                    yield suite, task, condition, cell

    def episodes(self) -> int:
        return sum(cell.episodes for agent in self.cells for *_, cell in self.of_agent(agent))

    def suites(self) -> list[str]:
        return sorted({suite for tasks in self.cells.values() for suite in tasks})

    def driven(self, conditions: Sequence[str]) -> list[str]:
        """The `conditions` some agent drove, in their order."""
        held = {condition for agent in self.cells for _, _, condition, _ in self.of_agent(agent)}
        return [condition for condition in conditions if condition in held]

    def to_json(self) -> dict[str, Any]:
        return {agent: {suite: {task: {condition: cell.to_json() for condition, cell in conditions.items()}
                                for task, conditions in tasks.items()}
                        for suite, tasks in suites.items()}
                for agent, suites in self.cells.items()}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Results:
        return cls({agent: {suite: {task: {condition: SummaryCell.from_json(cell) for condition, cell in
                                           conditions.items()}
                                    for task, conditions in tasks.items()}
                            for suite, tasks in suites.items()}
                    for agent, suites in data.items()})


def points_text(difference: float, interval: Interval) -> str:
    """A difference of success rates in points with its interval: "-7 (-16 to +1)"."""
    return f"{100 * difference:+.0f} ({100 * interval.low:+.0f} to {100 * interval.high:+.0f})"


@dataclass(frozen=True)
class PairedRow(JsonRecord):
    """Networks a and b on the routes both drove, in one suite ("all": every suite) and condition (results.json
    "paired")."""

    a: str
    b: str
    suite: str
    condition: str
    routes: int
    a_successes: int
    b_successes: int
    only_a: int
    only_b: int
    difference: float  # success rate a - b
    difference_ci95: Interval  # Newcombe 95 %
    mcnemar_p: float  # exact, two-sided

    INTERVALS: ClassVar[tuple[str, ...]] = ("difference_ci95",)

    @classmethod
    def of(cls, a: str, b: str, suite: str, condition: str, comparison: PairedComparison) -> PairedRow:
        """The row of a comparison, rounded as results.json holds it."""
        return cls(a=a, b=b, suite=suite, condition=condition, routes=comparison.routes,
                   a_successes=comparison.a_successes, b_successes=comparison.b_successes,
                   only_a=comparison.only_a, only_b=comparison.only_b,
                   difference=round(comparison.difference, CELL_DIGITS),
                   difference_ci95=_rounded(comparison.difference_ci95),
                   mcnemar_p=round(comparison.p_value, CELL_DIGITS))

    def difference_text(self) -> str:
        return points_text(self.difference, self.difference_ci95)

    def with_first(self, name: str) -> PairedRow:
        """The row with network `name` as a (as it is, or a and b swapped), so its difference reads "name minus the
        other"."""
        if self.b != name:
            return self
        low, high = self.difference_ci95.low, self.difference_ci95.high
        return PairedRow(a=self.b, b=self.a, suite=self.suite, condition=self.condition, routes=self.routes,
                         a_successes=self.b_successes, b_successes=self.a_successes, only_a=self.only_b,
                         only_b=self.only_a, difference=0.0 - self.difference,  # no -0 where they tie
                         difference_ci95=Interval(0.0 - high, 0.0 - low),
                         mcnemar_p=self.mcnemar_p)

    def markdown_row(self, pair: str | None = None, suite: bool = True) -> str:
        """The row of a paired table: `pair` (default "a vs b"), the suite (unless `suite` is False), condition,
        routes, both successes, the routes only one finished, a - b with its interval and the McNemar p."""
        cells = [f"{self.a} vs {self.b}" if pair is None else pair, *([self.suite] if suite else []), self.condition,
                 str(self.routes), str(self.a_successes), str(self.b_successes), str(self.only_a), str(self.only_b),
                 self.difference_text(), f"{self.mcnemar_p:.3f}"]
        return "| " + " | ".join(cells) + " |"


PAIRED_HEADER = ("| A vs B | Suite | Condition | Routes | A | B | Only A | Only B | A - B (95 % CI), points | McNemar p |",
                 "|" + " --- |" * 10)  # PairedRow.markdown_row's table


def paired_markdown(rows: Sequence[PairedRow]) -> list[str]:
    """The report's section of paired rows (none: no section)."""
    if not rows:
        return []
    return ["## Ablation: paired comparison on the same routes", "",
            "Both networks drove the same routes; only the routes exactly one of them finished (only A, only B) tell "
            "them apart. Difference: success rate A - B in points (Newcombe 95 % interval); p: exact McNemar test. "
            "An interval that excludes 0 (p < 0.05) separates the two.", "",
            *PAIRED_HEADER, *(row.markdown_row() for row in rows), ""]
