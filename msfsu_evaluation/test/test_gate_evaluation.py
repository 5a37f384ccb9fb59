"""The accuracy gate run end to end on a synthetic held-out bag with a tiny network."""

import pytest

from msfsu_evaluation.gate_evaluation import run_gate
from msfsu_perception.backends import is_installed
from msfsu_perception.synthetic import write_synthetic_bag

N_FRAMES = 8


@pytest.mark.skipif(not is_installed("onnxruntime"), reason="onnxruntime is not installed")
def test_an_fp32_backend_scores_like_torch_and_passes_the_gate(tiny_checkpoint, tmp_path):
    write_synthetic_bag(tmp_path / "bag", n_frames=N_FRAMES, split="test")
    [result] = run_gate(tiny_checkpoint, tmp_path / "bag", [("onnxruntime", "fp32")], tmp_path / "cache",
                        num_threads=1)
    assert (result.backend, result.precision, result.frames) == ("onnxruntime", "fp32", N_FRAMES)
    assert 0.0 <= result.reference.mean_iou <= 1.0 and result.reference.steer_mae > 0.0
    assert result.candidate.mean_iou == pytest.approx(result.reference.mean_iou, abs=1e-3)
    assert result.candidate.steer_mae == pytest.approx(result.reference.steer_mae, abs=1e-4)
    assert result.steer_agreement_mae < 1e-4 and result.class_agreement > 0.999
    assert result.passed


def test_a_bag_without_class_ids_cannot_gate_a_segmenting_network(tiny_checkpoint, tmp_path):
    from dataclasses import replace

    from msfsu_perception.bag_topics import BagTopics

    topics = replace(BagTopics(), semantic_ids="/not/recorded")
    write_synthetic_bag(tmp_path / "bag", n_frames=2, split="test")
    with pytest.raises(ValueError, match="no semantic class ids"):
        run_gate(tiny_checkpoint, tmp_path / "bag", [("torch", "bf16")], tmp_path / "cache", topics=topics)
