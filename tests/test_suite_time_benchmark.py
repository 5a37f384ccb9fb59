"""benchmarks/suite_time.py: a suite's wall time is read from the legs msfsu-benchmark records in run.json."""

import json
import subprocess
import sys
from pathlib import Path

from msfsu_evaluation.closed_loop.episode_record import EpisodeResult

BENCHMARK = Path(__file__).parents[1] / "benchmarks" / "suite_time.py"


def _episode(agent: str, route: str) -> EpisodeResult:
    return EpisodeResult(agent, route, "success", True, time_s=40.0, steps=400, route_completion=1.0, collision_type="",
                         distance_to_goal_m=1.0, timeout_s=60.0, wall_s=20.0, unanswered_frames=0)


def _run_dir(path: Path, legs: list[dict], agents: dict, episodes: list[EpisodeResult]) -> Path:
    path.mkdir()
    (path / "run.json").write_text(json.dumps({"simulator_revision": 4, "agents": agents, "legs": legs,
                                               "machines": ["CPU A, 2 CPUs, avx2"]}))
    (path / "episodes.jsonl").write_text("".join(json.dumps(e.to_dict()) + "\n" for e in episodes))
    return path


def _leg(agents: list[str], wall_s: float, finished: int, to_run: int) -> dict:
    return {"started": "2026-11-26T23:00:00+00:00", "ended": "2026-11-27T00:00:00+00:00", "wall_s": wall_s,
            "workers": 2, "agents": agents, "to_run": to_run, "finished": finished, "load_1min_start": 0.5,
            "load_1min_end": 2.1}


def test_a_whole_network_suite_leg_is_checked_against_the_hour_and_partial_legs_are_only_listed(tmp_path):
    network = [_episode("net", f"r{i}") for i in range(350)]
    expert = [_episode("expert", f"r{i}") for i in range(350)]
    run = _run_dir(tmp_path / "run", [_leg(["expert"], 600.0, 350, 350), _leg(["net"], 4320.0, 350, 350)],
                   {"expert": None, "net": "models/net.pt"}, expert + network)
    partial = _run_dir(tmp_path / "partial", [_leg(["net"], 1000.0, 90, 350)], {"net": "models/net.pt"}, network[:90])
    out = tmp_path / "suite.md"
    completed = subprocess.run([sys.executable, str(BENCHMARK), str(run), str(partial), "--out", str(out)],
                               capture_output=True, text=True, timeout=60)
    assert completed.returncode == 0, completed.stderr
    text = out.read_text()
    assert "| expert | 2 | 350 / 350 | 140,000 | 0.17 |" in text and "| net | 2 | 90 / 350 | 36,000 | 0.28 |" in text
    assert "One network agent's full suite (350 routes, one leg from start to end): 1.20 h with 2 workers (net); " \
           "the goal, at most 1 h: **not met**." in text
    assert len(json.loads(out.with_suffix(".json").read_text())) == 3
    empty = _run_dir(tmp_path / "old", [], {"net": "models/net.pt"}, network)
    completed = subprocess.run([sys.executable, str(BENCHMARK), str(empty), "--out", str(out)], capture_output=True,
                               text=True, timeout=60)
    assert completed.returncode == 1 and "no recorded legs" in completed.stderr
