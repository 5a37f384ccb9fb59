"""msfsu_evaluation.records: every committed benchmark record reads and writes back byte for byte, the pages that
have all they say in the record regenerate unchanged, and the goals' verdicts (soak, suite time)."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest

from msfsu_evaluation.records.gate import GATE_RECORDS, GateRecord, gate_block, read_gate_records
from msfsu_evaluation.records.gpu import GpuRecord
from msfsu_evaluation.records.int8_profile import Int8Profile
from msfsu_evaluation.deploy.recipe_record import SensitivityRecord
from msfsu_evaluation.records.lockstep import LockstepResults
from msfsu_evaluation.records.network import NetworkRecord
from msfsu_evaluation.records.perception import PerceptionRecord, read_perception
from msfsu_evaluation.records.simulator import SimulatorResults
from msfsu_evaluation.records.soak import (SOAK_GOALS, AebSoaks, SoakRecord, read_design_soaks, read_soaks, soak_block,
                                           soak_design_block)
from msfsu_evaluation.records.suite_time import FULL_SUITE_ROUTES, GOAL_H, SuiteLeg, SuiteTime
from msfsu_evaluation.records.training import TrainingResults, TrainingRun
from msfsu_evaluation.records.workers import WorkersResults

ROOT = Path(__file__).resolve().parents[2]
BENCHMARKS = ROOT / "benchmarks"
SOAKS = sorted(BENCHMARKS.glob("soak/*.json")) + sorted(BENCHMARKS.glob("soak/design/*.json")) + sorted(
    BENCHMARKS.glob("soak/aeb/*/*.json"))
GATES = [path for pattern in (*GATE_RECORDS, "models/*.deploy/*-gate-cuda.json") for path in sorted(ROOT.glob(pattern))]
SENSITIVITIES = sorted(BENCHMARKS.glob("int8_recipes/*.json"))
LISTS = {"simulator_results.json": SimulatorResults, "lockstep_results.json": LockstepResults,
         "suite_time_results.json": SuiteTime, "training_results.json": TrainingResults,
         "workers_results.json": WorkersResults}


@pytest.mark.parametrize("path", SOAKS, ids=lambda path: path.relative_to(BENCHMARKS).as_posix())
def test_a_committed_soak_reads_writes_and_renders_its_page_unchanged(path):
    record = SoakRecord.from_json(path.read_text())
    assert record.to_json() == path.read_text()
    assert record.page() == path.with_suffix(".md").read_text()


@pytest.mark.parametrize("name", LISTS)
def test_a_committed_list_record_round_trips(name):
    text = (BENCHMARKS / name).read_text()
    assert LISTS[name].from_json(text).to_json() == text


def test_the_network_record_round_trips_and_renders_its_page_unchanged():
    text, page = (BENCHMARKS / "network_results.json").read_text(), (BENCHMARKS / "network_results.md").read_text()
    record = NetworkRecord.from_json(text)
    assert record.to_json() == text
    limit = float(re.search(r"may weigh (\d+) MB", page)[1])  # msfsu_perception's setting, stated by the page
    assert record.page(limit) == page
    assert record.block().splitlines()[2].startswith("| MSFSU ResNet-50 V2 224 (`--preset paper`) | v1: kernel 3")


def test_the_pages_made_from_the_record_alone_regenerate_unchanged():
    training = TrainingResults.from_json((BENCHMARKS / "training_results.json").read_text())
    assert training.page() == (BENCHMARKS / "training_results.md").read_text()
    page = (BENCHMARKS / "suite_time_results.md").read_text()
    command = page.splitlines()[2].strip("`")  # the command line is the page's, not the record's
    assert SuiteTime.from_json((BENCHMARKS / "suite_time_results.json").read_text()).page(command) == page


@pytest.mark.parametrize("name", ["perception_results.json", "perception_results_avx2.json"])
def test_a_committed_perception_record_round_trips(name):
    text = (BENCHMARKS / name).read_text()
    assert PerceptionRecord.from_json(text).to_json() == text


def test_the_perception_records_hold_a_random_model_and_the_shipped_models_gated_path():
    machines = read_perception(BENCHMARKS)
    assert machines.avx2 is not None and machines.avx2.machine.startswith("AMD EPYC")
    shipped = next(model for model in machines.main.models if model.checkpoint == "models/msfsu_default.pt")
    assert shipped.fastest_gated.path == "openvino int8" and shipped.verdicts["openvino int8"] is True
    assert machines.main.headline().endswith("torch fp32 ([deployment.md](docs/deployment.md#latency-on-the-cpu)).")


@pytest.mark.parametrize("path", GATES, ids=lambda path: path.relative_to(ROOT).as_posix())
def test_a_committed_gate_record_round_trips_as_record_gate_results_writes_it(path):
    record = GateRecord.from_json(path.read_text())
    assert record.to_json() == path.read_text()
    assert all(verdict.passed == verdict.result.passed for verdict in record.paths.values())  # same thresholds


def test_the_gate_block_lists_every_path_of_every_committed_gate_record_with_its_stored_verdict():
    records = read_gate_records(ROOT)
    assert [record.checkpoint for record in records][0] == "models/msfsu_default.pt"
    rows = gate_block(records).splitlines()[2:]
    assert len(rows) == sum(len(record.paths) for record in records)
    record = records[0]
    key = next(iter(record.paths))
    record.paths[key] = dataclasses.replace(record.paths[key], passed=False)
    assert record.block_rows()[0].endswith("| FAIL |")


def test_the_gpu_record_round_trips_and_renders_its_page_unchanged():
    text = (BENCHMARKS / "gpu_results.json").read_text()
    record = GpuRecord.from_json(text)
    assert record.to_json() == text
    assert record.page() == (BENCHMARKS / "gpu_results.md").read_text()
    record.gate = None
    assert "## Accuracy gate" not in record.page()
    with pytest.raises(ValueError, match="has no gate"):
        record.gate_block()


def test_the_int8_profile_round_trips_and_renders_its_page_unchanged():
    text = (BENCHMARKS / "int8_profile_results.json").read_text()
    record = Int8Profile.from_json(text)
    assert record.to_json() == text
    assert record.page() == (BENCHMARKS / "int8_profile_results.md").read_text()


@pytest.mark.parametrize("path", SENSITIVITIES, ids=lambda path: path.name)
def test_a_committed_sensitivity_record_round_trips_and_renders_its_page_unchanged(path):
    record = SensitivityRecord.from_json(path.read_text())
    assert record.to_json() == path.read_text()
    assert record.page() == path.with_suffix(".md").read_text()


def test_the_committed_release_verdict_round_trips_and_says_why():
    from msfsu_evaluation.reports.release import ReleaseVerdict

    text = (ROOT / "docs" / "results" / "model_v3" / "release.json").read_text()
    verdict = ReleaseVerdict.from_json(text)
    assert verdict.to_json() == text and verdict.paired[0].suite == "all"
    assert verdict.line().startswith("release: released, " if verdict.released else "release: not released, ")


def test_a_list_file_that_is_not_a_list_is_an_error():
    with pytest.raises(ValueError, match="a list of records was expected"):
        TrainingResults.from_json("{}")


def _soak(size: str = "800x600", rate_hz: float = 30.0, **totals) -> SoakRecord:
    """A committed soak as if of camera `size` at `rate_hz`, with `totals` changed."""
    record = SoakRecord.from_json(SOAKS[0].read_text())
    record.size, record.rate_hz = size, rate_hz
    record.totals = dataclasses.replace(record.analysed(), **totals)
    return record


def _e2e(p95: float, worst: float) -> dict[str, float]:
    return {"n": 100, "p50": 10.0, "p95": p95, "p99": p95, "max": worst}


def test_the_soak_meets_its_goal_only_with_every_condition():
    goal = SOAK_GOALS[("800x600", 30.0)]
    assert (goal.p95_ms, goal.max_ms) == (30.0, 100.0)
    clean = dict(unpaired=0, watchdog_brakes_driving=0, answered_or_skipped_share=1.0)
    assert _soak(end_to_end_ms=_e2e(30.0, 99.9), **clean).met_goal() is True
    assert _soak(end_to_end_ms=_e2e(30.0, 99.9), **clean).goal_text() == "p95 <= 30, max < 100: met"
    for broken in (dict(end_to_end_ms=_e2e(30.1, 50.0)), dict(end_to_end_ms=_e2e(20.0, 100.0)),
                   dict(unpaired=1), dict(watchdog_brakes_driving=1), dict(answered_or_skipped_share=0.989)):
        record = _soak(**{**clean, "end_to_end_ms": _e2e(20.0, 50.0), **broken})
        assert record.met_goal() is False, broken
        assert record.goal_text() == "p95 <= 30, max < 100: **not met**"


def test_the_brakes_soak_pair_meets_its_goal_only_within_two_ms_of_added_p95():
    without, with_aeb = _soak(end_to_end_ms=_e2e(14.0, 20.0)), _soak(end_to_end_ms=_e2e(16.0, 25.0))
    assert "end-to-end p95 +2.0 ms with the brake (goal: at most +2 ms: met)" in AebSoaks([(without, with_aeb)]).block()
    with_aeb.totals = dataclasses.replace(with_aeb.analysed(), end_to_end_ms=_e2e(16.1, 25.0))
    assert "+2.1 ms with the brake (goal: at most +2 ms: **not met**)" in AebSoaks([(without, with_aeb)]).block()
    committed = AebSoaks.read(BENCHMARKS / "soak" / "aeb")
    assert [(a.name, b.name) for a, b in committed.pairs] == [("800x600_20hz", "800x600_20hz")]


def test_the_crossing_and_composed_soaks_get_their_own_columns_and_verdicts_beside_their_pair():
    without, with_aeb = _soak(end_to_end_ms=_e2e(14.0, 20.0)), _soak(end_to_end_ms=_e2e(15.0, 25.0))
    crossing, composed = _soak(end_to_end_ms=_e2e(17.5, 25.0)), _soak(end_to_end_ms=_e2e(15.5, 25.0))
    block = AebSoaks([(without, with_aeb)], {"crossing": {without.name: crossing},
                                             "composed": {without.name: composed}}).block()
    assert "+1.0 ms with the brake (goal: at most +2 ms: met)" in block
    assert "+3.5 ms with the brake predicting crossings (goal: at most +2 ms: **not met**)" in block
    assert "+1.5 ms with the brake composed with the control in one process (goal: at most +2 ms: met)" in block
    assert ("| without | with the brake | p95 added | composed with the control | p95 added | predicting crossings | "
            "p95 added |") in block
    assert "[predicting crossings](benchmarks/soak/aeb/crossing/" in block and "aeb/composed/" in block
    alone = AebSoaks([(without, with_aeb)]).block()
    assert "predicting crossings" not in alone and "composed" not in alone


def test_a_soak_without_answers_misses_its_goal_and_a_size_without_a_goal_has_none():
    assert _soak(end_to_end_ms={"n": 0}, unpaired=0, watchdog_brakes_driving=0,
                 answered_or_skipped_share=1.0).met_goal() is False
    assert _soak("1920x1080", 30.0, end_to_end_ms=_e2e(59.0, 500.0), unpaired=0, watchdog_brakes_driving=0,
                 answered_or_skipped_share=1.0).goal_text() == "p95 <= 60: met"
    untargeted = _soak("320x240", 10.0)
    assert untargeted.goal is None and untargeted.met_goal() is None and untargeted.goal_text() == "-"


def test_a_soak_not_yet_analysed_says_so():
    record = SoakRecord.from_json(SOAKS[0].read_text())
    record.totals = None
    with pytest.raises(ValueError, match="never analysed"):
        record.page()


def test_the_soak_blocks_list_by_width_then_rate_and_name_each_design_file(tmp_path):
    for path in SOAKS[:4]:
        (tmp_path / path.name).write_text(path.read_text())
    rows = soak_block(read_soaks(tmp_path)).splitlines()[2:6]
    assert [row.split(" | ")[:2] for row in rows] == [["| 800x600", "20 Hz"], ["| 800x600", "30 Hz"],
                                                      ["| 1280x720", "30 Hz"], ["| 1920x1080", "30 Hz"]]
    assert soak_block([]).startswith("Not soaked yet")
    design = read_design_soaks(BENCHMARKS / "soak" / "design")
    assert [(soak.inference, soak.transport, soak.record.size) for soak in design][:2] == [
        ("executor", "defaults", "800x600"), ("executor", "profile", "800x600")]
    assert "| on its executor thread (now) | Fast DDS defaults (before) | 800x600 at 30 Hz |" in soak_design_block(design)


def _training_row(**fields) -> dict:
    row = json.loads((BENCHMARKS / "training_results.json").read_text())[-1]
    return {**row, **fields}


def test_a_training_row_without_the_steady_state_writes_no_steady_keys_and_renders_dashes():
    row = {key: value for key, value in _training_row().items() if not key.startswith("steady_")}
    run = TrainingRun.from_dict(row)
    assert run.to_dict() == row and list(run.to_dict()) == list(row)
    assert "| – | " in TrainingResults([run]).block() and run.cells("").endswith("| –")


def test_a_training_run_replaces_the_row_of_its_machine_and_keeps_the_others():
    old, other = TrainingRun.from_dict(_training_row()), TrainingRun.from_dict(_training_row(batch_size=999))
    new = TrainingRun.from_dict(_training_row(trainer_samples_per_s=1.0))
    assert TrainingResults([old, other]).replacing(new).rows == [other, new]


def test_a_lockstep_segment_without_answered_frames_is_absent_and_rendered_as_a_dash():
    results = LockstepResults.from_json((BENCHMARKS / "lockstep_results.json").read_text())
    graph = results.rows[0].driven()
    graph.round_trip_ms = None
    assert "round trip ms" not in graph.to_dict() and "publish frame ms" in graph.to_dict()
    assert results.block().splitlines()[2].endswith(f"| {graph.frames_per_s} | - / - | {graph.load_1min} |")


def _leg(wall_s: float, finished: int = FULL_SUITE_ROUTES, agents: tuple[str, ...] = ("net",),
         network: bool = True) -> SuiteLeg:
    return SuiteLeg(started="2026-11-26T23:00:00+00:00", workers=2, load_1min_start=0.5, agents=list(agents),
                    to_run=FULL_SUITE_ROUTES, finished=finished, ended="2026-11-27T00:00:00+00:00",
                    load_1min_end=2.1, wall_s=wall_s, run="r", simulator_revision=4, machines=[], routes=finished,
                    steps=100, simulated_s=10.0, network=network)


def test_the_suite_goal_holds_only_whole_network_legs_and_the_fastest_decides():
    assert SuiteTime([_leg(100.0, finished=90), _leg(100.0, network=False),
                      _leg(100.0, agents=("a", "b"))]).met_goal() is None
    assert SuiteTime([_leg(GOAL_H * 3600 + 1), _leg(GOAL_H * 3600)]).met_goal() is True
    assert SuiteTime([_leg(GOAL_H * 3600 + 1)]).met_goal() is False


MODEL_V3 = Path(__file__).parents[2] / "docs" / "results" / "model_v3"


def test_the_committed_stage_lines_round_trip_and_the_plan_names_the_recipes_stages_in_order():
    from msfsu_evaluation.records.stages import read_recipe

    plan, done, overheads = read_recipe(MODEL_V3)
    lines = (MODEL_V3 / "stages.jsonl").read_text().splitlines()
    assert set(overheads) == {"re-collect", "lost", "refused"} and all(hours >= 0 for hours in overheads.values())
    assert [record.to_line() for record in done] == lines and done
    from msfsu_evaluation.pipelines.model_v3 import ModelV3, Settings

    stages = [stage.name for stage in ModelV3(Settings.from_environment()).stages()]  # the order the pipeline runs
    assert plan.names() == stages
    assert plan.planned_h <= plan.budget_h and all(stage.planned_h <= plan.longest_stage_h for stage in plan.stages)


def test_the_stages_block_puts_measured_hours_beside_planned_ones_and_holds_the_rest_against_the_budget():
    from msfsu_evaluation.records.stages import PlannedStage, StagePlan, StageRecord

    plan = StagePlan(budget_h=4, longest_stage_h=2.5, stages=[PlannedStage(stage="a", planned_h=1.0),
                                                              PlannedStage(stage="b", planned_h=2.0)])
    record = StageRecord(stage="a", started_utc=0, ended_utc=10800, invocations=2, hours=3.0, machine="m, 2 CPUs",
                         code="abc")
    block = plan.block([record])
    assert "| `a` | 1.0 | 3.00 (over the 2.5 h stage limit) | 2 | 1970-01-01 03:00 | abc |" in block
    assert "| `b` | 2.0 | not finished |" in block
    assert "planned for the rest: 5.0 h (over the budget)" in block and plan.projected_h([]) == 3.0
    with pytest.raises(ValueError, match="the plan lacks: c"):
        plan.block([dataclasses.replace(record, stage="c")])
    # time outside the stages counts: spent and against the budget
    block = plan.block([record], {"re-collect": 0.5, "lost": 0.0})
    assert "| bags collected again on a new machine | | 0.50 | | | |" in block and "lost with" not in block
    assert "**3.50** (1 of 2 stages)" in block and "planned for the rest: 5.5 h" in block


def test_a_revised_plan_replaces_the_stages_and_names_the_first_total():
    from msfsu_evaluation.records.stages import StagePlan

    first = {"budget_h": 4, "longest_stage_h": 2.5, "stages": [{"stage": "a", "planned_h": 1.0},
                                                               {"stage": "b", "planned_h": 2.0}]}
    assert StagePlan.from_json(json.dumps(first)).revision is None
    revised = {**first, "revised": {"date": "2026-12-03", "why": "b was dropped.", "stages": [
        {"stage": "a", "planned_h": 1.5}]}}
    plan = StagePlan.from_json(json.dumps(revised))
    assert plan.names() == ["a"] and plan.planned_h == 1.5 and plan.projected_h([]) == 1.5
    block = plan.block([], {"refused": 2.0})
    assert "| work whose submission was refused for its size (its commits never landed) | | 2.00 |" in block
    assert "planned for the rest: 3.5 h (within the budget)" in block
    assert block.endswith("Plan revised 2026-12-03 (the first plan: 3.0 h of stages): b was dropped.")


def test_a_stage_that_needs_the_bags_expects_their_re_collection_until_it_has_finished():
    from msfsu_evaluation.records.stages import PlannedStage, StagePlan, StageRecord

    plan = StagePlan.from_json(json.dumps({"budget_h": 4, "longest_stage_h": 2.5, "stages": [
        {"stage": "train", "planned_h": 1.0, "re_collect_h": 1.25}, {"stage": "judge", "planned_h": 0.5}]}))
    assert plan.stages[0] == PlannedStage(stage="train", planned_h=1.0, re_collect_h=1.25)
    assert plan.stages[1].to_dict() == {"stage": "judge", "planned_h": 0.5}  # absent, not null
    assert plan.expected_overheads_h([]) == {"re-collect": 1.25} and plan.projected_h([]) == 2.75
    block = plan.block([], {"re-collect": 0.5})
    assert "planned for the rest, 1.25 h more of bags collected again on a new machine: 3.2 h (within" in block
    trained = StageRecord(stage="train", started_utc=0, ended_utc=3600, invocations=1, hours=1.0, machine="m",
                          code="abc")
    assert plan.expected_overheads_h([trained]) == {} and plan.projected_h([trained], {"re-collect": 0.5}) == 2.0
    assert "more of bags" not in plan.block([trained], {"re-collect": 0.5})


def test_a_clock_s_hours_sum_its_invocations(tmp_path):
    from msfsu_evaluation.records.stages import clock_hours

    (tmp_path / "100").write_text("1900")
    (tmp_path / "5000").write_text("6800")
    assert clock_hours(tmp_path) == 1.0 and clock_hours(tmp_path / "never_ran") == 0.0
