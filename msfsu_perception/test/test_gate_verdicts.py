"""The accuracy gate's verdict on hand-made scores: mIoU drop <= 1 point and steer MAE rise <= 5 %."""

import math

import pytest

from msfsu_perception.gate_verdicts import GateResult, HeldOutScores


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
