"""msfsu-eval-bag end to end: synthetic bags through the real node graph (separate processes)."""

import csv
import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from msfsu_common import topics
from msfsu_evaluation.bag_eval import main
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.synthetic import SyntheticTruth, write_synthetic_bag

N_FRAMES = 30
INPUT_PIXELS = 64 * 64  # tiny_checkpoint's network input
FIGURES = ("actions.png", "confusion_matrix.png", "segmentation_overlays.png")
# A CARLA-bridge-style recording: other names for inputs and ground truth, bgra8 RGB (depth 32FC1 as ours).
CARLA_TOPICS = BagTopics(
    rgb="/carla/hero/rgb_front/image",
    depth="/carla/hero/depth_front/image",
    semantic_ids="/carla/hero/semantic_front/class_ids",
    expert_action="/hero/expert/driving_action",
    navigation_command="/hero/navigation_command",
)


def read_frames_csv(out: Path) -> dict[str, np.ndarray]:
    with (out / "frames.csv").open() as file:
        rows = list(csv.DictReader(file))
    return {column: np.array([float(row[column]) for row in rows]) for column in rows[0]}


def evaluate_bag(out: Path, bag: Path, checkpoint: Path, *options: str) -> dict:
    """Quarter speed: 400 ms per frame leaves the tiny network time even on a loaded 2-core machine."""
    exit_code = main([str(bag), "--checkpoint", str(checkpoint), "--out", str(out), "--rate", "0.25",
                      "--cache-dir", str(out.parent / "cache"), *options])
    assert exit_code == 0, (out / "replay.log").read_text() if (out / "replay.log").exists() else "no replay.log"
    return json.loads((out / "report.json").read_text())


@pytest.fixture(scope="module")
def synthetic_run(tiny_checkpoint, tmp_path_factory) -> tuple[SyntheticTruth, Path, dict]:
    root = tmp_path_factory.mktemp("synthetic")
    truth = write_synthetic_bag(root / "bag", n_frames=N_FRAMES, split="test")
    report = evaluate_bag(root / "out", root / "bag", tiny_checkpoint)
    return truth, root / "out", report


def assert_consistent_report(report: dict) -> None:
    frames = report["frames"]
    assert frames["camera_frames"] == N_FRAMES
    assert frames["processed"] + frames["skipped"] == N_FRAMES
    # The node keeps the newest frame (by design); a CPU-starved player can still deliver two frames at once even at
    # 2.5 Hz (seen: 26 of 30 with a 5 ms inference), so only a node that skips most frames fails here.
    assert frames["processed"] >= N_FRAMES * 2 // 3
    assert frames["with_ground_truth"] == N_FRAMES  # no noise window, no missing topic in 30 synthetic frames
    assert frames["evaluated"] == frames["processed"]
    assert 0 < frames["controlled"] <= frames["processed"]  # a CPU-starved control node may miss actions
    assert frames["command_mismatches"] <= 2  # commands precede their frames; only a starved node lags
    actions = report["actions"]
    overall = actions["overall"]
    assert overall["frames"] == frames["evaluated"]
    assert sum(errors["frames"] for name, errors in actions.items() if name != "overall") == overall["frames"]
    assert 0.0 <= overall["steer_mae"] <= overall["steer_rmse"] <= 2.0
    assert 0.0 <= overall["target_speed_mae"] < 100.0
    segmentation = report["segmentation"]
    assert segmentation["labelled_pixels"] == frames["evaluated"] * INPUT_PIXELS
    assert np.sum(segmentation["confusion_matrix"]) == segmentation["labelled_pixels"]
    assert 0.0 <= segmentation["mean_iou"] <= 1.0 and 0.0 <= segmentation["pixel_accuracy"] <= 1.0
    latency = report["latency_ms"]
    assert latency["frames"] == frames["processed"]
    assert 0.0 < latency["p50_ms"] <= latency["p95_ms"] <= latency["max_ms"] < 5000.0


def test_synthetic_bag_is_evaluated_frame_by_frame_against_its_expert(synthetic_run):
    truth, out, report = synthetic_run
    assert_consistent_report(report)
    for name in ("report.json", "report.md", "frames.csv", *FIGURES):
        assert (out / name).stat().st_size > 0, name
    assert f"| overall | {report['frames']['evaluated']} |" in (out / "report.md").read_text()
    # a bag that names no camera: the brake assumed the simulator's, and the report says so
    assert report["run"]["aeb_camera"] == "simulator"
    assert "the emergency brake assumes the simulator's front camera" in (out / "report.md").read_text()
    frames = read_frames_csv(out)
    rows = np.searchsorted(truth.stamps_ns, frames["stamp_ns"].astype(np.int64))
    np.testing.assert_allclose(frames["expert_steer"], truth.steer[rows], atol=1e-6)  # matched by stamp
    np.testing.assert_array_equal(frames["command"], truth.command[rows])
    steer_error = frames["predicted_steer"] - frames["expert_steer"]
    assert report["actions"]["overall"]["steer_rmse"] == pytest.approx(np.sqrt(np.mean(steer_error ** 2)), abs=1e-6)


def test_carla_style_bag_is_evaluated_through_remaps_with_the_same_predictions(
        synthetic_run, tiny_checkpoint, tmp_path):
    _, synthetic_out, _ = synthetic_run
    bag = tmp_path / "carla_bag"
    write_synthetic_bag(bag, n_frames=N_FRAMES, split="test", rgb_encoding="bgra8", topics=CARLA_TOPICS)
    report = evaluate_bag(
        tmp_path / "out", bag, tiny_checkpoint,
        "--remap", f"{CARLA_TOPICS.rgb}:={topics.RGB}",
        "--remap", f"{CARLA_TOPICS.depth}:={topics.DEPTH}",
        "--remap", f"{CARLA_TOPICS.navigation_command}:={topics.NAVIGATION_COMMAND}",
        "--expert-topic", CARLA_TOPICS.expert_action, "--semantic-topic", CARLA_TOPICS.semantic_ids,
    )
    assert_consistent_report(report)
    assert report["run"]["ground_truth_topics"]["rgb"] == CARLA_TOPICS.rgb
    # Same scenes as the rgb8 bag (same seed): bgra8 decoding and remapped commands must not change a prediction.
    carla, ours = read_frames_csv(tmp_path / "out"), read_frames_csv(synthetic_out)
    common, in_carla, in_ours = np.intersect1d(carla["stamp_ns"], ours["stamp_ns"], return_indices=True)
    assert len(common) >= N_FRAMES // 2
    np.testing.assert_allclose(carla["predicted_steer"][in_carla], ours["predicted_steer"][in_ours], atol=1e-4)
    np.testing.assert_allclose(carla["predicted_target_speed"][in_carla], ours["predicted_target_speed"][in_ours],
                               atol=1e-4)


@pytest.mark.parametrize("remap, message", [
    ("/a/b", "must look like /bag/topic:=/graph/topic"),
    (f"{topics.RGB}:=/carla/ego_vehicle/somewhere", "is not a graph input"),
    (f"/not/in/bag:={topics.RGB}", "is not in the bag"),
])
def test_bad_remaps_are_usage_errors_that_say_what_to_change(remap, message, tiny_checkpoint, tmp_path, capsys):
    write_synthetic_bag(tmp_path / "bag", n_frames=2)
    exit_code = main([str(tmp_path / "bag"), "--checkpoint", str(tiny_checkpoint), "--out", str(tmp_path / "out"),
                      "--remap", remap])
    assert exit_code == 2
    assert message in capsys.readouterr().err


def test_bag_without_the_expert_topic_fails_before_starting_the_graph(tiny_checkpoint, tmp_path, capsys):
    write_synthetic_bag(tmp_path / "bag", n_frames=2, topics=replace(BagTopics(), expert_action="/other/expert"))
    exit_code = main([str(tmp_path / "bag"), "--checkpoint", str(tiny_checkpoint), "--out", str(tmp_path / "out"),
                      "--cache-dir", str(tmp_path / "cache")])
    assert exit_code == 1
    assert f"lacks expert action {topics.EXPERT_ACTION}" in capsys.readouterr().err
    assert not (tmp_path / "out" / "replay.log").exists()


def test_a_bag_naming_no_camera_of_the_stack_is_one_line_before_anything_runs(tiny_checkpoint, tmp_path, capsys):
    write_synthetic_bag(tmp_path / "bag", n_frames=2)
    metadata_file = tmp_path / "bag" / "metadata.yaml"
    metadata = yaml.safe_load(metadata_file.read_text())
    metadata["rosbag2_bagfile_information"]["custom_data"]["msfsu.camera"] = '{"width": 800}'
    metadata_file.write_text(yaml.safe_dump(metadata))
    exit_code = main([str(tmp_path / "bag"), "--checkpoint", str(tiny_checkpoint), "--out", str(tmp_path / "out"),
                      "--cache-dir", str(tmp_path / "cache")])
    assert exit_code == 2 and not (tmp_path / "out").exists()
    assert capsys.readouterr().err.splitlines() == [
        f"msfsu-eval-bag: {tmp_path / 'bag'}: metadata msfsu.camera: not a front camera (needs exactly the fields "
        "forward_m, fov_deg, height, pitch_deg, right_m, up_m, width): '{\"width\": 800}'"]


def test_missing_bag_and_checkpoint_are_clear_errors(tiny_checkpoint, tmp_path, capsys):
    assert main([str(tmp_path / "nothing"), "--checkpoint", str(tiny_checkpoint), "--out", str(tmp_path / "o")]) == 1
    assert "nothing: no such bag (no such file or directory)" in capsys.readouterr().err
    write_synthetic_bag(tmp_path / "bag", n_frames=2)
    assert main([str(tmp_path / "bag"), "--checkpoint", str(tmp_path / "none.pt"), "--out", str(tmp_path / "o")]) == 1
    assert "does not exist" in capsys.readouterr().err


def test_what_is_not_a_bag_gets_one_line_and_exit_code_1(tiny_checkpoint, tmp_path, capsys):
    bag = tmp_path / "noise"
    write_synthetic_bag(bag, n_frames=2, split="test")
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(np.random.default_rng(0).bytes(10_000))  # a bag directory holding random bytes
    assert main([str(bag), "--checkpoint", str(tiny_checkpoint), "--out", str(tmp_path / "out")]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"msfsu-eval-bag: {mcap}: not an MCAP file (wrong magic bytes at its start)"]


def test_ground_truth_of_a_cut_bag_is_what_its_complete_chunks_hold(tmp_path):
    from msfsu_evaluation.graph_run import bag_duration_s
    from msfsu_evaluation.ground_truth import load_ground_truth
    from msfsu_perception.preprocessing import PreprocessConfig

    bag = tmp_path / "cut"
    truth = write_synthetic_bag(bag, 20, split="test", height=240, width=320, noise_duration_frames=0)
    mcap = next(bag.glob("*.mcap"))
    os.truncate(mcap, int(mcap.stat().st_size * 0.6))
    ground_truth = load_ground_truth(bag, BagTopics(), PreprocessConfig(64, 64), tmp_path / "cache")
    frames = len(ground_truth)
    assert 5 < frames < 20 and ground_truth.camera_frames in (frames, frames + 1)
    np.testing.assert_array_equal(ground_truth.steer, truth.steer[:frames])
    assert bag_duration_s(bag) == pytest.approx((truth.stamps_ns[frames - 1] - truth.stamps_ns[0]) * 1e-9, abs=0.12)


def test_the_replay_profile_gives_the_brake_the_bags_camera():
    """msfsu-eval-bag's request -> the replay profile's aeb node parameters: the bag's camera (a CARLA import's) on top
    of the profile's own, the simulator's defaults without one."""
    from msfsu_bringup.launcher import load_profile, profile_path
    from msfsu_common.camera_geometry import FrontCamera
    from msfsu_control.aeb_node import camera_parameters
    from msfsu_evaluation.graph_run import ReplayRequest, replay_command

    def aeb_parameters(camera: FrontCamera | None) -> dict:
        command = replay_command(ReplayRequest(Path("bag"), Path("c.pt"), Path("rec"), Path("log"), camera=camera,
                                               crop_top_fraction=0.4))
        given = dict(item.split("=", 1) for flag, item in zip(command, command[1:]) if flag == "--arg")
        (aeb,) = [node for node in load_profile(profile_path("replay"), given)[1] if node.name == "aeb"]
        return aeb.parameters

    profile = {"use_sim_time": True, "crop_top_fraction": 0.4}  # the product's brake: the aeb node's defaults
    assert aeb_parameters(None) == profile
    carla = FrontCamera(800, 600, 90.0, 2.0, 0.0, 2.0, 0.0)
    assert aeb_parameters(carla) == {**profile, **camera_parameters(carla)}
