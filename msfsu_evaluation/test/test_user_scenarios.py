"""Scenarios of a user's own: the generator writes a scenario file for the towns, weathers, seed and suite name given,
msfsu-benchmark --scenarios drives it, and msfsu-benchmark-report reads the file the run drove, not the committed one."""

import json
import subprocess
import sys

GENERATOR = [sys.executable, "-m", "msfsu_evaluation.closed_loop.make_abilities"]
BENCHMARK = [sys.executable, "-m", "msfsu_evaluation.closed_loop"]
REPORT = [sys.executable, "-m", "msfsu_evaluation.closed_loop.report"]


def test_a_scenario_file_of_ones_own_is_generated_driven_and_reported(tmp_path):
    scenarios = tmp_path / "mine.json"
    made = subprocess.run([*GENERATOR, "--per-ability", "1", "--condition", "dusk=town_b:soft_rain_dusk", "--seed", "7",
                           "--suite", "mine", "--out", str(scenarios)], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr[-2000:]
    routes = json.loads(scenarios.read_text())["routes"]
    assert len(routes) == 7 and {(r["suite"], r["condition"], r["town"], r["weather"]) for r in routes} == {
        ("mine", "dusk", "town_b", "soft_rain_dusk")}
    out = tmp_path / "run"
    run = subprocess.run([*BENCHMARK, "--agent", "expert", "--suite", "abilities", "--scenarios", str(scenarios),
                          "--tasks", "pedestrian_left", "lead_braking", "--out", str(out)],
                         capture_output=True, text=True, timeout=400)
    assert run.returncode == 0, run.stderr[-3000:]
    episodes = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert sorted(e["route"] for e in episodes) == ["mine/lead_braking/dusk/00", "mine/pedestrian_left/dusk/00"]
    assert all(e["status"] == "success" for e in episodes)  # the expert solves its scenarios
    assert json.loads((out / "run.json").read_text())["routes_file"].endswith("mine.json")
    page = (out / "results.md").read_text()
    report = subprocess.run([*REPORT, str(out), "--out", str(tmp_path / "report")], capture_output=True, text=True,
                            timeout=120)
    assert report.returncode == 0, report.stderr[-2000:]
    assert (tmp_path / "report" / "results.md").read_text() == page  # the same page, from the run's own file
    wrong = subprocess.run([*GENERATOR, "--condition", "x=town_z:clear_noon", "--out", str(tmp_path / "x.json")],
                           capture_output=True, text=True, timeout=60)
    assert wrong.returncode == 2 and "unknown town_z" in wrong.stderr
