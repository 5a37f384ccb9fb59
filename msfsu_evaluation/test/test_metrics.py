"""Metrics on hand-made predictions whose answers are worked out by hand in the comments."""

import math

import numpy as np
import pytest

from msfsu_common.road_option import RoadOption
from msfsu_evaluation.metrics import (
    action_errors,
    action_errors_by_command,
    confusion_matrix,
    latency_summary,
    segmentation_scores,
)

# 2x4 image, 3 classes; truth id 255 is unlabelled.
TRUTH = np.array([[0, 0, 1, 1],
                  [2, 2, 255, 0]], np.uint8)
PREDICTION = np.array([[0, 1, 1, 1],
                       [2, 0, 2, 0]], np.uint8)


def test_confusion_matrix_counts_true_rows_against_predicted_columns_and_ignores_unlabelled():
    expected = np.array([[2, 1, 0],   # true 0: (0,0) (0,1)->1 (1,3)
                         [0, 2, 0],   # true 1: both right
                         [1, 0, 1]])  # true 2: (1,0) right, (1,1)->0
    np.testing.assert_array_equal(confusion_matrix(TRUTH, PREDICTION, 3), expected)


def test_iou_is_true_positives_over_union_and_accuracy_over_labelled_pixels():
    scores = segmentation_scores(confusion_matrix(TRUTH, PREDICTION, 3))
    # class 0: TP 2, FP 1 (a true 2), FN 1 -> 2/4; class 1: TP 2, FP 1 -> 2/3; class 2: TP 1, FN 1 -> 1/2
    assert scores.per_class_iou == pytest.approx((0.5, 2 / 3, 0.5))
    assert scores.mean_iou == pytest.approx((0.5 + 2 / 3 + 0.5) / 3)
    assert scores.pixel_accuracy == pytest.approx(5 / 7)
    assert scores.labelled_pixels == 7


def test_a_class_absent_from_truth_and_prediction_has_no_iou_and_does_not_lower_the_mean():
    truth = np.array([0, 0, 1, 1])
    scores = segmentation_scores(confusion_matrix(truth, truth, 4))
    assert scores.per_class_iou[:2] == (1.0, 1.0)
    assert all(math.isnan(value) for value in scores.per_class_iou[2:])
    assert scores.mean_iou == 1.0
    assert scores.pixel_accuracy == 1.0


def test_predicted_class_never_in_truth_scores_zero_iou_and_stays_out_of_the_mean():
    scores = segmentation_scores(confusion_matrix(np.array([0, 0]), np.array([0, 1]), 2))
    assert scores.per_class_iou == (0.5, 0.0)
    assert scores.classes_in_truth == (0,) and scores.truth_pixels == (2, 0)
    assert scores.mean_iou == 0.5  # over the classes in the ground truth, not (0.5 + 0.0) / 2


def test_miou_averages_the_classes_present_in_the_ground_truth():
    # A CARLA frame after the top crop: no "other" (class 4) pixel is left in the truth, but the network paints a
    # few pixels as other. Classes 0-3: IoU 1, 1, 1, 3/4 (class 3: 3 right, 1 predicted as 4); class 4: 0/1.
    truth = np.array([0, 0, 1, 1, 2, 2, 3, 3, 3, 3])
    prediction = np.array([0, 0, 1, 1, 2, 2, 3, 3, 3, 4])
    scores = segmentation_scores(confusion_matrix(truth, prediction, 5))
    assert scores.per_class_iou == pytest.approx((1.0, 1.0, 1.0, 0.75, 0.0))
    assert scores.classes_in_truth == (0, 1, 2, 3)
    assert scores.mean_iou == pytest.approx(3.75 / 4)  # averaged in, class 4 would give 3.75 / 5


def test_segmentation_rejects_bad_input():
    with pytest.raises(ValueError, match="same shape"):
        confusion_matrix(np.zeros((2, 2)), np.zeros((2, 3)), 3)
    with pytest.raises(ValueError, match=r"in \[0, 3\)"):
        confusion_matrix(np.zeros(2, np.uint8), np.array([0, 3], np.uint8), 3)
    with pytest.raises(ValueError, match="no labelled pixel"):
        segmentation_scores(confusion_matrix(np.array([9, 9]), np.array([0, 1]), 3))


def test_steer_mae_rmse_and_speed_mae_follow_their_formulas():
    errors = action_errors(
        predicted_steer=np.array([0.0, 0.5, -0.5, 0.2]),
        expert_steer=np.array([0.0, 0.0, 0.5, 0.2]),  # errors 0, 0.5, -1, 0
        predicted_speed=np.array([8.0, 6.0, 0.0, 5.0]),
        expert_speed=np.array([8.0, 8.0, 1.0, 5.0]),  # errors 0, -2, -1, 0
    )
    assert errors.frames == 4
    assert errors.steer_mae == pytest.approx(1.5 / 4)
    assert errors.steer_rmse == pytest.approx(math.sqrt((0.25 + 1.0) / 4))
    assert errors.target_speed_mae == pytest.approx(3.0 / 4)


def test_errors_are_split_by_navigation_command_and_only_for_commands_present():
    command = np.array([RoadOption.LANE_FOLLOW, RoadOption.LEFT, RoadOption.LANE_FOLLOW])
    errors = action_errors_by_command(
        predicted_steer=np.array([0.1, -0.4, 0.3]), expert_steer=np.array([0.0, -0.8, 0.0]),
        predicted_speed=np.array([5.0, 3.0, 7.0]), expert_speed=np.array([6.0, 3.0, 6.0]),
        command=command,
    )
    assert list(errors) == ["overall", "LEFT", "LANE_FOLLOW"]
    assert errors["LEFT"].frames == 1 and errors["LEFT"].steer_mae == pytest.approx(0.4)
    assert errors["LANE_FOLLOW"].steer_rmse == pytest.approx(math.sqrt((0.01 + 0.09) / 2))
    assert errors["LANE_FOLLOW"].target_speed_mae == pytest.approx(1.0)
    assert errors["overall"].steer_mae == pytest.approx(0.8 / 3)


def test_action_errors_reject_empty_mismatched_and_unknown_commands():
    with pytest.raises(ValueError, match="no samples"):
        action_errors(np.array([]), np.array([]), np.array([]), np.array([]))
    with pytest.raises(ValueError, match="same shape"):
        action_errors(np.zeros(2), np.zeros(3), np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match=r"unknown navigation command values \[7\]"):
        action_errors_by_command(np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), np.array([7]))


def test_latency_percentiles_interpolate_between_samples():
    summary = latency_summary([10.0, 20.0, 30.0, 40.0, 100.0])
    assert summary.frames == 5
    assert summary.p50_ms == 30.0
    assert summary.p95_ms == pytest.approx(40.0 + 0.8 * 60.0)  # rank 0.95 * 4 = 3.8
    assert summary.max_ms == 100.0
    assert summary.mean_ms == 40.0
    with pytest.raises(ValueError, match="no samples"):
        latency_summary([])
    with pytest.raises(ValueError, match="finite"):
        latency_summary([1.0, float("nan")])
