"""The accuracy gate run end to end on synthetic held-out bags with a tiny network; pooled scoring of several bags."""

import numpy as np
import pytest

from msfsu_evaluation.deploy.scoring import (
    HeldOutPredictions,
    evenly_spaced,
    held_out_scores,
    load_held_out,
    run_gate,
)
from msfsu_evaluation.metrics import confusion_matrix, segmentation_scores
from msfsu_perception.backends import is_installed
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_perception.synthetic import write_synthetic_bag

N_FRAMES = 8


@pytest.mark.skipif(not is_installed("onnxruntime"), reason="onnxruntime is not installed")
def test_an_fp32_backend_scores_like_torch_and_passes_the_gate(tiny_checkpoint, tmp_path):
    write_synthetic_bag(tmp_path / "bag", n_frames=N_FRAMES, split="test")
    [result], held_out = run_gate(tiny_checkpoint, tmp_path / "bag", [("onnxruntime", "fp32")], tmp_path / "cache",
                                  num_threads=1)
    assert (result.backend, result.precision, result.frames) == ("onnxruntime", "fp32", N_FRAMES)
    assert 0.0 <= result.reference.mean_iou <= 1.0 and result.reference.steer_mae > 0.0
    assert result.candidate.mean_iou == pytest.approx(result.reference.mean_iou, abs=1e-3)
    assert result.candidate.steer_mae == pytest.approx(result.reference.steer_mae, abs=1e-4)
    assert result.steer_agreement_mae < 1e-4 and result.class_agreement > 0.999
    assert result.passed and result.build is None
    assert held_out["frames"] == N_FRAMES and held_out["bags"][0]["bag"] == "bag"


def test_several_bags_are_pooled_and_each_keeps_its_own_score(tiny_checkpoint, tmp_path):
    for seed, frames in ((1, 6), (2, 10)):
        write_synthetic_bag(tmp_path / f"bag{seed}", n_frames=frames, split="test", seed=seed, noise_period_frames=1000)
    bags = [tmp_path / "bag1", tmp_path / "bag2"]
    # torch fp32 as the candidate: every CPU runs it (bf16 needs avx512_bf16 / AMX), and pooling is what is tested
    [result], held_out = run_gate(tiny_checkpoint, bags, [("torch", "fp32")], tmp_path / "cache", num_threads=1)
    assert [b.bag for b in result.per_bag] == ["bag1", "bag2"] and [b.frames for b in result.per_bag] == [6, 10]
    assert result.frames == 16 and held_out["frames"] == 16
    assert sum(held_out["commands"].values()) == 16 and [b["frames"] for b in held_out["bags"]] == [6, 10]
    # the pooled steer MAE weighs every frame alike
    pooled = (6 * result.per_bag[0].reference.steer_mae + 10 * result.per_bag[1].reference.steer_mae) / 16
    assert result.reference.steer_mae == pytest.approx(pooled)


def test_pooled_miou_comes_from_the_summed_confusion_matrix_not_the_mean_of_the_bags(tmp_path):
    preprocess = PreprocessConfig(64, 64)
    for seed in (1, 2):
        write_synthetic_bag(tmp_path / f"bag{seed}", n_frames=3, split="test", seed=seed, noise_period_frames=1000)
    bags = load_held_out([tmp_path / "bag1", tmp_path / "bag2"], BagTopics(), preprocess, tmp_path / "cache")
    rng = np.random.default_rng(0)
    guesses = [HeldOutPredictions(bag.steer + 0.1, rng.integers(0, 5, bag.labels().shape).astype(np.uint8))
               for bag in bags]
    pooled = held_out_scores(guesses, bags, 5)
    confusion = sum(confusion_matrix(bag.labels(), guess.class_ids, 5) for bag, guess in zip(bags, guesses))
    assert pooled.mean_iou == pytest.approx(segmentation_scores(confusion).mean_iou)
    assert pooled.steer_mae == pytest.approx(0.1)


def test_frames_per_bag_are_spread_over_the_whole_bag():
    assert evenly_spaced(5, None).tolist() == [0, 1, 2, 3, 4]
    assert evenly_spaced(101, 5).tolist() == [0, 25, 50, 75, 100]
    assert evenly_spaced(3, 10).tolist() == [0, 1, 2]
    with pytest.raises(ValueError, match="must be positive"):
        evenly_spaced(10, 0)


def test_a_bag_without_class_ids_cannot_gate_a_segmenting_network(tiny_checkpoint, tmp_path):
    from dataclasses import replace

    topics = replace(BagTopics(), semantic_ids="/not/recorded")
    write_synthetic_bag(tmp_path / "bag", n_frames=2, split="test")
    with pytest.raises(ValueError, match="no semantic class ids"):
        run_gate(tiny_checkpoint, tmp_path / "bag", [("torch", "bf16")], tmp_path / "cache", topics=topics)
