"""A suite split over a SLURM array (scripts/slurm_benchmark.sh, shards 1/2 and 2/2) and merged by
msfsu-benchmark-report gives what one full run gives (the expert on the smoke suite: 2 routes).
Three simulator starts (~1.5-4 min): marked slow; the shard selection and the merge have fast tests in
msfsu_evaluation/test/test_closed_loop_statistics.py."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPOSITORY = Path(__file__).resolve().parents[1]
BENCHMARK = [sys.executable, "-m", "msfsu_evaluation.closed_loop"]
REPORT = [sys.executable, "-m", "msfsu_evaluation.closed_loop.report"]
SUITE = ["--agent", "expert", "--suite", "smoke"]
MACHINE_DEPENDENT = ("wall_s", "worker_peak_rss_mb", "worker", "worker_episode")
pytestmark = pytest.mark.slow


def _episodes(*runs: Path) -> dict:
    episodes = {}
    for run in runs:
        for line in (run / "episodes.jsonl").read_text().splitlines():
            episode = json.loads(line)
            episodes[episode["route"]] = {k: v for k, v in episode.items() if k not in MACHINE_DEPENDENT}
    return episodes


def _results(report_dir: Path) -> dict:
    results = json.loads((report_dir / "results.json").read_text())["results"]
    for suite in results["expert"].values():
        for task in suite.values():
            for cell in task.values():
                cell.pop("wall_s_per_episode")
    return results


def test_two_slurm_shards_merged_equal_one_full_run(tmp_path):
    full = subprocess.run(BENCHMARK + SUITE + ["--out", str(tmp_path / "full")], capture_output=True, text=True,
                          timeout=300)
    assert full.returncode == 0, full.stderr[-3000:]
    for index in (1, 2):
        environment = {**os.environ, "SLURM_ARRAY_TASK_ID": str(index), "SLURM_ARRAY_TASK_COUNT": "2",
                       "BENCH_OUT": str(tmp_path / "shards")}
        shard = subprocess.run(["bash", str(REPOSITORY / "scripts" / "slurm_benchmark.sh"), *SUITE], env=environment,
                               capture_output=True, text=True, timeout=300, cwd=tmp_path)
        assert shard.returncode == 0, shard.stderr[-3000:]
        assert f"2 routes x 1 agents, 1 episodes in shard {index}/2, 1 to run" in shard.stderr
    shards = sorted((tmp_path / "shards").glob("shard-*"))
    assert [s.name for s in shards] == ["shard-1", "shard-2"]
    assert _episodes(*shards) == _episodes(tmp_path / "full")  # disjoint halves, same outcomes
    merged = subprocess.run(REPORT + [*map(str, shards), "--out", str(tmp_path / "merged")], capture_output=True,
                            text=True, timeout=120)
    assert merged.returncode == 0, merged.stderr
    assert _results(tmp_path / "merged") == _results(tmp_path / "full")
    for route in _episodes(tmp_path / "full"):
        name = route.replace("/", "__") + ".npy"
        merged_trajectory = next(np.load(p) for s in shards if (p := s / "trajectories" / "expert" / name).exists())
        # a fresh engine per shard against one reused engine: the same drive to float rounding (< 1 mm)
        assert np.allclose(merged_trajectory, np.load(tmp_path / "full" / "trajectories" / "expert" / name),
                           atol=1e-3, rtol=0)
