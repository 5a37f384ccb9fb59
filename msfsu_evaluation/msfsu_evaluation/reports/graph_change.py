"""Several networks' episodes in two benchmark runs each, paired per route, in one table: per network, suite and
condition (and over all routes) the successes before and after, the paired difference with its 95 % interval and exact
McNemar p, the static-layout (kerb) collisions and the solid-line crossings per km before and after.

    msfsu-graph-change NAME BEFORE_RUN:AGENT AFTER_RUN:AGENT [NAME BEFORE AFTER ...] \\
        [--labels BEFORE AFTER] [--pages NAME] [--out FILE]

`msfsu-revision-change` (reports.revision_change) is the same comparison for one network with every route and flip;
this is the summary across networks (the node graph's before/after table:
`docs/results/closed_loop_v3_graph2/graph_change.md`; model v3's against the shipped models:
`docs/results/closed_loop_v3_model_v3/v3_change.md`, written by msfsu-model-v3). The page names the command that
makes it as `python scripts/graph_change_table.py` (the launcher the committed pages name).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

from msfsu_evaluation.closed_loop.cells import points_text
from msfsu_evaluation.closed_loop.statistics import cell_statistics, paired_comparison, recorded_infractions
from msfsu_evaluation.closed_loop.suites import load_routes
from msfsu_evaluation.reports.paired_runs import Episodes, episodes, run_and_agent, suite_and_condition

COMMAND = "python scripts/graph_change_table.py"  # as the committed pages name it

LABELS = ("graph 1", "graph 2")  # the node graph's change, the table's first use
PAGES = "graph_change_<network>.md"


def _p_text(p: float) -> str:
    return "< 0.001" if p < 0.0005 else f"{p:.3f}"


def rows(name: str, before: Episodes, after: Episodes, lengths: dict[str, float], version: int) -> list[str]:
    """The table's rows of one network: each suite and condition both runs drove, then all of its routes."""
    common = sorted(before.keys() & after.keys())
    cells = sorted({suite_and_condition(key) for key in common}, key=lambda cell: (cell[0], cell[1] != "train"))
    lines = []
    conditions = sorted({condition for _, condition in cells}, key=lambda condition: condition != "train")
    for suite, condition in [*cells, *(("all", condition) for condition in conditions), ("all", "all")]:
        keys = [k for k in common if (suite == "all" or suite_and_condition(k)[0] == suite)
                and (condition == "all" or suite_and_condition(k)[1] == condition)]
        comparison = paired_comparison({k: after[k].success for k in keys}, {k: before[k].success for k in keys})
        if comparison is None:
            continue
        stats = [cell_statistics([side[k] for k in keys], lengths, recorded_infractions(version))
                 for side in (before, after)]
        per_km = " / ".join(f"{s.infractions_per_km()['solid_line']:.2f}" for s in stats)
        lines.append(f"| {name} | {suite} | {condition} | {comparison.routes} | {comparison.b_successes} | "
                     f"{comparison.a_successes} | {points_text(comparison.difference, comparison.difference_ci95)} | "
                     f"{_p_text(comparison.p_value)} | {stats[0].infractions['static']} / {stats[1].infractions['static']} | "
                     f"{per_km} |")
    return lines


def table(networks: Sequence[tuple[str, tuple[Path, str], tuple[Path, str]]], labels: tuple[str, str],
          pages: str = PAGES) -> str:
    """The page; `pages`: the name of each network's every-route page beside it (scripts/revision_change.py)."""
    version, routes = load_routes()
    lengths = {route.key: route.length_m for route in routes}
    before_label, after_label = labels
    command = " ".join(f"{name} {b[0]}:{b[1]} {a[0]}:{a[1]}" for name, b, a in networks)
    if labels != LABELS:
        command += f" --labels {shlex.join(labels)}"
    if pages != PAGES:
        command += f" --pages {shlex.quote(pages)}"
    lines = [f"# {before_label} against {after_label}, paired per route", "",
             f"`{COMMAND} {command}`", "",
             "Per network, suite and condition, on the routes both runs drove: successes, the paired difference "
             f"({after_label} - {before_label}, points, Newcombe 95 % interval) and exact McNemar p; static-layout "
             "(kerb) collisions and solid-line crossings per km driven. Every route and flip: "
             f"`{pages}` (scripts/revision_change.py).", "",
             f"| network | suite | condition | routes | {before_label} | {after_label} | difference (95 % CI) | "
             f"McNemar p | kerb strikes {before_label} / {after_label} | solid lines per km {before_label} / "
             f"{after_label} |", "| --- |" + " --- |" * 9]
    for name, before, after in networks:
        lines += rows(name, episodes(*before), episodes(*after), lengths, version)
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("networks", nargs="+", help="NAME BEFORE_RUN:AGENT AFTER_RUN:AGENT, repeated")
    parser.add_argument("--labels", nargs=2, default=LABELS, metavar=("BEFORE", "AFTER"))
    parser.add_argument("--pages", default=PAGES,
                        help="the name of each network's every-route page, which the table points to")
    parser.add_argument("--out", type=Path, help="also write the page here")
    args = parser.parse_args(argv)
    if len(args.networks) % 3:
        parser.error("give the networks as triples: NAME BEFORE_RUN:AGENT AFTER_RUN:AGENT")
    networks = []
    for index in range(0, len(args.networks), 3):
        name, *sides = args.networks[index:index + 3]
        try:
            pair = [run_and_agent(side) for side in sides]
        except argparse.ArgumentTypeError as error:
            parser.error(str(error))
        for run, agent in pair:
            if not episodes(run, agent):
                print(f"graph_change_table: {run} has no episodes of agent '{agent}'", file=sys.stderr)
                return 1
        networks.append((name, pair[0], pair[1]))
    text = table(networks, tuple(args.labels), args.pages)
    print(text, end="")
    if args.out:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
