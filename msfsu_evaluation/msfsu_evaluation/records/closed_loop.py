"""A closed-loop report (msfsu-benchmark-report -> docs/results/<report>/results.json) as the docs' blocks read it.

Rules:
- The cells and the paired rows are closed_loop.cells' types, read as results.json holds them; a paired row is
  rendered by PairedRow alone (`markdown_row`, `difference_text`), turned with `with_first` so that a named network
  reads first ("MSFSU minus the other").
- The against-the-paper and free-running sections are closed_loop.markdown's, as the report's own page renders them.
- Which agents drove the very checkpoint of another (a precision check, not an ablation) comes from the
  `checkpoint_digests` of the run.json of each run directory the report was made from.
"""

from __future__ import annotations

import json
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msfsu_evaluation.closed_loop.cells import PairedRow, Results

CONDITIONS = ("train", "heldout")  # the tables' column order
SUITE_ORDER = {"corl2017": 0, "nocrash": 1, "all": 2}


@dataclass(frozen=True)
class ClosedLoopReport:
    """What the blocks read of a results.json, and the checkpoint digests of the runs it names."""

    agents: list[str]
    sources: dict[str, dict[str, int]]  # agent -> run directory -> episodes
    results: Results
    paired: list[PairedRow]
    against_paper: dict[str, Any]  # closed_loop.summary.against_paper's record (closed_loop.markdown renders it)
    free_running: dict[str, Any]  # closed_loop.summary.free_running_summary's record
    ran_as: dict[str, list[str]]  # network -> what it ran as on its machines ('cpu openvino/int8')
    checkpoint_digests: dict[str, str]  # agent -> its checkpoint's content digest, over the runs

    @classmethod
    def read(cls, path: Path, root: Path) -> ClosedLoopReport:
        """The results.json at `path`; the run directories it names are relative to `root` (the repository)."""
        record = json.loads(path.read_text())
        digests: dict[str, str] = {}
        for directory in record.get("records", []):
            run = root / directory / "run.json"
            if run.exists():
                digests.update(json.loads(run.read_text()).get("checkpoint_digests", {}))
        return cls(agents=list(record["agents"]), sources=record.get("sources", {}),
                   results=Results.from_json(record["results"]),
                   paired=[PairedRow.from_json(row) for row in record.get("paired", [])],
                   against_paper=record.get("against_paper", {}), free_running=record.get("free_running", {}),
                   ran_as={agent: list(runtime.get("ran_as", []))
                           for agent, runtime in record.get("run", {}).get("runtimes", {}).items()},
                   checkpoint_digests=digests)

    def episodes(self, agent: str) -> int:
        return sum(cell.episodes for *_, cell in self.results.of_agent(agent))

    def progress(self, planned: Sequence[str]) -> str:
        """"" when every `planned` agent has driven every route; else how far the run is."""
        driven = {agent: sum(self.sources.get(agent, {}).values()) for agent in planned}
        routes = max(driven.values())
        if all(count == routes for count in driven.values()):
            return ""
        return (f"In progress: {sum(driven.values())} of {routes * len(planned)} episodes driven ("
                + ", ".join(f"{agent} {count}" for agent, count in driven.items()) + ")")

    def runtime(self, agent: str, unknown: str) -> str:
        """What `agent` ran as, its machines joined ('cpu openvino/int8'); `unknown` without a record."""
        return ", ".join(self.ran_as[agent]) if agent in self.ran_as else unknown

    def same_checkpoint_as(self, first: str) -> set[str]:
        """The agents that drove `first`'s very checkpoint (by content digest), on another backend or precision."""
        digests = self.checkpoint_digests
        return {agent for agent, digest in digests.items() if agent != first and digest == digests.get(first)}

    def pooled(self, first: str) -> list[PairedRow]:
        """The rows over all suites (one per condition) of network `first` against each other agent, `first` as a."""
        return [row.with_first(first) for row in self.paired if row.suite == "all" and first in (row.a, row.b)]

    def success_table(self, tasks: Sequence[str]) -> str:
        """Success per suite and task (in `tasks`' order), condition and agent with Wilson 95 % intervals; then the
        pooled paired rows, MSFSU first."""
        header = [f"{condition}: {agent}" for condition in CONDITIONS for agent in self.agents]
        rows = ["| suite / task | " + " | ".join(header) + " |", "| --- |" + " --- |" * len(header)]
        cells = self.results.cells
        held = sorted({(suite, task) for agent in self.agents for suite in cells[agent] for task in cells[agent][suite]},
                      key=lambda key: (key[0], list(tasks).index(key[1]) if key[1] in tasks else len(tasks)))
        for suite, task in held:
            entries = []
            for condition in CONDITIONS:
                for agent in self.agents:
                    cell = self.results.cell(agent, suite, task, condition)
                    if cell is None:
                        entries.append("-")
                        continue
                    low, high = (round(100 * bound) for bound in (cell.success_ci95.low, cell.success_ci95.high))
                    entries.append(f"{cell.successes}/{cell.episodes} ({100 * cell.success_rate:.0f} %; {low}-{high})")
            rows.append(f"| {suite} / {task} | " + " | ".join(entries) + " |")
        pooled = [row.with_first("msfsu") for row in self.paired if row.suite == "all"]
        if pooled:
            rows += ["", "Paired over all tasks (the routes both drove; A - B in points with the Newcombe 95 % interval, "
                     "exact McNemar p):", "",
                     "| A vs B | condition | routes | A | B | only A | only B | A - B (95 % CI) | McNemar p |",
                     "| --- |" + " --- |" * 8]
            rows += [row.markdown_row(suite=False)
                     for row in sorted(pooled, key=lambda row: (row.a, row.b, CONDITIONS.index(row.condition)))]
        return "\n".join(rows)

    def precision_rows(self, first: str) -> list[PairedRow]:
        """`first` against the agents that drove its very checkpoint on another precision, per suite and condition
        and over all routes, `first` as a."""
        same = self.same_checkpoint_as(first)
        return [row.with_first(first) for row in self.paired if {row.a, row.b} & same and first in (row.a, row.b)]

    def precision_table(self, first: str, where: str) -> str:
        """The precision rows as a table under a line saying what each side ran as; `where`: the runs' revisions."""
        same, rows = self.same_checkpoint_as(first), self.precision_rows(first)
        lines = [f"MSFSU as the node deploys it (`{first}`: {self.runtime(first, 'auto')}) against the same checkpoint "
                 "on " + ", ".join(f"`{b}`: {self.runtime(b, '?')}" for b in sorted(same)) + ", on the routes both "
                 f"drove ({where}):", "",
                 f"| other | suite | condition | routes | {first} | other | only {first} | only other | {first} - other "
                 "(95 % CI) | McNemar p |", "| --- |" + " --- |" * 9]
        ordered = sorted(rows, key=lambda row: (row.b, SUITE_ORDER.get(row.suite, 3), row.condition != "train"))
        return "\n".join(lines + [row.markdown_row(pair=row.b) for row in ordered])

    def free_running_progress(self, free: Collection[str]) -> str:
        """How many routes each agent drove free-running and in lockstep, and whether the free run is finished."""
        episodes = {agent: self.episodes(agent) for agent in self.results.cells}
        lockstep = [agent for agent in self.agents if agent not in free]
        return (f"Routes driven: {', '.join(f'{a} {episodes[a]}' for a in free)} free-running, "
                f"{', '.join(f'{a} {episodes[a]}' for a in lockstep)} in lockstep"
                + (" (the free-running run is not finished: `bash scripts/free_running.sh` resumes it)."
                   if any(episodes[a] < max(episodes.values()) for a in free) else "."))


def pooled_parts(rows: Sequence[PairedRow]) -> str:
    """Pooled paired rows inline, "B condition A - B (interval) (p, routes)", by B then training conditions first."""
    return "; ".join(f"{row.b} {row.condition} {row.difference_text()} (p {row.mcnemar_p:.3f}, {row.routes} routes)"
                     for row in sorted(rows, key=lambda row: (row.b, row.condition != "train")))
