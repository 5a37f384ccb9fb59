"""reports.aeb_goals on hand-made records of the brake's route runs: each goal can come out either way."""

import json
from pathlib import Path

import pytest

from msfsu_evaluation.closed_loop.suites import load_routes
from msfsu_evaluation.reports.aeb_goals import AEB_V1, RouteRun, aeb_goals

ROOT = Path(__file__).resolve().parents[2]
RUN = ROOT / AEB_V1.records[0]
WITHOUT, WITH = AEB_V1.without, AEB_V1.judged
CROSSING = "msfsu_aeb_x"


def template() -> dict:
    """A committed msfsu_aeb record of the brake's run (every field as the runner writes it)."""
    return next(json.loads(line) for line in (RUN / "episodes.jsonl").read_text().splitlines()
                if json.loads(line)["agent"] == WITH)


def record(agent: str, route: str, outcome: str = "success", brakes: int = 0, false_brakes: int = 0,
           time_s: float = 40.0, caps: int = 0, false_caps: int | None = None) -> dict:
    collided = outcome in ("pedestrian", "vehicle")
    fields = {key: value for key, value in template().items() if key != "aeb"}
    fields.update(agent=agent, route=route, status="collision" if collided else outcome, success=outcome == "success",
                  collision_type=outcome if collided else "", route_completion=1.0 if outcome == "success" else 0.5,
                  time_s=time_s)
    if agent != WITHOUT:  # only the agents with the brake record its counts
        fields["aeb"] = {"brakes": brakes, "caps": caps, "false_brakes": false_brakes}
        if false_caps is not None:
            fields["aeb"]["false_caps"] = false_caps
    return fields


@pytest.fixture
def routes():
    _, all_routes = load_routes()
    dense = [r.key for r in all_routes if r.task == "nocrash_dense" and r.condition == "train"][:4]
    empty = [r.key for r in all_routes if r.task == "nocrash_empty" and r.condition == "train"][:2]
    return dense, empty


def write(directory: Path, records: list[dict]) -> Path:
    directory.mkdir(parents=True)
    (directory / "run.json").write_text((RUN / "run.json").read_text())
    (directory / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return directory


def one_run(tmp_path: Path, records: list[dict]):
    write(tmp_path / "routes", records)
    return aeb_goals(RouteRun(("routes",), "page.md", WITHOUT, (WITH,), "Brake", "a test run"), root=tmp_path)


def test_the_brake_that_stops_for_pedestrians_meets_its_goals(tmp_path, routes):
    dense, empty = routes
    records = [record(WITHOUT, key, "pedestrian") for key in dense[:2]] + [record(WITHOUT, key, "vehicle")
                                                                            for key in dense[2:]]
    records += [record(WITH, key, brakes=1) for key in dense]
    records += [record(agent, key, time_s=50.0) for key in empty for agent in (WITHOUT, WITH)]
    goals = one_run(tmp_path, records)
    verdicts = "\n".join(goals.verdicts())
    assert next(v for v in goals.verdicts() if v.startswith("pedestrian collisions train 0.000/km")).endswith(": met")
    assert "): halved" in verdicts and "NoCrash dense train 100 % (goal 61): met" in verdicts
    assert "false brakes (caps not judged in this run) 0.00 per 10 km: met" in verdicts
    assert "NoCrash empty time train x1.000: met" in verdicts
    (paired,) = goals.paired
    assert paired.routes == 6 and paired.only_a == 4 and paired.only_b == 0
    assert goals.row(WITH, "train").brakes == 4 and goals.row(WITHOUT, "train").brakes is None
    assert "in progress: 12 of 700 episodes" in goals.line()


def test_a_brake_for_nothing_that_slows_the_empty_road_misses_them(tmp_path, routes):
    dense, empty = routes
    records = [record(WITHOUT, key) for key in dense] + [record(WITH, key, "pedestrian", brakes=3, false_brakes=3)
                                                          for key in dense]
    records += [record(WITHOUT, key, time_s=50.0) for key in empty] + [record(WITH, key, time_s=60.0) for key in empty]
    goals = one_run(tmp_path, records)
    verdicts = "\n".join(goals.verdicts())
    assert "pedestrian collisions train" in verdicts and "(without 0.000): not met" in verdicts
    assert "none without the brake to halve" in verdicts
    assert "NoCrash dense train 0 % (goal 61): not met" in verdicts
    assert "per 10 km: not met" in verdicts and "NoCrash empty time train x1.200: not met" in verdicts
    assert goals.paired[0].only_b == 4 and goals.paired[0].difference < 0


def test_no_goals_before_both_agents_share_a_route(tmp_path, routes):
    dense, _ = routes
    assert one_run(tmp_path, [record(WITHOUT, key) for key in dense]) is None


def test_a_sharded_run_of_three_agents_judges_the_last_brake_and_counts_its_false_caps(tmp_path, routes):
    """The crossing brake's run: three agents, its routes in two shards; false caps count as false interventions,
    and the last brake is paired with the one before it and with the network without a brake."""
    dense, empty = routes
    run = RouteRun(("shard_1", "shard_2"), "page.md", WITHOUT, (WITH, CROSSING), "Crossing brake", "a test run")
    first, second = dense[:2] + empty, dense[2:]
    for directory, keys in (("shard_1", first), ("shard_2", second)):
        write(tmp_path / directory, [record(WITHOUT, key, "pedestrian" if key in dense else "success") for key in keys]
              + [record(WITH, key, "pedestrian" if key in dense[:3] else "success", brakes=1, false_caps=0)
                 for key in keys]
              + [record(CROSSING, key, caps=2, false_caps=1 if key == dense[0] else 0, false_brakes=0)
                 for key in keys])
    goals = aeb_goals(run, root=tmp_path)
    assert goals.done == 18 and goals.planned == 3 * 350
    assert [(row.a, row.b) for row in goals.paired] == [(CROSSING, WITH), (WITH, WITHOUT), (CROSSING, WITHOUT)]
    assert [(row.only_a, row.only_b) for row in goals.paired] == [(3, 0), (1, 0), (4, 0)]
    row = goals.row(CROSSING, "train")
    assert (row.caps, row.false_caps, row.false_interventions) == (12, 1, 1)
    verdicts = "\n".join(goals.verdicts())
    assert f"false interventions {10 / row.km:.2f} per 10 km" in verdicts
    assert "pedestrian collisions train 0.000/km (without" in verdicts  # the crossing brake's, not the corridor's
    assert "msfsu_aeb_x minus msfsu_aeb" in goals.line()
    # the same records with caps judged wrong in one episode: the whole condition's false caps are unknown
    records = (tmp_path / "shard_2" / "episodes.jsonl").read_text().replace(', "false_caps": 0}', "}", 1)
    (tmp_path / "shard_2" / "episodes.jsonl").write_text(records)
    assert aeb_goals(run, root=tmp_path).row(WITH, "train").false_caps is None
