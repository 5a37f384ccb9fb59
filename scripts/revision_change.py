"""One agent's episodes in two benchmark runs (two simulator revisions, or two machines), paired per route.

    .venv/bin/python scripts/revision_change.py BEFORE_RUN:AGENT AFTER_RUN:AGENT [--out FILE]
    .venv/bin/python scripts/revision_change.py docs/results/closed_loop_v3/records/networks:msfsu \\
        docs/results/closed_loop_v3_rev4/records/msfsu_v2:msfsu_v2

Prints a Markdown page: the two runs (simulator revision, machines), per task and condition the successes before and
after and how many episodes are identical (same status, steps, route completion, collision, distance to the goal
and solid-line crossings, and the same trajectory where both runs kept one), and per condition the paired
difference of success rates (after - before) with its 95 % interval (Newcombe) and exact McNemar p, on the routes
both runs drove. A change that only moves pixels
leaves a blind driver's (the expert's) episodes identical; a network's may change, and this says by how much.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from msfsu_evaluation.closed_loop.runner import EPISODES_FILE, RUN_FILE, read_episodes, trajectory_path
from msfsu_evaluation.closed_loop.statistics import paired_comparison
from msfsu_evaluation.closed_loop.suites import CONDITIONS, TASKS, load_routes

SAME = ("status", "steps", "route_completion", "collision_type", "distance_to_goal_m", "solid_line_crossings")


def episodes(run: Path, agent: str) -> dict[str, dict]:
    """The agent's episodes of a run directory by route key."""
    return {episode["route"]: episode for episode in read_episodes(run) if episode["agent"] == agent}


def identical(before: tuple[Path, str], after: tuple[Path, str], a: dict, b: dict) -> bool:
    """Same record fields, and the same trajectory where both runs kept one."""
    if any(a[name] != b[name] for name in SAME):
        return False
    paths = [trajectory_path(run, agent, a["route"]) for run, agent in (before, after)]
    return not all(path.exists() for path in paths) or np.array_equal(np.load(paths[0]), np.load(paths[1]))


def describe(run: Path, agent: str) -> str:
    info = json.loads((run / RUN_FILE).read_text()) if (run / RUN_FILE).exists() else {}
    machines = "; ".join(info.get("machines", [])) or "not recorded"
    return (f"`{run}` agent `{agent}`: simulator revision {info.get('simulator_revision', 1)}, "
            f"checkpoint {info.get('agents', {}).get(agent)}, machines: {machines}")


def page(before: tuple[Path, str], after: tuple[Path, str]) -> str:
    _, routes = load_routes()
    cell_of = {route.key: (route.task, route.condition) for route in routes}
    a, b = episodes(*before), episodes(*after)
    common = sorted(a.keys() & b.keys())
    lines = [f"# {before[1]} before / {after[1]} after, paired per route", "",
             f"`python scripts/revision_change.py {before[0]}:{before[1]} {after[0]}:{after[1]}`", "",
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
            same = sum(identical(before, after, a[k], b[k]) for k in keys)
            identical_total += same
            lines.append(f"| {task} | {condition} | {len(keys)} | {sum(a[k]['success'] for k in keys)} | "
                         f"{sum(b[k]['success'] for k in keys)} | {same} |")
    lines += ["", f"Identical episodes: {identical_total} of {len(common)}.", "",
              "| condition | routes | successes before | successes after | after - before, points (95 % interval) | "
              "McNemar p |", "| --- | --- | --- | --- | --- | --- |"]
    for condition in (*CONDITIONS, "all"):
        keys = [key for key in common if condition == "all" or cell_of.get(key, ("", ""))[1] == condition]
        comparison = paired_comparison({k: b[k]["success"] for k in keys}, {k: a[k]["success"] for k in keys})
        if comparison is None:
            continue
        interval = comparison.difference_ci95
        lines.append(f"| {condition} | {comparison.routes} | {comparison.b_successes} | {comparison.a_successes} | "
                     f"{100 * comparison.difference:+.0f} ({100 * interval.low:+.0f} to {100 * interval.high:+.0f}) | "
                     f"{comparison.p_value:.3f} |")
    return "\n".join(lines) + "\n"


def run_and_agent(text: str) -> tuple[Path, str]:
    run, separator, agent = text.rpartition(":")
    if not separator or not agent:
        raise argparse.ArgumentTypeError(f"{text!r}: give RUN_DIRECTORY:AGENT")
    return Path(run), agent


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
