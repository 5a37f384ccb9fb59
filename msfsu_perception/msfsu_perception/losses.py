"""Training objective of the paper, eq. 5-8.

    total = lambda1 * L_steer + lambda2 * L_speed + lambda3 * L_scene,  lambda = (10, 1, 2)

L_steer (eq. 6) weights the squared error by (1 + alpha * |a_gt|^beta)^gamma (alpha=5, beta=1,
gamma=2) so that the rare sharp turns count. L_speed (eq. 7) is the MSE of the normalised speed:
speed_normalised = target speed [m/s] / speed_scale (checkpoint field, 10 m/s by default), which
keeps L_speed on the scale of L_steer. L_scene (eq. 8) is the pixel-wise cross-entropy summed over
the one-hot classes and divided by L * N_p * N_c, i.e. torch's mean cross-entropy / N_c — literally
as written in the paper ("averaged over pixels and classes"). The MSF ablation has no scene term.

Two terms beyond the paper, for a network that waits (issue 77; both off by default, the paper's objective):
- L_stop: binary cross-entropy of the stop logit (MSFSUConfig.stop_output) against "the expert's target speed is
  below the control's stop speed" (msfsu_common.driving.STOP_SPEED_MPS), weighted by stop_weight;
- stop_speed_weight: the squared speed error of those frames counts this many times in L_speed (a weighted mean),
  so that a creep predicted for a stop costs more than its 0.04^2 (0.4 m/s over 10 m/s).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
import torch.nn.functional as F

from msfsu_common.driving import STOP_SPEED_MPS
from msfsu_perception.checkpoint import DEFAULT_SPEED_SCALE_MPS
from msfsu_perception.model import MSFSUOutput


@dataclass(frozen=True)
class LossConfig:
    steer_weight: float = 10.0  # lambda1
    speed_weight: float = 1.0  # lambda2
    scene_weight: float = 2.0  # lambda3
    alpha: float = 5.0
    beta: float = 1.0
    gamma: float = 2.0
    stop_weight: float = 1.0  # weight of L_stop in the total (a network with a stop output only)
    stop_speed_weight: float = 1.0  # weight of a stop frame's squared speed error in L_speed (1: the paper's MSE)
    stop_below: float = STOP_SPEED_MPS / DEFAULT_SPEED_SCALE_MPS  # normalised speed label below which a frame is a stop


class LossTerms(NamedTuple):
    total: torch.Tensor
    steer: torch.Tensor
    speed: torch.Tensor
    scene: torch.Tensor | None  # None for the MSF variant
    stop: torch.Tensor | None = None  # None for a network without a stop output


def weighted_steer_loss(
    steer: torch.Tensor, steer_gt: torch.Tensor, alpha: float, beta: float, gamma: float
) -> torch.Tensor:
    """Eq. 6: mean((1 + alpha * |a_gt|^beta)^gamma * (a - a_gt)^2) over (B,)."""
    weight = (1.0 + alpha * steer_gt.abs().pow(beta)).pow(gamma)
    return (weight * (steer - steer_gt).square()).mean()


def scene_loss(logits: torch.Tensor, class_ids: torch.Tensor) -> torch.Tensor:
    """Eq. 8: (B, N_c, H, W) logits, (B, H, W) long ids -> cross-entropy / (B * N_p * N_c)."""
    return F.cross_entropy(logits, class_ids) / logits.shape[1]


def speed_loss(speed: torch.Tensor, speed_gt: torch.Tensor, stop_below: float, stop_weight: float) -> torch.Tensor:
    """Eq. 7, with the squared error of the frames labelled below `stop_below` weighted `stop_weight` times (a
    weighted mean; 1: the paper's MSE)."""
    if stop_weight == 1.0:
        return F.mse_loss(speed, speed_gt)
    weight = torch.where(speed_gt < stop_below, stop_weight, 1.0)
    return (weight * (speed - speed_gt).square()).sum() / weight.sum()


def stop_loss(stop_logit: torch.Tensor, speed_gt: torch.Tensor, stop_below: float) -> torch.Tensor:
    """Binary cross-entropy of the stop logit against "the label is below `stop_below`"."""
    return F.binary_cross_entropy_with_logits(stop_logit, (speed_gt < stop_below).to(stop_logit.dtype))


def msfsu_loss(
    output: MSFSUOutput,
    steer_gt: torch.Tensor,
    speed_gt: torch.Tensor,
    class_ids: torch.Tensor | None,
    config: LossConfig = LossConfig(),
) -> LossTerms:
    """Eq. 5 in fp32 (outputs of a bf16 autocast forward are upcast first).

    steer_gt, speed_gt: (B,) normalised targets; class_ids: (B, H, W) long, ignored for MSF.
    """
    steer = weighted_steer_loss(output.steer.float(), steer_gt, config.alpha, config.beta, config.gamma)
    speed = speed_loss(output.speed.float(), speed_gt, config.stop_below, config.stop_speed_weight)
    total = config.steer_weight * steer + config.speed_weight * speed
    stop = None
    if output.stop_logit is not None:
        stop = stop_loss(output.stop_logit.float(), speed_gt, config.stop_below)
        total = total + config.stop_weight * stop
    scene = None
    if output.segmentation_logits is not None:
        if class_ids is None:
            raise ValueError("a network with a decoder needs class_ids for the scene loss")
        scene = scene_loss(output.segmentation_logits.float(), class_ids)
        total = total + config.scene_weight * scene
    return LossTerms(total, steer, speed, scene, stop)
