"""The per-ability suite's and the emergency brake's blocks: what the committed ability runs (closed_loop.ability_report's
results.json: AbilityCell and PairedRow records) and the brake's route run say, read into their types and rendered.

- `abilities`: per ability, pooled over both conditions, every agent of the baseline run and of the brake's run;
- the README's lines: the scenario suite's conflicts per agent, and the brake's pairing on the same scenarios;
- `aeb`: the brake's route run (msfsu and msfsu_aeb on the 350 routes, one run), once it holds both agents.
"""

from __future__ import annotations

import json
from pathlib import Path

from msfsu_evaluation.closed_loop.ability_report import BOTH, CONFLICTS, AbilityCell
from msfsu_evaluation.closed_loop.abilities import ABILITIES
from msfsu_evaluation.closed_loop.cells import PairedRow
from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT

ABILITY_RUNS = ROOT / "docs" / "results" / "abilities_v1" / "records"
BASELINE = ABILITY_RUNS / "baseline" / "results.json"
WITH_AEB = ABILITY_RUNS / "aeb" / "results.json"
PAGE_LINK = "docs/results/abilities_v1/results.md"  # the suite page: every agent, each from the run named
AEB_LINK = "docs/results/abilities_v1/records/aeb/results.md"
AEB_PAIRED_LINK = AEB_LINK + "#paired-comparison-on-the-same-scenarios"


def _read(path: Path) -> tuple[list[AbilityCell], list[PairedRow], list[str]]:
    report = json.loads(path.read_text())
    return ([AbilityCell.from_json(cell) for cell in report["cells"]],
            [PairedRow.from_json(row) for row in report["paired"]], report["agents"])


def abilities_table(baseline: Path = BASELINE, with_aeb: Path = WITH_AEB) -> str:
    """Per ability (both conditions pooled) and the pooled conflicts, each agent's success with its Wilson interval:
    the baseline run's agents, then the brake run's agents not in it."""
    cells, _, agents = _read(baseline)
    sources = [f"[every agent]({PAGE_LINK})"]
    if with_aeb.exists():
        more, _, more_agents = _read(with_aeb)
        added = [agent for agent in more_agents if agent not in agents]
        cells += [cell for cell in more if cell.agent in added]
        sources.append(f"[{', '.join(added)}: the brake's run, paired there with its own run of the same network]"
                       f"({AEB_LINK})")
        agents += added
    by_key = {(cell.agent, cell.ability): cell for cell in cells if cell.condition == BOTH}
    lines = [f"Success % (Wilson 95 % interval) over both conditions; pages: {'; '.join(sources)}.", "",
             "| ability | " + " | ".join(agents) + " |", "|" + " --- |" * (1 + len(agents))]
    for ability in (*ABILITIES, CONFLICTS):
        row = [(by_key[(agent, ability)].rate_text() if (agent, ability) in by_key else "-") for agent in agents]
        lines.append(f"| {ability} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def abilities_line(baseline: Path = BASELINE, with_aeb: Path = WITH_AEB) -> str:
    """The README's line: conflicts solved per agent, and the brake paired with the same network on the same
    scenarios."""
    cells, _, agents = _read(baseline)
    conflicts = {cell.agent: cell for cell in cells if cell.ability == CONFLICTS and cell.condition == BOTH}
    scenarios = next(iter(conflicts.values())).scenarios
    parts = ", ".join(f"{agent} {conflicts[agent].rate_text()}" for agent in agents if agent in conflicts)
    line = (f"- **Per-ability scenarios** ({scenarios} conflict scenarios of {len(ABILITIES) - 1} abilities, both "
            f"conditions; success %, Wilson 95 % interval): {parts} ([per ability]({PAGE_LINK})).")
    if with_aeb.exists():
        aeb_cells, paired, _ = _read(with_aeb)
        row = next((r for r in paired if r.suite == CONFLICTS and r.condition == BOTH), None)
        if row is not None:
            with_brake = row.with_first(row.a if "aeb" in row.a else row.b)
            line += (f" With the emergency brake, {with_brake.a} minus {with_brake.b} on the same scenarios: "
                     f"{with_brake.difference_text()} (McNemar p {with_brake.mcnemar_p:.3f}; [brake]({AEB_PAIRED_LINK})).")
    return line
