"""Routes v2 against routes v3, per agent and cell, from the committed reports (issue 28's before / after table).

    msfsu-rules-change [--v2 docs/results/closed_loop/results.json] [--v3 docs/results/closed_loop_v3/results.json]

Prints a Markdown table: successes / episodes under v2 (its rules and routes; the networks drove the first 10 routes
of a cell) and under v3 (25 routes), and of v3's failures those that the new static-layout rule ended (a kerb or
building strike: under v2 the car drove on, to an outcome no record can tell). v3's solid-line rule counts crossings
and fails no episode; its total is the last column. The routes differ between the versions (crossed held-out
conditions, traffic placed by seed), so a cell's change is rules and routes together, not the rules alone.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path

from msfsu_evaluation.closed_loop.cells import Results, SummaryCell
from msfsu_evaluation.closed_loop.suites import CONDITIONS, TASKS


def cell_text(cell: SummaryCell | None) -> str:
    return "-" if cell is None else cell.count_text()


def in_suite_order(results: Results, agent: str) -> Iterator[tuple[str, str, str, SummaryCell]]:
    """(suite, task, condition, cell) of the agent's cells, tasks and conditions in the suites' order."""
    for suite, tasks in results.cells[agent].items():
        for task in (name for name in TASKS if name in tasks):
            for condition in (name for name in CONDITIONS if name in tasks[task]):
                yield suite, task, condition, tasks[task][condition]


def table(v2: dict, v3: dict) -> list[str]:
    before, after = Results.from_json(v2["results"]), Results.from_json(v3["results"])
    lines = ["| agent | suite / task | condition | v2 | v3 | v3 failures by a kerb or building strike | v3 solid-line "
             "crossings |", "| --- | --- | --- | --- | --- | --- | --- |"]
    totals: dict[str, list[int]] = {}
    for agent in v3["agents"]:
        for suite, task, condition, cell in in_suite_order(after, agent):
            strikes = cell.infractions.get("static", 0)  # a static-layout strike ends its episode
            crossings = cell.infractions.get("solid_line", 0)
            lines.append(f"| {agent} | {suite} / {task} | {condition} | "
                         f"{cell_text(before.cell(agent, suite, task, condition))} | {cell_text(cell)} | {strikes} | "
                         f"{crossings} |")
            total = totals.setdefault(agent, [0, 0, 0])
            total[0] += cell.episodes
            total[1] += strikes
            total[2] += crossings
    lines.append("")
    for agent, (episodes, strikes, crossings) in totals.items():
        lines.append(f"- {agent}: {strikes} of {episodes} v3 episodes ended by a kerb or building strike "
                     f"({100 * strikes / episodes:.1f} %), {crossings} solid-line crossings")
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="msfsu-rules-change", description=__doc__.splitlines()[0])
    parser.add_argument("--v2", type=Path, default=Path("docs/results/closed_loop/results.json"))
    parser.add_argument("--v3", type=Path, default=Path("docs/results/closed_loop_v3/results.json"))
    args = parser.parse_args(argv)
    print("\n".join(table(json.loads(args.v2.read_text()), json.loads(args.v3.read_text()))))


if __name__ == "__main__":
    main()
