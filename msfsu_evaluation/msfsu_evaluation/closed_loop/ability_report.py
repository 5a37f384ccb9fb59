"""The per-ability suite's page: success per ability and condition, collisions, time to the goal, paired tests.

results.json and results.md of a run (or runs) of `msfsu-benchmark --suite abilities`: per agent, ability and
condition, successes / scenarios with a Wilson 95 % interval, collisions by kind, timeouts and blocks, and the mean
time to the goal of the successful scenarios; per pair of agents (the expert included), the paired comparison on the
same scenarios (exact McNemar p, Newcombe 95 % interval; closed_loop.statistics) per ability and condition, per
ability over both conditions and over every conflict ability (clear_road, the control, apart); and collisions.md, the
last seconds before each collision. Every number comes from the runs' episodes.jsonl and telemetry.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from msfsu_evaluation.closed_loop.abilities import ABILITIES, SUITE
from msfsu_evaluation.closed_loop.cells import JsonRecord, PairedRow
from msfsu_evaluation.closed_loop.collisions import collision_windows, collisions_markdown
from msfsu_evaluation.closed_loop.runner import EXPERT
from msfsu_evaluation.closed_loop.runs import Records, merge, relative, sources_of
from msfsu_evaluation.closed_loop.statistics import Interval, paired_comparison, wilson_interval
from msfsu_evaluation.closed_loop.suites import BenchmarkRoute

CONTROL = "clear_road"  # not a conflict: left out of the pooled conflict row
CONFLICTS = "conflicts"  # the pooled row of every ability but the control
BOTH = "all"


@dataclass(frozen=True)
class AbilityCell(JsonRecord):
    """One agent on one ability (or CONFLICTS) in one condition (or BOTH) (results.json "cells")."""

    agent: str
    ability: str
    condition: str
    scenarios: int
    successes: int
    success_ci95: Interval
    collisions: dict[str, int]  # collision type -> count
    timeouts: int  # timeout or blocked
    mean_time_to_goal_s: float | None  # over the successes

    INTERVALS: ClassVar[tuple[str, ...]] = ("success_ci95",)

    def rate_text(self) -> str:
        """Success % (Wilson 95 % interval)."""
        return (f"{100 * self.successes / self.scenarios:.0f} ({100 * self.success_ci95.low:.0f}-"
                f"{100 * self.success_ci95.high:.0f})")

    def text(self) -> str:
        rate = self.rate_text()
        hits = ", ".join(f"{count} {kind}" for kind, count in sorted(self.collisions.items()) if count)
        parts = [rate, f"hit {hits}" if hits else "", f"{self.timeouts} stuck" if self.timeouts else "",
                 f"{self.mean_time_to_goal_s:.1f} s" if self.mean_time_to_goal_s is not None else ""]
        return "; ".join(part for part in parts if part)


def cell(agent: str, ability: str, condition: str, records: Records, routes: Sequence[BenchmarkRoute]) -> AbilityCell | None:
    episodes = [records[(agent, route.key)].episode for route in routes if (agent, route.key) in records]
    if not episodes:
        return None
    successes = sum(episode.success for episode in episodes)
    collisions: dict[str, int] = {}
    for episode in episodes:
        if episode.status == "collision":
            collisions[episode.collision_type] = collisions.get(episode.collision_type, 0) + 1
    times = [episode.time_s for episode in episodes if episode.success]
    interval = wilson_interval(successes, len(episodes))
    return AbilityCell(agent, ability, condition, len(episodes), successes,
                       Interval(round(interval.low, 4), round(interval.high, 4)), collisions,
                       sum(episode.status in ("timeout", "blocked") for episode in episodes),
                       round(sum(times) / len(times), 2) if times else None)


def _groups(routes: Sequence[BenchmarkRoute], conditions: Sequence[str]) -> list[tuple[str, str, list[BenchmarkRoute]]]:
    """(ability, condition, its scenarios): every ability x condition, each ability over both, the conflicts pooled."""
    groups = []
    for ability in ABILITIES:
        for condition in conditions:
            groups.append((ability, condition, [r for r in routes if r.task == ability and r.condition == condition]))
        groups.append((ability, BOTH, [r for r in routes if r.task == ability]))
    for condition in (*conditions, BOTH):
        groups.append((CONFLICTS, condition, [r for r in routes if r.task != CONTROL
                                              and (condition == BOTH or r.condition == condition)]))
    return [group for group in groups if group[2]]


def ability_tables(records: Records, routes: Sequence[BenchmarkRoute], agents: Sequence[str],
                   conditions: Sequence[str]) -> tuple[list[AbilityCell], list[PairedRow]]:
    cells, paired = [], []
    for ability, condition, chosen in _groups(routes, conditions):
        for agent in agents:
            if (found := cell(agent, ability, condition, records, chosen)) is not None:
                cells.append(found)
        for a, b in itertools.combinations(agents, 2):
            success = {agent: {r.key: records[(agent, r.key)].episode.success for r in chosen
                               if (agent, r.key) in records} for agent in (a, b)}
            comparison = paired_comparison(success[a], success[b])
            if comparison is not None:
                paired.append(PairedRow.of(a, b, ability, condition, comparison))
    return cells, paired


def ability_markdown(cells: Sequence[AbilityCell], paired: Sequence[PairedRow], agents: Sequence[str],
                     conditions: Sequence[str], sources: dict, run_info: dict, collisions: int) -> str:
    by_key = {(c.agent, c.ability, c.condition): c for c in cells}
    rows = sorted({(c.ability, c.condition) for c in cells},
                  key=lambda key: ([*ABILITIES, CONFLICTS].index(key[0]), [*conditions, BOTH].index(key[1])))
    lines = ["# Per-ability scenarios", "",
             f"Scenario file: `{run_info.get('routes_file', '')}` (version {run_info.get('abilities_version')}), "
             f"simulator revision {run_info.get('simulator_revision')}"
             + (f", node graph revision {run_info['graph_revision']}" if "graph_revision" in run_info else "")
             + ". Records: " + "; ".join(f"{agent}: {', '.join(runs)}" for agent, runs in sources.items()) + ".", "",
             "Per agent: success % (Wilson 95 % interval); what it hit; scenarios that ended in a timeout or blocked "
             "(stuck); mean time to the goal of the successful ones. `conflicts`: every ability but the clear road "
             "(the control: a car that fails there stopped, or strayed, for nothing).", "",
             "| Ability | Condition | " + " | ".join(agents) + " |", "|" + " --- |" * (2 + len(agents))]
    for ability, condition in rows:
        title = ability if ability == CONFLICTS else f"{ability} ({ABILITIES[ability].title})"
        lines.append(f"| {title} | {condition} | " + " | ".join(
            by_key[(agent, ability, condition)].text() if (agent, ability, condition) in by_key else "-"
            for agent in agents) + " |")
    if paired:
        lines += ["", "## Paired comparison on the same scenarios", "",
                  "Only the scenarios exactly one of the two finished (only A, only B) tell them apart. A - B: success "
                  "rate in points (Newcombe 95 % interval); p: exact McNemar test.", "",
                  "| A vs B | Ability | Condition | Scenarios | A | B | Only A | Only B | A - B (95 % CI), points | "
                  "McNemar p |", "|" + " --- |" * 10, *(row.markdown_row() for row in paired)]
    if collisions:
        lines += ["", "## The last seconds before each collision", "",
                  f"[collisions.md](collisions.md): {collisions} collisions with a vehicle or pedestrian, step by step "
                  "from the episodes' telemetry."]
    return "\n".join(lines) + "\n"


def write_ability_report(out: Path, runs: Sequence[Path], routes: Sequence[BenchmarkRoute],
                         agents: Sequence[str] | None, conditions: Sequence[str], run_info: dict,
                         prefer: Mapping[str, Path] | None = None) -> dict:
    """Merge the runs' records (where two hold an agent's scenario, `prefer`'s run wins) and write results.json,
    results.md and collisions.md into `out`."""
    records = merge(runs, None if agents is None else set(agents), prefer)
    ran = {route_key for _, route_key in records}
    routes = [route for route in routes if route.key in ran]
    agents = sorted({agent for agent, _ in records} if agents is None else set(agents), key=lambda a: (a != EXPERT, a))
    cells, paired = ability_tables(records, routes, agents, conditions)
    windows, without_telemetry = collision_windows(records, agents)
    sources = sources_of(records)
    out.mkdir(parents=True, exist_ok=True)
    report = {"suite": SUITE, "run": run_info, "records": [relative(run) for run in runs], "agents": list(agents),
              "sources": sources, "cells": [c.to_json() for c in cells], "paired": [row.to_json() for row in paired]}
    if prefer:
        report["prefer"] = {agent: relative(run) for agent, run in sorted(prefer.items())}
    if windows:
        report["collisions"] = len(windows)
        (out / "collisions.md").write_text(collisions_markdown(windows, without_telemetry))
    (out / "results.json").write_text(json.dumps(report, indent=2) + "\n")
    (out / "results.md").write_text(ability_markdown(cells, paired, agents, conditions, sources, run_info,
                                                              len(windows)))
    return report

