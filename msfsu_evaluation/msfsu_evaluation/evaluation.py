"""Compares what the graph published with the bag's ground truth, frame by frame (matched by header stamp).

A camera frame counts as processed when a DrivingAction carries its stamp; the rest were skipped
(perception busy with an earlier frame, or input it rejected: see its diagnostics counters).
Metrics use the frames that have both ground truth and an action; per-command errors group frames
by the expert's navigation command.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_evaluation.ground_truth import GroundTruth
from msfsu_evaluation.metrics import (
    ActionErrors,
    LatencySummary,
    SegmentationScores,
    action_errors_by_command,
    confusion_matrix,
    latency_summary,
    segmentation_scores,
)
from msfsu_evaluation.recording import RecordedOutputs, iter_segmentation


@dataclass(frozen=True)
class FrameCounts:
    camera_frames: int  # RGB messages in the bag
    processed: int  # camera frames answered by a DrivingAction
    skipped: int  # camera frames without one
    with_ground_truth: int  # frames with usable ground truth
    evaluated: int  # frames with ground truth and an action: the metrics' sample
    left_out: dict[str, int]  # frames without usable ground truth, by reason
    controlled: int  # processed frames the control node answered (a VehicleControl with the frame's stamp)
    command_mismatches: int  # evaluated frames the network answered with another branch than the expert's command


@dataclass(frozen=True)
class FrameSeries:
    """Per evaluated frame, in stamp order (plots, frames.csv)."""

    time_s: np.ndarray  # since the first frame with ground truth
    stamps_ns: np.ndarray
    command: np.ndarray
    expert_steer: np.ndarray
    predicted_steer: np.ndarray
    expert_speed: np.ndarray
    predicted_speed: np.ndarray
    latency_ms: np.ndarray  # NaN where the recorder missed the frame's RGB


@dataclass(frozen=True)
class OverlayFrame:
    stamp_ns: int
    model_rgb: np.ndarray  # (h, w, 3) uint8
    truth: np.ndarray  # (h, w) class ids
    prediction: np.ndarray  # (h, w) class ids


@dataclass(frozen=True)
class BrakeInterventions:
    """What the emergency brake did during the replay (its decisions, by frame)."""

    frames: int  # actions the brake sent on to the control
    capped: int  # frames whose target speed it capped
    braked: int  # frames it braked (target speed 0)
    interventions: int  # times it started capping or braking


def brake_interventions(outputs: RecordedOutputs) -> BrakeInterventions | None:
    """None when the graph had no emergency brake."""
    if outputs.interventions is None:
        return None
    decisions = [outputs.interventions.get(int(stamp), "none") for stamp in sorted(outputs.action_stamps_ns)]
    starts = sum(1 for before, now in zip(["none", *decisions], decisions) if now != "none" and before == "none")
    return BrakeInterventions(len(decisions), decisions.count("cap"), decisions.count("brake"), starts)


@dataclass(frozen=True)
class Evaluation:
    frames: FrameCounts
    actions: dict[str, ActionErrors]  # "overall" and per RoadOption name
    latency: LatencySummary | None  # over every processed frame; None when no frame has both receipts
    segmentation: SegmentationScores | None  # None: the bag has no labels or the network no decoder
    confusion: np.ndarray | None  # (K, K) rows = truth
    perception_diagnostics: dict[str, str]
    series: FrameSeries
    overlays: list[OverlayFrame]
    brake: BrakeInterventions | None = None  # None: no emergency brake in the graph


def _latencies_ms(outputs: RecordedOutputs) -> np.ndarray:
    """(M,) wall-clock RGB receipt -> DrivingAction receipt per action; NaN where the RGB was not recorded."""
    frame_received = np.array([outputs.frame_received_ns.get(int(stamp), -1) for stamp in outputs.action_stamps_ns],
                              np.int64)
    return np.where(frame_received >= 0, (outputs.action_received_ns - frame_received) * 1e-6, np.nan)


def _series(truth: GroundTruth, outputs: RecordedOutputs, truth_rows: np.ndarray, action_rows: np.ndarray,
            latency_ms: np.ndarray) -> FrameSeries:
    stamps = truth.stamps_ns[truth_rows]
    return FrameSeries(
        time_s=(stamps - truth.stamps_ns[0]) * 1e-9,
        stamps_ns=stamps,
        command=truth.command[truth_rows],
        expert_steer=truth.steer[truth_rows],
        predicted_steer=outputs.steer[action_rows],
        expert_speed=truth.target_speed[truth_rows],
        predicted_speed=outputs.target_speed[action_rows],
        latency_ms=latency_ms[action_rows],
    )


def _segmentation(
    truth: GroundTruth, recording: Path, num_classes: int, evaluated_rows: np.ndarray, overlay_stamps: set[int]
) -> tuple[np.ndarray | None, list[OverlayFrame]]:
    """Accumulate the confusion matrix over recorded segmentations one frame at a time (bags can be long).

    Only the evaluated frames count (those whose DrivingAction was recorded too), so every metric of the report has
    one sample: a segmentation whose action the recorder missed (the replay's last frame, a starved recorder) is left out.
    """
    truth_row = {int(truth.stamps_ns[row]): int(row) for row in evaluated_rows}
    confusion = np.zeros((num_classes, num_classes), np.int64)
    overlays: list[OverlayFrame] = []
    seen: set[int] = set()
    for stamp, prediction in iter_segmentation(recording):
        row = truth_row.get(stamp)
        if row is None or stamp in seen:
            continue
        seen.add(stamp)
        labels = truth.class_ids(row)
        if labels.shape != prediction.shape:
            raise ValueError(f"segmentation is {prediction.shape[1]}x{prediction.shape[0]} but the ground truth "
                             f"at the network input size is {labels.shape[1]}x{labels.shape[0]}: "
                             "wrong checkpoint for this run?")
        confusion += confusion_matrix(labels, prediction, num_classes)
        if stamp in overlay_stamps:
            overlays.append(OverlayFrame(stamp, truth.model_rgb(row), labels, prediction))
    return (confusion if seen else None), overlays


def evaluate(
    truth: GroundTruth, outputs: RecordedOutputs, recording: Path, num_classes: int, overlay_count: int = 4
) -> Evaluation:
    """Match actions and segmentations to ground-truth frames and score them; ValueError if nothing matches."""
    action_index = {int(stamp): index for index, stamp in enumerate(outputs.action_stamps_ns)}
    truth_rows = np.array([row for row, stamp in enumerate(truth.stamps_ns) if int(stamp) in action_index], np.int64)
    if truth_rows.size == 0:
        raise ValueError(f"none of the {len(truth)} frames with ground truth got a DrivingAction "
                         f"({outputs.action_stamps_ns.size} actions recorded): did perception run? see replay.log")
    action_rows = np.array([action_index[int(truth.stamps_ns[row])] for row in truth_rows], np.int64)
    latency_ms = _latencies_ms(outputs)
    series = _series(truth, outputs, truth_rows, action_rows, latency_ms)
    processed = len(action_index)
    frames = FrameCounts(
        camera_frames=truth.camera_frames,
        processed=processed,
        skipped=truth.camera_frames - processed,
        with_ground_truth=len(truth),
        evaluated=int(truth_rows.size),
        left_out=truth.left_out,
        controlled=len(action_index.keys() & outputs.control_stamps_ns),
        command_mismatches=int(np.count_nonzero(outputs.command[action_rows] != series.command)),
    )
    measured = latency_ms[np.isfinite(latency_ms)]
    confusion, overlays = None, []
    if truth.has_labels:
        spread = np.linspace(0, truth_rows.size - 1, min(overlay_count, truth_rows.size)).round().astype(int)
        confusion, overlays = _segmentation(truth, recording, num_classes, truth_rows,
                                            {int(series.stamps_ns[i]) for i in spread})
    return Evaluation(
        frames=frames,
        actions=action_errors_by_command(series.predicted_steer, series.expert_steer, series.predicted_speed,
                                         series.expert_speed, series.command),
        latency=latency_summary(measured) if measured.size else None,
        segmentation=segmentation_scores(confusion) if confusion is not None else None,
        confusion=confusion,
        perception_diagnostics=outputs.perception_diagnostics,
        series=series,
        overlays=overlays,
        brake=brake_interventions(outputs),
    )
