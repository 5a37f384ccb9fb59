"""The committed closed-loop reports are exactly what msfsu-benchmark-report makes of the committed records.

Each report names the run directories it was made from and its agents (results.json: "records", "agents"): the
free-running report, for one, pairs its own records with the lockstep records of docs/results/closed_loop/."""

import json
from pathlib import Path

import pytest

from msfsu_evaluation.closed_loop import report
from msfsu_evaluation.reports import graph_change as graph_change_table
from msfsu_evaluation.reports import regenerate as regenerate_reports
from msfsu_evaluation.reports import revision_change, rules_change

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"
REPOSITORY = RESULTS.parents[1]
# closed_loop/, dagger/, free_running/ ... and the page msfsu-benchmark writes into each run directory at its end
REPORTS = regenerate_reports.report_directories()


def test_the_closed_loop_report_has_records():
    assert RESULTS / "closed_loop" in REPORTS, "no committed closed-loop records"


@pytest.mark.parametrize("docs", REPORTS, ids=[str(path.relative_to(RESULTS)) for path in REPORTS])
def test_report_is_what_the_committed_records_give(tmp_path, docs):
    committed = json.loads((docs / "results.json").read_text())
    runs = [REPOSITORY / run for run in committed["records"]]
    assert all(run.is_relative_to(RESULTS) for run in runs), committed["records"]  # committed records only
    assert report.main(regenerate_reports.arguments(docs, out=tmp_path)) == 0
    for name in ("results.md", "results.json"):
        assert (tmp_path / name).read_text() == (docs / name).read_text(), \
            f"{name}: regenerate with msfsu-regenerate-reports"
    committed_figures = sorted(path.name for path in docs.glob("*.png"))
    assert committed_figures == sorted(path.name for path in tmp_path.glob("*.png"))


def test_rules_change_sets_every_v3_cell_beside_its_v2_result(capsys):
    rules_change.main(["--v2", str(RESULTS / "closed_loop" / "results.json"),
                       "--v3", str(RESULTS / "closed_loop_v3" / "results.json")])
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ") and "---" not in line][1:]
    v3 = json.loads((RESULTS / "closed_loop_v3" / "results.json").read_text())
    assert len(rows) == sum(len(conditions) for agent in v3["agents"] for tasks in v3["results"][agent].values()
                            for conditions in tasks.values())
    dense = v3["results"]["expert"]["nocrash"]["nocrash_dense"]["train"]
    assert any(row.startswith("| expert | nocrash / nocrash_dense | train |")
               and f"| {dense['successes']}/{dense['episodes']} |" in row for row in rows)


def test_revision_change_pairs_an_agents_episodes_of_two_runs_and_counts_the_identical_ones(tmp_path, capsys):
    from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
    from msfsu_evaluation.closed_loop.suites import load_routes

    _, routes = load_routes()
    keys = [r.key for r in routes if r.task == "straight" and r.condition == "train"][:3]

    def write(run: Path, agent: str, outcomes: list[tuple[str, int]], revision: int) -> None:
        run.mkdir()
        (run / "run.json").write_text(json.dumps({"simulator_revision": revision, "agents": {agent: "m.pt"},
                                                  "machines": [f"CPU {revision}"]}))
        (run / "episodes.jsonl").write_text("".join(json.dumps(EpisodeResult(
            agent, key, status, status == "success", time_s=steps / 10, steps=steps,
            route_completion=1.0 if status == "success" else 0.5, collision_type="", distance_to_goal_m=4.0,
            timeout_s=100.0, wall_s=float(revision), unanswered_frames=0, solid_line_crossings=0).to_dict()) + "\n"
            for key, (status, steps) in zip(keys, outcomes)))

    write(tmp_path / "before", "a", [("success", 300), ("success", 310), ("timeout", 900)], 3)
    write(tmp_path / "after", "b", [("success", 300), ("success", 311), ("success", 420)], 4)
    out = tmp_path / "page.md"
    assert revision_change.main([f"{tmp_path / 'before'}:a", f"{tmp_path / 'after'}:b", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert text == out.read_text()
    assert "simulator revision 3" in text and "machines: CPU 4" in text
    assert "| straight | train | 3 | 2 | 3 | 1 |" in text  # one episode repeats exactly, one moved by a step
    assert "| train | 3 | 2 | 3 | +33 (" in text
    # the flip counted by its failure type, the route named with both outcomes; nothing was struck, nothing crossed
    assert "1 of 3 routes changed outcome: 1 failures became successes, 0 successes became failures" in text
    assert "| timeout | success | 1 |" in text
    assert f"| {keys[2]} | timeout (RC 50 %) | success (RC 100 %) |" in text
    assert "| train | 0 | 0 | 0.00 (0 in " in text
    assert revision_change.main([f"{tmp_path / 'before'}:nobody", f"{tmp_path / 'after'}:b"]) == 1


def test_lockstep_trace_finds_the_runs_of_frames_inferred_with_another_frames_command():
    import importlib.util

    spec = importlib.util.spec_from_file_location("lockstep_trace", REPOSITORY / "scripts" / "lockstep_trace.py")
    lockstep_trace = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(lockstep_trace)
    frames = [("a", 1, "LANE_FOLLOW", "LANE_FOLLOW"), ("a", 2, "LEFT", "LANE_FOLLOW"), ("a", 3, "LEFT", "LANE_FOLLOW"),
              ("a", 4, "LEFT", "LEFT"), ("a", 5, "LANE_FOLLOW", "LEFT"), ("a", 7, "LANE_FOLLOW", "LEFT"),
              ("a", 8, "LANE_FOLLOW", "")]  # step 6 missing: a new run; no action heard: not counted
    rows = [{"route": route, "step": step, "frame_command": own, "used_command": used}
            for route, step, own, used in frames]
    assert lockstep_trace.mismatches(rows) == [(2, 3, "LEFT", "LANE_FOLLOW"), (5, 5, "LANE_FOLLOW", "LEFT"),
                                               (7, 7, "LANE_FOLLOW", "LEFT")]
    assert [lockstep_trace.where(rows, step) for step in (1, 2, 5, 7)] == [
        "first frame", "command change", "command change", "elsewhere"]


def test_the_graph_change_table_says_what_each_networks_revision_change_page_says(tmp_path, capsys):
    graph1, graph2 = RESULTS / "closed_loop_v3_rev4/records/msfsu_v2", RESULTS / "closed_loop_v3_graph2/records/networks"
    out = tmp_path / "table.md"
    assert graph_change_table.main(["msfsu", f"{graph1}:msfsu_v2", f"{graph2}:msfsu", "--out", str(out)]) == 0
    assert capsys.readouterr().out == out.read_text()
    rows = {tuple(line.split(" | ")[1:3]): line.split(" | ") for line in out.read_text().splitlines()
            if line.startswith("| msfsu |")}
    assert list(rows) == [("corl2017", "train"), ("corl2017", "heldout"), ("nocrash", "train"),
                          ("nocrash", "heldout"), ("all", "train"), ("all", "heldout"), ("all", "all")]
    # the pooled row holds the numbers of the network's own page (scripts/revision_change.py)
    page = (RESULTS / "closed_loop_v3_graph2/graph_change_msfsu.md").read_text().splitlines()
    successes = next(line for line in page if line.startswith("| all | 350 |")).split(" | ")
    kerbs = [line for line in page if line.startswith("| all |")][1].split(" | ")
    pooled = rows[("all", "all")]
    assert pooled[3:7] == successes[1:5]
    assert pooled[8] == f"{kerbs[1]} / {kerbs[2]}"
    assert pooled[9].rstrip(" |") == f"{kerbs[3].split()[0]} / {kerbs[4].split()[0]}"
    assert graph_change_table.main(["msfsu", f"{graph1}:nobody", f"{graph2}:msfsu"]) == 1
    with pytest.raises(SystemExit):
        graph_change_table.main(["msfsu", f"{graph1}:msfsu_v2"])


def test_the_change_tables_command_line_with_other_labels_and_pages_prints_the_same_page(tmp_path, capsys):
    import shlex
    graph1, graph2 = RESULTS / "closed_loop_v3_rev4/records/msfsu_v2", RESULTS / "closed_loop_v3_graph2/records/networks"
    out = tmp_path / "v3_change.md"
    assert graph_change_table.main(["msfsu", f"{graph1}:msfsu_v2", f"{graph2}:msfsu", "--labels", "v2", "v3 (new)",
                                    "--pages", "v3_change_<network>.md", "--out", str(out)]) == 0
    page = out.read_text()
    assert "| routes | v2 | v3 (new) |" in page and "`v3_change_<network>.md`" in page
    command = next(line for line in page.splitlines() if line.startswith("`python scripts/graph_change_table.py"))
    capsys.readouterr()
    assert graph_change_table.main(shlex.split(command.strip("`"))[2:]) == 0
    assert capsys.readouterr().out == page


def test_revision_change_places_each_kerb_strike_by_the_solid_line_crossed_just_before_it():
    from msfsu_evaluation.closed_loop.episode_record import EpisodeResult, SolidLineCrossing

    def episode(collision: str, lines) -> EpisodeResult:
        return EpisodeResult("a", "r/1", "collision" if collision else "success", not collision, time_s=20.0, steps=200,
                             route_completion=0.2, collision_type=collision, distance_to_goal_m=4.0, timeout_s=100.0,
                             wall_s=1.0, unanswered_frames=0, solid_line_crossings=len(lines or ()), solid_lines=lines)

    struck = episode("sidewalk", (SolidLineCrossing(time_s=12.0, progress_m=30.0, command="LEFT", where="junction"),
                                  SolidLineCrossing(time_s=19.8, progress_m=40.0, command="LEFT", where="junction")))
    lines = revision_change.kerb_strikes_markdown({"r/1": episode("sidewalk", None)}, {"r/1": struck}, ["r/1"])
    assert "| before | r/1 | 20 % | 20.0 | not recorded |" in lines  # an older record without the placement
    assert "| after | r/1 | 20 % | 20.0 | LEFT, junction, 0.2 |" in lines
    assert revision_change.kerb_strikes_markdown({"r/1": episode("vehicle", ())}, {"r/1": episode("", ())},
                                                 ["r/1"]) == []
