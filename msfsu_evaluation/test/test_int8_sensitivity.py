"""Per-layer int8 sensitivity: damage in gate units, the ranking, the selection of float layers, and putting one
layer of a real NNCF-quantised model back in float."""

import json

import numpy as np
import pytest

from msfsu_evaluation.deploy.quantised_graph import quantised_layers, revert_to_float
from msfsu_evaluation.deploy.recipe import earlier_ranking
from msfsu_evaluation.deploy.scoring import HeldOutPredictions
from msfsu_evaluation.deploy.sensitivity import (
    Damage,
    LayerSensitivity,
    damage,
    is_free,
    passes_with_margin,
    rank_layers,
    select_keep_float,
    steps_choice,
)
from msfsu_perception.deploy_files import DEPLOY_FORMAT_VERSION
from msfsu_perception.gate_verdicts import GateResult, HeldOutScores


def predictions(steer, class_ids):
    return HeldOutPredictions(np.asarray(steer, np.float64), np.asarray(class_ids, np.uint8))


def test_damage_is_in_units_of_the_gate_thresholds():
    reference = [predictions([0.1, -0.2], [[[0, 1], [1, 1]], [[0, 0], [1, 1]]])]
    assert damage(reference, reference, 0.05, 2) == Damage(0.0, 0.0)
    # 1 pixel of 8 flips class 1 -> 0; steer off by 0.0025 on average = 5 % of a 0.05 MAE: one threshold
    candidate = [predictions([0.1025, -0.1975], [[[0, 0], [1, 1]], [[0, 0], [1, 1]]])]
    result = damage(reference, candidate, 0.05, 2)
    # agreement mIoU: class 0 IoU 3/4, class 1 IoU 4/5 -> 1 - 0.775 = 22.5 points
    assert result.segmentation == pytest.approx(22.5) and result.steer == pytest.approx(1.0)
    assert result.total == pytest.approx(23.5)


def test_layers_rank_by_recovered_damage_and_a_cheaper_near_tie_goes_first():
    all_int8 = Damage(30.0, 2.0)
    when_float = {"decoder.layers.3": Damage(9.8, 0.0), "decoder.layers.0": Damage(10.0, 0.0),
                  "encoder.stem.0": Damage(29.0, 2.0), "policy.branches.0.6": Damage(30.0, 2.2)}
    macs = {"decoder.layers.3": 0.16, "decoder.layers.0": 0.04, "encoder.stem.0": 0.06}
    ranking = rank_layers(all_int8, when_float, {}, macs)
    assert [s.layer for s in ranking] == ["decoder.layers.0", "decoder.layers.3", "encoder.stem.0",
                                          "policy.branches.0.6"]
    assert ranking[0].recovered == pytest.approx(22.0) and ranking[-1].recovered == pytest.approx(-0.2)


def gate(miou_drop_points: float, steer_rise: float) -> GateResult:
    return GateResult("openvino", "int8", 100, HeldOutScores(0.1, 0.5),
                      HeldOutScores(0.1 * (1 + steer_rise), 0.5 - miou_drop_points / 100), 0.0, 1.0)


def test_passing_with_a_margin_scales_both_thresholds():
    assert passes_with_margin(gate(0.45, 0.02), 0.5) and passes_with_margin(gate(0.9, 0.0), 1.0)
    assert not passes_with_margin(gate(0.6, 0.0), 0.5) and not passes_with_margin(gate(0.0, 0.03), 0.5)


def test_selection_keeps_layers_float_until_the_validation_frames_pass_and_skips_one_that_no_longer_helps():
    # decoder.layers.0 and .3 spoil the same activations: either one in float fixes them
    def evaluate(keep):
        broken = "decoder.layers.0" not in keep and "decoder.layers.3" not in keep
        stem = "encoder.stem.0" not in keep
        value = Damage(20.0 * broken + 0.6 * stem, 0.0)
        return value, gate(3.0 * broken + 0.6 * stem, 0.0)

    steps = select_keep_float(["decoder.layers.0", "decoder.layers.3", "encoder.stem.0", "pool:ReduceMean"],
                              evaluate, margin=0.5, max_layers=8)
    assert [(s.keep_float[-1:], s.accepted, s.passed) for s in steps] == [
        ((), True, False), (("decoder.layers.0",), True, False), (("decoder.layers.3",), False, False),
        (("encoder.stem.0",), True, True)]
    assert steps_choice(steps).keep_float == ("decoder.layers.0", "encoder.stem.0")


def test_selection_stops_at_the_layer_budget():
    steps = select_keep_float(["a", "b", "c"], lambda keep: (Damage(10.0 - len(keep), 0.0), gate(5.0, 0.0)),
                              margin=0.5, max_layers=2)
    assert steps_choice(steps).keep_float == ("a", "b") and not steps[-1].passed
    assert select_keep_float(["a"], lambda keep: (Damage(0.1, 0.0), gate(0.1, 0.0)), 0.5, 4)[-1].keep_float == ()


def test_a_layer_put_back_in_float_has_no_quantiser_left_and_the_others_keep_theirs(tiny_checkpoint, tmp_path):
    import onnx
    import openvino

    from msfsu_perception.backends import onnx_fp32, nncf_quantize
    from msfsu_perception.checkpoint import load_checkpoint
    from msfsu_perception.deploy_files import CalibrationSet, DeployFiles
    from msfsu_perception.int8_recipe import Int8Recipe, graph_layers, openvino_layer_names

    onnx_path = onnx_fp32(DeployFiles(tiny_checkpoint), load_checkpoint(tiny_checkpoint).model)
    rng = np.random.default_rng(0)
    np.savez(tmp_path / "calibration.npz", rgb=rng.integers(0, 256, (4, 3, 64, 64), np.uint8),
             depth=rng.random((4, 1, 64, 64)).astype(np.float16), command_index=np.arange(4))
    quantised = nncf_quantize(openvino.Core().read_model(str(onnx_path)), CalibrationSet.load(tmp_path / "calibration.npz"),
                              Int8Recipe(), onnx_path, compress_weights=False)
    layer_of = openvino_layer_names(quantised, graph_layers(onnx.load(str(onnx_path))))
    before = quantised_layers(quantised, layer_of)
    assert before["decoder.layers.0"] == "Convolution"  # the stride-4 layer, exported as a 1x1 convolution
    assert before["decoder.layers.3"] == "ConvolutionBackpropData" and "encoder.stem.0" in before
    reverted = revert_to_float(quantised, layer_of, ["decoder.layers.0"])
    after = quantised_layers(reverted, layer_of)
    assert set(before) - set(after) == {"decoder.layers.0"}
    assert quantised_layers(quantised, layer_of) == before  # the original is left as it was


def test_the_free_policy_head_goes_float_first_and_the_steer_damage_must_also_be_small():
    head = ("policy.branches.0.3", "network:Reshape")

    def evaluate(keep):
        steer = 3.0 - 1.5 * all(layer in keep for layer in head) - 0.6 * ("encoder.stages.3.1.conv2" in keep)
        broken = "decoder.layers.0" not in keep
        return Damage(20.0 * broken, steer), gate(3.0 * broken, -0.02)  # the validation steer rise looks fine

    # network:Reshape alone did not help on the validation frames (not ranked as helpful): it goes with the head
    ranking = ["decoder.layers.0", "policy.branches.0.3", "encoder.stages.3.1.conv2"]
    steps = select_keep_float(ranking, evaluate, margin=0.5, max_layers=8, free=head, max_steer_damage=1.0)
    assert [s.keep_float for s in steps] == [
        (), ("policy.branches.0.3", "network:Reshape"), ("policy.branches.0.3", "network:Reshape", "decoder.layers.0"),
        ("policy.branches.0.3", "network:Reshape", "decoder.layers.0", "encoder.stages.3.1.conv2")]
    assert [s.passed for s in steps] == [False, False, False, True]  # gate fine at step 3, steer 1.5 > 1.0 still
    assert is_free(LayerSensitivity("policy.branches.0.3", "MatMul", 0.0001, Damage(0, 0), 0.4))
    assert not is_free(LayerSensitivity("encoder.stem.0", "Convolution", 0.05, Damage(0, 0), 0.4))


def test_a_ranking_is_reused_only_if_it_measured_the_same_exported_graph_and_frames(tmp_path):
    validation = {"frames": 3, "bags": ["a"]}
    record = {"deploy_format": DEPLOY_FORMAT_VERSION, "checkpoint_digest": "c", "calibration": {"digest": "k"},
              "validation": validation,
              "ranking": [{"layer": "decoder.layers.0", "damage_when_float": {"segmentation": 1.0, "steer": 0.5}}]}
    path = tmp_path / "recipe.json"
    path.write_text(json.dumps(record))
    assert earlier_ranking(path, "c", "k", validation, {"decoder.layers.0"}) == {"decoder.layers.0": Damage(1.0, 0.5)}
    for stale in ({"deploy_format": DEPLOY_FORMAT_VERSION - 1}, {"checkpoint_digest": "other"}):
        path.write_text(json.dumps({**record, **stale}))
        with pytest.raises(ValueError, match="exported graph"):
            earlier_ranking(path, "c", "k", validation, {"decoder.layers.0"})
