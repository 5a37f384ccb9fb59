"""Evaluating the accuracy gate: the fast inference paths scored on a held-out bag against torch fp32
(thresholds, verdict and its record per checkpoint: msfsu_perception.gate_verdicts).

Every path sees the same frames (the bag's ground-truth cache, as training decodes it) and is scored
against the expert steer and the true class ids with the open-loop metrics; each fast path is also
compared with torch fp32 directly (steer difference, pixel agreement of the class ids).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_evaluation.ground_truth import GroundTruth, load_ground_truth
from msfsu_evaluation.metrics import confusion_matrix, segmentation_scores
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.deploy_files import cached_inputs
from msfsu_perception.gate_verdicts import GateResult, HeldOutScores
from msfsu_perception.inference import DrivingModel


@dataclass(frozen=True)
class HeldOutPredictions:
    steer: np.ndarray  # (N,) float64
    class_ids: np.ndarray | None  # (N, h, w) uint8


def predict_held_out(model: DrivingModel, truth: GroundTruth, frames: int | None = None) -> HeldOutPredictions:
    """Run `model` on the first `frames` ground-truth frames (all when None)."""
    count = len(truth) if frames is None else min(frames, len(truth))
    preprocess = model.preprocess
    inputs = np.empty((preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32)
    steer = np.empty(count)
    class_ids = np.empty((count, preprocess.input_height, preprocess.input_width), np.uint8)
    for index in range(count):
        row = truth.rows[index]
        depth = None if truth.cache.depth is None else truth.cache.depth[row]
        cached_inputs(truth.cache.rgb[row], depth, inputs)
        prediction = model.predict(inputs, RoadOption(int(truth.command[index])))
        steer[index] = prediction.steer
        if prediction.class_ids is not None:
            class_ids[index] = prediction.class_ids
    return HeldOutPredictions(steer, class_ids if model.has_segmentation else None)


def held_out_scores(predictions: HeldOutPredictions, truth: GroundTruth, num_classes: int) -> HeldOutScores:
    count = len(predictions.steer)
    steer_mae = float(np.abs(predictions.steer - truth.steer[:count]).mean())
    if predictions.class_ids is None:
        return HeldOutScores(steer_mae, None)
    labels = np.asarray(truth.cache.class_ids[truth.rows[:count]])
    scores = segmentation_scores(confusion_matrix(labels, predictions.class_ids, num_classes))
    return HeldOutScores(steer_mae, scores.mean_iou)


def compare(backend: str, precision: str, reference: HeldOutPredictions, candidate: HeldOutPredictions,
            truth: GroundTruth, num_classes: int) -> GateResult:
    class_agreement = None
    if reference.class_ids is not None and candidate.class_ids is not None:
        class_agreement = float(np.mean(reference.class_ids == candidate.class_ids))
    return GateResult(
        backend=backend,
        precision=precision,
        frames=len(reference.steer),
        reference=held_out_scores(reference, truth, num_classes),
        candidate=held_out_scores(candidate, truth, num_classes),
        steer_agreement_mae=float(np.abs(candidate.steer - reference.steer).mean()),
        class_agreement=class_agreement,
    )


def run_gate(
    checkpoint: Path,
    held_out_bag: Path,
    candidates: Sequence[tuple[str, str]],
    cache_dir: Path,
    frames: int | None = None,
    num_threads: int | None = None,
    topics: BagTopics = BagTopics(),
) -> list[GateResult]:
    """Gate each (backend, precision) in `candidates` against torch fp32 on `held_out_bag`.

    The bag needs semantic class ids when the network segments (ValueError otherwise).
    """
    reference_model = DrivingModel.from_checkpoint(checkpoint, num_threads, "torch", "fp32")
    truth = load_ground_truth(held_out_bag, topics, reference_model.preprocess, cache_dir)
    if reference_model.has_segmentation and not truth.has_labels:
        raise ValueError(f"held-out bag {held_out_bag} has no semantic class ids: mIoU cannot be gated")
    reference = predict_held_out(reference_model, truth, frames)
    results = []
    for backend, precision in candidates:
        model = DrivingModel.from_checkpoint(checkpoint, num_threads, backend, precision)
        candidate = predict_held_out(model, truth, frames)
        results.append(compare(backend, precision, reference, candidate, truth, len(model.class_names)))
    return results
