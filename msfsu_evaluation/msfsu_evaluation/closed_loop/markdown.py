"""The sections of a report's results.md.

Success tables are laid out like the paper's Tables 1-3, the expert first (the reference column); the RMSE table
holds the static CoRL2017 tasks. Sections made from results.json's own records (against the paper, free-running)
take its JSON, so that scripts/readme_results.py renders them from a committed results.json alike.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence

from msfsu_evaluation.closed_loop.cells import DASH, PairedRow, Results, paired_markdown, separation_text
from msfsu_evaluation.closed_loop.paper import GOALS, PAPER_MSFSU_SUCCESS
from msfsu_evaluation.closed_loop.runner import EXPERT
from msfsu_evaluation.closed_loop.statistics import recorded_infractions
from msfsu_evaluation.closed_loop.suites import TASKS
from msfsu_evaluation.closed_loop.summary import condition_infractions

RMSE_TASKS = ("straight", "one_turn", "navigation")  # paper Table 3: the static navigation tasks


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """A Markdown table: the header, its rule and one line per row."""
    return ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header),
            *("| " + " | ".join(row) + " |" for row in rows)]


def brake_parameters_text(runtime: Mapping[str, object]) -> str:
    """An agent's brake parameters given with --aeb-param (its run.json runtime), 'track_lost_s 0.5, ...'; ''
    without."""
    return ", ".join(f"{name} {value}" for name, value in runtime.get("aeb_parameters", {}).items())


def runtimes_markdown(runtimes: Mapping[str, dict]) -> list[str]:
    """One line: each network's backend/precision as asked and as run (empty where the runs recorded none), and the
    emergency brake's parameters where a run gave some other than the node's defaults (--aeb-param)."""
    if not runtimes:
        return []
    given = {agent: text for agent, r in runtimes.items() if (text := brake_parameters_text(r))}
    return ["Networks' inference (asked -> ran as): " + "; ".join(
        f"{agent}: {r['backend']}/{r['precision']} -> {', '.join(r['ran_as']) or 'not recorded'}"
        for agent, r in runtimes.items()) + ".", "",
        *(["Emergency brake parameters other than the aeb node's defaults: "
           + "; ".join(f"{agent}: {text}" for agent, text in given.items()) + ".", ""] if given else [])]


def sources_markdown(per_agent: Mapping[str, Mapping[str, int]], prefer: Mapping[str, str]) -> list[str]:
    """One line: each agent's runs with their record counts and, where --prefer named one, that it wins."""
    if not per_agent:
        return []
    return ["Records per agent: " + "; ".join(
        f"{agent}: " + ", ".join(f"`{run}` ({count})" for run, count in runs.items())
        + (f" (where both hold a route, `{prefer[agent]}` wins)" if agent in prefer else "")
        for agent, runs in per_agent.items()) + ".", ""]


def heading_markdown(results: Results, routes_version: int, sources: Sequence[str]) -> list[str]:
    return [f"# Closed-loop benchmark (routes v{routes_version})", "",
            f"{results.episodes()} episodes from {', '.join(f'`{source}`' for source in sources)} "
            "(`msfsu-benchmark-report` regenerates this page from those records).", ""]


LEGEND = ["Success: successes/episodes (rate %; Wilson 95 % interval %). Driving score (DS): route completion x "
          "infraction penalty (pedestrian 0.50, vehicle 0.60, static object 0.65), mean over episodes, %; "
          "RC: mean route completion, %.", ""]


def suite_markdown(results: Results, suite: str, agents: Sequence[str], conditions: Sequence[str]) -> list[str]:
    """A suite's success table, its driving score and route completion table and its outcomes line."""
    columns = [(c, a) for c in conditions for a in agents]
    tasks = [task for task in TASKS if any(results.cell(a, suite, task, c) for c, a in columns)]
    cells = {task: [results.cell(a, suite, task, c) for c, a in columns] for task in tasks}
    header = ["Task"] + [f"{c}: {a}" for c, a in columns]
    success = [[task] + [x.success_text() if x else DASH for x in cells[task]] for task in tasks]
    scores = [[task] + [x.score_text() if x else DASH for x in cells[task]] for task in tasks]
    outcomes = "; ".join(f"{a}/{c}/{t}: " + x.outcomes_text() for t in tasks for c, a in columns
                         if (x := results.cell(a, suite, t, c)))
    return [f"## {suite}: success", "", *table(header, success), "",
            f"## {suite}: driving score and route completion (%)", "", *table(header, scores), "",
            f"Outcomes ({suite}): {outcomes}", ""]


def infractions_markdown(results: Results, agents: Sequence[str], conditions: Sequence[str],
                         routes_version: int) -> list[str]:
    """Per agent and condition: each recorded infraction per km driven (with its count)."""
    infractions = recorded_infractions(routes_version)
    rows = []
    for agent, condition in itertools.product(agents, conditions):
        if driven := condition_infractions(results, agent, condition):
            km, counts = driven
            rows.append([agent, condition, f"{km:.2f}", *(f"{counts[k] / km:.2f} ({counts[k]})" if km > 0
                                                          else f"{DASH} ({counts[k]})" for k in infractions)])
    return ["## Infractions per km driven", "", *table(["Agent", "Condition", "km driven", *infractions], rows), ""]


def separation_markdown(results: Results, networks: Sequence[str], conditions: Sequence[str]) -> list[str]:
    """Per cell and every two networks: whether their success intervals overlap (fewer than two networks: none)."""
    if len(networks) < 2:
        return []
    pairs = list(itertools.combinations(networks, 2))
    rows = []
    for suite, task, condition in itertools.product(results.suites(), TASKS, conditions):
        row = [separation_text(results.cell(a, suite, task, condition), results.cell(b, suite, task, condition),
                               (a, b)) for a, b in pairs]
        if any(value != DASH for value in row):
            rows.append([f"{suite}/{task}", condition, *row])
    return ["## Ablation per cell: do the networks' success intervals separate?", "",
            "\"overlap\": the 95 % intervals overlap, so these episodes cannot rank the two; \"X higher\": "
            "they do not.", "", *table(["Suite / task", "Condition", *(f"{a} vs {b}" for a, b in pairs)], rows), ""]


def rmse_markdown(results: Results, networks: Sequence[str], conditions: Sequence[str]) -> list[str]:
    """Per static task and condition: each network's trajectory RMSE against the expert (no such cell: none)."""
    rows = []
    for suite, task, condition in itertools.product(results.suites(), RMSE_TASKS, conditions):
        cells = [results.cell(a, suite, task, condition) for a in networks]
        if any(cells):
            rows.append([f"{suite}/{task}", condition, *(x.rmse_text() if x else DASH for x in cells)])
    if not rows:
        return []
    return ["## Trajectory RMSE against the expert (m; paper formula, over successful episodes)", "",
            *table(["Task", "Condition", *networks], rows), ""]


def tables_markdown(results: Results, agents: Sequence[str], conditions: Sequence[str], routes_version: int,
                    sources: Sequence[str], paired_rows: Sequence[PairedRow] = (),
                    per_agent: Mapping[str, Mapping[str, int]] | None = None,
                    prefer: Mapping[str, str] | None = None, *, paper: Mapping[str, dict],
                    runtimes: Mapping[str, dict] | None = None) -> str:
    """results.md up to the sections of overlapping runs, free-running, solid lines and figures."""
    conditions = results.driven(conditions)
    networks = [a for a in agents if a != EXPERT]
    lines = [*heading_markdown(results, routes_version, sources), *sources_markdown(per_agent or {}, prefer or {}),
             *runtimes_markdown(runtimes or {}), *LEGEND]
    for suite in results.suites():
        lines += suite_markdown(results, suite, agents, conditions)
    lines += [*infractions_markdown(results, agents, conditions, routes_version), *against_paper_markdown(paper),
              *paired_markdown(paired_rows), *separation_markdown(results, networks, conditions),
              *rmse_markdown(results, networks, conditions)]
    return "\n".join(lines)


def _against_paper_entry(x: Mapping | None) -> str:
    """An agent's entry of the against-the-paper table: rate (interval); goal; where the paper's rate lies."""
    if x is None:
        return DASH
    goal = "" if x["goal_met"] is None else ("goal met; " if x["goal_met"] else "goal not met; ")
    low, high = x["success_ci95"]
    return f"{x['success_rate']:.0f} ({low:.0f}-{high:.0f}); {goal}{x['versus_paper']}"


def _against_paper_verdict(agent: str, found: Mapping) -> str:
    """An agent's line under the table: success goals met and its held-out pedestrian collisions per km."""
    cells = [x for x in found["cells"].values() if x["goal_met"] is not None]
    summary = f"{agent}: {sum(x['goal_met'] for x in cells)} of {len(cells)} success goals met"
    if pedestrian := found.get("pedestrian_per_km_heldout"):
        verdict = DASH if pedestrian["goal_met"] is None else ("met" if pedestrian["goal_met"] else "not met")
        per_km = DASH if pedestrian["per_km"] is None else f"{pedestrian['per_km']:.2f}"
        summary += (f"; pedestrian collisions held out {per_km} per km ({pedestrian['collisions']} in "
                    f"{pedestrian['km']:.2f} km), goal ≤ {pedestrian['goal']:g}: {verdict}")
    return summary + "."


def against_paper_markdown(found: Mapping[str, dict], title: bool = True) -> list[str]:
    """The section of results.md (without its heading: `title=False`) from against_paper()'s record."""
    if not found:
        return []
    agents = list(found)
    cells = [cell for cell in PAPER_MSFSU_SUCCESS if any("/".join(cell) in found[agent]["cells"] for agent in agents)]
    rows = [[f"{suite}/{task}", condition, f"{PAPER_MSFSU_SUCCESS[(suite, task, condition)]:g}",
             f"≥ {GOALS[(suite, task, condition)]:g}" if (suite, task, condition) in GOALS else DASH,
             *(_against_paper_entry(found[agent]["cells"].get(f"{suite}/{task}/{condition}")) for agent in agents)]
            for suite, task, condition in cells]
    lines = ["## Against the paper (MSFSU, Tables 1-2) and the v3 goals", ""] if title else []
    lines += ["Paper: the paper's MSFSU success rate, %. Goal: what the v3 models are held to (issue 58; "
              "`msfsu_evaluation/closed_loop/paper.py`). Per agent: success rate % (Wilson 95 % interval), whether it "
              "meets the goal, and where the paper's rate lies: at or above it, below it but inside the interval "
              "(these routes cannot tell the two apart), or below the interval (judged on the unrounded bounds).", "",
              *table(["Suite / task", "Condition", "Paper", "Goal", *agents], rows), ""]
    return [*lines, *(_against_paper_verdict(agent, found[agent]) for agent in agents), ""]


def overlap_markdown(found: Mapping[str, dict], listed: int = 12) -> list[str]:
    """One line per agent that two runs hold on the same routes: how many records agree (overlaps())."""
    lines = []
    for agent, x in found.items():
        differ = ", ".join(x["differ"][:listed]) + (f" and {len(x['differ']) - listed} more (results.json lists them)"
                                                    if len(x["differ"]) > listed else "")
        lines.append(f"{agent} drove {x['routes']} routes in more than one run: {x['identical']} records identical "
                     f"(every driven field and the whole trajectory), {x['same_outcome']} with the same outcome"
                     + (f"; not identical: {differ}" if x["differ"] else "") + ".")
    return lines


FREE_RUNNING_HEADER = ("Agent", "Condition", "episodes", "factor stated", "achieved mean (min)", "late steps",
                       "control age 0", "p95", "max", "steps before the first control")


def _pacing_row(agent: str, condition: str, x: Mapping) -> list[str]:
    return [agent, condition, str(x["episodes"]), ", ".join(f"{f:g}" for f in x["real_time_factor"]),
            f"{x['achieved_mean']:.2f} ({x['achieved_min']:.2f})", f"{100 * x['late_share']:.1f} %",
            f"{100 * x['fresh_share']:.1f} %", str(x["control_age_p95_steps"]), str(x["control_age_max_steps"]),
            str(x["without_control"])]


def emergency_brake_markdown(summary: Mapping[str, Mapping[str, dict]]) -> list[str]:
    """The emergency brake's interventions per agent and condition (empty without a brake)."""
    rows = [[agent, condition, str(x["episodes"]), f"{x['km']:.2f}", str(x["brakes"]), str(x["caps"]),
             str(x["false_brakes"]), "not judged" if x["false_caps"] is None else str(x["false_caps"]),
             "-" if x["false_per_10km"] is None else f"{x['false_per_10km']:.2f}"]
            for agent, conditions in sorted(summary.items()) for condition, x in sorted(conditions.items())]
    if not rows:
        return []
    return ["", "## The emergency brake's interventions", "",
            "Brakes and caps: how often the brake started one (the episode records); false: with no vehicle or "
            "pedestrian near the car's path ahead by the simulator's ground truth (closed_loop/episode.py, AebCount); "
            "per 10 km: the false ones, brakes and caps, per 10 km driven.",
            "", *table(["Agent", "Condition", "episodes", "km driven", "brakes", "caps", "false brakes", "false caps",
                        "false per 10 km"], rows), "", ""]


def free_running_markdown(summary: Mapping[str, Mapping[str, dict]]) -> list[str]:
    """The free-running section from free_running_summary()'s record (none: no section)."""
    if not summary:
        return []
    rows = [_pacing_row(agent, condition, x) for agent, conditions in summary.items()
            for condition, x in conditions.items()]
    return ["## Free-running (the simulator on the wall clock, the last control that arrived applies)", "",
            "Control age: simulator steps (100 ms) between the frame a control answered and the step it was applied "
            "to (0: its own frame, as in lockstep). Late: steps the simulator itself started after they were due.",
            "", *table(FREE_RUNNING_HEADER, rows), ""]
