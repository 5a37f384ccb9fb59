"""Closed-loop benchmark throughput with 1 and 2 workers: episodes per hour, wall time per route, memory.

    python benchmarks/workers.py                     # writes benchmarks/workers_results.{md,json}
    python benchmarks/workers.py --workers 1 2 --routes-per-task 2 --suite corl2017 nocrash

Runs `msfsu-benchmark` (the default model and the expert on the same routes) once per worker count into a
fresh directory, samples the machine's used memory (MemTotal - MemAvailable) every second, and reads the
episode records it wrote. The projection for a full suite (350 routes = 14 task x condition cells x 25)
uses the measured mean wall time per episode of each agent and the measured speed-up of the worker count.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from msfsu_common.benchmark_run import BenchmarkRun, command_line
from msfsu_evaluation.closed_loop.runner import read_episodes
from msfsu_evaluation.closed_loop.suites import full_suite_routes

DEFAULT_OUT = Path(__file__).with_name("workers_results.md")
FULL_SUITE_ROUTES = full_suite_routes()


def used_memory_gb() -> float:
    fields = dict(line.split(":", 1) for line in Path("/proc/meminfo").read_text().splitlines())
    kb = lambda name: int(fields[name].split()[0])  # noqa: E731
    return (kb("MemTotal") - kb("MemAvailable")) / 2**20


def run(workers: int, args: argparse.Namespace, directory: Path) -> dict:
    out = directory / f"workers_{workers}"
    command = [sys.executable, "-m", "msfsu_evaluation.closed_loop", "--checkpoint", f"network={args.checkpoint}",
               "--suite", *args.suite, "--routes-per-task", str(args.routes_per_task), "--workers", str(workers),
               "--out", str(out)]
    baseline, peak, running = used_memory_gb(), [0.0], [True]

    def sample() -> None:
        while running[0]:
            peak[0] = max(peak[0], used_memory_gb())
            time.sleep(1.0)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    measured = BenchmarkRun.start(sys.executable, command[1:])
    started = time.perf_counter()
    finished = subprocess.run(command, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    running[0] = False
    sampler.join()
    if finished.returncode != 0:
        raise SystemExit(f"msfsu-benchmark with {workers} workers exited with {finished.returncode}")
    episodes = read_episodes(out)
    per_agent = {}
    for agent in sorted({e.agent for e in episodes}):
        mine = [e for e in episodes if e.agent == agent]
        per_agent[agent] = {"episodes": len(mine), "mean_wall_s": round(sum(e.wall_s for e in mine) / len(mine), 1),
                            "mean_sim_s": round(sum(e.time_s for e in mine) / len(mine), 1),
                            "successes": sum(e.success for e in mine)}
    return {"workers": workers, "episodes": len(episodes), "wall_s": round(wall, 1),
            "episodes_per_hour": round(len(episodes) / wall * 3600, 1),
            "peak_used_memory_gb": round(peak[0], 1), "memory_before_gb": round(baseline, 1),
            "worker_peak_rss_gb": round(max(e.worker_peak_rss_mb or 0 for e in episodes) / 1024, 1),
            "agents": per_agent,
            **measured.end().fields({"load_1min_after": "load_end", "machine": "machine", "date": "date_end"})}


def markdown(results: list[dict], args: argparse.Namespace) -> str:
    one = next((r for r in results if r["workers"] == 1), results[0])
    # Records written before 2026-11-28 carry neither the machine nor the time; say so rather than guess.
    machines = sorted({r["machine"] for r in results if "machine" in r})
    date = max((r["date"] for r in results if "date" in r), default="time not recorded")
    lines = [f"# Closed-loop benchmark throughput ({date})", "",
             f"`{command_line('python benchmarks/workers.py', [a for a in sys.argv[1:] if a != '--from-json'])}`: suites {' '.join(args.suite)}, "
             f"{args.routes_per_task} route(s) per task and condition, agents `expert` and `network` "
             f"(`{args.checkpoint}`); machine: {'; '.join(machines) or 'not recorded'}.", "",
             "| workers | episodes | wall s | episodes/h | speed-up | peak memory used (machine) GB | "
             "simulator process peak RSS GB |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in results:
        lines.append(f"| {r['workers']} | {r['episodes']} | {r['wall_s']} | {r['episodes_per_hour']} | "
                     f"{r['episodes_per_hour'] / one['episodes_per_hour']:.2f}x | {r['peak_used_memory_gb']} "
                     f"(before: {r['memory_before_gb']}) | {r['worker_peak_rss_gb']} |")
    lines += ["", "| workers | agent | episodes | successes | mean wall s per episode | mean simulated s |",
              "| --- | --- | --- | --- | --- | --- |"]
    for r in results:
        for agent, stats in r["agents"].items():
            lines.append(f"| {r['workers']} | {agent} | {stats['episodes']} | {stats['successes']} | "
                         f"{stats['mean_wall_s']} | {stats['mean_sim_s']} |")
    best = max(results, key=lambda r: r["episodes_per_hour"])
    hours = 2 * FULL_SUITE_ROUTES / best["episodes_per_hour"]
    network_hours = {r["workers"]: FULL_SUITE_ROUTES * r["agents"]["network"]["mean_wall_s"] / r["workers"] / 3600
                     for r in results if "network" in r["agents"]}
    if network_hours:
        fastest = min(network_hours, key=network_hours.get)
        lines += ["", f"Projection, one network agent alone: {FULL_SUITE_ROUTES} routes x its mean wall time per "
                  f"episode / workers = {network_hours[fastest]:.2f} h with {fastest} worker(s) ("
                  + ", ".join(f"{w} worker(s): {h:.2f} h" for w, h in sorted(network_hours.items())) + ")."]
    lines += ["", f"Projection: a full suite of {FULL_SUITE_ROUTES} routes for one network plus the expert reference "
              f"({2 * FULL_SUITE_ROUTES} episodes) at the best rate measured here ({best['workers']} workers, "
              f"{best['episodes_per_hour']} episodes/h) takes {hours:.1f} h; the routes measured are "
              f"{'a sample' if args.routes_per_task < 25 else 'the full suite'} of the suites above, so the mix of "
              "route lengths differs from the full suite."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=Path("models/msfsu_default.pt"))
    parser.add_argument("--suite", nargs="+", default=["corl2017"])
    parser.add_argument("--routes-per-task", type=int, default=1)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="markdown table; JSON beside it")
    parser.add_argument("--from-json", action="store_true",
                        help="run nothing: rewrite the markdown from the JSON beside --out (same options as the run)")
    args = parser.parse_args(argv)
    results = []
    if args.from_json:
        results = json.loads(args.out.with_suffix(".json").read_text())
    else:
        with tempfile.TemporaryDirectory(prefix="msfsu-workers-") as directory:
            for workers in args.workers:
                results.append(run(workers, args, Path(directory)))
                print(json.dumps(results[-1]), flush=True)
    text = markdown(results, args)
    print(text)
    args.out.write_text(text)
    args.out.with_suffix(".json").write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
