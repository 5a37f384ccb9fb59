"""The emergency brake's goals (issue 75) measured on its route runs: the shipped MSFSU without the brake and with
each brake under judgment, on the routes all of them drove, one run on one machine (its shards' directories merged).

Per agent and condition: pedestrian and vehicle collisions per km driven, NoCrash dense success with its Wilson
interval, the brake's false interventions per 10 km (a brake, or a cap once caps are judged, with no vehicle or
pedestrian within 15 m of the path ahead, by the simulator's ground truth: closed_loop.episode.AebCount), and the time
to the goal on NoCrash empty routes all of them finished (a brake must not slow a free road). The goals are judged for
the run's last brake agent; each brake agent is paired with the network without the brake and with the brake before it.
Every figure is computed from the run's episode records.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from msfsu_evaluation.closed_loop.cells import PairedRow
from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT
from msfsu_evaluation.closed_loop.runs import merge
from msfsu_evaluation.closed_loop.statistics import Interval, paired_comparison, wilson_interval
from msfsu_evaluation.closed_loop.suites import CONDITIONS, full_suite_routes, load_routes
from msfsu_evaluation.closed_loop.summary import BRAKE_COUNTS, brake_interventions

PAIRED_ANCHOR = "ablation-paired-comparison-on-the-same-routes"  # a run page's paired section
GOALS = "pedestrian collisions <= 0.05 per km in both conditions; vehicle collisions per km at least halved; NoCrash " \
        "dense >= 61 % train and >= 43 % held out; false interventions <= 1 per 10 km; NoCrash empty within 5 % of " \
        "the time"
DENSE_GOAL = {"train": 0.61, "heldout": 0.43}
PEDESTRIAN_GOAL_PER_KM = 0.05
FALSE_GOAL_PER_10KM = 1.0
EMPTY_TIME_GOAL = 0.05


@dataclass(frozen=True)
class RouteRun:
    """A route run of the brake: its record directories (a run's shards), its page, the network without the brake and
    the brake agents, the last of them the one its goals judge."""

    records: tuple[str, ...]  # from the repository's root
    page: str  # msfsu-benchmark-report's page of the run (made while it is driven too)
    without: str
    brakes: tuple[str, ...]
    title: str  # the README line's lead
    words: str  # what the run is, for the README line

    @property
    def agents(self) -> tuple[str, ...]:
        return (self.without, *self.brakes)

    @property
    def judged(self) -> str:
        return self.brakes[-1]

    def directories(self, root: Path = ROOT) -> list[Path]:
        return [root / directory for directory in self.records]


AEB_V1 = RouteRun(("docs/results/aeb_v1/records/routes",), "docs/results/aeb_v1/results.md", "msfsu", ("msfsu_aeb",),
                  "Emergency brake on the routes", "the shipped MSFSU with and without it, one run")
# its legs, each an msfsu-benchmark --tasks run so that every route's three episodes are in one leg (--shard K/N
# deals the (agent, route) jobs out, so a shard would hold one agent of each route), each under ~2.5 h by the corridor
# brake's run's wall times: 1 nocrash_dense, 2 nocrash_regular straight one_turn, 3 navigation_dynamic navigation
# nocrash_empty
CROSSING_V1 = RouteRun(tuple(f"docs/results/aeb_crossing_v1/records/routes_{shard}" for shard in (1, 2, 3)),
                       "docs/results/aeb_crossing_v1/routes/results.md", "msfsu", ("msfsu_aeb", "msfsu_aeb_x"),
                       "Brake predicting crossings on the routes",
                       "the shipped MSFSU without a brake, with it and with it predicting crossings, one run in three "
                       "legs by task; the crossing rule before the track rule of 2026-12-05, the default since judged "
                       "on chosen routes and the scenario suite, not on every route")
ROUTE_RUNS = (AEB_V1, CROSSING_V1)


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
    brakes: int | None  # None: no brake
    caps: int | None
    false_brakes: int | None
    false_caps: int | None  # None: no brake, or caps not judged in the run's records

    @property
    def false_interventions(self) -> int | None:
        """False brakes, and false caps where the records judge them."""
        if self.false_brakes is None:
            return None
        return self.false_brakes + (self.false_caps or 0)


@dataclass(frozen=True)
class AebGoals:
    run: RouteRun
    rows: tuple[AgentCondition, ...]
    empty_time_ratio: dict[str, dict[str, float]]  # brake agent -> condition -> with / without, NoCrash empty
    done: int  # episodes recorded of the run's agents
    planned: int
    paired: tuple[PairedRow, ...]  # success, each brake agent minus the agent before it and minus the one without

    def row(self, agent: str, condition: str) -> AgentCondition:
        return next(row for row in self.rows if (row.agent, row.condition) == (agent, condition))

    @property
    def caps_judged(self) -> bool:
        """Whether every record of the judged brake counts its false caps (runs after the first brake's)."""
        rows = [self.row(self.run.judged, condition) for condition in CONDITIONS]
        return all(row.false_caps is not None for row in rows if row.routes)

    def table(self) -> str:
        run = self.run
        lines = [f"{self.done} of {self.planned} episodes of {', '.join(run.agents)} ([the run's page]"
                 f"({run.page})). Goals, for {run.judged}: {GOALS}.", "",
                 f"| agent | condition | km | pedestrian collisions / km | vehicle collisions / km | NoCrash dense % "
                 f"(95 % CI) | brakes / caps (false per 10 km) | NoCrash empty time, with / {run.without} |",
                 "|" + " --- |" * 8]
        for row in (row for row in self.rows if row.routes):
            dense = "-" if row.dense_ci95 is None else (
                f"{100 * row.dense_successes / row.dense_routes:.0f} ({100 * row.dense_ci95.low:.0f}-"
                f"{100 * row.dense_ci95.high:.0f})")
            if row.brakes is None:
                interventions = "-"
            else:
                judged = "" if row.false_caps is not None else "; caps not judged"
                interventions = f"{row.brakes} / {row.caps} ({per_10km(row.false_interventions, row.km):.2f}{judged})"
            ratio = self.empty_time_ratio.get(row.agent, {}).get(row.condition)
            lines.append(f"| {row.agent} | {row.condition} | {row.km:.1f} | {row.pedestrian_per_km:.3f} | "
                         f"{row.vehicle_per_km:.3f} | {dense} | {interventions} | "
                         f"{'-' if ratio is None else f'{ratio:.3f}'} |")
        return "\n".join(lines)

    def verdicts(self) -> list[str]:
        """Each goal for the judged brake, met or not (on the numbers so far)."""
        found = []
        run = self.run
        for condition in CONDITIONS:
            without, with_brake = self.row(run.without, condition), self.row(run.judged, condition)
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
        false_rate = self.false_rate()
        if false_rate is not None:
            what = "false interventions" if self.caps_judged else "false brakes (caps not judged in this run)"
            found.append(f"{what} {false_rate:.2f} per 10 km: "
                         f"{'met' if false_rate <= FALSE_GOAL_PER_10KM else 'not met'}")
        for condition, ratio in sorted(self.empty_time_ratio.get(run.judged, {}).items()):
            found.append(f"NoCrash empty time {condition} x{ratio:.3f}: "
                         f"{'met' if abs(ratio - 1) <= EMPTY_TIME_GOAL else 'not met'}")
        return found

    def false_rate(self) -> float | None:
        """The judged brake's false interventions per 10 km over both conditions."""
        rows = [row for row in (self.row(self.run.judged, condition) for condition in CONDITIONS) if row.routes]
        km = sum(row.km for row in rows)
        if not km or any(row.false_interventions is None for row in rows):
            return None
        return per_10km(sum(row.false_interventions for row in rows), km)

    def paired_text(self) -> str:
        return "; ".join(f"success {row.a} minus {row.b} {row.difference_text()} points on {row.routes} routes "
                         f"(McNemar p {row.mcnemar_p:.3f})" for row in self.paired)

    def line(self) -> str:
        """The README's line; while the run is driven, its verdicts are on the routes its agents drove so far."""
        progress = "" if self.done == self.planned else (f"; in progress: {self.done} of {self.planned} episodes, "
                                                         "verdicts so far")
        return (f"- **{self.run.title}** ({self.run.words}{progress}): "
                + "; ".join([self.paired_text(), *self.verdicts()]) + f" ([the run]({self.run.page}#{PAIRED_ANCHOR})).")


def per_10km(count: int, km: float) -> float:
    return 10.0 * count / km if km else 0.0


def aeb_goals(run: RouteRun = AEB_V1, root: Path = ROOT) -> AebGoals | None:
    """None before the run has records of all its agents on one route."""
    directories = [directory for directory in run.directories(root) if (directory / "episodes.jsonl").exists()]
    if not directories:
        return None
    records = merge(directories, set(run.agents))
    _, routes = load_routes()
    length = {route.key: route.length_m for route in routes}
    by_key = {route.key: route for route in routes}
    common = {route for _, route in records if all((agent, route) in records for agent in run.agents)}
    if not common:
        return None
    rows = []
    for agent in run.agents:
        for condition in CONDITIONS:
            episodes = [records[(agent, key)].episode for key in sorted(common) if by_key[key].condition == condition]
            km = sum(e.route_completion * length[e.route] for e in episodes) / 1000.0
            count = lambda kind: sum(e.status == "collision" and e.collision_type == kind for e in episodes)  # noqa: E731
            dense = [e for e in episodes if by_key[e.route].task == "nocrash_dense"]
            successes = sum(e.success for e in dense)
            counted = bool(episodes) and all(e.aeb is not None for e in episodes)
            total = brake_interventions(episodes) if counted else dict.fromkeys(BRAKE_COUNTS)
            rows.append(AgentCondition(
                agent, condition, len(episodes), round(km, 3), count("pedestrian") / km if km else 0.0,
                count("vehicle") / km if km else 0.0, successes, len(dense),
                wilson_interval(successes, len(dense)) if dense else None,
                total["brakes"], total["caps"], total["false_brakes"], total["false_caps"]))
    ratios: dict[str, dict[str, float]] = {}
    for agent in run.brakes:
        for condition in CONDITIONS:
            keys = [key for key in sorted(common) if by_key[key].condition == condition
                    and by_key[key].task == "nocrash_empty"
                    and all(records[(a, key)].episode.success for a in run.agents)]
            if keys:
                ratios.setdefault(agent, {})[condition] = (sum(records[(agent, k)].episode.time_s for k in keys)
                                                           / sum(records[(run.without, k)].episode.time_s for k in keys))
    done = sum(1 for agent, _ in records if agent in run.agents)
    success = {agent: {key: records[(agent, key)].episode.success for key in common} for agent in run.agents}
    pairs = [*zip(run.brakes[1:], run.brakes[:-1]), *((brake, run.without) for brake in run.brakes)]
    paired = tuple(PairedRow.of(a, b, "all", "all", paired_comparison(success[a], success[b])) for a, b in pairs)
    return AebGoals(run, tuple(rows), ratios, done, len(run.agents) * full_suite_routes(), paired)


def goals_block(run: RouteRun) -> str:
    goals = aeb_goals(run)
    if goals is None:
        return f"No episodes of this route run yet ({', '.join(run.records)})."
    return goals.table() + "\n\n" + "\n".join(f"- {verdict}" for verdict in [goals.paired_text(), *goals.verdicts()])


def aeb_goals_block() -> str:
    return goals_block(AEB_V1)


def aeb_crossing_goals_block() -> str:
    return goals_block(CROSSING_V1)


def aeb_lines() -> list[str]:
    """The README's lines: one per route run with records of all its agents on a route."""
    return [goals.line() for goals in (aeb_goals(run) for run in ROUTE_RUNS) if goals is not None]
