"""msfsu-dataset-report counts what the bags hold, and its markdown comes from the committed record alone."""

import json

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_evaluation.dataset_report import bag_stats, main
from msfsu_perception.synthetic import write_synthetic_bag


def test_counts_match_the_bag_truth_and_dropped_episodes_count_as_attempts(tmp_path, capsys):
    root = tmp_path / "data"
    truth = write_synthetic_bag(root / "train" / "a_000", 60, seed=1)
    write_synthetic_bag(root / "train" / "b_000", 40, seed=2)
    write_synthetic_bag(root / "train" / ".partial" / "c_000", 10, seed=3)  # unfinished: not in the data set
    episode = {"split": "train", "town": "synthetic", "weather": "0", "traffic": "none", "index": 1, "seed": 9,
               "round": 0}
    (root / "dropped.jsonl").write_text(json.dumps({"episode": episode, "reason": "collision", "steps": 12}) + "\n")

    stats = bag_stats(root / "train" / "a_000")
    assert stats.frames == 60 and stats.split == "train" and stats.round == 0 and stats.driver == "expert"
    assert stats.slow_frames == int(np.sum(truth.target_speed < 1.0)) > 0
    assert stats.noisy_frames == int(truth.noise.sum()) > 0 and stats.network_frames == 0
    assert stats.commands == {option.name: int(np.sum(truth.command == option)) for option in RoadOption
                              if np.any(truth.command == option)}
    stopped = int(np.sum(truth.limited_by == "vehicle"))
    assert stats.limited_by == {"free": 60 - stopped, "vehicle": stopped} and stopped > 0

    out = tmp_path / "report"
    assert main([str(root), "--out", str(out)]) == 0
    record = json.loads((out / "data.json").read_text())
    assert sorted(bag["name"] for bag in record["bags"]) == ["a_000", "b_000"]
    table = (out / "data.md").read_text()
    assert "| none | 2/3 (67 %; 21-94) | 1 collision | 100 |" in table  # Wilson interval of 2/3
    assert "| **all** | 2/3" in table
    b_stats = bag_stats(root / "train" / "b_000")
    held = 100 * (stats.limited_by["vehicle"] + b_stats.limited_by["vehicle"]) / 100
    assert f"| {held:.1f} / 0.0 / 0.0 % |" in table  # vehicle / pedestrian / junction over both bags' 100 frames

    generated = table
    (out / "data.md").unlink()
    assert main(["--record", str(out / "data.json"), "--out", str(out)]) == 0
    assert (out / "data.md").read_text() == generated


def test_a_root_without_bags_is_one_line_and_exit_1(tmp_path, capsys):
    assert main([str(tmp_path), "--out", str(tmp_path / "out")]) == 1
    assert capsys.readouterr().err.strip().count("\n") == 0
