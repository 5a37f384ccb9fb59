"""Scoring for the accuracy gate (step 3 of msfsu-gate, deploy.gate): the fast inference paths scored on held-out
bags against torch fp32 (thresholds, verdict and its record per checkpoint: msfsu_perception.gate_verdicts).

Every path sees the same frames (each bag's ground-truth cache, as training decodes it) and is scored
against the expert steer and the true class ids with the open-loop metrics; each fast path is also
compared with torch fp32 directly (steer difference, pixel agreement of the class ids). The frames of
several bags are pooled: steer MAE over all of them, mIoU from the summed confusion matrix. That pooled
score decides; each bag's own score is reported beside it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_evaluation.ground_truth import GroundTruth, load_ground_truth
from msfsu_evaluation.metrics import confusion_matrix, segmentation_scores
from msfsu_perception.backends import int8_build
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.deploy_files import cached_inputs
from msfsu_perception.gate_verdicts import BagComparison, GateResult, HeldOutScores
from msfsu_perception.inference import DrivingModel


@dataclass(frozen=True)
class HeldOutBag:
    """The frames of one held-out bag that the gate scores."""

    path: Path
    truth: GroundTruth
    indices: np.ndarray  # (N,) indices into truth: all frames, or evenly spaced ones

    def __len__(self) -> int:
        return len(self.indices)

    @property
    def steer(self) -> np.ndarray:
        return self.truth.steer[self.indices].astype(np.float64)

    def labels(self) -> np.ndarray:
        """(N, h, w) uint8 true class ids."""
        return np.asarray(self.truth.cache.class_ids[self.truth.rows[self.indices]])

    def describe(self) -> dict[str, Any]:
        """What the bag contributes: frames per command, turn frames, how much the expert steers."""
        commands = self.truth.command[self.indices]
        counts = {option.name: int(np.sum(commands == option.value)) for option in RoadOption}
        return {"bag": self.path.name, "frames": len(self), "commands": counts,
                "turn_frames": counts["LEFT"] + counts["RIGHT"],
                "mean_abs_steer": round(float(np.mean(np.abs(self.steer))), 5)}


def evenly_spaced(count: int, at_most: int | None) -> np.ndarray:
    """Indices 0..count-1, or `at_most` of them spread over the whole range (first and last included)."""
    if at_most is None or at_most >= count:
        return np.arange(count)
    if at_most <= 0:
        raise ValueError(f"frames per bag must be positive, got {at_most}")
    return np.unique(np.linspace(0, count - 1, at_most).round().astype(np.int64))


def load_held_out(bags: Sequence[Path], topics: BagTopics, preprocess, cache_dir: Path,
                  frames_per_bag: int | None = None) -> list[HeldOutBag]:
    """Ground truth of each bag (ValueError names a bag that has none), frames per bag capped evenly."""
    if not bags:
        raise ValueError("no held-out bag given")
    held_out = []
    for bag in bags:
        truth = load_ground_truth(bag, topics, preprocess, cache_dir)
        held_out.append(HeldOutBag(bag, truth, evenly_spaced(len(truth), frames_per_bag)))
    return held_out


def describe_held_out(held_out: Sequence[HeldOutBag]) -> dict[str, Any]:
    """The record of which bags and frames were pooled (stored with the verdicts)."""
    bags = [bag.describe() for bag in held_out]
    commands = {option.name: sum(bag["commands"][option.name] for bag in bags) for option in RoadOption}
    return {"bags": bags, "frames": sum(bag["frames"] for bag in bags), "commands": commands,
            "turn_frames": commands["LEFT"] + commands["RIGHT"]}


@dataclass(frozen=True)
class HeldOutPredictions:
    steer: np.ndarray  # (N,) float64
    class_ids: np.ndarray | None  # (N, h, w) uint8


def predict_held_out(model: DrivingModel, bag: HeldOutBag) -> HeldOutPredictions:
    """Run `model` on the bag's gate frames."""
    truth, preprocess = bag.truth, model.preprocess
    inputs = np.empty((preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32)
    steer = np.empty(len(bag))
    class_ids = np.empty((len(bag), preprocess.input_height, preprocess.input_width), np.uint8)
    for position, index in enumerate(bag.indices):
        row = truth.rows[index]
        depth = None if truth.cache.depth is None else truth.cache.depth[row]
        cached_inputs(truth.cache.rgb[row], depth, inputs)
        prediction = model.predict(inputs, RoadOption(int(truth.command[index])))
        steer[position] = prediction.steer
        if prediction.class_ids is not None:
            class_ids[position] = prediction.class_ids
    return HeldOutPredictions(steer, class_ids if model.has_segmentation else None)


def held_out_scores(predictions: Sequence[HeldOutPredictions], bags: Sequence[HeldOutBag],
                    num_classes: int) -> HeldOutScores:
    """Scores of the pooled frames of `bags`: steer MAE over all frames, mIoU of the summed confusion matrix."""
    errors = np.concatenate([np.abs(p.steer - bag.steer) for p, bag in zip(predictions, bags)])
    if any(p.class_ids is None for p in predictions):
        return HeldOutScores(float(errors.mean()), None)
    confusion = sum(confusion_matrix(bag.labels(), p.class_ids, num_classes) for p, bag in zip(predictions, bags))
    return HeldOutScores(float(errors.mean()), segmentation_scores(confusion).mean_iou)


def _agreement(reference: Sequence[HeldOutPredictions], candidate: Sequence[HeldOutPredictions]
               ) -> tuple[float, float | None]:
    """(mean |candidate - reference| steer, share of pixels with the same class) over all frames."""
    steer = float(np.abs(np.concatenate([c.steer - r.steer for r, c in zip(reference, candidate)])).mean())
    if any(p.class_ids is None for p in (*reference, *candidate)):
        return steer, None
    same = sum(int(np.count_nonzero(r.class_ids == c.class_ids)) for r, c in zip(reference, candidate))
    return steer, same / sum(r.class_ids.size for r in reference)


def compare(backend: str, precision: str, reference: Sequence[HeldOutPredictions],
            candidate: Sequence[HeldOutPredictions], bags: Sequence[HeldOutBag], num_classes: int,
            build: dict[str, Any] | None = None) -> GateResult:
    """The pooled verdict of one path, with each bag's own comparison."""
    per_bag = []
    for ref, cand, bag in zip(reference, candidate, bags):
        steer_agreement, class_agreement = _agreement([ref], [cand])
        per_bag.append(BagComparison(bag.path.name, len(bag), held_out_scores([ref], [bag], num_classes),
                                     held_out_scores([cand], [bag], num_classes), steer_agreement, class_agreement))
    steer_agreement, class_agreement = _agreement(reference, candidate)
    return GateResult(
        backend=backend,
        precision=precision,
        frames=sum(len(bag) for bag in bags),
        reference=held_out_scores(reference, bags, num_classes),
        candidate=held_out_scores(candidate, bags, num_classes),
        steer_agreement_mae=steer_agreement,
        class_agreement=class_agreement,
        build=build,
        per_bag=tuple(per_bag),
    )


def run_gate(
    checkpoint: Path,
    held_out_bags: Path | Sequence[Path],
    candidates: Sequence[tuple[str, str]],
    cache_dir: Path,
    frames_per_bag: int | None = None,
    num_threads: int | None = None,
    topics: BagTopics = BagTopics(),
    device: str = "cpu",
) -> tuple[list[GateResult], dict[str, Any]]:
    """Gate each (backend, precision) in `candidates`, run on `device`, against torch fp32 on the CPU (the reference)
    on the pooled frames of the bags.

    Returns the verdicts and the description of the frames (describe_held_out). The bags need semantic
    class ids when the network segments (ValueError otherwise).
    """
    bags = [held_out_bags] if isinstance(held_out_bags, Path) else list(held_out_bags)
    reference_model = DrivingModel.from_checkpoint(checkpoint, num_threads, "torch", "fp32")
    held_out = load_held_out(bags, topics, reference_model.preprocess, cache_dir, frames_per_bag)
    unlabelled = [bag.path.name for bag in held_out if not bag.truth.has_labels]
    if reference_model.has_segmentation and unlabelled:
        raise ValueError(f"held-out bag(s) {', '.join(unlabelled)} have no semantic class ids: mIoU cannot be gated")
    reference = [predict_held_out(reference_model, bag) for bag in held_out]
    results = []
    for backend, precision in candidates:
        model = DrivingModel.from_checkpoint(checkpoint, num_threads, backend, precision, device=device)
        candidate = [predict_held_out(model, bag) for bag in held_out]
        build = int8_build(checkpoint) if precision == "int8" else None
        results.append(compare(backend, precision, reference, candidate, held_out, len(model.class_names),
                               None if build is None else build.to_dict()))
    return results, describe_held_out(held_out)
