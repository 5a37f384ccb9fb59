"""Closed loop through the node graph as msfsu-benchmark drives it: steps/s per worker and where a step's time goes.

    python benchmarks/closed_loop.py                       # this tree, writes benchmarks/closed_loop_results.{md,json}
    python benchmarks/closed_loop.py --variant base=tree:/tmp/base --variant current   # two source trees, one run
    python benchmarks/closed_loop.py --variant lp0=env:LP_NUM_THREADS=0 --variant current --sets routes

Each variant runs `msfsu-benchmark` with 2 workers on the fixed sets, one after the other on this machine:
`routes` (the first training route of every CoRL2017 and NoCrash task in town_a: 7 routes) and `scenarios` (every
training scenario of the per-ability suite in town_a: 42), each driven by the product (the shipped network with the
emergency brake, msfsu_bringup/product.yaml) and by its network alone (`--network-only`). A variant is this tree
(`current`), another source tree (`tree:DIR`, e.g. a `git worktree` of an earlier commit, run from this venv with its
packages first on PYTHONPATH) or this tree with environment variables (`env:KEY=VALUE,...`). From the runs' records
(closed_loop.throughput): steps/s per worker, episodes per hour, the milliseconds of each stage of a step in the
worker (simulator, publishing, waiting for the graph, labels, telemetry, judge) and the CPU milliseconds of each
process per step; and per episode whether the variants drove it the same (status and steps). The 1-minute load
average is printed with every run: numbers taken under load are not comparable. Records of a tree without the
episode timing (before it was kept) give the rate only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from msfsu_bringup.product import load_product
from msfsu_common.benchmark_run import load_1min
from msfsu_common.machine import describe_cpu
from msfsu_evaluation.closed_loop.runner import read_episodes
from msfsu_evaluation.closed_loop.throughput import by_agent

REPOSITORY = Path(__file__).resolve().parents[1]
DEFAULT_OUT = Path(__file__).with_name("closed_loop_results.md")
PACKAGES = ("msfsu_common", "msfsu_perception", "msfsu_control", "msfsu_bringup", "msfsu_sim", "msfsu_evaluation")
SETS = {"routes": ["--suite", "corl2017", "nocrash", "--conditions", "train", "--routes-per-task", "1"],
        "scenarios": ["--suite", "abilities", "--conditions", "train"]}
TOWN = "town_a"
PRODUCT, NETWORK = "product", "network"  # the agents: the product, and its network alone


@dataclass(frozen=True)
class Variant:
    name: str
    tree: Path  # the source tree its packages come from
    env: dict[str, str]

    @classmethod
    def parse(cls, text: str) -> Variant:
        name, _, spec = text.partition("=")
        if not spec or spec == "current":
            return cls(name, REPOSITORY, {})
        kind, _, value = spec.partition(":")
        if kind == "tree":
            return cls(name, Path(value).resolve(), {})
        if kind == "env":
            return cls(name, REPOSITORY, dict(item.split("=", 1) for item in value.split(",")))
        raise argparse.ArgumentTypeError(f"--variant {text}: give NAME, NAME=tree:DIR or NAME=env:KEY=VALUE,...")

    def environment(self) -> dict[str, str]:
        paths = [str(self.tree / package) for package in PACKAGES]
        return {**os.environ, **self.env, "PYTHONPATH": os.pathsep.join([*paths, os.environ.get("PYTHONPATH", "")])}


def run_set(variant: Variant, name: str, out: Path, workers: int) -> dict:
    """One msfsu-benchmark run of a set by a variant; its throughput, wall time and episodes."""
    checkpoint = REPOSITORY / load_product().checkpoint
    command = [sys.executable, "-m", "msfsu_evaluation.closed_loop", *SETS[name], "--towns", TOWN, "--no-expert",
               "--workers", str(workers), "--checkpoint", f"{PRODUCT}={checkpoint}", "--checkpoint",
               f"{NETWORK}={checkpoint}", "--network-only", NETWORK, "--out", str(out)]
    load_start, started = load_1min(), time.monotonic()
    run = subprocess.run(command, cwd=variant.tree, env=variant.environment(), capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"closed_loop.py: {variant.name} on {name} failed: {run.stderr.strip().splitlines()[-1]}")
    wall_s = time.monotonic() - started
    episodes = read_episodes(out)
    print(f"{variant.name} {name}: {len(episodes)} episodes in {wall_s:.0f} s (load {load_start} -> {load_1min()})",
          flush=True)
    return {"variant": variant.name, "set": name, "wall_s": round(wall_s, 1), "workers": workers,
            "load_1min": [load_start, load_1min()], "episodes_per_hour": round(len(episodes) / wall_s * 3600, 1),
            "throughput": {agent: speed.to_dict() for agent, speed in by_agent(episodes).items()},
            "episodes": {f"{e.agent} {e.route}": [e.status, e.steps] for e in episodes}}


def markdown(results: list[dict], command: str, machine: str, when: str | None) -> str:
    lines = [f"# Closed loop through the graph: speed and where a step goes ({when})",
             "", f"`{command}` on {machine}; 2 workers; the product (`{PRODUCT}`, with the emergency brake) and its "
             f"network alone (`{NETWORK}`) on the routes and scenarios of {TOWN} (training condition).", "",
             "| variant | set | agent | steps/s per worker | steps | episodes/h (both agents) | wall s | load (1 min) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for result in results:
        for agent, speed in result["throughput"].items():
            lines.append(f"| {result['variant']} | {result['set']} | {agent} | {speed['steps_per_s_per_worker']} | "
                         f"{speed['steps']} | {result['episodes_per_hour']} | {result['wall_s']} | "
                         f"{result['load_1min'][0]} -> {result['load_1min'][1]} |")
    columns = [(r["variant"], r["set"], agent) for r in results for agent in r["throughput"]]
    stages = list(dict.fromkeys(stage for r in results for t in r["throughput"].values() for stage in t["stage_ms_per_step"]))
    processes = list(dict.fromkeys(p for r in results for t in r["throughput"].values() for p in t["cpu_ms_per_step"]))
    header = "| | " + " | ".join(f"{v} {s} {a}" for v, s, a in columns) + " |"
    rule = "| --- |" + " --- |" * len(columns)
    lookup = {(r["variant"], r["set"], agent): speed for r in results for agent, speed in r["throughput"].items()}
    lines += ["", "Wall milliseconds per step in the worker, by stage of its loop (closed_loop.episode.STAGES; a "
              "stage of the graph's processes shows as the worker's wait for control):", "", header, rule]
    for stage in stages:
        lines.append(f"| {stage} | " + " | ".join(str(lookup[c]["stage_ms_per_step"].get(stage, "-")) for c in columns)
                     + " |")
    lines += ["", "CPU milliseconds per step, by process (the worker: simulator, publishing, labels, telemetry; the "
              "graph's nodes; user + system):", "", header, rule]
    for process in processes:
        lines.append(f"| {process} | " + " | ".join(str(lookup[c]["cpu_ms_per_step"].get(process, "-")) for c in columns)
                     + " |")
    names = list(dict.fromkeys(r["variant"] for r in results))
    if len(names) > 1:
        lines += ["", f"Episodes driven the same as by `{names[0]}` (two runs of one tree need not repeat every episode step "
                  "for step: two simulators rendering at once, docs/evaluation.md#determinism):", ""]
        for name in names[1:]:
            for set_name in SETS:
                base = next((r["episodes"] for r in results if r["variant"] == names[0] and r["set"] == set_name), None)
                other = next((r["episodes"] for r in results if r["variant"] == name and r["set"] == set_name), None)
                if base is None or other is None:
                    continue
                same = sum(base.get(key) == value for key, value in other.items())
                status = sum(base.get(key, [None])[0] == value[0] for key, value in other.items())
                lines.append(f"- {name}, {set_name}: {status} of {len(other)} with the same outcome, {same} of them "
                             "step for step")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", action="append", type=Variant.parse, metavar="NAME[=tree:DIR|env:K=V,...]",
                        help="a variant to run (repeatable, in order; default: this tree as 'current')")
    parser.add_argument("--sets", nargs="+", choices=list(SETS), default=list(SETS))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--runs", type=Path, default=Path("runs/closed_loop_benchmark"), help="the run directories")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown table; JSON beside it")
    parser.add_argument("--render", action="store_true", help="rewrite --out's page from the JSON beside it")
    args = parser.parse_args(argv)
    if args.render:
        record = json.loads(args.out.with_suffix(".json").read_text())
        args.out.write_text(markdown(record["results"], record["command"], record["machine"], record.get("time")))
        return 0
    variants = args.variant or [Variant.parse("current")]
    stamp = time.strftime("%Y%m%d-%H%M%S")
    results = [run_set(variant, name, args.runs / stamp / variant.name / name, args.workers)
               for name in args.sets for variant in variants]
    command = "python benchmarks/closed_loop.py " + " ".join(sys.argv[1:] if argv is None else argv)
    machine, when = describe_cpu(), time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    args.out.write_text(markdown(results, command.strip(), machine, when))
    args.out.with_suffix(".json").write_text(json.dumps({"command": command.strip(), "machine": machine, "time": when,
                                                         "results": results}, indent=1) + "\n")
    print(args.out.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
