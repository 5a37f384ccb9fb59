"""report.json (every number, NaN as null), report.md (tables + figures) and the terminal summary."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_common import topics
from msfsu_evaluation.evaluation import Evaluation, FrameSeries


def _json_safe(value: Any) -> Any:
    if isinstance(value, dict):
        return {key: _json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def report_dict(evaluation: Evaluation, run: dict[str, Any], class_names: tuple[str, ...]) -> dict[str, Any]:
    """All numbers of the evaluation; `run` describes what was evaluated (bag, checkpoint, rate, topics)."""
    segmentation = None
    if evaluation.segmentation is not None:
        scores = evaluation.segmentation
        segmentation = {
            "class_names": list(class_names),
            "per_class_iou": dict(zip(class_names, scores.per_class_iou)),
            "truth_pixels": dict(zip(class_names, scores.truth_pixels)),
            "mean_iou": scores.mean_iou,
            "mean_iou_classes": [class_names[index] for index in scores.classes_in_truth],
            "pixel_accuracy": scores.pixel_accuracy,
            "labelled_pixels": scores.labelled_pixels,
            "confusion_matrix": evaluation.confusion.tolist(),  # rows = truth, columns = prediction
        }
    return _json_safe({
        "run": run,
        "frames": asdict(evaluation.frames),
        "actions": {name: asdict(errors) for name, errors in evaluation.actions.items()},
        "segmentation": segmentation,
        "latency_ms": None if evaluation.latency is None else asdict(evaluation.latency),
        "perception_diagnostics": evaluation.perception_diagnostics,
        "emergency_brake": None if evaluation.brake is None else asdict(evaluation.brake),
    })


def format_number(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def markdown_table(header: list[str], rows: list[list[Any]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    return lines + ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows] + [""]


def miou_sentence(segmentation: dict[str, Any]) -> str:
    """The mIoU and the classes it averages: those with a ground-truth pixel (metrics.segmentation_scores)."""
    averaged = segmentation["mean_iou_classes"]
    absent = [name for name in segmentation["per_class_iou"] if name not in averaged]
    sentence = (f"mIoU {format_number(segmentation['mean_iou'])} over the {len(averaged)} classes in the ground truth "
                f"({', '.join(averaged)})")
    if absent:
        sentence += f"; {', '.join(absent)} {'has' if len(absent) == 1 else 'have'} no ground-truth pixel, left out"
    return sentence + "."


def camera_sentence(camera: dict[str, Any] | str) -> str:
    """Which camera the emergency brake placed pixels with: the run's `aeb_camera` (FrontCamera's fields, or
    "simulator" where the bag named none)."""
    if camera == "simulator":
        return "the bag names no camera: the emergency brake assumes the simulator's front camera"
    return (f"the emergency brake sees with the bag's camera: {camera['width']}x{camera['height']}, field of view "
            f"{camera['fov_deg']:g} deg, {camera['forward_m']:g} m ahead of the vehicle's centre and "
            f"{camera['up_m']:g} m above the road, pitch {camera['pitch_deg']:g} deg")


def latency_sentence(brake: bool) -> str:
    """What the latency below spans: the recorder's receipts of a frame's RGB image and of the action the control
    takes, which with the emergency brake is the aeb node's, one hop after perception's."""
    if brake:
        return (f"From the recorder's receipt of a frame's RGB image to its receipt of the frame's action on "
                f"{topics.DRIVING_ACTION}, which the control takes: with the emergency brake in the graph that is the "
                "aeb node's, so this includes the brake's hop after perception (msfsu-eval-bag --no-aeb, make demo "
                "AEB=0: perception's own action).")
    return (f"From the recorder's receipt of a frame's RGB image to its receipt of the frame's action on "
            f"{topics.DRIVING_ACTION}, which the control takes: without the emergency brake, perception's own.")


def summary_markdown(report: dict[str, Any]) -> list[str]:
    """The tables of the report (also printed to the terminal)."""
    frames = report["frames"]
    lines = ["## Frames", ""]
    lines += markdown_table(["camera frames", "processed", "skipped", "with ground truth", "evaluated",
                             "answered by control"],
                            [[frames["camera_frames"], frames["processed"], frames["skipped"],
                              frames["with_ground_truth"], frames["evaluated"], frames["controlled"]]])
    left_out = ", ".join(f"{reason} {count}" for reason, count in frames["left_out"].items() if count) or "none"
    lines += [f"Frames without usable ground truth: {left_out}. Evaluated frames where the network used another "
              f"command than the expert's: {frames['command_mismatches']}.", ""]
    lines += ["## Driving actions (expert command)", ""]
    lines += markdown_table(["command", "frames", "steer MAE", "steer RMSE", "target speed MAE (m/s)"],
                            [[name, errors["frames"], format_number(errors["steer_mae"]),
                              format_number(errors["steer_rmse"]), format_number(errors["target_speed_mae"])]
                             for name, errors in report["actions"].items()])
    segmentation = report["segmentation"]
    lines += ["## Segmentation", ""]
    if segmentation is None:
        lines += ["No segmentation ground truth in the bag, or the network has no decoder.", ""]
    else:
        lines += markdown_table(["class", "IoU", "ground-truth pixels"],
                                [[name, format_number(iou), segmentation["truth_pixels"][name]]
                                 for name, iou in segmentation["per_class_iou"].items()])
        lines += [miou_sentence(segmentation) + f" Pixel accuracy {format_number(segmentation['pixel_accuracy'])} "
                  f"over {segmentation['labelled_pixels']} labelled pixels.", ""]
    brake = report.get("emergency_brake")
    lines += ["## Emergency brake", ""]
    if brake is None:
        lines += ["No emergency brake in the graph (msfsu-eval-bag --no-aeb): the network's action went to the "
                  "control unchanged.", ""]
    else:
        lines += [f"The aeb node sent on {brake['frames']} actions: it capped the target speed on {brake['capped']} "
                  f"frames and braked on {brake['braked']}, in {brake['interventions']} interventions. The action "
                  "errors above score the network's own action, before the brake."
                  + (f" In this run {camera_sentence(camera)}." if (camera := report["run"].get("aeb_camera")) else ""),
                  ""]
    latency = report["latency_ms"]
    lines += ["## Latency: camera frame in -> DrivingAction out (wall clock, ms)", "",
              latency_sentence(brake is not None), ""]
    if latency is None:
        lines += ["Not measured: no frame had both receipts recorded.", ""]
    else:
        statistics = [format_number(latency[key], 1) for key in ("p50_ms", "p95_ms", "max_ms", "mean_ms")]
        lines += markdown_table(["frames", "p50", "p95", "max", "mean"], [[latency["frames"], *statistics]])
    return lines


def markdown_report(report: dict[str, Any], figures: list[Path]) -> str:
    run = report["run"]
    lines = ["# Open-loop bag evaluation", ""]
    lines += [f"- {key}: `{value}`" for key, value in run.items()] + [""]
    lines += summary_markdown(report)
    diagnostics = report["perception_diagnostics"]
    if diagnostics:
        lines += ["## Perception node, last diagnostics", ""]
        lines += markdown_table(["key", "value"], [[key, value] for key, value in diagnostics.items()])
    lines += ["## Figures", ""] + [f"![{figure.stem}]({figure.name})" for figure in figures] + [""]
    return "\n".join(lines)


def write_frames_csv(series: FrameSeries, path: Path) -> None:
    columns = {
        "stamp_ns": series.stamps_ns, "time_s": np.round(series.time_s, 6), "command": series.command,
        "expert_steer": series.expert_steer, "predicted_steer": series.predicted_steer,
        "expert_target_speed": series.expert_speed, "predicted_target_speed": series.predicted_speed,
        "latency_ms": np.round(series.latency_ms, 3),
    }
    with path.open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(columns)
        writer.writerows(zip(*(values.tolist() for values in columns.values())))


def write_report(report: dict[str, Any], figures: list[Path], out: Path) -> None:
    (out / "report.json").write_text(json.dumps(report, indent=2))
    (out / "report.md").write_text(markdown_report(report, figures))
