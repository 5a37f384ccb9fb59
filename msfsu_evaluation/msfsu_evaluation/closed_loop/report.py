"""results.json, results.md and Fig. 7-style plots from the episode records of one or more benchmark runs.

    msfsu-benchmark-report RUN_DIR [RUN_DIR ...] --out DIR        # e.g. the shards of one suite
    msfsu-benchmark-report LOCKSTEP_RUN FREE_RUN --agents msfsu msfsu_realtime --out DIR   # only these agents
    msfsu-benchmark-report EXPERT_RUN NETWORKS_RUN --prefer expert=EXPERT_RUN --out DIR   # both hold the expert

Every number comes from the runs' `episodes.jsonl` (and, for the trajectory RMSE and the plots, their
`trajectories/`). Runs merge only where they do not overlap: an agent's route recorded in two runs is
refused unless `--prefer AGENT=RUN` names the run whose records of that agent win (within one run, a later
record of a route replaces an earlier one: a resumed or repeated route); results.json and the page say which
run each agent's records came from. Per cell (agent x suite x task x condition): successes / episodes with
a Wilson 95 % interval, route completion, the leaderboard-style driving score, infractions per km
(closed_loop.statistics); for every two networks, a paired comparison on the routes both drove (per
suite and condition, and over both suites: exact McNemar p, Newcombe interval of the difference) and,
per cell, whether their success intervals overlap. Success
tables are laid out like the paper's Tables 1-3, the expert first (the reference column). RMSE table:
the static CoRL2017 tasks, each network's trajectory against the expert's on the same route (both
successful). Paths written into the results are relative to the repository (or the working directory).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections import Counter
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msfsu_evaluation.closed_loop.lateral import solid_line_markdown, solid_line_summary  # noqa: E402
from msfsu_evaluation.closed_loop.paper import (  # noqa: E402
    GOALS, PAPER_MSFSU_SUCCESS, PEDESTRIAN_PER_KM_HELDOUT_GOAL, against)
from msfsu_evaluation.closed_loop.runner import (  # noqa: E402
    EXPERT, RUN_FILE, RunInfo, read_episodes, trajectory_path)
from msfsu_evaluation.closed_loop.statistics import (  # noqa: E402
    cell_statistics, paired_comparison, recorded_infractions)
from msfsu_evaluation.closed_loop.suites import ROUTE_FILES, TASKS, BenchmarkRoute, load_routes  # noqa: E402
from msfsu_evaluation.closed_loop.trajectory import episode_path_rmse, episode_rmse, task_rmse  # noqa: E402
from msfsu_evaluation.usage import UsageError  # noqa: E402

RMSE_TASKS = ("straight", "one_turn", "navigation")  # paper Table 3: the static navigation tasks
REPOSITORY = Path(__file__).resolve().parents[3]


def relative(path: Path | str) -> str:
    """`path` relative to the repository, else to the working directory, else as given."""
    path = Path(path)
    for base in (REPOSITORY, Path.cwd()):
        try:
            return str(path.resolve().relative_to(base.resolve()))
        except ValueError:
            continue
    return str(path)


@dataclass(frozen=True)
class Record:
    """One finished episode and the run directory that holds its trajectory."""

    run: Path
    episode: dict

    @property
    def key(self) -> tuple[str, str]:
        return self.episode["agent"], self.episode["route"]

    def trajectory(self) -> np.ndarray:
        return np.load(trajectory_path(self.run, *self.key))


def merge(runs: Sequence[Path], agents: Collection[str] | None = None,
          prefer: Mapping[str, Path] | None = None) -> dict[tuple[str, str], Record]:
    """The episodes of several runs (of `agents`; None: all). Within a run the last record of an (agent, route)
    wins; across runs an (agent, route) may appear once, unless `prefer` names the run that wins for that agent
    (UsageError otherwise, naming both runs)."""
    prefer = prefer or {}
    merged: dict[tuple[str, str], Record] = {}
    for run in runs:
        own: dict[tuple[str, str], Record] = {}
        for episode in read_episodes(run):
            if agents is None or episode["agent"] in agents:
                record = Record(run, episode)
                own[record.key] = record
        for key, record in own.items():
            earlier = merged.get(key)
            if earlier is not None:
                agent, route = key
                if prefer.get(agent) not in (earlier.run, run):
                    raise UsageError(f"{agent} drove {route} in both {relative(earlier.run)} and {relative(run)}: "
                                     f"name the run that wins with --prefer {agent}=RUN")
                if earlier.run == prefer[agent]:
                    continue
            merged[key] = record
    return merged


# what an episode did, as its record says (wall time and the worker that ran it aside)
DRIVEN_FIELDS = ("status", "success", "time_s", "steps", "route_completion", "collision_type", "distance_to_goal_m",
                 "solid_line_crossings")


def _same(a: Record, b: Record, fields: Sequence[str]) -> bool:
    return all(a.episode.get(field) == b.episode.get(field) for field in fields)


def identical(a: Record, b: Record) -> bool:
    """Two records of one agent and route drove the same episode: every DRIVEN_FIELDS value the same and, where both
    runs kept it, the whole trajectory."""
    if not _same(a, b, DRIVEN_FIELDS):
        return False
    paths = [trajectory_path(record.run, *record.key) for record in (a, b)]
    return not all(path.exists() for path in paths) or np.array_equal(np.load(paths[0]), np.load(paths[1]))


def overlaps(runs: Sequence[Path], agents: Collection[str] | None = None) -> dict[str, dict]:
    """Where two runs hold the same agent on the same route (the expert re-driven beside the networks), how often
    they agree: {agent: {"routes", "identical" (every driven field and the whole trajectory), "same_outcome",
    "differ": [routes whose records are not identical]}}. With a deterministic simulator every record is identical."""
    held: dict[tuple[str, str], list[Record]] = {}
    for run in runs:
        own = {(e["agent"], e["route"]): e for e in read_episodes(run) if agents is None or e["agent"] in agents}
        for key, episode in own.items():  # within a run the last record of a route wins, as in merge()
            held.setdefault(key, []).append(Record(run, episode))
    found: dict[str, dict] = {}
    for (agent, route), records in sorted(held.items()):
        if len(records) < 2:
            continue
        first, *others = records
        same = all(identical(first, other) for other in others)
        entry = found.setdefault(agent, {"routes": 0, "identical": 0, "same_outcome": 0, "differ": []})
        entry["routes"] += 1
        entry["identical"] += same
        entry["same_outcome"] += all(_same(first, o, ("status",)) for o in others)
        if not same:
            entry["differ"].append(route)
    return found


def overlap_markdown(found: Mapping[str, dict], listed: int = 12) -> list[str]:
    lines = []
    for agent, x in found.items():
        differ = ", ".join(x["differ"][:listed]) + (f" and {len(x['differ']) - listed} more (results.json lists them)"
                                                    if len(x["differ"]) > listed else "")
        lines.append(f"{agent} drove {x['routes']} routes in more than one run: {x['identical']} records identical "
                     f"(every driven field and the whole trajectory), {x['same_outcome']} with the same outcome"
                     + (f"; not identical: {differ}" if x["differ"] else "") + ".")
    return lines


def sources_of(records: Mapping[tuple[str, str], Record]) -> dict[str, dict[str, int]]:
    """{agent: {run: episodes}}: where each agent's records came from."""
    counts: dict[str, Counter[str]] = {}
    for (agent, _), record in records.items():
        counts.setdefault(agent, Counter())[relative(record.run)] += 1
    return {agent: dict(sorted(runs.items())) for agent, runs in sorted(counts.items())}


def _percent(value: float | None, digits: int = 0) -> str:
    return "–" if value is None else f"{100 * value:.{digits}f}"


def _metres(value: float | None) -> str:
    return "–" if value is None else f"{value:.3f}"


def summarise(records: dict[tuple[str, str], Record], routes: Sequence[BenchmarkRoute],
              agents: Sequence[str], routes_version: int) -> dict:
    """Per agent, suite, task and condition: the cell's statistics, outcomes, collisions by type, RMSE."""
    by_key = {route.key: route for route in routes}
    lengths = {route.key: route.length_m for route in routes}
    cells: dict[tuple[str, str, str, str], list[Record]] = {}
    for (agent, key), record in sorted(records.items()):
        if key in by_key and agent in agents:
            route = by_key[key]
            cells.setdefault((agent, route.suite, route.task, route.condition), []).append(record)
    results: dict = {}
    for (agent, suite, task, condition), members in cells.items():
        episodes = [record.episode for record in members]
        stats = cell_statistics(episodes, lengths, recorded_infractions(routes_version))
        rmse, path_rmse = [], []
        for record in members:
            reference = records.get((EXPERT, record.key[1]))
            if agent != EXPERT and record.episode["success"] and reference and reference.episode["success"]:
                mine, expert = record.trajectory()[:, 1:3], reference.trajectory()[:, 1:3]
                rmse.append(episode_rmse(mine, expert))
                path_rmse.append(episode_path_rmse(mine, expert))
        results.setdefault(agent, {}).setdefault(suite, {}).setdefault(task, {})[condition] = {
            "episodes": stats.episodes, "successes": stats.successes, "success_rate": stats.success_rate,
            "success_ci95": [round(stats.success.low, 4), round(stats.success.high, 4)],
            "route_completion": round(stats.route_completion, 4), "driving_score": round(stats.driving_score, 4),
            "km_driven": round(stats.km_driven, 3), "infractions": stats.infractions,
            "infractions_per_km": {k: (None if v is None else round(v, 3))
                                   for k, v in stats.infractions_per_km().items()},
            "outcomes": dict(Counter(e["status"] for e in episodes)),
            "collisions": dict(Counter(e["collision_type"] for e in episodes if e["collision_type"])),
            "wall_s_per_episode": round(float(np.mean([e["wall_s"] for e in episodes])), 1),
            "rmse_m": task_rmse(rmse), "path_rmse_m": task_rmse(path_rmse), "rmse_episodes": len(rmse),
        }
    return results


def paired(records: dict[tuple[str, str], Record], routes: Sequence[BenchmarkRoute], agents: Sequence[str],
           conditions: Sequence[str]) -> list[dict]:
    """Every two networks on the routes both drove: per suite and condition, then both suites ("all") per condition."""
    networks = [a for a in agents if a != EXPERT]
    by_key = {route.key: route for route in routes}
    success: dict[str, dict[str, bool]] = {agent: {} for agent in networks}
    for (agent, key), record in records.items():
        if agent in success and key in by_key:
            success[agent][key] = bool(record.episode["success"])
    suites = sorted({route.suite for route in routes})
    scopes = [(suite, condition, {key for key, route in by_key.items()
                                  if route.condition == condition and suite in ("all", route.suite)})
              for suite in [*suites, *(["all"] if len(suites) > 1 else [])] for condition in conditions]
    rows = []
    for a, b in itertools.combinations(networks, 2):
        for suite, condition, keys in scopes:
            comparison = paired_comparison({k: v for k, v in success[a].items() if k in keys},
                                           {k: v for k, v in success[b].items() if k in keys})
            if comparison is not None:
                rows.append({"a": a, "b": b, "suite": suite, "condition": condition, "routes": comparison.routes,
                             "a_successes": comparison.a_successes, "b_successes": comparison.b_successes,
                             "only_a": comparison.only_a, "only_b": comparison.only_b,
                             "difference": round(comparison.difference, 4),
                             "difference_ci95": [round(comparison.difference_ci95.low, 4),
                                                 round(comparison.difference_ci95.high, 4)],
                             "mcnemar_p": round(comparison.p_value, 4)})
    return rows


def difference_text(row: dict) -> str:
    """A paired row's A - B in points with its interval: "-7 (-16 to +1)"."""
    low, high = row["difference_ci95"]
    return f"{100 * row['difference']:+.0f} ({100 * low:+.0f} to {100 * high:+.0f})"


def paired_markdown(rows: Sequence[dict]) -> list[str]:
    if not rows:
        return []
    lines = ["## Ablation: paired comparison on the same routes", "",
             "Both networks drove the same routes; only the routes exactly one of them finished (only A, only B) tell "
             "them apart. Difference: success rate A - B in points (Newcombe 95 % interval); p: exact McNemar test. "
             "An interval that excludes 0 (p < 0.05) separates the two.", "",
             "| A vs B | Suite | Condition | Routes | A | B | Only A | Only B | A - B (95 % CI), points | McNemar p |",
             "|" + " --- |" * 10]
    for row in rows:
        lines.append(f"| {row['a']} vs {row['b']} | {row['suite']} | {row['condition']} | {row['routes']} | "
                     f"{row['a_successes']} | {row['b_successes']} | {row['only_a']} | {row['only_b']} | "
                     f"{difference_text(row)} | {row['mcnemar_p']:.3f} |")
    return [*lines, ""]


def _cell(results: dict, agent: str, suite: str, task: str, condition: str) -> dict | None:
    return results.get(agent, {}).get(suite, {}).get(task, {}).get(condition)


def _success(cell: dict | None) -> str:
    if not cell:
        return "–"
    low, high = cell["success_ci95"]
    return f"{cell['successes']}/{cell['episodes']} ({_percent(cell['success_rate'])}; {_percent(low)}-{_percent(high)})"


def _separation(a: dict | None, b: dict | None, names: tuple[str, str]) -> str:
    """Do two cells' success intervals overlap? Otherwise, which agent is higher."""
    if not a or not b:
        return "–"
    (a_low, a_high), (b_low, b_high) = a["success_ci95"], b["success_ci95"]
    if a_low <= b_high and b_low <= a_high:
        return "overlap"
    return f"{names[0] if a_low > b_high else names[1]} higher"


def condition_infractions(results: dict, agent: str, condition: str) -> tuple[float, dict[str, int]] | None:
    """An agent's km driven and infraction counts over every cell of one condition (None: it drove none)."""
    cells = [cell for suite in results.get(agent, {}).values() for task in suite.values()
             if (cell := task.get(condition))]
    if not cells:
        return None
    return (sum(cell["km_driven"] for cell in cells),
            {kind: sum(cell["infractions"][kind] for cell in cells) for kind in cells[0]["infractions"]})


def against_paper(results: dict, agents: Sequence[str]) -> dict:
    """Per agent: every cell of the paper's Tables 1-2 it drove, measured against the paper's MSFSU and the v3 goal
    (closed_loop.paper), and its pedestrian collisions per km over the held-out cells against that goal."""
    found: dict = {}
    for agent in agents:
        cells = {}
        for suite, task, condition in PAPER_MSFSU_SUCCESS:
            if cell := _cell(results, agent, suite, task, condition):
                measured = against((suite, task, condition), cell["successes"], cell["episodes"],
                                   *cell["success_ci95"])
                cells[f"{suite}/{task}/{condition}"] = {
                    "success_rate": round(measured.rate, 2),
                    "success_ci95": [round(measured.low, 2), round(measured.high, 2)],
                    "paper": measured.paper, "goal": measured.goal, "goal_met": measured.goal_met,
                    "versus_paper": measured.versus_paper}
        if not cells:
            continue
        found[agent] = {"cells": cells}
        if driven := condition_infractions(results, agent, "heldout"):
            km, counts = driven
            per_km = counts["pedestrian"] / km if km > 0 else None
            found[agent]["pedestrian_per_km_heldout"] = {
                "km": round(km, 3), "collisions": counts["pedestrian"],
                "per_km": None if per_km is None else round(per_km, 3), "goal": PEDESTRIAN_PER_KM_HELDOUT_GOAL,
                "goal_met": None if per_km is None else per_km <= PEDESTRIAN_PER_KM_HELDOUT_GOAL}
    return found


def against_paper_markdown(found: Mapping[str, dict], title: bool = True) -> list[str]:
    """The section of results.md (without its heading: `title=False`) from against_paper()'s record."""
    if not found:
        return []
    agents = list(found)
    keys = [key for key in (f"{s}/{t}/{c}" for s, t, c in PAPER_MSFSU_SUCCESS)
            if any(key in found[agent]["cells"] for agent in agents)]
    lines = ["## Against the paper (MSFSU, Tables 1-2) and the v3 goals", ""] if title else []
    lines += ["Paper: the paper's MSFSU success rate, %. Goal: what the v3 models are held to (issue 58; "
              "`msfsu_evaluation/closed_loop/paper.py`). Per agent: success rate % (Wilson 95 % interval), whether it "
              "meets the goal, and where the paper's rate lies: at or above it, below it but inside the interval "
              "(these routes cannot tell the two apart), or below the interval (judged on the unrounded bounds).", "",
              "| Suite / task | Condition | Paper | Goal | " + " | ".join(agents) + " |",
              "|" + " --- |" * (4 + len(agents))]
    for key in keys:
        suite, task, condition = key.split("/")
        row = [f"{suite}/{task}", condition, f"{PAPER_MSFSU_SUCCESS[(suite, task, condition)]:g}",
               f"≥ {GOALS[(suite, task, condition)]:g}" if (suite, task, condition) in GOALS else "–"]
        for agent in agents:
            x = found[agent]["cells"].get(key)
            if x is None:
                row.append("–")
                continue
            goal = "" if x["goal_met"] is None else ("goal met; " if x["goal_met"] else "goal not met; ")
            low, high = x["success_ci95"]
            row.append(f"{x['success_rate']:.0f} ({low:.0f}-{high:.0f}); {goal}{x['versus_paper']}")
        lines.append("| " + " | ".join(row) + " |")
    lines.append("")
    for agent in agents:
        cells = [x for x in found[agent]["cells"].values() if x["goal_met"] is not None]
        summary = f"{agent}: {sum(x['goal_met'] for x in cells)} of {len(cells)} success goals met"
        if pedestrian := found[agent].get("pedestrian_per_km_heldout"):
            verdict = "–" if pedestrian["goal_met"] is None else ("met" if pedestrian["goal_met"] else "not met")
            per_km = "–" if pedestrian["per_km"] is None else f"{pedestrian['per_km']:.2f}"
            summary += (f"; pedestrian collisions held out {per_km} per km ({pedestrian['collisions']} in "
                        f"{pedestrian['km']:.2f} km), goal ≤ {pedestrian['goal']:g}: {verdict}")
        lines.append(summary + ".")
    return [*lines, ""]


def tables_markdown(results: dict, agents: Sequence[str], conditions: Sequence[str], routes_version: int,
                    sources: Sequence[str], paired_rows: Sequence[dict] = (),
                    per_agent: Mapping[str, Mapping[str, int]] | None = None,
                    prefer: Mapping[str, str] | None = None, *, paper: Mapping[str, dict],
                    runtimes: Mapping[str, dict] | None = None) -> str:
    episodes = sum(cell["episodes"] for agent in results.values() for suite in agent.values()
                   for task in suite.values() for cell in task.values())
    lines = [f"# Closed-loop benchmark (routes v{routes_version})", "",
             f"{episodes} episodes from {', '.join(f'`{source}`' for source in sources)} "
             "(`msfsu-benchmark-report` regenerates this page from those records).", "",
             *([("Records per agent: " + "; ".join(
                 f"{agent}: " + ", ".join(f"`{run}` ({count})" for run, count in runs.items())
                 + (f" (where both hold a route, `{prefer[agent]}` wins)" if agent in (prefer or {}) else "")
                 for agent, runs in per_agent.items()) + "."), ""] if per_agent else []),
             *runtimes_markdown(runtimes or {}),
             "Success: successes/episodes (rate %; Wilson 95 % interval %). Driving score (DS): route completion x "
             "infraction penalty (pedestrian 0.50, vehicle 0.60, static object 0.65), mean over episodes, %; "
             "RC: mean route completion, %.", ""]
    suites = sorted({suite for agent in results.values() for suite in agent})
    conditions = [c for c in conditions if any(c in cells for agent in results.values() for suite in agent.values()
                                               for cells in suite.values())]
    networks = [a for a in agents if a != EXPERT]
    for suite in suites:
        tasks = [key for key in TASKS if any(_cell(results, a, suite, key, c) for a in agents for c in conditions)]
        header = ["Task"] + [f"{c}: {a}" for c in conditions for a in agents]
        lines += [f"## {suite}: success", "", "| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
        for task in tasks:
            lines.append("| " + " | ".join([task] + [_success(_cell(results, a, suite, task, c))
                                                      for c in conditions for a in agents]) + " |")
        lines += ["", f"## {suite}: driving score and route completion (%)", "",
                  "| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
        for task in tasks:
            cells = [_cell(results, a, suite, task, c) for c in conditions for a in agents]
            lines.append("| " + " | ".join([task] + [
                f"DS {_percent(x['driving_score'], 1)}, RC {_percent(x['route_completion'], 1)}" if x else "–"
                for x in cells]) + " |")
        lines += ["", f"Outcomes ({suite}): " + "; ".join(
            f"{a}/{c}/{t}: " + ", ".join(f"{k} {v}" for k, v in sorted(x["outcomes"].items()))
            + (" (collisions: " + ", ".join(f"{k} {v}" for k, v in sorted(x["collisions"].items())) + ")"
               if x["collisions"] else "")
            for t in tasks for c in conditions for a in agents if (x := _cell(results, a, suite, t, c))), ""]
    infractions = recorded_infractions(routes_version)
    lines += ["## Infractions per km driven", "",
              "| Agent | Condition | km driven | " + " | ".join(infractions) + " |",
              "|" + " --- |" * (3 + len(infractions))]
    for agent in agents:
        for condition in conditions:
            if driven := condition_infractions(results, agent, condition):
                km, counts = driven
                lines.append(f"| {agent} | {condition} | {km:.2f} | " + " | ".join(
                    f"{counts[k] / km:.2f} ({counts[k]})" if km > 0 else f"– ({counts[k]})" for k in infractions)
                    + " |")
    lines.append("")
    lines += against_paper_markdown(paper)
    lines += paired_markdown(paired_rows)
    if len(networks) > 1:
        pairs = list(itertools.combinations(networks, 2))
        header = ["Suite / task", "Condition"] + [f"{a} vs {b}" for a, b in pairs]
        lines += ["## Ablation per cell: do the networks' success intervals separate?", "",
                  "\"overlap\": the 95 % intervals overlap, so these episodes cannot rank the two; \"X higher\": "
                  "they do not.", "", "| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
        for suite in suites:
            for task in TASKS:
                for condition in conditions:
                    row = [_separation(_cell(results, a, suite, task, condition),
                                       _cell(results, b, suite, task, condition), (a, b)) for a, b in pairs]
                    if any(value != "–" for value in row):
                        lines.append("| " + " | ".join([f"{suite}/{task}", condition] + row) + " |")
        lines.append("")
    if networks:
        header = ["Task", "Condition"] + networks
        rows = []
        for suite in suites:
            for task in RMSE_TASKS:
                for condition in conditions:
                    cells = [_cell(results, a, suite, task, condition) for a in networks]
                    if any(cells):
                        rows.append("| " + " | ".join([f"{suite}/{task}", condition] + [
                            f"{_metres(x['rmse_m'])} (path {_metres(x['path_rmse_m'])}, n={x['rmse_episodes']})"
                            if x else "–" for x in cells]) + " |")
        if rows:
            lines += ["## Trajectory RMSE against the expert (m; paper formula, over successful episodes)", "",
                      "| " + " | ".join(header) + " |", "|" + " --- |" * len(header), *rows, ""]
    return "\n".join(lines)


def plot_trajectories(records: dict[tuple[str, str], Record], route_key: str, agents: Sequence[str],
                      path: Path) -> Path | None:
    """Paper Fig. 7: the agents' and the expert's trajectory on one route, and their yaw rates over time."""
    drawn = [(agent, records[(agent, route_key)].trajectory()) for agent in agents if (agent, route_key) in records]
    if not drawn:
        return None
    figure, (xy, yaw) = plt.subplots(1, 2, figsize=(11, 4.5))
    for agent, trajectory in drawn:
        style = dict(color="black", linestyle="--") if agent == EXPERT else {}
        xy.plot(trajectory[:, 1], trajectory[:, 2], label=agent, **style)
        yaw.plot(trajectory[:, 0] - trajectory[0, 0], trajectory[:, 4], label=agent, **style)
    xy.set(title=f"trajectory ({route_key})", xlabel="x (m)", ylabel="y (m)")
    xy.set_aspect("equal", adjustable="datalim")
    yaw.set(title="yaw rate", xlabel="time (s)", ylabel="yaw rate (rad/s)")
    xy.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=110, metadata={"Software": None})  # no version stamp: regenerated files compare
    plt.close(figure)
    return path


def figure_routes(routes: Sequence[BenchmarkRoute], records: dict[tuple[str, str], Record],
                  agents: Sequence[str]) -> list[str]:
    """Per condition, the first route with the most turns that every agent finished successfully (else any)."""
    succeeded = {key for key, record in records.items() if record.episode["success"]}
    ran = {route_key for _, route_key in records}
    chosen = []
    for condition in dict.fromkeys(route.condition for route in routes):
        candidates = sorted((r for r in routes if r.condition == condition and r.key in ran),
                            key=lambda r: (not all((a, r.key) in succeeded for a in agents), -len(r.junctions), r.key))
        if candidates:
            chosen.append(candidates[0].key)
    return chosen


def free_running_summary(records: dict[tuple[str, str], Record], routes: Sequence[BenchmarkRoute],
                         agents: Sequence[str]) -> dict:
    """Per agent that drove free-running (msfsu_sim.pacing) and condition: factors and the ages of the controls."""
    conditions = {route.key: route.condition for route in routes}
    groups: dict[tuple[str, str], list[dict]] = {}
    for (agent, key), record in sorted(records.items()):
        if agent in agents and key in conditions and record.episode.get("free_running"):
            groups.setdefault((agent, conditions[key]), []).append(record.episode["free_running"])
    summary: dict = {}
    for (agent, condition), runs in groups.items():
        ages: Counter[int] = Counter()
        for run in runs:
            ages.update({int(age): count for age, count in run["control_age_steps"].items()})
        ordered = sorted(ages.elements())
        steps = sum(run["steps"] for run in runs)
        achieved = [run["achieved_real_time_factor"] for run in runs]
        summary.setdefault(agent, {})[condition] = {
            "episodes": len(runs), "real_time_factor": sorted({run["real_time_factor"] for run in runs}),
            "achieved_mean": round(float(np.mean(achieved)), 3), "achieved_min": round(float(min(achieved)), 3),
            "steps": steps, "late_share": round(sum(run["late_steps"] for run in runs) / max(steps, 1), 4),
            "without_control": sum(run["steps_without_control"] for run in runs),
            "control_age_steps": {str(age): ages[age] for age in sorted(ages)},
            "fresh_share": round(ages[0] / max(len(ordered), 1), 4),
            "control_age_p95_steps": ordered[min(len(ordered) - 1, int(np.ceil(0.95 * len(ordered))) - 1)]
            if ordered else None,
            "control_age_max_steps": ordered[-1] if ordered else None,
        }
    return summary


def free_running_markdown(summary: dict) -> list[str]:
    if not summary:
        return []
    lines = ["## Free-running (the simulator on the wall clock, the last control that arrived applies)", "",
             "Control age: simulator steps (100 ms) between the frame a control answered and the step it was applied "
             "to (0: its own frame, as in lockstep). Late: steps the simulator itself started after they were due.",
             "", "| Agent | Condition | episodes | factor stated | achieved mean (min) | late steps | control age 0 "
             "| p95 | max | steps before the first control |", "|" + " --- |" * 10]
    for agent, conditions in summary.items():
        for condition, x in conditions.items():
            lines.append(f"| {agent} | {condition} | {x['episodes']} | {', '.join(f'{f:g}' for f in x['real_time_factor'])} "
                         f"| {x['achieved_mean']:.2f} ({x['achieved_min']:.2f}) | {100 * x['late_share']:.1f} % | "
                         f"{100 * x['fresh_share']:.1f} % | {x['control_age_p95_steps']} | {x['control_age_max_steps']} | "
                         f"{x['without_control']} |")
    return lines + [""]


def write_reports(out: Path, runs: Sequence[Path], routes: Sequence[BenchmarkRoute], agents: Sequence[str] | None,
                  conditions: Sequence[str], routes_version: int, run_info: dict,
                  prefer: Mapping[str, Path] | None = None) -> dict:
    """Merge the runs' records and write results.json, results.md and the figures into `out`."""
    # the expert's records stay in whenever they exist: they are every network's RMSE reference
    records = merge(runs, None if agents is None else {*agents, EXPERT}, prefer)
    ran = {route_key for _, route_key in records}
    routes = [route for route in routes if route.key in ran]
    # the expert first, then by name, however they were asked for (the benchmark's own page equals the report's)
    agents = sorted({agent for agent, _ in records} if agents is None else set(agents), key=lambda a: (a != EXPERT, a))
    results = summarise(records, routes, agents, routes_version)
    paired_rows = paired(records, routes, agents, conditions)
    free_running = free_running_summary(records, routes, agents)
    solid_lines = solid_line_summary([record.episode for key, record in sorted(records.items()) if key[0] in agents],
                                     {route.key: route.condition for route in routes})
    out.mkdir(parents=True, exist_ok=True)
    figures = []
    for key in figure_routes(routes, records, agents):
        figure = plot_trajectories(records, key, agents, out / f"trajectories_{key.replace('/', '_')}.png")
        if figure:
            figures.append(figure.name)
    sources = [relative(run) for run in runs]
    per_agent = sources_of(records)
    report = {"routes_version": routes_version, "run": run_info, "records": sources, "agents": list(agents),
              "sources": per_agent, "results": results, "paired": paired_rows,
              "against_paper": against_paper(results, agents), "figures": figures}
    if prefer:
        report["prefer"] = {agent: relative(run) for agent, run in sorted(prefer.items())}
        report["overlap"] = overlaps(runs, set(prefer))
    if free_running:
        report["free_running"] = free_running
    if solid_lines:
        report["solid_lines"] = solid_lines
    (out / "results.json").write_text(json.dumps(report, indent=2) + "\n")
    markdown = tables_markdown(results, agents, conditions, routes_version, sources, paired_rows, per_agent,
                               report.get("prefer", {}), paper=report["against_paper"],
                               runtimes=run_info.get("runtimes", {}))
    if report.get("overlap"):
        markdown += "\n## Runs that drove the same routes\n\n" + "\n".join(overlap_markdown(report["overlap"])) + "\n"
    markdown += "\n".join(free_running_markdown(free_running))
    markdown += "\n".join(solid_line_markdown(solid_lines))
    markdown += "\n" + "\n".join(f"![{name}]({name})" for name in figures) + "\n"
    (out / "results.md").write_text(markdown)
    return report


def read_run_info(run: Path) -> dict:
    path = run / RUN_FILE
    if not path.is_file():
        raise UsageError(f"{run} is no benchmark run directory (no {RUN_FILE})")
    return json.loads(path.read_text())


def report_run_info(infos: Sequence[dict], routes_version: int, routes_file: str) -> dict:
    """What a report says of the runs it merges (results.json "run"): routes, the simulator revision and, where they
    drove networks, the node graph revision (msfsu_bringup.GRAPH_REVISION; absent for the expert alone, who drives
    without the graph). UsageError where runs of different revisions would mix."""
    runs = [RunInfo.of(run) for run in infos]
    revisions = {run.simulator_revision for run in runs}
    if len(revisions) != 1:
        raise UsageError(f"the runs are of different simulator revisions {sorted(revisions)}: never mixed")
    info = {"routes_version": routes_version, "routes_file": routes_file, "simulator_revision": revisions.pop()}
    graphs = {run.graph_revision for run in runs if run.graph_revision is not None}
    if len(graphs) > 1:
        raise UsageError(f"the runs drove networks through different node graph revisions {sorted(graphs)}: "
                         "never mixed")
    info = {**info, "graph_revision": graphs.pop()} if graphs else info
    runtimes = network_runtimes(infos)
    return {**info, "runtimes": runtimes} if runtimes else info


def network_runtimes(infos: Sequence[dict]) -> dict[str, dict]:
    """Per network agent of runs that recorded it (run.json agent_runtimes): the backend and precision asked of its
    perception node and what the node ran on each leg's machine ('cpu openvino/int8'). Empty for older runs."""
    runtimes: dict[str, dict] = {}
    for run in infos:
        for agent, asked in run.get("agent_runtimes", {}).items():
            ran = [leg["runtimes"][agent] for leg in run.get("legs", []) if agent in leg.get("runtimes", {})]
            entry = runtimes.setdefault(agent, {**asked, "ran_as": []})
            entry["ran_as"] = sorted({*entry["ran_as"], *ran})
    return dict(sorted(runtimes.items()))


def runtimes_markdown(runtimes: Mapping[str, dict]) -> list[str]:
    """One line: each network's backend/precision as asked and as run (empty where the runs recorded none)."""
    if not runtimes:
        return []
    return ["Networks' inference (asked -> ran as): " + "; ".join(
        f"{agent}: {r['backend']}/{r['precision']} -> {', '.join(r['ran_as']) or 'not recorded'}"
        for agent, r in runtimes.items()) + ".", ""]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="msfsu-benchmark-report", description=__doc__.split("\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("runs", nargs="+", type=Path, help="run directories of msfsu-benchmark (shards, re-runs)")
    parser.add_argument("--out", type=Path, required=True, help="where results.json, results.md and PNGs go")
    parser.add_argument("--agents", nargs="+", help="report only these agents (default: every agent the records hold)")
    parser.add_argument("--prefer", nargs="+", default=[], metavar="AGENT=RUN",
                        help="where two runs hold the same route of AGENT, RUN's record wins (else refused)")
    options = parser.parse_args(argv)
    try:
        infos = [read_run_info(run) for run in options.runs]
        versions = {info["routes_version"] for info in infos}
        if len(versions) != 1:
            raise UsageError(f"the runs are on different route versions {sorted(versions)}: never mixed")
        version = versions.pop()
        if version not in ROUTE_FILES:
            raise UsageError(f"the runs are on routes v{version}, this benchmark knows {sorted(ROUTE_FILES)}")
        info = report_run_info(infos, version, relative(ROUTE_FILES[version]))
        version, routes = load_routes(ROUTE_FILES[version])
        conditions = list(dict.fromkeys(route.condition for route in routes))
        agents = None
        if options.agents:
            held = {episode["agent"] for run in options.runs for episode in read_episodes(run)}
            if missing := [agent for agent in options.agents if agent not in held]:
                raise UsageError(f"no episodes of {', '.join(missing)} in these runs (they hold {', '.join(sorted(held))})")
            agents = options.agents
        prefer = {}
        for item in options.prefer:
            agent, separator, run = item.partition("=")
            if not separator or Path(run) not in options.runs:
                raise UsageError(f"--prefer {item}: expected AGENT=RUN with RUN one of the run directories given")
            prefer[agent] = Path(run)
        report = write_reports(options.out, options.runs, routes, agents, conditions, version, info, prefer)
    except (UsageError, OSError, ValueError, KeyError) as error:
        print(f"msfsu-benchmark-report: {error}", file=sys.stderr)
        return 2
    count = sum(len(read_episodes(run)) for run in options.runs)
    print(f"{count} episode records from {len(options.runs)} runs, {len(report['agents'])} agents -> "
          f"{options.out / 'results.md'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
