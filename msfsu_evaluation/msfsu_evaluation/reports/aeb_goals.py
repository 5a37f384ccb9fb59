"""The emergency brake's goals (issue 75) measured on its route run: the shipped MSFSU with and without the brake on
the routes both drove, one run on one machine (docs/results/aeb_v1/records/routes).

Per condition: pedestrian and vehicle collisions per km driven, NoCrash dense success with its Wilson interval, the
brake's false brakes per 10 km (a brake with no vehicle or pedestrian within 15 m of the path ahead, by the
simulator's ground truth: closed_loop.episode.AebCount), and the time to the goal on NoCrash empty routes both
finished (the brake must not slow a free road). Every figure is computed from the run's episode records.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT
from msfsu_evaluation.closed_loop.runs import merge
from msfsu_evaluation.closed_loop.cells import PairedRow
from msfsu_evaluation.closed_loop.statistics import Interval, paired_comparison, wilson_interval
from msfsu_evaluation.closed_loop.suites import CONDITIONS, full_suite_routes, load_routes

RUN = ROOT / "docs" / "results" / "aeb_v1" / "records" / "routes"
PAIRED_ANCHOR = "ablation-paired-comparison-on-the-same-routes"  # the page's paired section
PAGE = "docs/results/aeb_v1/results.md"  # msfsu-benchmark-report's page of the run, made while it is driven too
WITHOUT, WITH = "msfsu", "msfsu_aeb"
GOALS = "pedestrian collisions <= 0.05 per km in both conditions; vehicle collisions per km at least halved; NoCrash " \
        "dense >= 61 % train and >= 43 % held out; false brakes <= 1 per 10 km; NoCrash empty within 5 % of the time"
DENSE_GOAL = {"train": 0.61, "heldout": 0.43}
PEDESTRIAN_GOAL_PER_KM = 0.05
FALSE_BRAKE_GOAL_PER_10KM = 1.0
EMPTY_TIME_GOAL = 0.05


@dataclass(frozen=True)
class AgentCondition:
    agent: str
    condition: str
    routes: int
    km: float
    pedestrian_per_km: float
    vehicle_per_km: float
    dense_successes: int
    dense_routes: int
    dense_ci95: Interval | None
    false_brakes_per_10km: float | None  # None: no brake
    brakes: int | None


@dataclass(frozen=True)
class AebGoals:
    rows: tuple[AgentCondition, ...]
    empty_time_ratio: dict[str, float]  # condition -> with / without, mean over NoCrash empty routes both finished
    done: int  # episodes recorded of the two agents
    planned: int
    paired: PairedRow  # success, with minus without, on every route both drove

    def row(self, agent: str, condition: str) -> AgentCondition:
        return next(row for row in self.rows if (row.agent, row.condition) == (agent, condition))

    def table(self) -> str:
        lines = [f"{self.done} of {self.planned} episodes of {WITHOUT} and {WITH} ([the run's page]({PAGE})). Goals: "
                 f"{GOALS}.", "",
                 "| agent | condition | km | pedestrian collisions / km | vehicle collisions / km | NoCrash dense % "
                 "(95 % CI) | brakes (false per 10 km) | NoCrash empty time, with / without |",
                 "|" + " --- |" * 8]
        for row in (row for row in self.rows if row.routes):
            dense = "-" if row.dense_ci95 is None else (
                f"{100 * row.dense_successes / row.dense_routes:.0f} ({100 * row.dense_ci95.low:.0f}-"
                f"{100 * row.dense_ci95.high:.0f})")
            brakes = "-" if row.brakes is None else f"{row.brakes} ({row.false_brakes_per_10km:.2f})"
            ratio = self.empty_time_ratio.get(row.condition) if row.agent == WITH else None
            lines.append(f"| {row.agent} | {row.condition} | {row.km:.1f} | {row.pedestrian_per_km:.3f} | "
                         f"{row.vehicle_per_km:.3f} | {dense} | {brakes} | "
                         f"{'-' if ratio is None else f'{ratio:.3f}'} |")
        return "\n".join(lines)

    def verdicts(self) -> list[str]:
        """Each goal, met or not (on the numbers so far)."""
        found = []
        for condition in CONDITIONS:
            without, with_brake = self.row(WITHOUT, condition), self.row(WITH, condition)
            if not with_brake.routes:
                continue
            found.append(f"pedestrian collisions {condition} {with_brake.pedestrian_per_km:.3f}/km (without "
                         f"{without.pedestrian_per_km:.3f}): "
                         f"{'met' if with_brake.pedestrian_per_km <= PEDESTRIAN_GOAL_PER_KM else 'not met'}")
            if without.vehicle_per_km == 0:
                halved = "none without the brake to halve"
            else:
                halved = "halved" if with_brake.vehicle_per_km <= without.vehicle_per_km / 2 else "not halved"
            found.append(f"vehicle collisions {condition} {with_brake.vehicle_per_km:.3f}/km (without "
                         f"{without.vehicle_per_km:.3f}): {halved}")
            if with_brake.dense_routes:
                rate = with_brake.dense_successes / with_brake.dense_routes
                found.append(f"NoCrash dense {condition} {100 * rate:.0f} % (goal {100 * DENSE_GOAL[condition]:.0f}): "
                             f"{'met' if rate >= DENSE_GOAL[condition] else 'not met'}")
        false_rate = self.false_brake_rate()
        if false_rate is not None:
            found.append(f"false brakes {false_rate:.2f} per 10 km: "
                         f"{'met' if false_rate <= FALSE_BRAKE_GOAL_PER_10KM else 'not met'}")
        for condition, ratio in sorted(self.empty_time_ratio.items()):
            found.append(f"NoCrash empty time {condition} x{ratio:.3f}: "
                         f"{'met' if abs(ratio - 1) <= EMPTY_TIME_GOAL else 'not met'}")
        return found

    def false_brake_rate(self) -> float | None:
        rows = [row for row in (self.row(WITH, condition) for condition in CONDITIONS) if row.routes]
        km = sum(row.km for row in rows)
        if not km or any(row.brakes is None for row in rows):
            return None
        return sum(row.false_brakes_per_10km * row.km for row in rows) / km

    def paired_text(self) -> str:
        row = self.paired
        return (f"success {WITH} minus {WITHOUT} {row.difference_text()} points on {row.routes} routes (McNemar p "
                f"{row.mcnemar_p:.3f})")

    def line(self) -> str:
        """The README's line; while the run is driven, its verdicts are on the routes both agents drove so far."""
        progress = "" if self.done == self.planned else (f"; in progress: {self.done} of {self.planned} episodes, "
                                                         "verdicts so far")
        return (f"- **Emergency brake on the routes** (the shipped MSFSU with and without it, one run{progress}): "
                + "; ".join([self.paired_text(), *self.verdicts()]) + f" ([the run]({PAGE}#{PAIRED_ANCHOR})).")


def aeb_goals(run: Path = RUN) -> AebGoals | None:
    """None before the run has records of both agents."""
    if not (run / "episodes.jsonl").exists():
        return None
    records = merge([run], {WITHOUT, WITH})
    _, routes = load_routes()
    length = {route.key: route.length_m for route in routes}
    by_key = {route.key: route for route in routes}
    both = {route for agent, route in records if (WITH, route) in records and (WITHOUT, route) in records}
    if not both:
        return None
    rows = []
    for agent in (WITHOUT, WITH):
        for condition in CONDITIONS:
            episodes = [records[(agent, key)].episode for key in sorted(both) if by_key[key].condition == condition]
            km = sum(e.route_completion * length[e.route] for e in episodes) / 1000.0
            count = lambda kind: sum(e.status == "collision" and e.collision_type == kind for e in episodes)  # noqa: E731
            dense = [e for e in episodes if by_key[e.route].task == "nocrash_dense"]
            successes = sum(e.success for e in dense)
            brakes = None if not episodes or any(e.aeb is None for e in episodes) else sum(e.aeb.brakes for e in episodes)
            false = None if brakes is None else sum(e.aeb.false_brakes for e in episodes)
            rows.append(AgentCondition(
                agent, condition, len(episodes), round(km, 3), count("pedestrian") / km if km else 0.0,
                count("vehicle") / km if km else 0.0, successes, len(dense),
                wilson_interval(successes, len(dense)) if dense else None,
                None if false is None else (10.0 * false / km if km else 0.0), brakes))
    ratios = {}
    for condition in CONDITIONS:
        pairs = [(records[(WITH, key)].episode.time_s, records[(WITHOUT, key)].episode.time_s) for key in sorted(both)
                 if by_key[key].condition == condition and by_key[key].task == "nocrash_empty"
                 and records[(WITH, key)].episode.success and records[(WITHOUT, key)].episode.success]
        if pairs:
            ratios[condition] = sum(w for w, _ in pairs) / sum(o for _, o in pairs)
    done = sum(1 for agent, _ in records if agent in (WITHOUT, WITH))
    success = {agent: {key: records[(agent, key)].episode.success for key in both} for agent in (WITHOUT, WITH)}
    paired = PairedRow.of(WITH, WITHOUT, "all", "all", paired_comparison(success[WITH], success[WITHOUT]))
    return AebGoals(tuple(rows), ratios, done, 2 * full_suite_routes(), paired)


def aeb_goals_block() -> str:
    goals = aeb_goals()
    if goals is None:
        return "No episodes of the brake's route run yet (docs/results/aeb_v1/records/routes)."
    return goals.table() + "\n\n" + "\n".join(f"- {verdict}" for verdict in [goals.paired_text(), *goals.verdicts()])


def aeb_line() -> str:
    goals = aeb_goals()
    return "" if goals is None else goals.line()
