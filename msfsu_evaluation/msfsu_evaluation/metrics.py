"""Open-loop metrics on numpy arrays (no ROS): segmentation, driving actions, latency.

Every function rejects empty or mismatched input with a ValueError that says what was wrong, so a
report never shows a number computed from nothing.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from msfsu_common.road_option import RoadOption


def _require_same_nonempty_shape(**arrays: np.ndarray) -> None:
    shapes = {name: np.shape(array) for name, array in arrays.items()}
    if len(set(shapes.values())) != 1:
        raise ValueError(f"arrays must have the same shape, got {shapes}")
    if np.size(next(iter(arrays.values()))) == 0:
        raise ValueError(f"no samples to score ({', '.join(shapes)} are empty)")


# --- segmentation ------------------------------------------------------------------------------
def confusion_matrix(truth: np.ndarray, prediction: np.ndarray, num_classes: int) -> np.ndarray:
    """(K, K) int64 pixel counts, rows = true class, columns = predicted class.

    Truth ids >= num_classes are "unlabelled" and ignored (like an ignore index); a predicted id
    outside [0, num_classes) is a bug upstream and raises.
    """
    truth, prediction = np.asarray(truth), np.asarray(prediction)
    _require_same_nonempty_shape(truth=truth, prediction=prediction)
    if prediction.min() < 0 or prediction.max() >= num_classes:
        raise ValueError(f"predicted class ids must be in [0, {num_classes}), "
                         f"got {prediction.min()}..{prediction.max()}")
    labelled = (truth >= 0) & (truth < num_classes)
    pairs = truth[labelled].astype(np.int64) * num_classes + prediction[labelled].astype(np.int64)
    return np.bincount(pairs, minlength=num_classes * num_classes).reshape(num_classes, num_classes)


@dataclass(frozen=True)
class SegmentationScores:
    per_class_iou: tuple[float, ...]  # NaN for a class neither in the truth nor predicted
    mean_iou: float  # mean over the classes in the ground truth (`classes_in_truth`)
    pixel_accuracy: float
    labelled_pixels: int
    truth_pixels: tuple[int, ...]  # ground-truth pixels per class
    classes_in_truth: tuple[int, ...]  # the classes with a ground-truth pixel: those the mIoU averages


def segmentation_scores(confusion: np.ndarray) -> SegmentationScores:
    """IoU_c = TP / (TP + FP + FN); accuracy = trace / total. mIoU averages the classes present in the ground truth:
    a class with no ground-truth pixel (e.g. every "other" pixel of a CARLA frame lies in the top crop) has an IoU
    of 0 as soon as one pixel is predicted as it, which says nothing of the classes that are there, so it stays in
    `per_class_iou` but out of the mean."""
    confusion = np.asarray(confusion, np.int64)
    if confusion.ndim != 2 or confusion.shape[0] != confusion.shape[1]:
        raise ValueError(f"confusion matrix must be square, got shape {confusion.shape}")
    total = int(confusion.sum())
    if total == 0:
        raise ValueError("confusion matrix counts no labelled pixel")
    true_positive = np.diag(confusion).astype(np.float64)
    truth_pixels = confusion.sum(axis=1)
    union = confusion.sum(axis=0) + truth_pixels - true_positive
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(union > 0, true_positive / union, np.nan)
    present = np.flatnonzero(truth_pixels > 0)
    return SegmentationScores(
        per_class_iou=tuple(float(value) for value in iou),
        mean_iou=float(iou[present].mean()),
        pixel_accuracy=float(true_positive.sum() / total),
        labelled_pixels=total,
        truth_pixels=tuple(int(count) for count in truth_pixels),
        classes_in_truth=tuple(int(index) for index in present),
    )


# --- driving actions ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ActionErrors:
    frames: int
    steer_mae: float
    steer_rmse: float  # sqrt(mean((predicted - expert)^2))
    target_speed_mae: float  # m/s


def action_errors(
    predicted_steer: np.ndarray, expert_steer: np.ndarray, predicted_speed: np.ndarray, expert_speed: np.ndarray
) -> ActionErrors:
    _require_same_nonempty_shape(predicted_steer=predicted_steer, expert_steer=expert_steer,
                                 predicted_speed=predicted_speed, expert_speed=expert_speed)
    steer_error = np.asarray(predicted_steer, np.float64) - np.asarray(expert_steer, np.float64)
    speed_error = np.asarray(predicted_speed, np.float64) - np.asarray(expert_speed, np.float64)
    return ActionErrors(
        frames=int(steer_error.size),
        steer_mae=float(np.abs(steer_error).mean()),
        steer_rmse=float(np.sqrt(np.square(steer_error).mean())),
        target_speed_mae=float(np.abs(speed_error).mean()),
    )


def action_errors_by_command(
    predicted_steer: np.ndarray,
    expert_steer: np.ndarray,
    predicted_speed: np.ndarray,
    expert_speed: np.ndarray,
    command: np.ndarray,
) -> dict[str, ActionErrors]:
    """{"overall": ..., "LANE_FOLLOW": ..., ...}: one entry per RoadOption that occurs in `command`."""
    arrays = tuple(np.asarray(array) for array in (predicted_steer, expert_steer, predicted_speed, expert_speed))
    command = np.asarray(command)
    _require_same_nonempty_shape(predicted_steer=arrays[0], command=command)
    unknown = set(np.unique(command).tolist()) - {option.value for option in RoadOption}
    if unknown:
        raise ValueError(f"unknown navigation command values {sorted(unknown)}")
    errors = {"overall": action_errors(*arrays)}
    for option in RoadOption:
        chosen = command == option.value
        if chosen.any():
            errors[option.name] = action_errors(*(array[chosen] for array in arrays))
    return errors


# --- latency -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class LatencySummary:
    frames: int
    p50_ms: float
    p95_ms: float
    max_ms: float
    mean_ms: float


def latency_summary(latencies_ms: Sequence[float] | np.ndarray) -> LatencySummary:
    """Percentiles with linear interpolation between samples (numpy's default)."""
    samples = np.asarray(latencies_ms, np.float64)
    _require_same_nonempty_shape(latencies_ms=samples)
    if not np.isfinite(samples).all():
        raise ValueError("latencies must be finite")
    p50, p95 = np.percentile(samples, [50, 95])
    return LatencySummary(frames=int(samples.size), p50_ms=float(p50), p95_ms=float(p95),
                          max_ms=float(samples.max()), mean_ms=float(samples.mean()))


def time_calls(call: Callable[[], object], iterations: int, warmup: int) -> LatencySummary:
    """Wall time of `call()` over `iterations` calls after `warmup` untimed ones (benchmarks; a call that runs on a
    device must end with its own synchronisation)."""
    for _ in range(warmup):
        call()
    samples = []
    for _ in range(iterations):
        started = time.perf_counter()
        call()
        samples.append((time.perf_counter() - started) * 1e3)
    return latency_summary(samples)
