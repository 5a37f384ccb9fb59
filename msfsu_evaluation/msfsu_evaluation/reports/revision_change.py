"""One agent's episodes in two benchmark runs (two simulator or node-graph revisions, or two machines), paired per route.

    msfsu-revision-change BEFORE_RUN:AGENT AFTER_RUN:AGENT [--out FILE]
    msfsu-revision-change docs/results/closed_loop_v3/records/networks:msfsu \\
        docs/results/closed_loop_v3_rev4/records/msfsu_v2:msfsu_v2

Prints a Markdown page: the two runs (simulator and graph revision, machines), per task and condition the successes
before and after and how many episodes are identical (closed_loop.runs.identical: the same driven fields, and the
same trajectory where both runs kept one), and per condition the paired difference of success rates (after - before) with its 95 % interval (Newcombe) and exact McNemar p, on the routes
both runs drove; then the outcomes that flipped, counted by failure type, the static-layout (kerb) collisions and
solid-line crossings per km per condition, and every route whose outcome changed. A change that only moves pixels
leaves a blind driver's (the expert's) episodes identical; a network's may change, and this says by how much.
The page names the command that makes it as `python scripts/revision_change.py` (the launcher the committed pages
name; `msfsu-revision-change` is the same command).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

from msfsu_evaluation.closed_loop.cells import points_text
from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.runner import EPISODES_FILE, RUN_FILE, RunInfo
from msfsu_evaluation.closed_loop.runs import Record, identical
from msfsu_evaluation.closed_loop.statistics import (STATIC_LAYOUT, cell_statistics, paired_comparison,
                                                     recorded_infractions)
from msfsu_evaluation.closed_loop.suites import CONDITIONS, TASKS, load_routes
from msfsu_evaluation.reports.paired_runs import Episodes, episodes, run_and_agent

COMMAND = "python scripts/revision_change.py"  # as the committed pages name it


def describe(run: Path, agent: str) -> str:
    info = json.loads((run / RUN_FILE).read_text()) if (run / RUN_FILE).exists() else {}
    machines = "; ".join(info.get("machines", [])) or "not recorded"
    checkpoint, revisions = info.get("agents", {}).get(agent), RunInfo.of(info)
    graph = f", node graph revision {revisions.graph_revision}" if checkpoint else ""  # the expert drives without it
    return (f"`{run}` agent `{agent}`: simulator revision {revisions.simulator_revision}{graph}, "
            f"checkpoint {checkpoint}, machines: {machines}")


def outcome(episode: EpisodeResult) -> str:
    """'success', or the failure: its status and, for a collision, what was hit ('collision: sidewalk')."""
    if episode.success:
        return "success"
    return f"{episode.status}: {episode.collision_type}" if episode.collision_type else episode.status


def flips_markdown(a: Episodes, b: Episodes, common: list[str]) -> list[str]:
    """The routes whose outcome changed, counted by (before, after) outcome, most frequent first."""
    flips = Counter((outcome(a[k]), outcome(b[k])) for k in common if outcome(a[k]) != outcome(b[k]))
    lost = sum(n for (before, after), n in flips.items() if before == "success")
    won = sum(n for (before, after), n in flips.items() if after == "success")
    lines = ["## Outcomes that changed", "",
             f"{sum(flips.values())} of {len(common)} routes changed outcome: {won} failures became successes, "
             f"{lost} successes became failures, {sum(flips.values()) - won - lost} failed both times another way.", ""]
    if flips:
        lines += ["| before | after | routes |", "| --- | --- | --- |"]
        lines += [f"| {before} | {after} | {n} |" for (before, after), n in
                  sorted(flips.items(), key=lambda item: (-item[1], item[0]))]
        lines.append("")
    return lines


def infractions_markdown(a: Episodes, b: Episodes, common: list[str], cell_of: dict,
                         lengths: dict[str, float], version: int) -> list[str]:
    """Per condition on the routes both drove: static-layout (kerb) collisions and solid-line crossings per km."""
    lines = ["## Kerb strikes and solid lines", "",
             "| condition | static-layout collisions before | after | solid-line crossings per km before | after |",
             "| --- | --- | --- | --- | --- |"]
    for condition in (*CONDITIONS, "all"):
        keys = [k for k in common if condition == "all" or cell_of.get(k, ("", ""))[1] == condition]
        if not keys:
            continue
        stats = [cell_statistics([side[k] for k in keys], lengths, recorded_infractions(version)) for side in (a, b)]
        per_km = [f"{s.infractions_per_km()['solid_line']:.2f} ({s.infractions['solid_line']} in {s.km_driven:.1f} km)"
                  if s.km_driven > 0 else "–" for s in stats]
        lines.append(f"| {condition} | {stats[0].infractions['static']} | {stats[1].infractions['static']} | "
                     f"{per_km[0]} | {per_km[1]} |")
    return lines + [""]


def kerb_strikes_markdown(a: Episodes, b: Episodes, common: list[str]) -> list[str]:
    """Every episode of either run that ended on the static layout (a kerb strike), with where it happened: route
    completion, time, and the last solid-line crossing before the end (its command and place, and how long before;
    records older than that placement say 'not recorded')."""
    struck = [(label, side[k]) for k in common for label, side in (("before", a), ("after", b))
              if side[k].collision_type in STATIC_LAYOUT]
    if not struck:
        return []
    lines = ["## Kerb strikes, where", "",
             "| run | route | RC | time s | last solid-line crossing before it: command, place, s before the end |",
             "| --- | --- | --- | --- | --- |"]
    for label, episode in struck:
        if episode.solid_lines is None:
            last = "not recorded"
        elif not episode.solid_lines:
            last = "none"
        else:
            crossing = episode.solid_lines[-1]
            last = f"{crossing.command}, {crossing.where}, {episode.time_s - crossing.time_s:.1f}"
        lines.append(f"| {label} | {episode.route} | {100 * episode.route_completion:.0f} % | {episode.time_s:.1f} | "
                     f"{last} |")
    return lines + [""]


def changed_routes_markdown(a: Episodes, b: Episodes, common: list[str]) -> list[str]:
    """Every route whose outcome changed, before beside after, with the route completion of each."""
    keys = [k for k in common if outcome(a[k]) != outcome(b[k])]
    if not keys:
        return []
    lines = ["## Routes whose outcome changed", "", "| route | before | after |", "| --- | --- | --- |"]
    lines += [f"| {k} | {outcome(a[k])} (RC {100 * a[k].route_completion:.0f} %) | "
              f"{outcome(b[k])} (RC {100 * b[k].route_completion:.0f} %) |" for k in keys]
    return lines + [""]


def page(before: tuple[Path, str], after: tuple[Path, str]) -> str:
    version, routes = load_routes()
    cell_of = {route.key: (route.task, route.condition) for route in routes}
    lengths = {route.key: route.length_m for route in routes}
    a, b = episodes(*before), episodes(*after)
    common = sorted(a.keys() & b.keys())
    lines = [f"# {before[1]} before / {after[1]} after, paired per route", "",
             f"`{COMMAND} {before[0]}:{before[1]} {after[0]}:{after[1]}`", "",
             f"- before: {describe(*before)}", f"- after: {describe(*after)}",
             f"- routes both drove: {len(common)} (before only: {len(a.keys() - b.keys())}, after only: "
             f"{len(b.keys() - a.keys())})", "",
             "| task | condition | routes | successes before | successes after | identical episodes |",
             "| --- | --- | --- | --- | --- | --- |"]
    identical_total = 0
    for task in TASKS:
        for condition in CONDITIONS:
            keys = [key for key in common if cell_of.get(key) == (task, condition)]
            if not keys:
                continue
            same = sum(identical(Record(before[0], a[k]), Record(after[0], b[k])) for k in keys)
            identical_total += same
            lines.append(f"| {task} | {condition} | {len(keys)} | {sum(a[k].success for k in keys)} | "
                         f"{sum(b[k].success for k in keys)} | {same} |")
    lines += ["", f"Identical episodes: {identical_total} of {len(common)}.", "",
              "| condition | routes | successes before | successes after | after - before, points (95 % interval) | "
              "McNemar p |", "| --- | --- | --- | --- | --- | --- |"]
    for condition in (*CONDITIONS, "all"):
        keys = [key for key in common if condition == "all" or cell_of.get(key, ("", ""))[1] == condition]
        comparison = paired_comparison({k: b[k].success for k in keys}, {k: a[k].success for k in keys})
        if comparison is None:
            continue
        lines.append(f"| {condition} | {comparison.routes} | {comparison.b_successes} | {comparison.a_successes} | "
                     f"{points_text(comparison.difference, comparison.difference_ci95)} | {comparison.p_value:.3f} |")
    lines += ["", *flips_markdown(a, b, common), *infractions_markdown(a, b, common, cell_of, lengths, version),
              *kerb_strikes_markdown(a, b, common), *changed_routes_markdown(a, b, common)]
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=run_and_agent, help="RUN_DIRECTORY:AGENT")
    parser.add_argument("after", type=run_and_agent, help="RUN_DIRECTORY:AGENT")
    parser.add_argument("--out", type=Path, help="also write the page here")
    args = parser.parse_args(argv)
    for run, agent in (args.before, args.after):
        if not (run / EPISODES_FILE).exists():
            print(f"revision_change: {run} has no {EPISODES_FILE}", file=sys.stderr)
            return 1
        if not episodes(run, agent):
            print(f"revision_change: {run} has no episodes of agent '{agent}'", file=sys.stderr)
            return 1
    text = page(args.before, args.after)
    print(text, end="")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
