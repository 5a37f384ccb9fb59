"""The per-ability suite's and the emergency brake's blocks: what the committed ability runs (closed_loop.ability_report's
results.json: AbilityCell and PairedRow records) and the brake's route run say, read into their types and rendered.

- `abilities`: per ability, pooled over both conditions, every agent of the baseline run and of the brake's runs
  (the brake on its corridor beside the network without it; the brake predicting crossings beside the first);
- the README's lines: the scenario suite's conflicts per agent, and each brake run's pairing on the same scenarios;
- `aeb`: the brake's route run (msfsu and msfsu_aeb on the 350 routes, one run), once it holds both agents.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from msfsu_evaluation.closed_loop.ability_report import BOTH, CONFLICTS, AbilityCell
from msfsu_evaluation.closed_loop.abilities import ABILITIES
from msfsu_evaluation.closed_loop.cells import PairedRow
from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT

ABILITY_RUNS = ROOT / "docs" / "results" / "abilities_v1" / "records"
BASELINE = ABILITY_RUNS / "baseline" / "results.json"
PAGE_LINK = "docs/results/abilities_v1/results.md"  # the suite page: every agent, each from the run named
PAIRED_ANCHOR = "#paired-comparison-on-the-same-scenarios"


@dataclass(frozen=True)
class BrakeRun:
    """A run of the brake on the scenario suite: its new agent paired with the one it is compared with there."""

    page: str  # the run's results.md, from the repository's root (results.json beside it)
    agent: str  # the agent the run adds
    against: str  # the agent it is paired with in the same run
    words: str  # what the agent is, for the lines

    @property
    def results(self) -> Path:
        return ROOT / Path(self.page).parent / "results.json"


BRAKE_RUNS = (BrakeRun("docs/results/abilities_v1/records/aeb/results.md", "msfsu_aeb", "msfsu", "the emergency brake"),
              BrakeRun("docs/results/aeb_crossing_v1/records/abilities/results.md", "msfsu_aeb_x", "msfsu_aeb",
                       "the brake predicting crossings"))


def read_ability_run(path: Path) -> tuple[list[AbilityCell], list[PairedRow], list[str]]:
    """A scenario-suite run's results.json: its cells, its paired rows and its agents."""
    report = json.loads(path.read_text())
    return ([AbilityCell.from_json(cell) for cell in report["cells"]],
            [PairedRow.from_json(row) for row in report["paired"]], report["agents"])


def abilities_table(baseline: Path = BASELINE, brake_runs: tuple[BrakeRun, ...] = BRAKE_RUNS) -> str:
    """Per ability (both conditions pooled) and the pooled conflicts, each agent's success with its Wilson interval:
    the baseline run's agents, then each brake run's agent (from that run, where it exists)."""
    cells, _, agents = read_ability_run(baseline)
    sources = [f"[every agent]({PAGE_LINK})"]
    for run in brake_runs:
        if run.results.exists() and run.agent not in agents:
            more, _, _ = read_ability_run(run.results)
            cells += [cell for cell in more if cell.agent == run.agent]
            sources.append(f"[{run.agent}: {run.words}, paired there with {run.against} driven again]({run.page})")
            agents.append(run.agent)
    by_key = {(cell.agent, cell.ability): cell for cell in cells if cell.condition == BOTH}
    lines = [f"Success % (Wilson 95 % interval) over both conditions; pages: {'; '.join(sources)}.", "",
             "| ability | " + " | ".join(agents) + " |", "|" + " --- |" * (1 + len(agents))]
    for ability in (*ABILITIES, CONFLICTS):
        row = [(by_key[(agent, ability)].rate_text() if (agent, ability) in by_key else "-") for agent in agents]
        lines.append(f"| {ability} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def abilities_line(baseline: Path = BASELINE, brake_runs: tuple[BrakeRun, ...] = BRAKE_RUNS) -> str:
    """The README's line: conflicts solved per agent, and each brake run's agent paired with the one it is compared
    with on the same scenarios."""
    cells, _, agents = read_ability_run(baseline)
    conflicts = {cell.agent: cell for cell in cells if cell.ability == CONFLICTS and cell.condition == BOTH}
    scenarios = next(iter(conflicts.values())).scenarios
    parts = ", ".join(f"{agent} {conflicts[agent].rate_text()}" for agent in agents if agent in conflicts)
    line = (f"- **Per-ability scenarios** ({scenarios} conflict scenarios of {len(ABILITIES) - 1} abilities, both "
            f"conditions; success %, Wilson 95 % interval): {parts} ([per ability]({PAGE_LINK})).")
    for run in brake_runs:
        if not run.results.exists():
            continue
        _, paired, _ = read_ability_run(run.results)
        row = next((r for r in paired if r.suite == CONFLICTS and r.condition == BOTH
                    and {r.a, r.b} == {run.agent, run.against}), None)
        if row is not None:
            row = row.with_first(run.agent)
            line += (f" With {run.words}, {row.a} minus {row.b} on the same scenarios: {row.difference_text()} "
                     f"(McNemar p {row.mcnemar_p:.3f}; [{run.agent}]({run.page}{PAIRED_ANCHOR})).")
    return line
