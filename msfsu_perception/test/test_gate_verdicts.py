"""The accuracy gate's verdict on hand-made scores: mIoU drop <= 1 point and steer MAE rise <= 5 %; the record of
verdicts per checkpoint; picking the fastest path that passed."""

import math

import pytest

from msfsu_perception.gate_verdicts import (
    GateResult,
    HeldOutScores,
    fastest_passing,
    gate_record,
    gate_verdicts,
    gated_precisions,
    record_gate_results,
)
from msfsu_perception.int8_recipe import Int8Build


def result(reference: HeldOutScores, candidate: HeldOutScores) -> GateResult:
    return GateResult("openvino", "int8", 100, reference, candidate, steer_agreement_mae=0.01, class_agreement=0.99)


@pytest.mark.parametrize(("candidate_miou", "passed"), [(0.60, True), (0.591, True), (0.589, False), (0.70, True)])
def test_miou_may_drop_by_one_point_at_most(candidate_miou, passed):
    gate = result(HeldOutScores(0.1, 0.60), HeldOutScores(0.1, candidate_miou))
    assert gate.miou_drop_points == pytest.approx(100 * (0.60 - candidate_miou))
    assert gate.passed is passed


@pytest.mark.parametrize(("candidate_mae", "passed"), [(0.100, True), (0.104, True), (0.106, False), (0.05, True)])
def test_steer_mae_may_rise_by_five_percent_at_most(candidate_mae, passed):
    gate = result(HeldOutScores(0.100, 0.6), HeldOutScores(candidate_mae, 0.6))
    assert gate.steer_mae_rise == pytest.approx(candidate_mae / 0.100 - 1.0)
    assert gate.passed is passed


def test_a_perfect_reference_tolerates_no_steer_error():
    assert result(HeldOutScores(0.0, 0.6), HeldOutScores(0.0, 0.6)).passed
    failing = result(HeldOutScores(0.0, 0.6), HeldOutScores(0.001, 0.6))
    assert math.isinf(failing.steer_mae_rise) and not failing.passed


def test_without_segmentation_only_the_steer_is_gated():
    gate = result(HeldOutScores(0.1, None), HeldOutScores(0.104, None))
    assert gate.miou_drop_points == 0.0 and gate.passed
    assert not result(HeldOutScores(0.1, None), HeldOutScores(0.2, None)).passed


def test_the_fastest_passing_path_wins_and_the_reference_always_counts():
    p50 = {("torch", "fp32"): 20.0, ("openvino", "fp32"): 10.0, ("openvino", "bf16"): 7.0, ("openvino", "int8"): 4.0,
           ("onnxruntime", "int8"): 3.0}
    verdicts = {("openvino", "fp32"): True, ("openvino", "bf16"): True, ("openvino", "int8"): False}
    assert fastest_passing(p50, verdicts) == ("openvino", "bf16")  # int8 failed, onnxruntime int8 never gated
    assert fastest_passing(p50, {**verdicts, ("openvino", "int8"): True}) == ("openvino", "int8")
    assert fastest_passing(p50, {}) == ("torch", "fp32")
    assert fastest_passing({("openvino", "int8"): 4.0}, {}) is None


def _int8(passed: bool, build: Int8Build | None) -> GateResult:
    candidate = HeldOutScores(0.1, 0.60 if passed else 0.50)
    return GateResult("openvino", "int8", 10, HeldOutScores(0.1, 0.6), candidate, 0.0, 1.0,
                      build=None if build is None else build.to_dict())


def test_an_int8_verdict_counts_only_for_the_calibration_and_recipe_it_was_measured_with(tmp_path):
    checkpoint = tmp_path / "model.pt"
    checkpoint.write_bytes(b"weights")
    measured = Int8Build(calibration="c1", recipe="r1", keep_float=("decoder.layers.0",))
    record_gate_results(checkpoint, [_int8(True, measured)], {"bags": ["a"]})
    assert gated_precisions(checkpoint, "openvino", measured) == {"int8"}
    assert gated_precisions(checkpoint, "openvino", Int8Build("c2", "r1")) == set()  # other calibration frames
    assert gated_precisions(checkpoint, "openvino", Int8Build("c1", "r2")) == set()  # another recipe
    assert gated_precisions(checkpoint, "openvino", None) == set()  # no calibration frames at all
    record_gate_results(checkpoint, [_int8(True, None)], {"bags": ["a"]})  # a verdict that names no build
    assert gated_precisions(checkpoint, "openvino", measured) == set()


def test_verdicts_of_another_held_out_set_are_replaced_not_mixed(tmp_path):
    checkpoint = tmp_path / "model.pt"
    checkpoint.write_bytes(b"weights")
    bf16 = GateResult("openvino", "bf16", 10, HeldOutScores(0.1, 0.6), HeldOutScores(0.1, 0.6), 0.0, 1.0)
    record_gate_results(checkpoint, [bf16], {"bags": ["a"]}, command="gate a")
    record_gate_results(checkpoint, [_int8(False, None)], {"bags": ["a"]})
    assert set(gate_verdicts(checkpoint)) == {("openvino", "bf16"), ("openvino", "int8")}
    assert gate_record(checkpoint)["command"] == "gate a"
    record_gate_results(checkpoint, [_int8(False, None)], {"bags": ["b"]}, command="gate b")
    assert set(gate_verdicts(checkpoint)) == {("openvino", "int8")}
    assert gate_record(checkpoint)["held_out"] == {"bags": ["b"]}


def test_changes_are_reported_absolute_and_relative():
    gate = result(HeldOutScores(0.040, 0.60), HeldOutScores(0.041, 0.595))
    assert gate.steer_mae_change == pytest.approx(0.001) and gate.steer_mae_rise == pytest.approx(0.025)
    assert gate.miou_drop_points == pytest.approx(0.5)
