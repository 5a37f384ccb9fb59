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
from msfsu_evaluation.records.workers import WorkersResults, WorkersRun, WorkersSetup

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


def setup(args: argparse.Namespace) -> WorkersSetup:
    """What the page says of this run besides its records."""
    return WorkersSetup(command=command_line("python benchmarks/workers.py",
                                             [a for a in sys.argv[1:] if a != "--from-json"]),
                        suites=tuple(args.suite), routes_per_task=args.routes_per_task,
                        checkpoint=str(args.checkpoint), full_suite_routes=FULL_SUITE_ROUTES)


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
    if args.from_json:
        results = WorkersResults.from_json(args.out.with_suffix(".json").read_text())
    else:
        results = WorkersResults([])
        with tempfile.TemporaryDirectory(prefix="msfsu-workers-") as directory:
            for workers in args.workers:
                results.rows.append(WorkersRun.from_dict(run(workers, args, Path(directory))))
                print(json.dumps(results.rows[-1].to_dict()), flush=True)
    text = results.page(setup(args))
    print(text)
    args.out.write_text(text)
    args.out.with_suffix(".json").write_text(results.to_json())
    return 0


if __name__ == "__main__":
    sys.exit(main())
