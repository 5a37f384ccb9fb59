"""reports.waiting_goals on hand-made judge pages (results.json written with the report's own record types): each goal
can come out either way, and the tables pair the candidate with the shipped network."""

import json
from pathlib import Path

import pytest

from msfsu_evaluation.closed_loop.ability_report import BOTH, CONFLICTS, AbilityCell
from msfsu_evaluation.closed_loop.abilities import ABILITIES
from msfsu_evaluation.closed_loop.cells import PairedRow, SummaryCell
from msfsu_evaluation.closed_loop.statistics import paired_comparison, wilson_interval
from msfsu_evaluation.reports.waiting_goals import JUDGED, RECORD, SHIPPED, waiting_goals

CANDIDATE = "msfsu_weighted"
EXPERT = Path("expert/results.json")


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
        (root / JUDGED / "judge-routes").mkdir(parents=True)
        (root / JUDGED / "judge-routes" / "results.json").write_text(json.dumps(routes))
    if candidate_abilities is not None:
        (root / JUDGED / "judge-abilities").mkdir(parents=True)
        cells = ability_cells(SHIPPED, {"pedestrian_left": 0}) + ability_cells(CANDIDATE, candidate_abilities)
        rows = [paired("pedestrian_left", BOTH, [True] * candidate_abilities.get("pedestrian_left", 32)
                       + [False] * (32 - candidate_abilities.get("pedestrian_left", 32)), [False] * 32)]
        page = {"cells": cells, "paired": rows, "agents": [SHIPPED, CANDIDATE]}
        (root / JUDGED / "judge-abilities" / "results.json").write_text(json.dumps(page))
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
