"""Per-layer int8 sensitivity and the float layers it selects: the pure core of `msfsu-int8-recipe` (deploy.recipe).

The *damage* of a model is measured against the torch fp32 reference on the same frames, in units of the gate's
thresholds: segmentation 100 x (1 - mIoU of its class ids scored against the reference's) per mIoU point, steer
mean |steer - reference steer| per 5 % of the reference's steer MAE against the expert (an upper bound of the MAE
rise). A layer's sensitivity is the damage that goes away when it alone is float. Layers go back to float in
order of sensitivity until the validation frames pass the gate with a margin (select_keep_float).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from msfsu_evaluation.deploy.scoring import HeldOutPredictions
from msfsu_evaluation.metrics import confusion_matrix, segmentation_scores
from msfsu_perception.gate_verdicts import MAX_MIOU_DROP_POINTS, MAX_STEER_MAE_RISE, GateResult

NEAR_TIE = 0.9  # ranking: a layer recovering >= 90 % of the best one's damage counts as as good


@dataclass(frozen=True)
class Damage:
    """How far a model is from the reference, in units of the gate's thresholds."""

    segmentation: float  # 100 (1 - mIoU vs the reference's class ids) / MAX_MIOU_DROP_POINTS
    steer: float  # mean |steer - reference steer| / (MAX_STEER_MAE_RISE x reference steer MAE vs the expert)

    @property
    def total(self) -> float:
        return self.segmentation + self.steer


def damage(reference: Sequence[HeldOutPredictions], candidate: Sequence[HeldOutPredictions],
           reference_steer_mae: float, num_classes: int) -> Damage:
    """Damage of `candidate` against `reference` on the same frames (see the module docstring)."""
    deviation = float(np.mean(np.abs(np.concatenate([c.steer - r.steer for r, c in zip(reference, candidate)]))))
    steer = deviation / (MAX_STEER_MAE_RISE * reference_steer_mae) if reference_steer_mae > 0 else (
        0.0 if deviation == 0 else math.inf)
    if any(p.class_ids is None for p in (*reference, *candidate)):
        return Damage(0.0, steer)
    confusion = sum(confusion_matrix(r.class_ids, c.class_ids, num_classes) for r, c in zip(reference, candidate))
    agreement_miou = segmentation_scores(confusion).mean_iou
    return Damage(100.0 * (1.0 - agreement_miou) / MAX_MIOU_DROP_POINTS, steer)


@dataclass(frozen=True)
class LayerSensitivity:
    layer: str
    op_type: str
    mac_share: float  # share of the network's multiply-accumulates (0 for unweighted layers)
    damage_when_float: Damage  # the all-int8 model with this layer alone in float
    recovered: float  # all-int8 damage minus damage_when_float (gate units; > 0: the layer costs accuracy)

    @classmethod
    def from_record(cls, entry: dict[str, Any]) -> LayerSensitivity:
        """One entry of a sensitivity record's "ranking" (the JSON recipe.analyse writes)."""
        return cls(entry["layer"], entry["op_type"], entry["mac_share"], Damage(**entry["damage_when_float"]),
                   entry["recovered"])


def rank_layers(all_int8: Damage, when_float: dict[str, Damage], op_types: dict[str, str],
                mac_shares: dict[str, float], near_tie: float = NEAR_TIE) -> list[LayerSensitivity]:
    """Layers by the damage their int8 causes, most first; among layers that recover nearly as much as the
    best remaining one (at least `near_tie` of it) the one with the fewest MACs comes first (it is cheaper to
    leave in float). Exact ties: by name."""
    remaining = sorted((LayerSensitivity(layer, op_types.get(layer, "?"), mac_shares.get(layer, 0.0), value,
                                         all_int8.total - value.total) for layer, value in when_float.items()),
                       key=lambda s: (-s.recovered, s.mac_share, s.layer))
    ranking = []
    while remaining:
        best = remaining[0].recovered
        close = [s for s in remaining if best > 0 and s.recovered >= near_tie * best] or remaining[:1]
        chosen = min(close, key=lambda s: (s.mac_share, -s.recovered, s.layer))
        ranking.append(chosen)
        remaining.remove(chosen)
    return ranking


FREE_OPS = frozenset({"MatMul", "Reshape", "ReduceMean"})  # the policy head and the pooled feature vector
FREE_MAC_SHARE = 0.005


def is_free(layer: LayerSensitivity) -> bool:
    """A layer that costs next to nothing in float: the fully connected policy head and the pooled features."""
    return layer.op_type in FREE_OPS and layer.mac_share < FREE_MAC_SHARE


def passes_with_margin(result: GateResult, margin: float) -> bool:
    """The gate with each threshold scaled by `margin` (0 < margin <= 1)."""
    return (result.miou_drop_points <= margin * MAX_MIOU_DROP_POINTS
            and result.steer_mae_rise <= margin * MAX_STEER_MAE_RISE)


@dataclass(frozen=True)
class SelectionStep:
    keep_float: tuple[str, ...]
    damage: Damage
    result: GateResult  # the gate on the validation frames
    passed: bool  # with the margin
    accepted: bool  # the layer it added lowered the damage, so it stays float


def select_keep_float(ranking: Sequence[str], evaluate: Callable[[tuple[str, ...]], tuple[Damage, GateResult]],
                      margin: float, max_layers: int, free: Sequence[str] = (),
                      max_steer_damage: float = math.inf) -> list[SelectionStep]:
    """Put layers back in float until the validation frames pass: the gate with `margin`, and a steer damage of
    at most `max_steer_damage` (the validation frames' steer MAE rise alone is too noisy to trust: the mean
    |steer - reference steer| bounds what any frames could see).

    `free` layers (no arithmetic to speak of: the policy head after the global pool) go back together first,
    whether or not `ranking` lists them (a branch's own damage is measured on the few validation frames of its
    command only), then the others one at a time in ranking order. A step is kept only if it lowers the damage of what is
    already float (layers interact: once one of two layers that spoil the same activations is float, the other
    may no longer matter). Stops at `max_layers` float layers besides the free ones, or after 2 x max_layers
    tries. The last accepted step is the choice. evaluate: keep_float -> (damage, validation gate result).
    """
    def passes(damage_value: Damage, result: GateResult) -> bool:
        return passes_with_margin(result, margin) and damage_value.steer <= max_steer_damage

    start, result = evaluate(())
    steps = [SelectionStep((), start, result, passes(start, result), True)]
    damage_now = start.total
    keep: tuple[str, ...] = ()
    free_group = tuple(dict.fromkeys(free))
    candidates = [free_group] if free_group else []
    candidates += [(layer,) for layer in ranking if layer not in free_group]
    tries = 0
    for added in candidates:
        costly = [layer for layer in keep if layer not in free_group]
        if steps_choice(steps).passed or len(costly) >= max_layers or tries >= 2 * max_layers:
            break
        tries += added != free_group
        trial = keep + added
        trial_damage, result = evaluate(trial)
        accepted = trial_damage.total < damage_now
        steps.append(SelectionStep(trial, trial_damage, result, passes(trial_damage, result), accepted))
        if accepted:
            keep, damage_now = trial, trial_damage.total
    return steps


def steps_choice(steps: Sequence[SelectionStep]) -> SelectionStep:
    """The last accepted step: what the selection settled on."""
    return next(step for step in reversed(steps) if step.accepted)

