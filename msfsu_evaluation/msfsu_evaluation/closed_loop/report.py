"""results.json, tables laid out like the paper's Tables 1-3, and Fig. 7-style trajectory / yaw-rate plots.

Success tables: one per suite, a row per task, per condition a column per agent (the expert first, as
the reference row of the paper's tables becomes a reference column here). RMSE table: the static
CoRL2017 tasks, the networks' trajectory RMSE against the expert on the same route (the expert's
own episode of that route must have succeeded too).
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msfsu_evaluation.closed_loop.runner import EXPERT, trajectory_path  # noqa: E402
from msfsu_evaluation.closed_loop.suites import TASKS, BenchmarkRoute  # noqa: E402
from msfsu_evaluation.closed_loop.trajectory import episode_path_rmse, episode_rmse, task_rmse  # noqa: E402

RMSE_TASKS = ("straight", "one_turn", "navigation")  # paper Table 3: the static navigation tasks


def _percent(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.0f}"


def _metres(value: float | None) -> str:
    return "–" if value is None else f"{value:.3f}"


def summarise(episodes: Sequence[dict], routes: Sequence[BenchmarkRoute], agents: Sequence[str],
              out: Path) -> dict:
    """Per agent, suite, task and condition: success rate, outcomes, collisions by type, RMSE."""
    by_key = {route.key: route for route in routes}
    results: dict = {}
    latest = {(e["agent"], e["route"]): e for e in episodes if e["route"] in by_key and e["agent"] in agents}
    for (agent, key), episode in sorted(latest.items()):
        route = by_key[key]
        cell = results.setdefault(agent, {}).setdefault(route.suite, {}).setdefault(route.task, {}).setdefault(
            route.condition, {"episodes": 0, "successes": 0, "outcomes": Counter(), "collisions": Counter(),
                              "route_completion": [], "wall_s": [], "rmse": [], "path_rmse": []})
        cell["episodes"] += 1
        cell["successes"] += episode["success"]
        cell["outcomes"][episode["status"]] += 1
        if episode["collision_type"]:
            cell["collisions"][episode["collision_type"]] += 1
        cell["route_completion"].append(episode["route_completion"])
        cell["wall_s"].append(episode["wall_s"])
        reference = latest.get((EXPERT, key))
        if agent != EXPERT and episode["success"] and reference and reference["success"]:
            mine = np.load(trajectory_path(out, agent, key))[:, 1:3]
            expert = np.load(trajectory_path(out, EXPERT, key))[:, 1:3]
            cell["rmse"].append(episode_rmse(mine, expert))
            cell["path_rmse"].append(episode_path_rmse(mine, expert))
    for agent_cells in results.values():
        for suite in agent_cells.values():
            for task in suite.values():
                for condition, cell in task.items():
                    task[condition] = {
                        "episodes": cell["episodes"], "success_rate": cell["successes"] / cell["episodes"],
                        "outcomes": dict(cell["outcomes"]), "collisions": dict(cell["collisions"]),
                        "route_completion": float(np.mean(cell["route_completion"])),
                        "wall_s_per_episode": float(np.mean(cell["wall_s"])),
                        "rmse_m": task_rmse(cell["rmse"]), "path_rmse_m": task_rmse(cell["path_rmse"]),
                        "rmse_episodes": len(cell["rmse"]),
                    }
    return results


def _cell(results: dict, agent: str, route_suite: str, task: str, condition: str) -> dict | None:
    return results.get(agent, {}).get(route_suite, {}).get(task, {}).get(condition)


def tables_markdown(results: dict, agents: Sequence[str], conditions: Sequence[str], routes_version: int) -> str:
    lines = [f"# Closed-loop benchmark (routes v{routes_version})", ""]
    suites = sorted({suite for agent in results.values() for suite in agent})
    conditions = [c for c in conditions if any(c in cells for agent in results.values() for suite in agent.values()
                                               for cells in suite.values())]
    for suite in suites:
        tasks = [key for key in TASKS if any(_cell(results, a, suite, key, c) for a in agents for c in conditions)]
        header = ["Task"] + [f"{c}: {a}" for c in conditions for a in agents]
        lines += [f"## {suite}: success rate (%)", "", "| " + " | ".join(header) + " |",
                  "|" + " --- |" * len(header)]
        for task in tasks:
            cells = [_cell(results, a, suite, task, c) for c in conditions for a in agents]
            lines.append("| " + " | ".join([task] + [_percent(x and x["success_rate"]) if x else "–" for x in cells])
                         + " |")
        lines += ["", f"Outcomes ({suite}): " + "; ".join(
            f"{a}/{c}/{t}: " + ", ".join(f"{k} {v}" for k, v in sorted(x["outcomes"].items()))
            + (" (collisions: " + ", ".join(f"{k} {v}" for k, v in x["collisions"].items()) + ")"
               if x["collisions"] else "")
            for t in tasks for c in conditions for a in agents if (x := _cell(results, a, suite, t, c))), ""]
    networks = [a for a in agents if a != EXPERT]
    if networks:
        header = ["Task", "Condition"] + networks
        lines += ["## Trajectory RMSE against the expert (m; paper formula, over successful episodes)", "",
                  "| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
        for suite in suites:
            for task in RMSE_TASKS:
                for condition in conditions:
                    cells = [_cell(results, a, suite, task, condition) for a in networks]
                    if any(cells):
                        lines.append("| " + " | ".join([f"{suite}/{task}", condition] + [
                            f"{_metres(x['rmse_m'])} (path {_metres(x['path_rmse_m'])}, n={x['rmse_episodes']})"
                            if x else "–" for x in cells]) + " |")
        lines.append("")
    return "\n".join(lines)


def plot_trajectories(out: Path, route_key: str, agents: Sequence[str], path: Path) -> Path | None:
    """Paper Fig. 7: the agents' and the expert's trajectory on one route, and their yaw rates over time."""
    drawn = [(agent, np.load(p)) for agent in agents if (p := trajectory_path(out, agent, route_key)).exists()]
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
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def figure_routes(routes: Sequence[BenchmarkRoute], episodes: Sequence[dict], agents: Sequence[str]) -> list[str]:
    """Per condition, the first route with the most turns that every agent finished successfully (else any)."""
    succeeded = {(e["agent"], e["route"]) for e in episodes if e["success"]}
    chosen = []
    for condition in dict.fromkeys(route.condition for route in routes):
        candidates = sorted((r for r in routes if r.condition == condition),
                            key=lambda r: (not all((a, r.key) in succeeded for a in agents), -len(r.junctions), r.key))
        if candidates:
            chosen.append(candidates[0].key)
    return chosen


def write_reports(out: Path, episodes: Sequence[dict], routes: Sequence[BenchmarkRoute], agents: Sequence[str],
                  conditions: Sequence[str], routes_version: int, run_info: dict) -> dict:
    results = summarise(episodes, routes, agents, out)
    figures = []
    for key in figure_routes(routes, episodes, agents):
        figure = plot_trajectories(out, key, agents, out / f"trajectories_{key.replace('/', '_')}.png")
        if figure:
            figures.append(figure.name)
    report = {"routes_version": routes_version, "run": run_info, "agents": list(agents), "results": results,
              "figures": figures}
    (out / "results.json").write_text(json.dumps(report, indent=2) + "\n")
    markdown = tables_markdown(results, agents, conditions, routes_version)
    markdown += "\n" + "\n".join(f"![{name}]({name})" for name in figures) + "\n"
    (out / "results.md").write_text(markdown)
    return report
