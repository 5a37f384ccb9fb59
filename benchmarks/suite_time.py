"""Wall time of whole closed-loop suites, read from the run directories that drove them.

    python benchmarks/suite_time.py docs/results/closed_loop_v3_rev4/records/*/   # writes benchmarks/suite_time_results.{md,json}

`msfsu-benchmark` records every invocation in its run directory's `run.json` ('legs': start, end, wall seconds,
workers, the agents it drove, episodes to run and finished, the 1-minute load average at both ends) and the
machines that ran it. A leg that drove one agent's whole suite from start to end is that suite's wall time, graph
start-ups and town builds included; this page lists every leg with its agents' episodes and simulated steps, and
the issue's goal (a network's 350-route suite in at most an hour) against the network legs that finished whole.
`workers.py` projects the same figure from a sample of routes; this is the measurement.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from msfsu_evaluation.closed_loop.runner import EPISODES_FILE, RUN_FILE, read_episodes
from msfsu_evaluation.closed_loop.suites import full_suite_routes

DEFAULT_OUT = Path(__file__).with_name("suite_time_results.md")
FULL_SUITE_ROUTES = full_suite_routes()
GOAL_H = 1.0  # issue 27: one network agent's 350 routes with the best worker count


def legs(run: Path) -> list[dict]:
    """Every leg of a run directory with its agents' episodes (routes, steps, simulated s) from episodes.jsonl."""
    info = json.loads((run / RUN_FILE).read_text())
    episodes = read_episodes(run)
    found = []
    for leg in info.get("legs", []):
        mine = [e for e in episodes if e["agent"] in leg["agents"]]
        found.append({**leg, "run": str(run), "simulator_revision": info.get("simulator_revision"),
                      "machines": info.get("machines", []), "routes": len(mine),
                      "steps": sum(e["steps"] for e in mine), "simulated_s": round(sum(e["time_s"] for e in mine), 1),
                      "network": any(info.get("agents", {}).get(agent) for agent in leg["agents"])})
    return found


def markdown(found: list[dict], command: str) -> str:
    lines = ["# Closed-loop suites: wall time", "", f"`{command}`", "",
             "| run | agents | workers | episodes finished / to run | steps | wall h | simulated / wall | "
             "load (1 min) start / end | started (UTC) |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for leg in found:
        lines.append(f"| `{leg['run']}` | {', '.join(leg['agents'])} | {leg['workers']} | {leg['finished']} / "
                     f"{leg['to_run']} | {leg['steps']:,} | {leg['wall_s'] / 3600:.2f} | "
                     f"{leg['simulated_s'] / leg['wall_s']:.1f}x | {leg['load_1min_start']} / {leg['load_1min_end']} | "
                     f"{leg['started'][:16].replace('T', ' ')} |")
    machines = sorted({machine for leg in found for machine in leg["machines"]})
    lines += ["", f"Machines: {'; '.join(machines) or 'not recorded'}. Simulator revisions: "
              f"{', '.join(str(r) for r in sorted({leg['simulator_revision'] for leg in found}))}."]
    whole = [leg for leg in found if leg["network"] and len(leg["agents"]) == 1 and leg["finished"] == leg["to_run"]
             == FULL_SUITE_ROUTES]
    if whole:
        best = min(whole, key=lambda leg: leg["wall_s"])
        verdict = "met" if best["wall_s"] / 3600 <= GOAL_H else "not met"
        lines += ["", f"One network agent's full suite ({FULL_SUITE_ROUTES} routes, one leg from start to end): "
                  f"{best['wall_s'] / 3600:.2f} h with {best['workers']} workers ({', '.join(best['agents'])}); "
                  f"the goal, at most {GOAL_H:.0f} h: **{verdict}**."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run directories of msfsu-benchmark")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown table; JSON beside it")
    args = parser.parse_args(argv)
    found = []
    for run in args.runs:
        if not (run / RUN_FILE).exists() or not (run / EPISODES_FILE).exists():
            print(f"suite_time: {run} is not a run directory (no {RUN_FILE} and {EPISODES_FILE})", file=sys.stderr)
            return 1
        found += legs(run)
    if not found:
        print("suite_time: no recorded legs in these run directories (recorded since 2026-11-26)", file=sys.stderr)
        return 1
    command = " ".join(["python", "benchmarks/suite_time.py", *(str(run) for run in args.runs)])
    text = markdown(found, command)
    print(text, end="")
    args.out.write_text(text)
    args.out.with_suffix(".json").write_text(json.dumps(found, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
