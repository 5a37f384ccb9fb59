"""One markdown table from several `msfsu-eval-bag` reports: networks side by side on the same bags.

    python -m msfsu_evaluation.open_loop_table runs/open_loop > docs/results/open_loop.md

Layout `<root>/<network>/<bag>/report.json`. Each network also gets an "all bags" row pooled over
frames (steer errors weighted by frames, mIoU from the summed confusion matrices), not an average of
per-bag averages.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_evaluation.metrics import segmentation_scores
from msfsu_evaluation.open_loop_report import format_number, markdown_table

HEADER = ["network", "bag", "frames", "steer MAE", "steer RMSE", "speed MAE (m/s)", "mIoU", "pixel acc.",
          "latency p50 / p95 (ms)"]


def _cells(network: str, bag: str, frames: int, steer_mae: float, steer_rmse: float, speed_mae: float,
           mean_iou: float | None, pixel_accuracy: float | None, latency: str) -> list[Any]:
    return [network, bag, frames, format_number(steer_mae), format_number(steer_rmse), format_number(speed_mae, 2),
            format_number(mean_iou), format_number(pixel_accuracy), latency]


def _row(network: str, bag: str, report: dict[str, Any]) -> list[Any]:
    overall, segmentation, latency = report["actions"]["overall"], report["segmentation"], report["latency_ms"]
    mean_iou, pixel_accuracy = (segmentation["mean_iou"], segmentation["pixel_accuracy"]) if segmentation else (None, None)
    return _cells(network, bag, overall["frames"], overall["steer_mae"], overall["steer_rmse"],
                  overall["target_speed_mae"], mean_iou, pixel_accuracy,
                  "n/a" if latency is None else f"{latency['p50_ms']:.1f} / {latency['p95_ms']:.1f}")


def pooled_row(network: str, reports: list[dict[str, Any]]) -> list[Any]:
    """Frame-weighted errors and the mIoU of the summed confusion matrix over every bag of a network."""
    overall = [report["actions"]["overall"] for report in reports]
    frames = np.array([errors["frames"] for errors in overall], np.float64)
    weights = frames / frames.sum()
    steer_mae = float(np.dot(weights, [errors["steer_mae"] for errors in overall]))
    steer_rmse = float(np.sqrt(np.dot(weights, [errors["steer_rmse"] ** 2 for errors in overall])))
    speed_mae = float(np.dot(weights, [errors["target_speed_mae"] for errors in overall]))
    mean_iou = pixel_accuracy = None
    if all(report["segmentation"] for report in reports):
        confusion = sum(np.asarray(report["segmentation"]["confusion_matrix"], np.int64) for report in reports)
        scores = segmentation_scores(confusion)
        mean_iou, pixel_accuracy = scores.mean_iou, scores.pixel_accuracy
    return _cells(network, "**all bags**", int(frames.sum()), steer_mae, steer_rmse, speed_mae, mean_iou,
                  pixel_accuracy, "")


def open_loop_table(root: Path) -> list[str]:
    rows = []
    for network_dir in sorted(path for path in root.iterdir() if path.is_dir()):
        reports = {path.parent.name: json.loads(path.read_text())
                   for path in sorted(network_dir.glob("*/report.json"))}
        if not reports:
            continue
        rows += [_row(network_dir.name, bag, report) for bag, report in reports.items()]
        rows.append(pooled_row(network_dir.name, list(reports.values())))
    if not rows:
        raise FileNotFoundError(f"no <network>/<bag>/report.json under {root}")
    return markdown_table(HEADER, rows)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m msfsu_evaluation.open_loop_table RUNS_DIR", file=sys.stderr)
        return 2
    try:
        print("\n".join(open_loop_table(Path(args[0]))))
    except FileNotFoundError as error:
        print(f"open_loop_table: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
