"""The side-by-side open-loop table pools bags by frames, not by averaging averages."""

import json
import math

import pytest

from msfsu_evaluation.open_loop_table import main, open_loop_table


def write_report(path, frames, steer_mae, steer_rmse, confusion):
    path.mkdir(parents=True)
    report = {
        "actions": {"overall": {"frames": frames, "steer_mae": steer_mae, "steer_rmse": steer_rmse,
                                "target_speed_mae": 1.0}},
        "segmentation": None if confusion is None else {"mean_iou": 0.0, "pixel_accuracy": 0.0,
                                                        "confusion_matrix": confusion},
        "latency_ms": {"p50_ms": 5.0, "p95_ms": 7.5},
    }
    (path / "report.json").write_text(json.dumps(report))


def test_pooled_row_weights_bags_by_frames_and_sums_confusion_matrices(tmp_path):
    write_report(tmp_path / "msfsu" / "bag_a", 30, 0.1, 0.2, [[10, 0], [0, 0]])  # class 0 perfect
    write_report(tmp_path / "msfsu" / "bag_b", 10, 0.5, 0.6, [[0, 10], [0, 10]])  # half of class 0 wrong
    write_report(tmp_path / "msf" / "bag_a", 30, 0.3, 0.3, None)
    lines = open_loop_table(tmp_path)
    pooled = next(line for line in lines if line.startswith("| msfsu | **all bags**"))
    cells = [cell.strip() for cell in pooled.strip("|").split("|")]
    assert cells[2] == "40"
    assert float(cells[3]) == pytest.approx(0.75 * 0.1 + 0.25 * 0.5, abs=1e-3)
    assert float(cells[4]) == pytest.approx(math.sqrt(0.75 * 0.04 + 0.25 * 0.36), abs=1e-3)
    # summed confusion [[10, 10], [0, 10]]: IoU 10/20 for both classes
    assert float(cells[6]) == pytest.approx(0.5, abs=1e-3) and float(cells[7]) == pytest.approx(20 / 30, abs=1e-3)
    msf_pooled = next(line for line in lines if line.startswith("| msf | **all bags**"))
    assert "n/a" in msf_pooled  # no decoder: no mIoU
    assert sum(line.startswith("| msfsu | bag_") for line in lines) == 2


def test_an_empty_directory_is_a_clear_error(tmp_path, capsys):
    assert main([str(tmp_path)]) == 1
    assert "no <network>/<bag>/report.json" in capsys.readouterr().err
