"""Issue 77's goals for the network that waits, measured on the judge stages' pages (msfsu-waiting: the shipped MSFSU
driven again beside the chosen candidate, one run, each route's pair on one machine; the block says which), and the
before/after tables of the two.

- Routes (records/judge-routes/results.json, benchmark v3's 350 routes): per agent and condition, pooled over the
  suites, the km driven, pedestrian and vehicle collisions per km, solid-line crossings per km and NoCrash dense
  success (Wilson 95 %); every paper cell of the candidate against the shipped model's interval; the candidate minus
  the shipped per suite and condition on the same routes (Newcombe 95 % interval, exact McNemar p); from the run's
  telemetry, each network's steering beside the expert's in the same state, per branch (where solid lines are
  crossed: junction branches that do not steer as the expert would).
- Scenario suite (records/judge-abilities/results.json): per ability over both conditions, both agents and the
  candidate minus the shipped on the same scenarios; the ability goal holds where the expert solved >= 95 % in the
  suite's baseline run. Per pedestrian ability, from the run's telemetry: where the pedestrian was when the expert
  (labelling beside the network) first slowed for it, what the network asked for then, and what it asked for while
  the expert would have stood still for the pedestrian.
- Real time (`make waiting-realtime`, alone on the machine, both networks in one run): the fastest precision that
  passed the accuracy gate and its rate (benchmarks/waiting/perception_<agent>.json), and the deployed graph's 20 Hz
  soak (benchmarks/soak/waiting/<agent>/800x600_20hz.json: camera -> VehicleControl, the emergency brake in it).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_common.driving import STOP_SPEED_MPS
from msfsu_common.road_option import RoadOption
from msfsu_evaluation.closed_loop.ability_report import BOTH, CONFLICTS
from msfsu_evaluation.closed_loop.abilities import ABILITIES
from msfsu_evaluation.closed_loop.cells import PAIRED_HEADER, PairedRow, Results, SummaryCell
from msfsu_evaluation.closed_loop.collisions import number_text
from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT, Records, route_machines, run_records
from msfsu_evaluation.closed_loop.telemetry import EXPERT_LIMITS
from msfsu_evaluation.closed_loop.suites import CONDITIONS
from msfsu_evaluation.records.perception import PerceptionRecord
from msfsu_evaluation.records.soak import SoakRecord
from msfsu_evaluation.reports.ability_blocks import BASELINE as ABILITY_BASELINE, read_ability_run
from msfsu_evaluation.reports.aeb_goals import DENSE_GOAL, PEDESTRIAN_GOAL_PER_KM
from msfsu_sim.scenario_spec import PEDESTRIAN_BEHIND_PARKED_CAR, PEDESTRIAN_CROSSING

RECORD = Path("docs/results/waiting")  # msfsu-waiting's RECORD default, from the repository's root
JUDGED = RECORD / "records"  # msfsu-waiting's JUDGED default: the benchmark runs' records and pages, one folder each
SHIPPED = "msfsu"  # the pipeline's BASELINE_AGENT
SOLID_LINE_GOAL_PER_KM = 0.5
ABILITY_GOAL = 0.90  # the candidate's success on an ability ...
EXPERT_SOLVES = 0.95  # ... where the expert's is at least this
GATED_RATE_GOAL_HZ = 100.0  # the fastest gated precision on 2 cores: 5x the 20 Hz camera
SOAK_P95_GOAL_MS = 25.0  # the deployed graph's camera -> VehicleControl p95 at 20 Hz
REALTIME_SPEED = Path("benchmarks/waiting")  # perception_<agent>.json (make waiting-realtime)
REALTIME_SOAK = Path("benchmarks/soak/waiting")  # <agent>/800x600_20hz.json (make waiting-realtime)
SOAK_NAME = "800x600_20hz"
GOALS = (f"pedestrian collisions <= {PEDESTRIAN_GOAL_PER_KM} per km in both conditions; NoCrash dense >= "
         f"{100 * DENSE_GOAL['train']:.0f} % train and >= {100 * DENSE_GOAL['heldout']:.0f} % held out; no other paper "
         f"cell below the shipped model's interval; every ability >= {100 * ABILITY_GOAL:.0f} % where the expert has >= "
         f"{100 * EXPERT_SOLVES:.0f} %; solid-line crossings <= {SOLID_LINE_GOAL_PER_KM} per km; still real time: "
         f"the gated precision >= {GATED_RATE_GOAL_HZ:g} Hz and the 20 Hz soak's p95 <= {SOAK_P95_GOAL_MS:g} ms")


@dataclass(frozen=True)
class ConditionRow:
    """One agent's routes of one condition, pooled over the suites."""

    agent: str
    condition: str
    km: float
    pedestrians: int
    vehicles: int
    solid_lines: int
    dense: SummaryCell | None

    def per_km(self, count: int) -> float:
        return count / self.km if self.km else 0.0


def condition_rows(results: Results, agent: str) -> list[ConditionRow]:
    rows = []
    for condition in CONDITIONS:
        cells = [cell for _, _, held, cell in results.of_agent(agent) if held == condition]
        if cells:
            count = lambda kind: sum(cell.infractions.get(kind, 0) for cell in cells)  # noqa: E731
            rows.append(ConditionRow(agent, condition, sum(cell.km_driven for cell in cells), count("pedestrian"),
                                     count("vehicle"), count("solid_line"),
                                     results.cell(agent, "nocrash", "nocrash_dense", condition)))
    return rows


PEDESTRIAN_ABILITIES = tuple(name for name, ability in ABILITIES.items()
                             if ability.kind in (PEDESTRIAN_CROSSING, PEDESTRIAN_BEHIND_PARKED_CAR))
HELD_BY_PEDESTRIAN = EXPERT_LIMITS.index("pedestrian")


@dataclass(frozen=True)
class PedestrianApproach:
    """One agent's scenarios of one pedestrian ability, from their telemetry: medians over the scenarios at the step
    the expert (labelling beside the network) was first held by the pedestrian, and over the steps it stood still for
    it (its target speed below the control's stop threshold)."""

    agent: str
    ability: str
    scenarios: int
    collisions: int  # with a pedestrian
    distance_m: float  # the pedestrian at the expert's first step held by it
    bearing_deg: float
    height_px: float  # in network input pixels
    target_first_mps: float  # the network's target speed at that step
    target_standing_mps: float  # the network's target speed while the expert stood for the pedestrian (median)
    standing_steps: int
    stopping_share: float  # of those steps, the share on which the network asked to stop too (target below it)

    @classmethod
    def of(cls, records: Records, agent: str, ability: str) -> PedestrianApproach | None:
        """From a scenario run's records (closed_loop.runs.run_records); None where none of them kept telemetry."""
        first, standing, scenarios, collisions = [], [], 0, 0
        for (name, route), record in records.items():
            if name != agent or f"/{ability}/" not in route or (telemetry := record.telemetry()) is None:
                continue
            scenarios += 1
            collisions += record.episode.collision_type == "pedestrian"
            held = telemetry.column("expert_limit") == HELD_BY_PEDESTRIAN
            target = telemetry.column("action_target_speed_mps")
            standing += list(target[held & (telemetry.column("expert_target_speed_mps") < STOP_SPEED_MPS)])
            if held.any():
                step = int(np.flatnonzero(held)[0])
                first.append([telemetry.column(column)[step] for column in (
                    "pedestrian_distance_m", "pedestrian_bearing_deg", "pedestrian_height_px")] + [target[step]])
        if not scenarios:
            return None
        at = np.nanmedian(np.array(first), axis=0) if first else np.full(4, np.nan)
        stood = np.array(standing)
        return cls(agent, ability, scenarios, collisions, *(float(value) for value in at),
                   float(np.nanmedian(stood)) if standing else float("nan"), len(standing),
                   float(np.mean(stood < STOP_SPEED_MPS)) if standing else float("nan"))

    def markdown_row(self) -> str:
        return (f"| {self.ability} | {self.agent} | {self.collisions} of {self.scenarios} | "
                f"{number_text(self.distance_m)} | {number_text(self.bearing_deg, 0)} | "
                f"{number_text(self.height_px, 0)} | {number_text(self.target_first_mps)} | "
                f"{number_text(self.target_standing_mps, 2)} | {number_text(100 * self.stopping_share, 0)} % of "
                f"{self.standing_steps} |")


@dataclass(frozen=True)
class BranchSteering:
    """One network's steering on the steps its action came from one branch (the run's telemetry), beside the expert's
    steering in the same state (labels computed beside the network)."""

    agent: str
    branch: str  # RoadOption name
    steps: int
    network_std: float
    expert_std: float
    correlation: float
    mean_abs_difference: float

    @classmethod
    def of(cls, records: Records, agent: str) -> list[BranchSteering]:
        """From a run's records (closed_loop.runs.run_records): one row per branch the agent drove on."""
        network: dict[int, list[np.ndarray]] = {option.value: [] for option in RoadOption}
        expert: dict[int, list[np.ndarray]] = {option.value: [] for option in RoadOption}
        for (name, _), record in records.items():
            if name != agent or (telemetry := record.telemetry()) is None:
                continue
            branch = telemetry.column("action_command")
            steer, label = telemetry.column("action_steer"), telemetry.column("expert_steer")
            for value in network:
                both = (branch == value) & np.isfinite(steer) & np.isfinite(label)
                network[value].append(steer[both])
                expert[value].append(label[both])
        rows = []
        for option in RoadOption:
            mine, theirs = np.concatenate(network[option.value] or [np.zeros(0)]), \
                np.concatenate(expert[option.value] or [np.zeros(0)])
            if len(mine) > 1:
                rows.append(cls(agent, option.name, len(mine), float(mine.std()), float(theirs.std()),
                                float(np.corrcoef(mine, theirs)[0, 1]), float(np.abs(mine - theirs).mean())))
        return rows

    def markdown_row(self) -> str:
        return (f"| {self.agent} | {self.branch} | {self.steps:,} | {self.network_std:.3f} | {self.expert_std:.3f} | "
                f"{self.correlation:.2f} | {self.mean_abs_difference:.3f} |")


@dataclass(frozen=True)
class WaitingGoals:
    candidate: str
    routes: Path | None  # judge-routes' results.json, where it is made (from `root`)
    abilities: Path | None  # judge-abilities' results.json
    expert: Path  # the suite's baseline run's results.json, with the expert
    root: Path = ROOT

    def _paired(self, rows: list[PairedRow]) -> list[PairedRow]:
        return [row.with_first(self.candidate) for row in rows if {row.a, row.b} == {self.candidate, SHIPPED}]

    def machines_text(self, results: Path) -> str:
        """Where the run's pairs were driven ('AMD EPYC: 275, Intel(R) Xeon(R) Processor: 75; each pair on one
        machine'), from the run's episode records (closed_loop.runs.route_machines)."""
        on_one, split = route_machines((self.root / results).parent, (SHIPPED, self.candidate))
        where = ", ".join(f"{machine}: {routes}" for machine, routes in on_one.items())
        return f"{where}" + (f"; {split} driven on two machines" if split else "; each pair on one machine")

    def route_lines(self) -> tuple[list[str], list[str]]:
        """The routes' tables and their verdicts."""
        assert self.routes is not None
        data = json.loads((self.root / self.routes).read_text())
        results = Results.from_json(data["results"])
        rows = {agent: condition_rows(results, agent) for agent in (SHIPPED, self.candidate)}
        page = self.routes.parent / "results.md"
        lines = [f"Routes ([the run's page]({page})): {results.episodes()} episodes; routes by machine: "
                 f"{self.machines_text(self.routes)}.", "",
                 "| agent | condition | km | pedestrian collisions / km | vehicle collisions / km | solid-line crossings "
                 "/ km | NoCrash dense |", "|" + " --- |" * 7]
        for row in (row for agent_rows in rows.values() for row in agent_rows):
            dense = "-" if row.dense is None else row.dense.success_text()
            lines.append(f"| {row.agent} | {row.condition} | {row.km:.1f} | {row.per_km(row.pedestrians):.3f} | "
                         f"{row.per_km(row.vehicles):.3f} | {row.per_km(row.solid_lines):.2f} | {dense} |")
        lines += ["", f"{self.candidate} minus {SHIPPED} on the same routes:", "", *PAIRED_HEADER,
                  *(row.markdown_row() for row in self._paired([PairedRow.from_json(r) for r in data["paired"]]))]
        records = run_records((self.root / self.routes).parent, (SHIPPED, self.candidate))
        steering = [row for agent in (SHIPPED, self.candidate) for row in BranchSteering.of(records, agent)]
        if steering:
            lines += ["", "Steering per branch beside the expert's in the same state (the run's telemetry, every "
                      "step): the spread of each, their correlation and the mean absolute difference. Solid lines are "
                      "crossed where a branch does not steer back as the expert would (the page's crossings by "
                      "command and place).", "", "| agent | branch | steps | network steer std | expert steer std | "
                      "correlation | mean abs difference |", "|" + " --- |" * 7,
                      *(row.markdown_row() for row in steering)]
        verdicts = []
        for row in rows[self.candidate]:
            shipped = next(r for r in rows[SHIPPED] if r.condition == row.condition)
            rate = row.per_km(row.pedestrians)
            verdicts.append(f"pedestrian collisions {row.condition} {rate:.3f}/km (shipped "
                            f"{shipped.per_km(shipped.pedestrians):.3f}): "
                            f"{'met' if rate <= PEDESTRIAN_GOAL_PER_KM else 'not met'}")
            if row.dense is not None:
                verdicts.append(f"NoCrash dense {row.condition} {row.dense.success_text()} (goal "
                                f"{100 * DENSE_GOAL[row.condition]:.0f} %): "
                                f"{'met' if row.dense.success_rate >= DENSE_GOAL[row.condition] else 'not met'}")
        km = sum(row.km for row in rows[self.candidate])
        crossings = sum(row.solid_lines for row in rows[self.candidate]) / km if km else 0.0
        verdicts.append(f"solid-line crossings {crossings:.2f}/km: "
                        f"{'met' if crossings <= SOLID_LINE_GOAL_PER_KM else 'not met'}")
        below = []
        for key in data["against_paper"].get(self.candidate, {}).get("cells", {}):
            suite, task, condition = key.split("/")
            mine, theirs = (results.cell(agent, suite, task, condition) for agent in (self.candidate, SHIPPED))
            if mine and theirs and mine.success_rate < theirs.success_ci95.low:
                below.append(f"{key} {mine.success_text()} under the shipped {theirs.success_text()}")
        verdicts.append("paper cells below the shipped model's interval: " + ("; ".join(below) if below else "none"))
        return lines, verdicts

    def ability_lines(self) -> tuple[list[str], list[str]]:
        """The scenario suite's table and its verdicts."""
        assert self.abilities is not None
        run_cells, run_paired, _ = read_ability_run(self.root / self.abilities)
        cells = {(c.agent, c.ability): c for c in run_cells if c.condition == BOTH}
        expert = {c.ability: c for c in read_ability_run(self.root / self.expert)[0]
                  if c.agent == "expert" and c.condition == BOTH}
        paired = {row.suite: row for row in self._paired(run_paired) if row.condition == BOTH}
        page = self.abilities.parent / "results.md"
        lines = [f"Scenario suite ([the run's page]({page})), both conditions: success "
                 "% (Wilson 95 % interval), the candidate minus the shipped on the same scenarios (points, Newcombe "
                 "95 % interval; exact McNemar p), and the expert from the suite's baseline run. Scenarios by "
                 f"machine: {self.machines_text(self.abilities)}.", "",
                 f"| ability | {SHIPPED} | {self.candidate} | difference | McNemar p | expert |", "|" + " --- |" * 6]
        short = []
        for ability in (*ABILITIES, CONFLICTS):
            shipped, mine = cells.get((SHIPPED, ability)), cells.get((self.candidate, ability))
            row, by_expert = paired.get(ability), expert.get(ability)
            lines.append(f"| {ability} | {shipped.rate_text() if shipped else '-'} | {mine.rate_text() if mine else '-'}"
                         f" | {row.difference_text() if row else '-'} | {f'{row.mcnemar_p:.3f}' if row else '-'} | "
                         f"{by_expert.rate_text() if by_expert else '-'} |")
            if (ability != CONFLICTS and mine and by_expert and by_expert.successes >= EXPERT_SOLVES * by_expert.scenarios
                    and mine.successes < ABILITY_GOAL * mine.scenarios):
                short.append(f"{ability} {mine.rate_text()}")
        verdict = (f"every ability >= {100 * ABILITY_GOAL:.0f} % where the expert has >= {100 * EXPERT_SOLVES:.0f} %: "
                   + ("met" if not short else "not met (" + "; ".join(short) + ")"))
        return lines + self.pedestrian_lines(), [verdict]

    def pedestrian_lines(self) -> list[str]:
        """The pedestrian abilities' approach table (PedestrianApproach), where the run kept telemetry."""
        assert self.abilities is not None
        records = run_records((self.root / self.abilities).parent, (SHIPPED, self.candidate))
        rows = [row for ability in PEDESTRIAN_ABILITIES for agent in (SHIPPED, self.candidate)
                if (row := PedestrianApproach.of(records, agent, ability)) is not None]
        if not rows:
            return []
        return ["", "The pedestrian abilities step by step (the run's telemetry; medians over the scenarios): where "
                "the pedestrian was when the expert, labelling beside the network, first slowed for it (distance and "
                "bearing from the car, bearing positive right; height in network input pixels), the network's target "
                "speed then, and, over the steps the expert stood still for the pedestrian, the network's median "
                "target speed and the share of them on which it asked to stop too (target below "
                f"{STOP_SPEED_MPS} m/s).", "",
                "| ability | agent | pedestrian collisions | distance m | bearing deg | height px | target m/s then | "
                "target m/s while the expert stood | it asked to stop |", "|" + " --- |" * 9,
                *(row.markdown_row() for row in rows)]

    def realtime_records(self) -> dict[str, tuple[PerceptionRecord, SoakRecord]]:
        """Per network measured so far (the shipped first): its perception benchmark and its 20 Hz soak."""
        found = {}
        for agent in (SHIPPED, self.candidate):
            speed = self.root / REALTIME_SPEED / f"perception_{agent}.json"
            soak = self.root / REALTIME_SOAK / agent / f"{SOAK_NAME}.json"
            if speed.exists() and soak.exists():
                found[agent] = (PerceptionRecord.from_json(speed.read_text()), SoakRecord.from_json(soak.read_text()))
        return found

    def realtime_lines(self, measured: dict[str, tuple[PerceptionRecord, SoakRecord]]) -> tuple[list[str], list[str]]:
        """The real-time table of `realtime_records` (both networks, one run) and the candidate's verdicts."""
        machine = next(iter(measured.values()))[0].machine
        lines = [f"Real time (`make waiting-realtime`, alone on the machine; {machine}):",
                 "", "| network | fastest gated precision | its rate (p50) | load average before | 20 Hz soak: "
                 "inference | camera -> VehicleControl p50 / p95 / p99 / max ms | answered | load average start "
                 "| soak page |", "|" + " --- |" * 9]
        rates, p95s = {}, {}
        for agent, (speed, soak) in measured.items():
            model = speed.models[0]
            gated = model.fastest_gated
            totals = soak.analysed()
            e2e = totals.end_to_end_ms
            rates[agent], p95s[agent] = (gated.hz if gated else 0.0), e2e["p95"]
            lines.append(f"| {agent} | {gated.path if gated else '-'} | {rates[agent]:.0f} Hz | "
                         f"{model.load_average_before[0]:.2f} | {soak.inference.split(',')[0]} | "
                         f"{e2e['p50']:.1f} / {e2e['p95']:.1f} / {e2e['p99']:.1f} / {e2e['max']:.1f} | "
                         f"{totals.answered:,} of {totals.published:,} | {soak.load_average_start.split()[0]} | "
                         f"[{agent}]({REALTIME_SOAK / agent / SOAK_NAME}.md) |")
        verdicts = []
        if self.candidate in measured:
            rate, p95 = rates[self.candidate], p95s[self.candidate]
            shipped = (f" (shipped {rates[SHIPPED]:.0f} Hz)", f" (shipped {p95s[SHIPPED]:.1f} ms)") \
                if SHIPPED in measured else ("", "")
            verdicts += [f"gated precision {rate:.0f} Hz{shipped[0]}: "
                         f"{'met' if rate >= GATED_RATE_GOAL_HZ else 'not met'}",
                         f"20 Hz soak p95 {p95:.1f} ms{shipped[1]}: {'met' if p95 <= SOAK_P95_GOAL_MS else 'not met'}"]
        return lines, verdicts

    def conflicts_text(self) -> str | None:
        """The scenario suite's pooled conflicts, both conditions: each network's success and the paired difference
        (the README's line); None before judge-abilities."""
        if self.abilities is None:
            return None
        run_cells, run_paired, _ = read_ability_run(self.root / self.abilities)
        cells = {c.agent: c for c in run_cells if c.ability == CONFLICTS and c.condition == BOTH}
        row = next((row for row in self._paired(run_paired) if row.suite == CONFLICTS and row.condition == BOTH), None)
        if row is None or not {SHIPPED, self.candidate} <= set(cells):
            return None
        return (f"the scenario suite's conflicts (both conditions) {self.candidate} "
                f"{cells[self.candidate].rate_text()} % against the shipped {cells[SHIPPED].rate_text()} %, "
                f"{row.difference_text()} points (McNemar p {row.mcnemar_p:.3f})")

    def block(self) -> str:
        measured = self.realtime_records()
        if self.routes is None and self.abilities is None and not measured:
            return "Not judged yet: the judge stages' pages (judge-routes, judge-abilities) are not there."
        lines, verdicts = [f"The shipped MSFSU ({SHIPPED}) driven again beside the candidate ({self.candidate}) in one "
                           f"run per suite, each route's pair on one machine. Goals: {GOALS}.", ""], []
        for part, made in ((self.route_lines, self.routes), (self.ability_lines, self.abilities),
                           (lambda: self.realtime_lines(measured), measured or None)):
            if made is not None:
                table, found = part()
                lines += [*table, ""]
                verdicts += found
        return "\n".join([*lines, *(f"- {verdict}" for verdict in verdicts)])


def waiting_goals(record: Path = RECORD, judged: Path = JUDGED, root: Path = ROOT,
                  expert: Path = ABILITY_BASELINE.relative_to(ROOT)) -> WaitingGoals | None:
    """None before the select stage chose the candidate."""
    selection = root / record / "selection.json"
    if not selection.exists():
        return None

    def made(stage: str) -> Path | None:
        results = judged / stage / "results.json"
        return results if (root / results).exists() else None

    return WaitingGoals(json.loads(selection.read_text())["chosen"], made("judge-routes"), made("judge-abilities"),
                        expert, root)


def waiting_goals_block() -> str:
    goals = waiting_goals()
    if goals is None:
        return "Not judged yet: the select stage has not chosen the candidate (docs/results/waiting/selection.json)."
    return goals.block()
