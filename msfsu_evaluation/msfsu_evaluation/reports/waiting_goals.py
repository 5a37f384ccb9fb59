"""Issue 77's goals for the network that waits, measured on the judge stages' pages (msfsu-waiting: the shipped MSFSU
driven again beside the chosen candidate, one run on one machine), and the before/after tables of the two.

- Routes (records/judge-routes/results.json, benchmark v3's 350 routes): per agent and condition, pooled over the
  suites, the km driven, pedestrian and vehicle collisions per km, solid-line crossings per km and NoCrash dense
  success (Wilson 95 %); every paper cell of the candidate against the shipped model's interval; the candidate minus
  the shipped per suite and condition on the same routes (Newcombe 95 % interval, exact McNemar p).
- Scenario suite (records/judge-abilities/results.json): per ability over both conditions, both agents and the
  candidate minus the shipped on the same scenarios; the ability goal holds where the expert solved >= 95 % in the
  suite's baseline run.
Real time (the gated precision's rate, the soak's p95) is measured by the timing benchmarks, not by these runs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from msfsu_evaluation.closed_loop.ability_report import BOTH, CONFLICTS
from msfsu_evaluation.closed_loop.abilities import ABILITIES
from msfsu_evaluation.closed_loop.cells import PAIRED_HEADER, PairedRow, Results, SummaryCell
from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT
from msfsu_evaluation.closed_loop.suites import CONDITIONS
from msfsu_evaluation.reports.ability_blocks import BASELINE as ABILITY_BASELINE, read_ability_run
from msfsu_evaluation.reports.aeb_goals import DENSE_GOAL, PEDESTRIAN_GOAL_PER_KM

RECORD = Path("docs/results/waiting")  # msfsu-waiting's RECORD default, from the repository's root
JUDGED = RECORD / "records"  # msfsu-waiting's JUDGED default: the benchmark runs' records and pages, one folder each
SHIPPED = "msfsu"  # the pipeline's BASELINE_AGENT
SOLID_LINE_GOAL_PER_KM = 0.5
ABILITY_GOAL = 0.90  # the candidate's success on an ability ...
EXPERT_SOLVES = 0.95  # ... where the expert's is at least this
GOALS = (f"pedestrian collisions <= {PEDESTRIAN_GOAL_PER_KM} per km in both conditions; NoCrash dense >= "
         f"{100 * DENSE_GOAL['train']:.0f} % train and >= {100 * DENSE_GOAL['heldout']:.0f} % held out; no other paper "
         f"cell below the shipped model's interval; every ability >= {100 * ABILITY_GOAL:.0f} % where the expert has >= "
         f"{100 * EXPERT_SOLVES:.0f} %; solid-line crossings <= {SOLID_LINE_GOAL_PER_KM} per km")


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


@dataclass(frozen=True)
class WaitingGoals:
    candidate: str
    routes: Path | None  # judge-routes' results.json, where it is made (from `root`)
    abilities: Path | None  # judge-abilities' results.json
    expert: Path  # the suite's baseline run's results.json, with the expert
    root: Path = ROOT

    def _paired(self, rows: list[PairedRow]) -> list[PairedRow]:
        return [row.with_first(self.candidate) for row in rows if {row.a, row.b} == {self.candidate, SHIPPED}]

    def route_lines(self) -> tuple[list[str], list[str]]:
        """The routes' tables and their verdicts."""
        assert self.routes is not None
        data = json.loads((self.root / self.routes).read_text())
        results = Results.from_json(data["results"])
        rows = {agent: condition_rows(results, agent) for agent in (SHIPPED, self.candidate)}
        lines = [f"Routes ([the run's page]({self.routes.parent / 'results.md'})): {results.episodes()} episodes.", "",
                 "| agent | condition | km | pedestrian collisions / km | vehicle collisions / km | solid-line crossings "
                 "/ km | NoCrash dense |", "|" + " --- |" * 7]
        for row in (row for agent_rows in rows.values() for row in agent_rows):
            dense = "-" if row.dense is None else row.dense.success_text()
            lines.append(f"| {row.agent} | {row.condition} | {row.km:.1f} | {row.per_km(row.pedestrians):.3f} | "
                         f"{row.per_km(row.vehicles):.3f} | {row.per_km(row.solid_lines):.2f} | {dense} |")
        lines += ["", f"{self.candidate} minus {SHIPPED} on the same routes:", "", *PAIRED_HEADER,
                  *(row.markdown_row() for row in self._paired([PairedRow.from_json(r) for r in data["paired"]]))]
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
        lines = [f"Scenario suite ([the run's page]({self.abilities.parent / 'results.md'})), both conditions: success "
                 "% (Wilson 95 % interval), the candidate minus the shipped on the same scenarios (points, Newcombe "
                 "95 % interval; exact McNemar p), and the expert from the suite's baseline run.", "",
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
        return lines, [verdict]

    def block(self) -> str:
        if self.routes is None and self.abilities is None:
            return "Not judged yet: the judge stages' pages (judge-routes, judge-abilities) are not there."
        lines, verdicts = [f"The shipped MSFSU ({SHIPPED}) driven again beside the candidate ({self.candidate}), one "
                           f"run on one machine. Goals: {GOALS}.", ""], []
        for part, made in ((self.route_lines, self.routes), (self.ability_lines, self.abilities)):
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
