"""The open-loop report says which classes its mIoU averages (those with a ground-truth pixel) and what its latency
spans."""

import numpy as np
import pytest

from msfsu_common.semantic_classes import CLASS_NAMES
from msfsu_evaluation.metrics import confusion_matrix, segmentation_scores
from msfsu_evaluation.open_loop_report import summary_markdown

CLASSES = CLASS_NAMES


def report_with(truth: np.ndarray, prediction: np.ndarray) -> dict:
    """A report.json as report_dict writes it, around the segmentation of `prediction` against `truth`."""
    confusion = confusion_matrix(truth, prediction, len(CLASSES))
    scores = segmentation_scores(confusion)
    segmentation = {
        "class_names": list(CLASSES), "per_class_iou": dict(zip(CLASSES, scores.per_class_iou)),
        "truth_pixels": dict(zip(CLASSES, scores.truth_pixels)), "mean_iou": scores.mean_iou,
        "mean_iou_classes": [CLASSES[index] for index in scores.classes_in_truth],
        "pixel_accuracy": scores.pixel_accuracy, "labelled_pixels": scores.labelled_pixels,
        "confusion_matrix": confusion.tolist()}
    frames = {"camera_frames": 1, "processed": 1, "skipped": 0, "with_ground_truth": 1, "evaluated": 1,
              "controlled": 1, "left_out": {}, "command_mismatches": 0}
    return {"frames": frames, "actions": {}, "segmentation": segmentation, "latency_ms": None}


def test_the_report_names_the_classes_its_miou_averages_and_the_ones_it_leaves_out():
    # no "other" in the truth (a CARLA frame after the top crop), one pixel predicted as other
    truth = np.array([0, 0, 1, 1, 2, 2, 3, 3, 3, 3])
    prediction = np.array([0, 0, 1, 1, 2, 2, 3, 3, 3, 4])
    lines = summary_markdown(report_with(truth, prediction))
    assert ("mIoU 0.938 over the 4 classes in the ground truth (road, road_line, sidewalk, vehicle_or_pedestrian); "
            "other has no ground-truth pixel, left out. Pixel accuracy 0.900 over 10 labelled pixels.") in lines
    assert "| other | 0.000 | 0 |" in lines and "| vehicle_or_pedestrian | 0.750 | 4 |" in lines


def test_with_every_class_in_the_truth_the_report_leaves_none_out():
    truth = prediction = np.arange(5).repeat(2)
    [line] = [line for line in summary_markdown(report_with(truth, prediction)) if line.startswith("mIoU")]
    assert line.startswith("mIoU 1.000 over the 5 classes in the ground truth (road, road_line, sidewalk, "
                           "vehicle_or_pedestrian, other). Pixel")
    assert pytest.approx(1.0) == report_with(truth, prediction)["segmentation"]["mean_iou"]


def test_the_latency_says_whether_the_emergency_brakes_hop_is_in_it():
    truth = prediction = np.arange(5).repeat(2)
    without = report_with(truth, prediction)
    with_brake = {**without, "run": {}, "emergency_brake": {"frames": 1, "capped": 0, "braked": 0, "interventions": 0}}

    def latency_line(report: dict) -> str:
        [line] = [line for line in summary_markdown(report) if line.startswith("From the recorder's receipt")]
        return line

    assert "with the emergency brake in the graph that is the aeb node's, so this includes the brake's hop after " \
           "perception (msfsu-eval-bag --no-aeb, make demo AEB=0: perception's own action)" in latency_line(with_brake)
    assert latency_line(without).endswith("without the emergency brake, perception's own.")
