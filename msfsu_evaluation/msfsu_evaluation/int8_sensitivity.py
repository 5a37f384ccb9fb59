"""`msfsu-int8-recipe`: per-layer int8 sensitivity of a checkpoint, and the int8 recipe it leads to.

    msfsu-int8-recipe models/msfsu_default.pt --val-bags 'data/sim/validation/*' --out benchmarks/int8_sensitivity_cpu

1. The checkpoint's calibration frames (msfsu-calibrate) quantise the whole network once with NNCF, its weights
   left as float constants behind their FakeQuantize, so any layer can be put back in float by bypassing the
   quantisers on its inputs (int8_recipe names the layers).
2. Validation frames (training towns: never the held-out gate bags) run through torch fp32 (the reference), the
   all-int8 model, and the all-int8 model with one layer at a time back in float. The *damage* of a model is
   measured against the reference in units of the gate's thresholds: segmentation 100 x (1 - mIoU of its class
   ids scored against the reference's) per mIoU point, steer mean |steer - reference steer| per 5 % of the
   reference's steer MAE against the expert (an upper bound of the MAE rise). A layer's sensitivity is the damage
   that goes away when it alone is float.
3. Layers go back to float in order of sensitivity until the validation frames pass the gate with a margin (by
   default half of each threshold) or --max-layers are float. That list is the recipe; the NNCF model built from
   it (ignored_scope, weights compressed: what deploys) is scored once more, and the recipe is stored beside the
   checkpoint with the ranking (int8_recipe.write_recipe). The gate on held-out bags decides afterwards
   (msfsu-gate, which runs this command as its recipe step).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_common.benchmark_run import load_1min
from msfsu_evaluation.gate_evaluation import (
    HeldOutBag,
    HeldOutPredictions,
    compare,
    describe_held_out,
    load_held_out,
    predict_held_out,
)
from msfsu_evaluation.metrics import confusion_matrix, segmentation_scores
from msfsu_perception.deploy_files import DEPLOY_FORMAT_VERSION
from msfsu_perception.gate_verdicts import MAX_MIOU_DROP_POINTS, MAX_STEER_MAE_RISE, GateResult

DEFAULT_MARGIN = 0.5  # the validation frames must pass with half of each gate threshold to spare
DEFAULT_MAX_LAYERS = 16
DEFAULT_MAX_STEER_DAMAGE = 1.5
DEFAULT_FRAMES = 400
NEAR_TIE = 0.9  # ranking: a layer recovering >= 90 % of the best one's damage counts as as good


# --- the pure core: damage, ranking, selection ------------------------------------------------------
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
        """One entry of a sensitivity record's "ranking" (the JSON analyse() writes)."""
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


# --- OpenVINO graph work ---------------------------------------------------------------------------
def quantised_layers(model: Any, layer_of: dict[str, str]) -> dict[str, str]:
    """{layer name: OpenVINO op type} of the ops with a FakeQuantize on an input."""
    found = {}
    for op in model.get_ordered_ops():
        name = layer_of.get(op.get_friendly_name())
        if name is None or op.get_type_name() == "FakeQuantize":
            continue
        if any(port.get_source_output().get_node().get_type_name() == "FakeQuantize" for port in op.inputs()):
            found[name] = op.get_type_name()
    return found


def revert_to_float(quantised: Any, layer_of: dict[str, str], layers: Collection[str]) -> Any:
    """A copy of `quantised` with the quantisers on the inputs of `layers` bypassed (weights back to float)."""
    model = quantised.clone()
    layers = set(layers)
    for op in model.get_ordered_ops():
        if layer_of.get(op.get_friendly_name()) not in layers:
            continue
        for port in op.inputs():
            source = port.get_source_output().get_node()
            if source.get_type_name() == "FakeQuantize":
                port.replace_source_output(source.input_value(0))
    return model


def layer_macs(model: Any, layer_of: dict[str, str]) -> dict[str, int]:
    """Multiply-accumulates per weighted layer at batch 1."""
    from msfsu_perception.backends.openvino_runner import input_shapes

    model = model.clone()
    model.reshape({name: [1, *shape[1:]] for name, shape in input_shapes(model).items()})
    macs = {}
    for op in model.get_ordered_ops():
        name, kind = layer_of.get(op.get_friendly_name()), op.get_type_name()
        if name is None or kind not in ("Convolution", "ConvolutionBackpropData", "MatMul"):
            continue
        weight = [int(d) for d in op.input(1).get_partial_shape().to_shape()]
        out = [int(d) for d in op.output(0).get_partial_shape().to_shape()]
        if kind == "Convolution":  # weight (Cout, Cin, kh, kw)
            macs[name] = math.prod(out) * math.prod(weight[1:])
        elif kind == "ConvolutionBackpropData":  # weight (Cin, Cout, kh, kw): every input element scatters
            inputs = [int(d) for d in op.input(0).get_partial_shape().to_shape()]
            macs[name] = math.prod(inputs) * math.prod(weight[1:])
        else:  # MatMul: (B, K) x (K, N) or transposed
            macs[name] = math.prod(out) * min(weight)
    return macs


# --- the run ---------------------------------------------------------------------------------------
class _Evaluator:
    """Scores OpenVINO models (in memory) on the validation frames against the torch fp32 reference."""

    def __init__(self, checkpoint: Path, bags: list[HeldOutBag], threads: int | None) -> None:
        from msfsu_perception.inference import DrivingModel

        self.reference_model = DrivingModel.from_checkpoint(checkpoint, threads, "torch", "fp32")
        self.bags, self.threads = bags, threads
        self.num_classes = len(self.reference_model.class_names)
        self.reference = [predict_held_out(self.reference_model, bag) for bag in bags]
        self.reference_steer_mae = float(np.mean(np.concatenate(
            [np.abs(p.steer - bag.steer) for p, bag in zip(self.reference, bags)])))

    def predictions(self, model: Any) -> list[HeldOutPredictions]:
        from msfsu_perception.backends import OpenVinoRunner
        from msfsu_perception.inference import DrivingModel

        ref = self.reference_model
        driving = DrivingModel(OpenVinoRunner(model, "int8", self.threads, None), ref.preprocess, ref.speed_scale,
                               ref.class_names, ref.has_segmentation, "openvino", "int8")
        return [predict_held_out(driving, bag) for bag in self.bags]

    def score(self, model: Any) -> tuple[Damage, GateResult]:
        candidate = self.predictions(model)
        return (damage(self.reference, candidate, self.reference_steer_mae, self.num_classes),
                compare("openvino", "int8", self.reference, candidate, self.bags, self.num_classes))


def _latency_ms(model: Any, preprocess: Any, threads: int | None, iterations: int = 30) -> float:
    from msfsu_perception.backends import OpenVinoRunner

    runner = OpenVinoRunner(model, "int8", threads, None)
    inputs = np.random.default_rng(0).random((1, preprocess.channels, preprocess.input_height,
                                              preprocess.input_width), dtype=np.float32)
    command = np.zeros(1, np.int64)
    for _ in range(5):
        runner(inputs, command)
    samples = []
    for _ in range(iterations):
        started = time.perf_counter()
        runner(inputs, command)
        samples.append((time.perf_counter() - started) * 1e3)
    return float(np.median(samples))


def earlier_ranking(path: Path, checkpoint_digest: str, calibration_digest: str, validation: dict[str, Any],
                    layers: set[str]) -> dict[str, Damage]:
    """The one-layer-in-float damages of an earlier run (its JSON), if it measured the same thing."""
    record = json.loads(path.read_text())
    same = (record.get("deploy_format") == DEPLOY_FORMAT_VERSION and record["checkpoint_digest"] == checkpoint_digest
            and record["calibration"]["digest"] == calibration_digest
            and record["validation"] == validation and {entry["layer"] for entry in record["ranking"]} == layers)
    if not same:
        raise ValueError(f"{path} ranked another checkpoint, exported graph, calibration or validation frames: run "
                         "without --ranking-from")
    return {entry["layer"]: Damage(**entry["damage_when_float"]) for entry in record["ranking"]}


def _gate_summary(result: GateResult) -> dict[str, Any]:
    return {"miou_drop_points": round(result.miou_drop_points, 3), "steer_mae_rise": round(result.steer_mae_rise, 4),
            "reference": asdict(result.reference), "candidate": asdict(result.candidate),
            "steer_agreement_mae": result.steer_agreement_mae, "class_agreement": result.class_agreement}


def analyse(args: argparse.Namespace) -> dict[str, Any]:
    import onnx

    from msfsu_perception.backends import nncf_quantize, onnx_fp32, openvino_core
    from msfsu_perception.bag_topics import BagTopics
    from msfsu_perception.checkpoint import load_checkpoint
    from msfsu_perception.dataset import expand_bag_paths
    from msfsu_perception.deploy_files import CalibrationSet, DeployFiles, calibration_path, file_digest
    from msfsu_perception.int8_recipe import Int8Recipe, graph_layers, openvino_layer_names

    loaded = load_checkpoint(args.checkpoint)
    calibration = CalibrationSet.for_checkpoint(args.checkpoint)
    if calibration is None:
        raise ValueError(f"{calibration_path(args.checkpoint)} is missing: write it first (msfsu-calibrate)")
    bags = expand_bag_paths(args.val_bags)
    frames_per_bag = max(1, math.ceil(args.frames / len(bags))) if args.frames else None
    held_out = load_held_out(bags, BagTopics(), loaded.preprocess, args.cache_dir, frames_per_bag)
    print(f"validation: {sum(len(b) for b in held_out)} frames of {len(held_out)} bags", flush=True)
    evaluator = _Evaluator(args.checkpoint, held_out, args.threads)

    onnx_path = onnx_fp32(DeployFiles(args.checkpoint), loaded.model)
    layers = graph_layers(onnx.load(str(onnx_path)))
    base_recipe = Int8Recipe(preset=args.preset, fast_bias_correction=args.fast_bias_correction)
    fp32_model = openvino_core().read_model(str(onnx_path))
    quantised = nncf_quantize(fp32_model, calibration, base_recipe, onnx_path, compress_weights=False)
    layer_of = openvino_layer_names(quantised, layers)
    candidates = quantised_layers(quantised, layer_of)
    macs = layer_macs(fp32_model, openvino_layer_names(fp32_model, layers))
    total_macs = sum(macs.values())

    all_int8, all_int8_gate = evaluator.score(quantised)
    print(f"all int8: damage {all_int8.total:.2f} (segmentation {all_int8.segmentation:.2f}, steer "
          f"{all_int8.steer:.2f}); validation mIoU drop {all_int8_gate.miou_drop_points:.2f} points, steer MAE rise "
          f"{all_int8_gate.steer_mae_rise:+.1%}; {len(candidates)} quantised layers", flush=True)
    when_float = earlier_ranking(args.ranking_from, file_digest(args.checkpoint), calibration.digest,
                                 describe_held_out(held_out), set(candidates)) if args.ranking_from else {}
    for position, layer in enumerate(candidates, 1):
        if layer not in when_float:
            when_float[layer], _ = evaluator.score(revert_to_float(quantised, layer_of, [layer]))
        print(f"  [{position}/{len(candidates)}] {layer}: damage {when_float[layer].total:.2f}", flush=True)
    ranking = rank_layers(all_int8, when_float, candidates, {k: v / total_macs for k, v in macs.items()})

    def evaluate(keep: tuple[str, ...]) -> tuple[Damage, GateResult]:
        return evaluator.score(revert_to_float(quantised, layer_of, keep))

    helpful = [s.layer for s in ranking if s.recovered > 0]
    free = [s.layer for s in ranking if is_free(s)]
    steps = select_keep_float(helpful, evaluate, args.margin, args.max_layers, free, args.max_steer_damage)
    for step in steps:
        print(f"  float {', '.join(step.keep_float) or '-'}: damage {step.damage.total:.2f}, mIoU drop "
              f"{step.result.miou_drop_points:.2f}, steer MAE rise {step.result.steer_mae_rise:+.1%}"
              f"{'' if step.accepted else ' (not kept)'}{' (passes with margin)' if step.passed else ''}", flush=True)
    chosen = Int8Recipe(steps_choice(steps).keep_float, args.preset, args.fast_bias_correction)
    deployed = nncf_quantize(fp32_model, calibration, chosen, onnx_path)
    deployed_damage, deployed_gate = evaluator.score(deployed)
    all_int8_deployed = nncf_quantize(fp32_model, calibration, base_recipe, onnx_path)
    latency = {"load_average_1min": load_1min(),
               "all_int8_ms": round(_latency_ms(all_int8_deployed, loaded.preprocess, args.threads), 2),
               "recipe_ms": round(_latency_ms(deployed, loaded.preprocess, args.threads), 2)}
    print(f"recipe ({len(chosen.keep_float)} layers float), NNCF-built: damage {deployed_damage.total:.2f}, mIoU "
          f"drop {deployed_gate.miou_drop_points:.2f}, steer MAE rise {deployed_gate.steer_mae_rise:+.1%}; "
          f"p50 {latency['recipe_ms']} ms vs all int8 {latency['all_int8_ms']} ms", flush=True)
    return {
        "checkpoint": str(args.checkpoint),
        "checkpoint_digest": file_digest(args.checkpoint),
        "deploy_format": DEPLOY_FORMAT_VERSION,  # the exported graph the damages were measured on
        "command": args.command,
        "calibration": {"digest": calibration.digest, "frames": len(calibration)},
        "validation": describe_held_out(held_out),
        "margin": args.margin,
        "max_layers": args.max_layers,
        "max_steer_damage": args.max_steer_damage,
        "all_int8": {"damage": asdict(all_int8), "validation_gate": _gate_summary(all_int8_gate)},
        "ranking": [{**asdict(s), "damage_when_float": asdict(s.damage_when_float)} for s in ranking],
        "selection": [{"keep_float": list(s.keep_float), "damage": asdict(s.damage), "accepted": s.accepted,
                       "passed_with_margin": s.passed, "validation_gate": _gate_summary(s.result)} for s in steps],
        "recipe": chosen.settings(),
        "recipe_digest": chosen.digest,
        "recipe_float_mac_share": sum(macs.get(layer, 0) for layer in chosen.keep_float) / total_macs,
        "deployed": {"damage": asdict(deployed_damage), "validation_gate": _gate_summary(deployed_gate)},
        "latency": latency,
    }


def report_markdown(record: dict[str, Any]) -> str:
    all_int8, deployed = record["all_int8"], record["deployed"]
    lines = [f"# int8 sensitivity of {record['checkpoint']} ({record['checkpoint_digest']})", "",
             f"Made by `{record['command']}`", "",
             f"Validation frames: {record['validation']['frames']} from {len(record['validation']['bags'])} bags "
             f"({', '.join(f'{k} {v}' for k, v in record['validation']['commands'].items())}); calibration "
             f"{record['calibration']['frames']} frames ({record['calibration']['digest']}). Damage is in gate units "
             "(1.0 = one threshold): segmentation = mIoU points lost against torch fp32's own class ids, steer = "
             "mean |steer - fp32 steer| per 5 % of fp32's steer MAE.", "",
             "| model | damage (seg + steer) | validation mIoU drop (points) | steer MAE rise | float MACs |",
             "|---|---:|---:|---:|---:|"]

    def row(label: str, part: dict[str, Any], share: float) -> str:
        d, g = part["damage"], part["validation_gate"]
        return (f"| {label} | {d['segmentation'] + d['steer']:.2f} ({d['segmentation']:.2f} + {d['steer']:.2f}) | "
                f"{g['miou_drop_points']:.2f} | {g['steer_mae_rise']:+.1%} | {share:.1%} |")

    lines.append(row("all layers int8", all_int8, 0.0))
    lines.append(row(f"recipe: {len(record['recipe']['keep_float'])} layers float (NNCF ignored_scope)", deployed,
                     record["recipe_float_mac_share"]))
    latency = record["latency"]
    lines += ["", f"Latency p50 (OpenVINO, batch 1, 1-min load {latency['load_average_1min']}): all int8 "
              f"{latency['all_int8_ms']} ms, recipe {latency['recipe_ms']} ms.", "",
              "Selection (the free policy head first, then layers back to float in ranking order, kept only if they "
              f"lower the damage; stops when the validation gate passes with margin {record['margin']} and the steer "
              f"damage is at most {record.get('max_steer_damage', 'inf')}):", "",
              "| float layers | last added | damage | mIoU drop | steer MAE rise | kept | passes with margin |",
              "|---:|---|---:|---:|---:|---|---|"]
    for step in record["selection"]:
        gate, d = step["validation_gate"], step["damage"]
        previous = next((p["keep_float"] for p in reversed(record["selection"][:record["selection"].index(step)])
                         if p["accepted"]), [])
        new_layers = [layer for layer in step["keep_float"] if layer not in previous]
        added = (new_layers[0] if len(new_layers) == 1 else f"{len(new_layers)} free layers (policy head)"
                 ) if step["keep_float"] else "(all int8)"
        lines.append(f"| {len(step['keep_float'])} | {added} | {d['segmentation'] + d['steer']:.2f} | "
                     f"{gate['miou_drop_points']:.2f} | {gate['steer_mae_rise']:+.1%} | "
                     f"{'yes' if step['accepted'] else 'no'} | {'yes' if step['passed_with_margin'] else 'no'} |")
    lines += ["", f"Kept in float: {', '.join(record['recipe']['keep_float']) or 'nothing'}", "",
              "Per-layer sensitivity (damage of the all-int8 model with only this layer in float):", "",
              "| rank | layer | op | MACs | damage when float (seg + steer) | recovered |", "|---:|---|---|---:|---:|---:|"]
    for rank, entry in enumerate(record["ranking"], 1):
        d = entry["damage_when_float"]
        lines.append(f"| {rank} | {entry['layer']} | {entry['op_type']} | {entry['mac_share']:.1%} | "
                     f"{d['segmentation'] + d['steer']:.2f} ({d['segmentation']:.2f} + {d['steer']:.2f}) | "
                     f"{entry['recovered']:+.2f} |")
    return "\n".join(lines) + "\n"


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="msfsu-int8-recipe", description=__doc__.splitlines()[0],
                                     epilog="The checkpoint needs its calibration frames (msfsu-calibrate).")
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--val-bags", nargs="+", required=True,
                        help="bags/globs with class ids to rank the layers on (validation split: not the gate's bags)")
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES,
                        help="validation frames in all, spread evenly over the bags (0: every frame)")
    parser.add_argument("--margin", type=float, default=DEFAULT_MARGIN,
                        help="share of each gate threshold the validation frames may use (0-1]")
    parser.add_argument("--max-layers", type=int, default=DEFAULT_MAX_LAYERS,
                        help="at most this many layers float (besides the free policy head)")
    parser.add_argument("--max-steer-damage", type=float, default=DEFAULT_MAX_STEER_DAMAGE,
                        help="the recipe must also keep mean |steer - fp32 steer| within this many 5 %% of fp32's "
                             "steer MAE on the validation frames")
    parser.add_argument("--preset", choices=("performance", "mixed"), default="performance",
                        help="NNCF preset: symmetric (performance) or asymmetric (mixed) activations")
    parser.add_argument("--fast-bias-correction", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--threads", type=int, default=2, help="intra-op threads")
    parser.add_argument("--cache-dir", type=Path, default=Path("data/cache"), help="decoded frame cache")
    parser.add_argument("--out", type=Path, help="write the ranking as <out>.md and <out>.json")
    parser.add_argument("--dry-run", action="store_true", help="report only: do not store the recipe")
    parser.add_argument("--ranking-from", type=Path,
                        help="reuse the per-layer damages of an earlier run's JSON (same checkpoint, calibration and "
                             "validation frames; refused otherwise) and only select again")
    args = parser.parse_args(argv)
    if not 0 < args.margin <= 1:
        parser.error(f"--margin must be in (0, 1], got {args.margin}")
    if args.frames < 0 or args.max_layers < 0:
        parser.error("--frames and --max-layers must not be negative")
    return args


def provenance(record: dict[str, Any]) -> dict[str, Any]:
    """What the stored recipe keeps of the sensitivity record that chose it: how, on which frames, its top ranks."""
    kept = {key: record[key] for key in ("command", "calibration", "validation", "margin", "deployed")}
    return {**kept, "ranking_top": [entry["layer"] for entry in record["ranking"][:10]]}


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    args.command = "msfsu-int8-recipe " + shlex.join(sys.argv[1:] if argv is None else list(argv))
    from msfsu_perception.checkpoint import CheckpointError
    from msfsu_perception.int8_recipe import Int8Recipe, RecipeError, write_recipe

    try:
        record = analyse(args)
    except (CheckpointError, RecipeError, ValueError) as error:  # BagError is a ValueError
        print(f"msfsu-int8-recipe: {error}", file=sys.stderr)
        return 1
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.with_suffix(".json").write_text(json.dumps(record, indent=1) + "\n")
        args.out.with_suffix(".md").write_text(report_markdown(record))
    if not args.dry_run:
        print(f"wrote {write_recipe(args.checkpoint, Int8Recipe.from_settings(record['recipe']), provenance(record))}")
    print(report_markdown(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
