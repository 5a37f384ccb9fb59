"""benchmarks/workers.py --from-json: its page names the machine and the time its records carry, never this one's."""

import json
import subprocess
import sys
from pathlib import Path

WORKERS = Path(__file__).parents[1] / "benchmarks" / "workers.py"


def record(workers: int, **extra) -> dict:
    agents = {name: {"episodes": 2, "mean_wall_s": 60.0 / workers, "mean_sim_s": 30.0, "successes": 2}
              for name in ("expert", "network")}
    return {"workers": workers, "episodes": 4, "wall_s": 240.0 / workers, "episodes_per_hour": 60.0 * workers,
            "peak_used_memory_gb": 3.0, "memory_before_gb": 1.0, "worker_peak_rss_gb": 1.2, "agents": agents,
            "load_1min_after": 1.9, **extra}


def rebuild(tmp_path: Path, results: list[dict]) -> str:
    out = tmp_path / "workers_results.md"
    out.with_suffix(".json").write_text(json.dumps(results))
    completed = subprocess.run([sys.executable, str(WORKERS), "--from-json", "--out", str(out)],
                               capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0, completed.stderr[-3000:]
    return out.read_text()


def test_page_names_the_machine_and_time_of_its_records(tmp_path):
    machine = "Example CPU @ 2.0GHz, 2 CPUs, avx2 avx512f"
    page = rebuild(tmp_path, [record(w, machine=machine, date=f"2026-11-2{w} 10:00 UTC") for w in (1, 2)])
    assert page.startswith("# Closed-loop benchmark throughput (2026-11-22 10:00 UTC)")
    assert f"machine: {machine}." in page and "| 2 | 4 | 120.0 | 120.0 | 2.00x |" in page


def test_records_without_a_machine_say_so(tmp_path):
    page = rebuild(tmp_path, [record(1), record(2)])
    assert "(time not recorded)" in page and "machine: not recorded." in page and "cores" not in page
