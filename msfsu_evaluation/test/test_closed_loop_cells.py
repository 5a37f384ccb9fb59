"""The typed records of a closed-loop report read and write results.json unchanged, and render as the page says."""

import json
from pathlib import Path

from msfsu_evaluation.closed_loop.cells import PairedRow, Results, SummaryCell, separation_text
from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.statistics import Interval, PairedComparison, cell_statistics

COMMITTED = Path(__file__).resolve().parents[2] / "docs" / "results" / "closed_loop" / "results.json"


def test_a_committed_results_json_reads_into_records_and_writes_back_byte_for_byte():
    record = json.loads(COMMITTED.read_text())
    results = Results.from_json(record["results"])
    rows = [PairedRow.from_json(row) for row in record["paired"]]
    assert json.dumps(results.to_json(), indent=2) == json.dumps(record["results"], indent=2)
    assert json.dumps([row.to_json() for row in rows], indent=2) == json.dumps(record["paired"], indent=2)
    assert results.cell("expert", "corl2017", "straight", "train").episodes > 0
    assert results.cell("nobody", "corl2017", "straight", "train") is None


def test_a_cell_is_rounded_as_results_json_holds_it_and_renders_its_entries():
    episodes = [EpisodeResult("a", "r", "success" if s else "collision", s, time_s=30.0, steps=300, route_completion=rc,
                              collision_type="" if s else "vehicle", distance_to_goal_m=0.0, timeout_s=60.0,
                              wall_s=10.0, unanswered_frames=0, solid_line_crossings=0)
                for s, rc in ((True, 1.0), (True, 1.0), (False, 1 / 3))]
    cell = SummaryCell.of(cell_statistics(episodes, {"r": 1000.0}), outcomes={"success": 2, "collision": 1},
                          collisions={"vehicle": 1}, wall_s=12.345, rmse_m=None, path_rmse_m=None, rmse_episodes=0)
    assert cell.route_completion == 0.7778 and cell.km_driven == 2.333 and cell.wall_s_per_episode == 12.3
    assert SummaryCell.from_json(json.loads(json.dumps(cell.to_json()))) == cell
    assert cell.success_text() == "2/3 (67; 21-94)"
    assert cell.outcomes_text() == "collision 1, success 2 (collisions: vehicle 1)"
    assert cell.rmse_text() == "– (path –, n=0)"
    assert separation_text(cell, cell, ("a", "b")) == "overlap" and separation_text(cell, None, ("a", "b")) == "–"


def test_a_paired_row_says_its_difference_in_points_as_the_readme_does_from_json():
    comparison = PairedComparison(routes=20, a_successes=12, b_successes=8, only_a=5, only_b=1, difference=0.2,
                                  difference_ci95=Interval(-0.0123456, 0.41), p_value=0.21875)
    row = PairedRow.of("msfsu", "msf", "all", "heldout", comparison)
    assert row.difference_ci95 == Interval(-0.0123, 0.41) and row.mcnemar_p == 0.2188
    assert row.difference_text() == "+20 (-1 to +41)"
    assert row.markdown_row() == "| msfsu vs msf | all | heldout | 20 | 12 | 8 | 5 | 1 | +20 (-1 to +41) | 0.219 |"
    # the README's tables: the pooled one without the suite, the precision one named by the other network
    assert row.markdown_row(suite=False) == "| msfsu vs msf | heldout | 20 | 12 | 8 | 5 | 1 | +20 (-1 to +41) | 0.219 |"
    assert row.markdown_row(pair="msf") == "| msf | all | heldout | 20 | 12 | 8 | 5 | 1 | +20 (-1 to +41) | 0.219 |"
    swapped = row.with_first("msf")
    assert swapped.markdown_row() == "| msf vs msfsu | all | heldout | 20 | 8 | 12 | 1 | 5 | -20 (-41 to +1) | 0.219 |"
    assert row.with_first("msfsu") is row and swapped.with_first("msfsu") == row
    assert PairedRow.from_json(row.to_json()) == row
