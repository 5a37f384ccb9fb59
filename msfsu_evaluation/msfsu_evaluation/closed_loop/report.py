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
import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from msfsu_evaluation.closed_loop.abilities import SUITE as ABILITY_SUITE
from msfsu_evaluation.closed_loop.collisions import collision_windows, collisions_markdown
from msfsu_evaluation.closed_loop.lateral import solid_line_markdown, solid_line_summary
from msfsu_evaluation.closed_loop.markdown import (emergency_brake_markdown, free_running_markdown, overlap_markdown,
                                                   tables_markdown)
from msfsu_evaluation.closed_loop.plots import figure_routes, plot_trajectories
from msfsu_evaluation.closed_loop.runner import EXPERT, read_episodes
from msfsu_evaluation.closed_loop.runs import (
    REPOSITORY, Records, merge, overlaps, read_run_info, relative, report_run_info, sources_of)
from msfsu_evaluation.closed_loop.suites import ROUTE_FILES, BenchmarkRoute, load_routes
from msfsu_evaluation.closed_loop.summary import (against_paper, emergency_brake_summary, free_running_summary, paired,
                                                  summarise)
from msfsu_evaluation.usage import UsageError


def write_figures(out: Path, routes: Sequence[BenchmarkRoute], records: Records, agents: Sequence[str]) -> list[str]:
    """The Fig. 7 plots of the chosen routes into `out`; their file names."""
    figures = []
    for key in figure_routes(routes, records, agents):
        figure = plot_trajectories(records, key, agents, out / f"trajectories_{key.replace('/', '_')}.png")
        if figure:
            figures.append(figure.name)
    return figures


def page_markdown(report: Mapping, tables: str) -> str:
    """results.md: the tables, then the sections of overlapping runs, free-running and solid lines, then the figures."""
    markdown = tables
    if report.get("overlap"):
        markdown += "\n## Runs that drove the same routes\n\n" + "\n".join(overlap_markdown(report["overlap"])) + "\n"
    markdown += "\n".join(emergency_brake_markdown(report.get("emergency_brake", {})))
    markdown += "\n".join(free_running_markdown(report.get("free_running", {})))
    markdown += "\n".join(solid_line_markdown(report.get("solid_lines", {})))
    if report.get("collisions"):
        markdown += ("\n## The last seconds before each collision\n\n"
                     f"[collisions.md](collisions.md): {report['collisions']} collisions with a vehicle or pedestrian, "
                     "step by step from the episodes' telemetry.\n")
    return markdown + "\n" + "\n".join(f"![{name}]({name})" for name in report["figures"]) + "\n"


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
    emergency_brake = emergency_brake_summary(records, routes, agents)
    solid_lines = solid_line_summary([record.episode for key, record in sorted(records.items()) if key[0] in agents],
                                     {route.key: route.condition for route in routes})
    out.mkdir(parents=True, exist_ok=True)
    sources, per_agent = [relative(run) for run in runs], sources_of(records)
    report = {"routes_version": routes_version, "run": run_info, "records": sources, "agents": list(agents),
              "sources": per_agent, "results": results.to_json(), "paired": [row.to_json() for row in paired_rows],
              "against_paper": against_paper(results, agents), "figures": write_figures(out, routes, records, agents)}
    if prefer:
        report["prefer"] = {agent: relative(run) for agent, run in sorted(prefer.items())}
        report["overlap"] = overlaps(runs, set(prefer))
    if emergency_brake:
        report["emergency_brake"] = emergency_brake
    if free_running:
        report["free_running"] = free_running
    if solid_lines:
        report["solid_lines"] = solid_lines
    windows, without_telemetry = collision_windows(records, agents)
    if windows:
        report["collisions"] = len(windows)
        (out / "collisions.md").write_text(collisions_markdown(windows, without_telemetry))
    (out / "results.json").write_text(json.dumps(report, indent=2) + "\n")
    tables = tables_markdown(results, agents, conditions, routes_version, sources, paired_rows, per_agent,
                             report.get("prefer", {}), paper=report["against_paper"],
                             runtimes=run_info.get("runtimes", {}))
    (out / "results.md").write_text(page_markdown(report, tables))
    return report


def routes_version_of(infos: Sequence[dict]) -> int:
    """The one routes version of the runs (UsageError: several, or one this benchmark does not know)."""
    versions = {info["routes_version"] for info in infos}
    if len(versions) != 1:
        raise UsageError(f"the runs are on different route versions {sorted(versions)}: never mixed")
    version = versions.pop()
    if version not in ROUTE_FILES:
        raise UsageError(f"the runs are on routes v{version}, this benchmark knows {sorted(ROUTE_FILES)}")
    return version


def held_agents(runs: Sequence[Path], agents: Sequence[str] | None) -> Sequence[str] | None:
    """The agents asked for (None: every agent), each of which the runs must hold (UsageError otherwise)."""
    if not agents:
        return None
    held = {episode.agent for run in runs for episode in read_episodes(run)}
    if missing := [agent for agent in agents if agent not in held]:
        raise UsageError(f"no episodes of {', '.join(missing)} in these runs (they hold {', '.join(sorted(held))})")
    return agents


def preferred_runs(items: Sequence[str], runs: Sequence[Path]) -> dict[str, Path]:
    """--prefer AGENT=RUN items by agent; RUN must be one of `runs` (UsageError otherwise)."""
    prefer = {}
    for item in items:
        agent, separator, run = item.partition("=")
        if not separator or Path(run) not in runs:
            raise UsageError(f"--prefer {item}: expected AGENT=RUN with RUN one of the run directories given")
        prefer[agent] = Path(run)
    return prefer


def parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="msfsu-benchmark-report", description=__doc__.split("\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("runs", nargs="+", type=Path, help="run directories of msfsu-benchmark (shards, re-runs)")
    parser.add_argument("--out", type=Path, required=True, help="where results.json, results.md and PNGs go")
    parser.add_argument("--agents", nargs="+", help="report only these agents (default: every agent the records hold)")
    parser.add_argument("--prefer", nargs="+", default=[], metavar="AGENT=RUN",
                        help="where two runs hold the same route of AGENT, RUN's record wins (else refused)")
    return parser


def driven_routes(infos: Sequence[dict], version: int) -> tuple[Path, list[BenchmarkRoute]]:
    """The route file the runs drove and its routes: the one every run names (msfsu-benchmark --routes, e.g. a chosen
    few routes) where it is still there and of the runs' version; else the version's shipped file (ROUTE_FILES)."""
    named = {info.get("routes_file") for info in infos}
    if len(named) == 1 and (name := named.pop()) and (path := REPOSITORY / name).is_file():
        try:
            held, routes = load_routes(path)
            if held == version:
                return path, routes
        except (OSError, ValueError, KeyError, TypeError):
            pass  # not a route file this code reads: the shipped one of the version
    return ROUTE_FILES[version], load_routes(ROUTE_FILES[version])[1]


def main(argv: Sequence[str] | None = None) -> int:
    options = parser().parse_args(argv)
    try:
        infos = [read_run_info(run) for run in options.runs]
        if any(info.get("suite") == ABILITY_SUITE for info in infos):
            return _ability_report(options, infos)
        version = routes_version_of(infos)
        route_file, routes = driven_routes(infos, version)
        info = report_run_info(infos, version, relative(route_file))
        conditions = list(dict.fromkeys(route.condition for route in routes))
        agents = held_agents(options.runs, options.agents)
        prefer = preferred_runs(options.prefer, options.runs)
        report = write_reports(options.out, options.runs, routes, agents, conditions, version, info, prefer)
    except (UsageError, OSError, ValueError, KeyError) as error:
        print(f"msfsu-benchmark-report: {error}", file=sys.stderr)
        return 2
    count = sum(len(read_episodes(run)) for run in options.runs)
    print(f"{count} episode records from {len(options.runs)} runs, {len(report['agents'])} agents -> "
          f"{options.out / 'results.md'}", flush=True)
    return 0


def _ability_report(options: argparse.Namespace, infos: Sequence[dict]) -> int:
    """msfsu-benchmark-report on runs of the per-ability suite (closed_loop.ability_report)."""
    from msfsu_evaluation.closed_loop.abilities import load_abilities
    from msfsu_evaluation.closed_loop.ability_report import write_ability_report
    from msfsu_evaluation.closed_loop.runs import ability_run_info, recorded_path

    info = ability_run_info(infos)
    _, routes = load_abilities(recorded_path(info["routes_file"]))  # the scenario file the runs drove
    conditions = list(dict.fromkeys(route.condition for route in routes))
    report = write_ability_report(options.out, options.runs, routes, held_agents(options.runs, options.agents),
                                  conditions, info, preferred_runs(options.prefer, options.runs))
    print(f"{len(report['agents'])} agents on the per-ability scenarios -> {options.out / 'results.md'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
