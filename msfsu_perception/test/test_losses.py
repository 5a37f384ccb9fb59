import math

import pytest
import torch

from msfsu_perception.losses import LossConfig, msfsu_loss, scene_loss, weighted_steer_loss
from msfsu_perception.model import MSFSUOutput


def test_steer_loss_weights_sharp_turns_by_eq6():
    steer = torch.tensor([0.5, 0.0])
    steer_gt = torch.tensor([0.2, -0.4])
    # (1 + 5 * 0.2)^2 * 0.3^2 = 4 * 0.09 = 0.36 ; (1 + 5 * 0.4)^2 * 0.4^2 = 9 * 0.16 = 1.44
    assert weighted_steer_loss(steer, steer_gt, 5.0, 1.0, 2.0).item() == pytest.approx((0.36 + 1.44) / 2)


def test_scene_loss_is_cross_entropy_averaged_over_pixels_and_classes():
    logits = torch.zeros(1, 5, 1, 2)
    logits[0, 0, 0, 0] = math.log(4.0)  # pixel 0: p(class 0) = 4 / 8 = 0.5
    class_ids = torch.tensor([[[0, 3]]])  # pixel 1: uniform, p = 0.2
    expected = (-math.log(0.5) - math.log(0.2)) / 2 / 5
    assert scene_loss(logits, class_ids).item() == pytest.approx(expected)


def test_total_is_lambda_weighted_sum_10_1_2():
    logits = torch.zeros(1, 5, 1, 1)
    output = MSFSUOutput(logits, steer=torch.tensor([0.1]), speed=torch.tensor([0.5]))
    terms = msfsu_loss(output, torch.tensor([0.0]), torch.tensor([0.8]), torch.tensor([[[2]]]))
    assert terms.steer.item() == pytest.approx(0.01)
    assert terms.speed.item() == pytest.approx(0.09)
    assert terms.scene.item() == pytest.approx(math.log(5) / 5)
    assert terms.total.item() == pytest.approx(10 * 0.01 + 1 * 0.09 + 2 * math.log(5) / 5)


def test_msf_has_no_scene_term():
    output = MSFSUOutput(None, steer=torch.tensor([0.0]), speed=torch.tensor([1.0]))
    terms = msfsu_loss(output, torch.tensor([0.0]), torch.tensor([0.0]), None, LossConfig())
    assert terms.scene is None
    assert terms.total.item() == pytest.approx(1.0)


def test_decoder_output_without_labels_is_an_error():
    output = MSFSUOutput(torch.zeros(1, 5, 1, 1), steer=torch.zeros(1), speed=torch.zeros(1))
    with pytest.raises(ValueError, match="class_ids"):
        msfsu_loss(output, torch.zeros(1), torch.zeros(1), None)


def test_stop_term_is_the_cross_entropy_of_label_below_the_stop_speed():
    # labels 0.02 (0.2 m/s: a stop at the default speed scale) and 0.5 (5 m/s: a drive); logits 0 and 0
    output = MSFSUOutput(None, steer=torch.zeros(2), speed=torch.tensor([0.02, 0.5]), stop_logit=torch.zeros(2))
    terms = msfsu_loss(output, torch.zeros(2), torch.tensor([0.02, 0.5]), None, LossConfig(stop_weight=3.0))
    assert terms.stop.item() == pytest.approx(math.log(2))
    assert terms.total.item() == pytest.approx(3.0 * math.log(2))
    confident = MSFSUOutput(None, steer=torch.zeros(2), speed=torch.zeros(2), stop_logit=torch.tensor([9.0, -9.0]))
    assert msfsu_loss(confident, torch.zeros(2), torch.tensor([0.02, 0.5]), None).stop.item() < 1e-3
    wrong = MSFSUOutput(None, steer=torch.zeros(2), speed=torch.zeros(2), stop_logit=torch.tensor([-9.0, 9.0]))
    assert msfsu_loss(wrong, torch.zeros(2), torch.tensor([0.02, 0.5]), None).stop.item() > 8


def test_a_network_without_a_stop_output_has_no_stop_term():
    output = MSFSUOutput(None, steer=torch.zeros(1), speed=torch.zeros(1))
    assert msfsu_loss(output, torch.zeros(1), torch.zeros(1), None, LossConfig(stop_weight=5.0)).stop is None


def test_stop_speed_weight_counts_a_stop_frames_speed_error_that_many_times():
    # frame 0 is a stop (label 0.0) predicted as a creep (0.08): error^2 0.0064; frame 1 a drive off by 0.1: 0.01
    output = MSFSUOutput(None, steer=torch.zeros(2), speed=torch.tensor([0.08, 0.6]))
    labels = torch.tensor([0.0, 0.5])
    plain = msfsu_loss(output, torch.zeros(2), labels, None).speed.item()
    assert plain == pytest.approx((0.0064 + 0.01) / 2)
    weighted = msfsu_loss(output, torch.zeros(2), labels, None, LossConfig(stop_speed_weight=9.0)).speed.item()
    assert weighted == pytest.approx((9 * 0.0064 + 0.01) / 10)
