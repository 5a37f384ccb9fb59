"""reports.aeb_goals on hand-made records of the brake's route run: each goal can come out either way."""

import json
from pathlib import Path

import pytest

from msfsu_evaluation.closed_loop.suites import load_routes
from msfsu_evaluation.reports.aeb_goals import WITH, WITHOUT, aeb_goals

RUN = Path(__file__).resolve().parents[2] / "docs" / "results" / "aeb_v1" / "records" / "routes"


def template() -> dict:
    """A committed msfsu_aeb record of the brake's run (every field as the runner writes it)."""
    return next(json.loads(line) for line in (RUN / "episodes.jsonl").read_text().splitlines()
                if json.loads(line)["agent"] == WITH)


def record(agent: str, route: str, outcome: str = "success", brakes: int = 0, false_brakes: int = 0,
           time_s: float = 40.0) -> dict:
    collided = outcome in ("pedestrian", "vehicle")
    fields = {key: value for key, value in template().items() if key != "aeb"}
    fields.update(agent=agent, route=route, status="collision" if collided else outcome, success=outcome == "success",
                  collision_type=outcome if collided else "", route_completion=1.0 if outcome == "success" else 0.5,
                  time_s=time_s)
    if agent == WITH:  # only the agent with the brake records its counts
        fields["aeb"] = {"brakes": brakes, "caps": 0, "false_brakes": false_brakes}
    return fields


@pytest.fixture
def routes():
    _, all_routes = load_routes()
    dense = [r.key for r in all_routes if r.task == "nocrash_dense" and r.condition == "train"][:4]
    empty = [r.key for r in all_routes if r.task == "nocrash_empty" and r.condition == "train"][:2]
    return dense, empty


def write(tmp_path: Path, records: list[dict]) -> Path:
    run = tmp_path / "routes"
    run.mkdir()
    (run / "run.json").write_text((RUN / "run.json").read_text())
    (run / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return run


def test_the_brake_that_stops_for_pedestrians_meets_its_goals(tmp_path, routes):
    dense, empty = routes
    records = [record(WITHOUT, key, "pedestrian") for key in dense[:2]] + [record(WITHOUT, key, "vehicle")
                                                                            for key in dense[2:]]
    records += [record(WITH, key, brakes=1) for key in dense]
    records += [record(agent, key, time_s=50.0) for key in empty for agent in (WITHOUT, WITH)]
    goals = aeb_goals(write(tmp_path, records))
    verdicts = "\n".join(goals.verdicts())
    assert next(v for v in goals.verdicts() if v.startswith("pedestrian collisions train 0.000/km")).endswith(": met")
    assert "): halved" in verdicts and "NoCrash dense train 100 % (goal 61): met" in verdicts
    assert "false brakes 0.00 per 10 km: met" in verdicts and "NoCrash empty time train x1.000: met" in verdicts
    assert goals.paired.routes == 6 and goals.paired.only_a == 4 and goals.paired.only_b == 0
    assert goals.row(WITH, "train").brakes == 4 and goals.row(WITHOUT, "train").brakes is None
    assert "in progress: 12 of 700 episodes" in goals.line()


def test_a_brake_for_nothing_that_slows_the_empty_road_misses_them(tmp_path, routes):
    dense, empty = routes
    records = [record(WITHOUT, key) for key in dense] + [record(WITH, key, "pedestrian", brakes=3, false_brakes=3)
                                                          for key in dense]
    records += [record(WITHOUT, key, time_s=50.0) for key in empty] + [record(WITH, key, time_s=60.0) for key in empty]
    goals = aeb_goals(write(tmp_path, records))
    verdicts = "\n".join(goals.verdicts())
    assert "pedestrian collisions train" in verdicts and "(without 0.000): not met" in verdicts
    assert "none without the brake to halve" in verdicts
    assert "NoCrash dense train 0 % (goal 61): not met" in verdicts
    assert "per 10 km: not met" in verdicts and "NoCrash empty time train x1.200: not met" in verdicts
    assert goals.paired.only_b == 4 and goals.paired.difference < 0


def test_no_goals_before_both_agents_share_a_route(tmp_path, routes):
    dense, _ = routes
    assert aeb_goals(write(tmp_path, [record(WITHOUT, key) for key in dense])) is None
