"""What a report computes from merged episode records: the cells, the paired comparisons of the networks, the
measurement against the paper and the free-running pacing (closed_loop.statistics does the statistics).

Per cell (agent x suite x task x condition): successes / episodes with a Wilson 95 % interval, route completion,
the leaderboard-style driving score, infractions per km and, for a network, its trajectory RMSE against the expert's on
the routes both finished. For every two networks, the paired comparison on the routes both drove, per suite and
condition and, with more than one suite, over all of them ("all").
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Sequence

import numpy as np

from msfsu_evaluation.closed_loop.cells import PairedRow, Results, SummaryCell
from msfsu_evaluation.closed_loop.episode_record import EpisodeResult, FreeRunning
from msfsu_evaluation.closed_loop.paper import PAPER_MSFSU_SUCCESS, PEDESTRIAN_PER_KM_HELDOUT_GOAL, against
from msfsu_evaluation.closed_loop.runner import EXPERT
from msfsu_evaluation.closed_loop.runs import Record, Records
from msfsu_evaluation.closed_loop.statistics import cell_statistics, paired_comparison, recorded_infractions
from msfsu_evaluation.closed_loop.suites import BenchmarkRoute
from msfsu_evaluation.closed_loop.trajectory import episode_path_rmse, episode_rmse, task_rmse

CellKey = tuple[str, str, str, str]  # agent, suite, task, condition


def _cell_members(records: Records, routes: Sequence[BenchmarkRoute],
                  agents: Sequence[str]) -> dict[CellKey, list[Record]]:
    """The records of `agents` on `routes`, grouped by cell, in (agent, route) order."""
    by_key = {route.key: route for route in routes}
    cells: dict[CellKey, list[Record]] = {}
    for (agent, key), record in sorted(records.items()):
        if key in by_key and agent in agents:
            route = by_key[key]
            cells.setdefault((agent, route.suite, route.task, route.condition), []).append(record)
    return cells


def _rmse_against_expert(records: Records, members: Sequence[Record]) -> tuple[list[float], list[float]]:
    """Per member the expert also finished (a network's own success only): the time-aligned and the path RMSE."""
    rmse, path_rmse = [], []
    for record in members:
        agent, route = record.key
        reference = records.get((EXPERT, route))
        if agent != EXPERT and record.episode.success and reference and reference.episode.success:
            mine, expert = record.trajectory()[:, 1:3], reference.trajectory()[:, 1:3]
            rmse.append(episode_rmse(mine, expert))
            path_rmse.append(episode_path_rmse(mine, expert))
    return rmse, path_rmse


def summarise(records: Records, routes: Sequence[BenchmarkRoute], agents: Sequence[str],
              routes_version: int) -> Results:
    """Per agent, suite, task and condition: the cell's statistics, outcomes, collisions by type, RMSE."""
    lengths = {route.key: route.length_m for route in routes}
    cells: dict = {}
    for (agent, suite, task, condition), members in _cell_members(records, routes, agents).items():
        episodes = [record.episode for record in members]
        rmse, path_rmse = _rmse_against_expert(records, members)
        cells.setdefault(agent, {}).setdefault(suite, {}).setdefault(task, {})[condition] = SummaryCell.of(
            cell_statistics(episodes, lengths, recorded_infractions(routes_version)),
            outcomes=Counter(e.status for e in episodes),
            collisions=Counter(e.collision_type for e in episodes if e.collision_type),
            wall_s=float(np.mean([e.wall_s for e in episodes])),
            rmse_m=task_rmse(rmse), path_rmse_m=task_rmse(path_rmse), rmse_episodes=len(rmse))
    return Results(cells)


def paired(records: Records, routes: Sequence[BenchmarkRoute], agents: Sequence[str],
           conditions: Sequence[str]) -> list[PairedRow]:
    """Every two networks on the routes both drove: per suite and condition, then both suites ("all") per condition."""
    networks = [a for a in agents if a != EXPERT]
    by_key = {route.key: route for route in routes}
    success: dict[str, dict[str, bool]] = {agent: {} for agent in networks}
    for (agent, key), record in records.items():
        if agent in success and key in by_key:
            success[agent][key] = record.episode.success
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
                rows.append(PairedRow.of(a, b, suite, condition, comparison))
    return rows


def condition_infractions(results: Results, agent: str, condition: str) -> tuple[float, dict[str, int]] | None:
    """An agent's km driven and infraction counts over every cell of one condition (None: it drove none)."""
    cells = [cell for _, _, held, cell in results.of_agent(agent) if held == condition]
    if not cells:
        return None
    return (sum(cell.km_driven for cell in cells),
            {kind: sum(cell.infractions[kind] for cell in cells) for kind in cells[0].infractions})


def _against_paper_cells(results: Results, agent: str) -> dict[str, dict]:
    """Every cell of the paper's Tables 1-2 the agent drove, measured against the paper and the v3 goal."""
    cells = {}
    for suite, task, condition in PAPER_MSFSU_SUCCESS:
        if cell := results.cell(agent, suite, task, condition):
            measured = against((suite, task, condition), cell.successes, cell.episodes, cell.success_ci95.low,
                               cell.success_ci95.high)
            cells[f"{suite}/{task}/{condition}"] = {
                "success_rate": round(measured.rate, 2),
                "success_ci95": [round(measured.low, 2), round(measured.high, 2)],
                "paper": measured.paper, "goal": measured.goal, "goal_met": measured.goal_met,
                "versus_paper": measured.versus_paper}
    return cells


def _pedestrians_held_out(km: float, counts: dict[str, int]) -> dict:
    per_km = counts["pedestrian"] / km if km > 0 else None
    return {"km": round(km, 3), "collisions": counts["pedestrian"],
            "per_km": None if per_km is None else round(per_km, 3), "goal": PEDESTRIAN_PER_KM_HELDOUT_GOAL,
            "goal_met": None if per_km is None else per_km <= PEDESTRIAN_PER_KM_HELDOUT_GOAL}


def against_paper(results: Results, agents: Sequence[str]) -> dict:
    """Per agent: every cell of the paper's Tables 1-2 it drove, measured against the paper's MSFSU and the v3 goal
    (closed_loop.paper), and its pedestrian collisions per km over the held-out cells against that goal."""
    found: dict = {}
    for agent in agents:
        if not (cells := _against_paper_cells(results, agent)):
            continue
        found[agent] = {"cells": cells}
        if driven := condition_infractions(results, agent, "heldout"):
            found[agent]["pedestrian_per_km_heldout"] = _pedestrians_held_out(*driven)
    return found


def _pacing(runs: Sequence[FreeRunning]) -> dict:
    """The free-running records of one agent and condition pooled: factors, lateness and the ages of the controls."""
    ages: Counter[int] = Counter()
    for run in runs:
        ages.update({int(age): count for age, count in run.control_age_steps.items()})
    ordered = sorted(ages.elements())
    steps = sum(run.steps for run in runs)
    achieved = [run.achieved_real_time_factor for run in runs]
    return {
        "episodes": len(runs), "real_time_factor": sorted({run.real_time_factor for run in runs}),
        "achieved_mean": round(float(np.mean(achieved)), 3), "achieved_min": round(float(min(achieved)), 3),
        "steps": steps, "late_share": round(sum(run.late_steps for run in runs) / max(steps, 1), 4),
        "without_control": sum(run.steps_without_control for run in runs),
        "control_age_steps": {str(age): ages[age] for age in sorted(ages)},
        "fresh_share": round(ages[0] / max(len(ordered), 1), 4),
        "control_age_p95_steps": ordered[min(len(ordered) - 1, int(np.ceil(0.95 * len(ordered))) - 1)]
        if ordered else None,
        "control_age_max_steps": ordered[-1] if ordered else None,
    }


BRAKE_COUNTS = ("brakes", "caps", "false_brakes", "false_caps")  # brake_interventions' keys


def brake_interventions(episodes: Sequence[EpisodeResult]) -> dict[str, int | None]:
    """The summed interventions of episodes that all drove with the emergency brake: brakes, caps, false_brakes and
    false_caps (None unless every record judged its caps: the first brake's runs did not)."""
    return {"brakes": sum(e.aeb.brakes for e in episodes), "caps": sum(e.aeb.caps for e in episodes),
            "false_brakes": sum(e.aeb.false_brakes for e in episodes),
            "false_caps": (sum(e.aeb.false_caps for e in episodes)
                           if all(e.aeb.false_caps is not None for e in episodes) else None)}


def emergency_brake_summary(records: Records, routes: Sequence[BenchmarkRoute], agents: Sequence[str]) -> dict:
    """Per agent that drove with the emergency brake and condition: episodes, km driven and the brake's interventions
    (brakes, caps and, by the simulator's ground truth, the false ones: false_caps None where a record did not judge
    them), with the false ones per 10 km."""
    by_key = {route.key: route for route in routes}
    groups: dict[tuple[str, str], list] = {}
    for (agent, key), record in sorted(records.items()):
        if agent in agents and key in by_key and record.episode.aeb is not None:
            groups.setdefault((agent, by_key[key].condition), []).append(record.episode)
    summary: dict = {}
    for (agent, condition), episodes in groups.items():
        km = sum(e.route_completion * by_key[e.route].length_m for e in episodes) / 1000.0
        total = brake_interventions(episodes)
        false = total["false_brakes"] + (total["false_caps"] or 0)
        summary.setdefault(agent, {})[condition] = {
            "episodes": len(episodes), "km": round(km, 3), **total,
            "false_per_10km": round(10.0 * false / km, 2) if km else None}
    return summary


def free_running_summary(records: Records, routes: Sequence[BenchmarkRoute], agents: Sequence[str]) -> dict:
    """Per agent that drove free-running (msfsu_sim.pacing) and condition: factors and the ages of the controls."""
    conditions = {route.key: route.condition for route in routes}
    groups: dict[tuple[str, str], list[FreeRunning]] = {}
    for (agent, key), record in sorted(records.items()):
        if agent in agents and key in conditions and record.episode.free_running is not None:
            groups.setdefault((agent, conditions[key]), []).append(record.episode.free_running)
    summary: dict = {}
    for (agent, condition), runs in groups.items():
        summary.setdefault(agent, {})[condition] = _pacing(runs)
    return summary
