"""Wall time of whole closed-loop suites, read from the run directories that drove them.

    python benchmarks/suite_time.py docs/results/closed_loop_v3_rev4/records/*/   # writes benchmarks/suite_time_results.{md,json}

`msfsu-benchmark` records every invocation in its run directory's `run.json` ('legs': start, end, wall seconds,
workers, the agents it drove, episodes to run and finished, the 1-minute load average at both ends) and the
machines that ran it. A leg that drove one agent's whole suite from start to end is that suite's wall time, graph
start-ups and town builds included; this page lists every leg with its agents' episodes and simulated steps, and
the issue's goal (a network's 350-route suite in at most an hour) against the network legs that finished whole.
`workers.py` projects the same figure from a sample of routes; this is the measurement. The record, its page and
the goal are msfsu_evaluation.records.suite_time's.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from msfsu_evaluation.closed_loop.runner import EPISODES_FILE, RUN_FILE, read_episodes
from msfsu_evaluation.records.suite_time import SuiteLeg, SuiteTime

DEFAULT_OUT = Path(__file__).with_name("suite_time_results.md")


def legs(run: Path) -> list[SuiteLeg]:
    """Every leg of a run directory with its agents' episodes (routes, steps, simulated s) from episodes.jsonl."""
    info = json.loads((run / RUN_FILE).read_text())
    episodes = read_episodes(run)
    found = []
    for leg in info.get("legs", []):
        mine = [e for e in episodes if e.agent in leg["agents"]]
        found.append(SuiteLeg.from_dict({
            **leg, "run": str(run), "simulator_revision": info.get("simulator_revision"),
            "machines": info.get("machines", []), "routes": len(mine), "steps": sum(e.steps for e in mine),
            "simulated_s": round(sum(e.time_s for e in mine), 1),
            "network": any(info.get("agents", {}).get(agent) for agent in leg["agents"])}))
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run directories of msfsu-benchmark")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown table; JSON beside it")
    args = parser.parse_args(argv)
    found: list[SuiteLeg] = []
    for run in args.runs:
        if not (run / RUN_FILE).exists() or not (run / EPISODES_FILE).exists():
            print(f"suite_time: {run} is not a run directory (no {RUN_FILE} and {EPISODES_FILE})", file=sys.stderr)
            return 1
        found += legs(run)
    if not found:
        print("suite_time: no recorded legs in these run directories (recorded since 2026-11-26)", file=sys.stderr)
        return 1
    command = " ".join(["python", "benchmarks/suite_time.py", *(str(run) for run in args.runs)])
    suites = SuiteTime(found)
    text = suites.page(command)
    print(text, end="")
    args.out.write_text(text)
    args.out.with_suffix(".json").write_text(suites.to_json())
    return 0


if __name__ == "__main__":
    sys.exit(main())
