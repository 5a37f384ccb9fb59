"""reports.waiting_goals on hand-made judge pages (results.json written with the report's own record types): each goal
can come out either way, and the tables pair the candidate with the shipped network."""

import json
from pathlib import Path

import numpy as np
import pytest

from msfsu_evaluation.closed_loop.ability_report import BOTH, CONFLICTS, AbilityCell
from msfsu_evaluation.closed_loop.abilities import ABILITIES
from msfsu_evaluation.closed_loop.cells import PairedRow, SummaryCell
from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.runner import EPISODES_FILE, RUN_FILE, telemetry_path
from msfsu_evaluation.closed_loop.telemetry import COLUMNS, EXPERT_LIMITS, save
from msfsu_evaluation.closed_loop.statistics import paired_comparison, wilson_interval
from msfsu_evaluation.records.perception import GatedPath, PerceptionModel, PerceptionRecord
from msfsu_evaluation.records.soak import SoakRecord, SoakTotals
from msfsu_evaluation.reports.waiting_goals import (
    JUDGED,
    REALTIME_SOAK,
    REALTIME_SPEED,
    RECORD,
    SHIPPED,
    SOAK_NAME,
    waiting_goals,
)

CANDIDATE = "msfsu_weighted"
EXPERT = Path("expert/results.json")
AMD, INTEL = "AMD EPYC, 2 CPUs, avx2", "Intel(R) Xeon(R) Processor, 2 CPUs, avx2 amx_int8"
# (agent, route, machine) of a judge run's records: route r0 recorded before machines were (its run's first: AMD)
DRIVEN = ((SHIPPED, "r0", None), (CANDIDATE, "r0", None), (SHIPPED, "r1", INTEL), (CANDIDATE, "r1", INTEL),
          (SHIPPED, "r2", AMD), (CANDIDATE, "r2", AMD))


def write_run(folder: Path, page: dict, driven=DRIVEN) -> None:
    """A judge run's folder: its page (results.json), run.json's machines and its episode records."""
    folder.mkdir(parents=True)
    (folder / "results.json").write_text(json.dumps(page))
    (folder / RUN_FILE).write_text(json.dumps({"machines": [AMD, INTEL]}))
    records = [EpisodeResult(agent, route, "success", True, 1.0, 10, 1.0, "", 1.0, 60.0, 1.0, 0, machine=machine)
               for agent, route, machine in driven]
    (folder / EPISODES_FILE).write_text("".join(json.dumps(record.to_dict()) + "\n" for record in records))


def cell(successes: int, episodes: int, km: float, pedestrians: int = 0, solid_lines: int = 0) -> dict:
    infractions = {"pedestrian": pedestrians, "vehicle": 0, "solid_line": solid_lines}
    return SummaryCell(episodes=episodes, successes=successes, success_rate=successes / episodes,
                       success_ci95=wilson_interval(successes, episodes), route_completion=1.0, driving_score=1.0,
                       km_driven=km, infractions=infractions,
                       infractions_per_km={kind: count / km for kind, count in infractions.items()},
                       outcomes={"success": successes}, collisions={"pedestrian": pedestrians} if pedestrians else {},
                       wall_s_per_episode=60.0, rmse_m=None, path_rmse_m=None, rmse_episodes=0).to_json()


def paired(suite: str, condition: str, candidate: list[bool], shipped: list[bool]) -> dict:
    successes = lambda outcomes: dict(enumerate(outcomes))  # noqa: E731
    return PairedRow.of(SHIPPED, CANDIDATE, suite, condition,  # as a report may order them: shipped first
                        paired_comparison(successes(shipped), successes(candidate))).to_json()


def routes_page(candidate_pedestrians: int = 0, candidate_dense: int = 20, candidate_one_turn: int = 25,
                solid_lines: int = 2) -> dict:
    """Each agent: nocrash_dense (25 routes, 20 km) and corl2017 one_turn (25 routes, 10 km) in each condition."""
    results = {}
    for agent, dense, one_turn, pedestrians in ((SHIPPED, 10, 25, 6), (CANDIDATE, candidate_dense, candidate_one_turn,
                                                                        candidate_pedestrians)):
        results[agent] = {
            "nocrash": {"nocrash_dense": {c: cell(dense, 25, 20.0, pedestrians if c == "heldout" else 0,
                                                  solid_lines if agent == CANDIDATE else 30) for c in ("train", "heldout")}},
            "corl2017": {"one_turn": {c: cell(one_turn, 25, 10.0) for c in ("train", "heldout")}}}
    paper = {"cells": {"corl2017/one_turn/train": {}, "nocrash/nocrash_dense/train": {},
                       "nocrash/nocrash_dense/heldout": {}}}
    return {"results": results, "against_paper": {CANDIDATE: paper, SHIPPED: paper},
            "paired": [paired("nocrash", "train", [True] * candidate_dense + [False] * (25 - candidate_dense),
                              [True] * 10 + [False] * 15)]}


def ability_cells(agent: str, successes: dict[str, int]) -> list[dict]:
    return [AbilityCell(agent=agent, ability=ability, condition=BOTH, scenarios=32, successes=successes.get(ability, 32),
                        success_ci95=wilson_interval(successes.get(ability, 32), 32), collisions={}, timeouts=0,
                        mean_time_to_goal_s=None).to_json() for ability in (*ABILITIES, CONFLICTS)]


def write(root: Path, routes: dict | None, candidate_abilities: dict[str, int] | None, expert: dict[str, int]) -> None:
    record = root / RECORD
    record.mkdir(parents=True)
    (record / "selection.json").write_text(json.dumps({"chosen": CANDIDATE}))
    if routes is not None:
        write_run(root / JUDGED / "judge-routes", routes)
    if candidate_abilities is not None:
        cells = ability_cells(SHIPPED, {"pedestrian_left": 0}) + ability_cells(CANDIDATE, candidate_abilities)
        rows = [paired("pedestrian_left", BOTH, [True] * candidate_abilities.get("pedestrian_left", 32)
                       + [False] * (32 - candidate_abilities.get("pedestrian_left", 32)), [False] * 32),
                paired(CONFLICTS, BOTH, [True] * 32, [True] * 32)]
        page = {"cells": cells, "paired": rows, "agents": [SHIPPED, CANDIDATE]}
        write_run(root / JUDGED / "judge-abilities", page, driven=[(agent, route, INTEL) for agent, route, _ in DRIVEN])
    (root / EXPERT).parent.mkdir(parents=True)
    (root / EXPERT).write_text(json.dumps({"cells": ability_cells("expert", expert), "paired": [], "agents": ["expert"]}))


def block(root: Path) -> str:
    goals = waiting_goals(root=root, expert=EXPERT)
    assert goals is not None
    return goals.block()


def test_a_candidate_that_waits_meets_every_goal_and_its_tables_pair_it_with_the_shipped(tmp_path):
    write(tmp_path, routes_page(), {}, {})
    text = block(tmp_path)
    assert "| msfsu | heldout | 30.0 | 0.200 |" in text and f"| {CANDIDATE} | heldout | 30.0 | 0.000 |" in text
    # the report's row had the shipped first: the table reads candidate minus shipped
    assert f"| {CANDIDATE} vs {SHIPPED} | nocrash | train | 25 | 20 | 10 | 10 | 0 | +40 (" in text
    assert f"| pedestrian_left | 0 (0-11) | 100 (89-100) | +100 (" in text
    assert "routes by machine: AMD EPYC: 2, Intel(R) Xeon(R) Processor: 1; each pair on one machine." in text
    assert "Scenarios by machine: Intel(R) Xeon(R) Processor: 3; each pair on one machine." in text
    conflicts = waiting_goals(root=tmp_path, expert=EXPERT).conflicts_text()
    assert conflicts == (f"the scenario suite's conflicts (both conditions) {CANDIDATE} 100 (89-100) % against the "
                         "shipped 100 (89-100) %, +0 (-11 to +11) points (McNemar p 1.000)")
    for verdict in ("pedestrian collisions train 0.000/km (shipped 0.000): met",
                    "pedestrian collisions heldout 0.000/km (shipped 0.200): met",
                    "NoCrash dense train 20/25 (80; 61-91) (goal 61 %): met", "solid-line crossings 0.07/km: met",
                    "paper cells below the shipped model's interval: none",
                    "every ability >= 90 % where the expert has >= 95 %: met"):
        assert f"- {verdict}" in text


def test_each_goal_fails_when_its_figure_misses(tmp_path):
    write(tmp_path, routes_page(candidate_pedestrians=2, candidate_dense=12, candidate_one_turn=15, solid_lines=40),
          {"pedestrian_left": 28, "cut_in": 20}, {"cut_in": 25})
    text = block(tmp_path)
    assert "- pedestrian collisions heldout 0.067/km (shipped 0.200): not met" in text
    assert "- NoCrash dense heldout 12/25 (48; 30-67) (goal 43 %): met" in text  # held out's goal is lower
    assert "- NoCrash dense train 12/25 (48; 30-67) (goal 61 %): not met" in text
    assert "- solid-line crossings 1.33/km: not met" in text
    # one_turn train 15/25 is under the shipped 25/25's interval; nocrash_dense 12/25 is above the shipped 10/25's low
    assert "- paper cells below the shipped model's interval: corl2017/one_turn/train 15/25 (60; 41-77) under" in text
    assert "nocrash/nocrash_dense" not in text.split("paper cells below")[1]
    # cut_in: 20 of 32, but the expert solved only 25 of 32 (78 %): no goal there
    assert "- every ability >= 90 % where the expert has >= 95 %: not met (pedestrian_left 88 (72-95))" in text


@pytest.mark.parametrize("made", ["nothing", "selection only"])
def test_before_the_judge_stages_the_block_says_so(tmp_path, made):
    if made == "nothing":
        assert waiting_goals(root=tmp_path, expert=EXPERT) is None
        return
    write(tmp_path, None, None, {})
    assert block(tmp_path).startswith("Not judged yet")


def write_realtime(root: Path, agent: str, hz: float, p95_ms: float) -> None:
    """What `make waiting-realtime` leaves for one network: its perception benchmark and its 20 Hz soak."""
    model = PerceptionModel(model="cpu preset resnet18v2 128x128", checkpoint=f"{agent}.pt", checkpoint_digest="0",
                            load_average_before=[0.3, 0.5, 0.6], paths={}, verdicts={"openvino int8": True},
                            verdict_source="recorded", fastest_gated=GatedPath(path="openvino int8", p50_ms=1e3 / hz,
                                                                               hz=hz, speedup_vs_torch_fp32=6.0))
    speed = PerceptionRecord(date="2026-12-05", command="perception.py", machine="AMD EPYC, 2 CPUs", threads=2,
                             iterations=40, torch="2.13.0+cpu", models=[model], end_to_end=[])
    (root / REALTIME_SPEED).mkdir(parents=True, exist_ok=True)
    (root / REALTIME_SPEED / f"perception_{agent}.json").write_text(speed.to_json())
    totals = SoakTotals(published=3600, answered=3600, processed=3600, skipped=0, unpaired=0,
                        answered_or_skipped_share=1.0, watchdog_brakes_driving=0,
                        end_to_end_ms={"n": 3600, "p50": p95_ms - 4, "p95": p95_ms, "p99": p95_ms + 2, "max": 40.0})
    soak = SoakRecord(started_utc="2026-12-05 19:40 UTC", minutes=3, size="800x600", camera="800x600 rgb8 + 32FC1",
                      rate_hz=20.0, checkpoint=f"{agent}.pt", inference="cpu openvino/int8", machine="AMD EPYC",
                      load_average_start="0.2 0.4 0.5", load_average_end="2.0 1.0 0.6", totals=totals)
    (root / REALTIME_SOAK / agent).mkdir(parents=True)
    (root / REALTIME_SOAK / agent / f"{SOAK_NAME}.json").write_text(soak.to_json())


@pytest.mark.parametrize(("hz", "p95_ms", "verdicts"), [
    (360.0, 18.5, ["gated precision 360 Hz (shipped 365 Hz): met", "20 Hz soak p95 18.5 ms (shipped 18.0 ms): met"]),
    (90.0, 26.0, ["gated precision 90 Hz (shipped 365 Hz): not met",
                  "20 Hz soak p95 26.0 ms (shipped 18.0 ms): not met"]),
])
def test_the_real_time_goal_is_judged_from_both_networks_measured_in_one_run(tmp_path, hz, p95_ms, verdicts):
    write(tmp_path, None, None, {})
    write_realtime(tmp_path, SHIPPED, 365.0, 18.0)
    write_realtime(tmp_path, CANDIDATE, hz, p95_ms)
    text = block(tmp_path)
    assert f"| {SHIPPED} | openvino int8 | 365 Hz | 0.30 | cpu openvino/int8 | 14.0 / 18.0 / 20.0 / 40.0 | 3,600 of " \
           "3,600 | 0.2 | [msfsu](benchmarks/soak/waiting/msfsu/800x600_20hz.md) |" in text
    for verdict in verdicts:
        assert f"- {verdict}" in text
    assert "Routes (" not in text and "Scenario suite (" not in text  # not judged yet: no table of theirs


def test_the_shipped_network_alone_gives_no_real_time_verdict(tmp_path):
    write(tmp_path, None, None, {})
    write_realtime(tmp_path, SHIPPED, 365.0, 18.0)
    text = block(tmp_path)
    assert f"| {SHIPPED} | openvino int8 | 365 Hz |" in text and "- gated precision" not in text


def test_a_route_whose_pair_was_driven_on_two_machines_is_counted_apart(tmp_path):
    write(tmp_path, None, None, {})
    split = [(SHIPPED, "r0", AMD), (CANDIDATE, "r0", INTEL), (SHIPPED, "r1", INTEL), (CANDIDATE, "r1", INTEL),
             (SHIPPED, "r2", AMD)]  # r2: the candidate has not driven it (no pair)
    write_run(tmp_path / JUDGED / "judge-routes", routes_page(), driven=split)
    assert "routes by machine: Intel(R) Xeon(R) Processor: 1; 1 driven on two machines." in block(tmp_path)


def approach(target_when_held: float, steps_held: int = 10) -> np.ndarray:
    """Telemetry rows of a pedestrian scenario: 5 free steps, then the expert held by a pedestrian 20 m ahead at -12
    deg, first slowing, then standing (target 0) for the rest, while the network asks `target_when_held`."""
    rows = np.full((5 + steps_held, len(COLUMNS)), np.nan)
    column = {c.name: i for i, c in enumerate(COLUMNS)}
    rows[:, column["action_target_speed_mps"]] = 8.0
    rows[:, column["expert_limit"]] = EXPERT_LIMITS.index("free")
    rows[5:, column["expert_limit"]] = EXPERT_LIMITS.index("pedestrian")
    rows[5:, column["expert_target_speed_mps"]] = 0.0
    rows[5, column["expert_target_speed_mps"]] = 3.0
    rows[5:, column["action_target_speed_mps"]] = target_when_held
    rows[5, column["action_target_speed_mps"]] = 7.5
    rows[5:, column["pedestrian_distance_m"]] = 20.0
    rows[5:, column["pedestrian_bearing_deg"]] = -12.0
    rows[5:, column["pedestrian_height_px"]] = 14.0
    return rows


def test_the_pedestrian_abilities_table_says_where_the_pedestrian_was_and_what_each_network_asked(tmp_path):
    write(tmp_path, None, {}, {})
    run = tmp_path / JUDGED / "judge-abilities"
    driven = [(SHIPPED, "abilities/pedestrian_left/train/00", 8.0, "pedestrian"),
              (SHIPPED, "abilities/pedestrian_left/train/01", 0.0, ""),
              (CANDIDATE, "abilities/pedestrian_left/train/00", 0.0, ""),
              (CANDIDATE, "abilities/pedestrian_left/train/01", 0.2, "")]
    records = [EpisodeResult(agent, route, "success", not hit, 1.0, 10, 1.0, hit, 1.0, 60.0, 1.0, 0, machine=INTEL)
               for agent, route, _, hit in driven]
    (run / EPISODES_FILE).write_text("".join(json.dumps(record.to_dict()) + "\n" for record in records))
    for agent, route, target, _ in driven:
        save(telemetry_path(run, agent, route), approach(target), ["pedestrian crossing from the left"])
    text = block(tmp_path)
    assert f"| pedestrian_left | {SHIPPED} | 1 of 2 | 20.0 | -12 | 14 | 7.5 | 4.00 | 50 % of 18 |" in text
    assert f"| pedestrian_left | {CANDIDATE} | 0 of 2 | 20.0 | -12 | 14 | 7.5 | 0.10 | 100 % of 18 |" in text
    assert f"| pedestrian_right | {SHIPPED} |" not in text  # no telemetry of it: no row


def test_the_routes_steering_table_sets_each_branch_beside_the_expert(tmp_path):
    write(tmp_path, routes_page(), None, {})
    run = tmp_path / JUDGED / "judge-routes"
    column = {c.name: i for i, c in enumerate(COLUMNS)}
    for agent, offset in ((SHIPPED, 0.0), (CANDIDATE, 0.1)):
        rows = np.full((40, len(COLUMNS)), np.nan)
        rows[:, column["action_command"]] = [3] * 20 + [4] * 20  # STRAIGHT, then LANE_FOLLOW
        expert = np.linspace(-0.2, 0.2, 40)
        rows[:, column["expert_steer"]] = expert
        rows[:, column["action_steer"]] = expert - np.where(np.arange(40) < 20, offset, 0.0)  # off on STRAIGHT only
        for route in ("r0", "r1", "r2"):
            save(telemetry_path(run, agent, route), rows, [])
    text = block(tmp_path)
    assert f"| {SHIPPED} | STRAIGHT | 60 | 0.059 | 0.059 | 1.00 | 0.000 |" in text
    assert f"| {CANDIDATE} | STRAIGHT | 60 | 0.059 | 0.059 | 1.00 | 0.100 |" in text
    assert f"| {CANDIDATE} | LANE_FOLLOW | 60 | 0.059 | 0.059 | 1.00 | 0.000 |" in text
    assert "| LEFT |" not in text  # no step of that branch
