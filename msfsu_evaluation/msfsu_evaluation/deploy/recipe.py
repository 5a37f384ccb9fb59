"""`msfsu-int8-recipe`: per-layer int8 sensitivity of a checkpoint, and the int8 recipe it leads to.

    msfsu-int8-recipe models/msfsu_default.pt --val-bags 'data/sim/validation/*' --out benchmarks/int8_recipes/cpu

1. The checkpoint's calibration frames (msfsu-calibrate) quantise the whole network once with NNCF, its weights
   left as float constants behind their FakeQuantize, so any layer can be put back in float by bypassing the
   quantisers on its inputs (deploy.quantised_graph; int8_recipe names the layers).
2. Validation frames (training towns: never the held-out gate bags) run through torch fp32 (the reference), the
   all-int8 model, and the all-int8 model with one layer at a time back in float; a layer's sensitivity is the
   damage, in units of the gate's thresholds, that goes away when it alone is float (deploy.sensitivity).
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
from collections.abc import Collection, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from msfsu_common.benchmark_run import load_1min
from msfsu_evaluation.deploy.quantised_graph import layer_macs, quantised_layers, revert_to_float
from msfsu_evaluation.deploy.scoring import (
    HeldOutBag,
    HeldOutPredictions,
    compare,
    describe_held_out,
    load_held_out,
    predict_held_out,
)
from msfsu_evaluation.deploy.sensitivity import (
    Damage,
    SelectionStep,
    damage,
    is_free,
    rank_layers,
    select_keep_float,
    steps_choice,
)
from msfsu_evaluation.metrics import time_calls
from msfsu_evaluation.deploy.recipe_record import SensitivityRecord
from msfsu_perception.deploy_files import DEPLOY_FORMAT_VERSION
from msfsu_perception.gate_verdicts import GateResult

if TYPE_CHECKING:
    from msfsu_perception.deploy_files import CalibrationSet
    from msfsu_perception.int8_recipe import Int8Recipe
    from msfsu_perception.preprocessing import PreprocessConfig

DEFAULT_MARGIN = 0.5  # the validation frames must pass with half of each gate threshold to spare
DEFAULT_MAX_LAYERS = 16
DEFAULT_MAX_STEER_DAMAGE = 1.5
DEFAULT_FRAMES = 400


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


def _latency_ms(model: Any, preprocess: PreprocessConfig, threads: int | None, iterations: int = 30,
                warmup: int = 5) -> float:
    """p50 (ms) of one OpenVINO inference of `model` at batch 1 on random inputs, compiled as the node compiles it."""
    from msfsu_perception.backends import OpenVinoRunner

    runner = OpenVinoRunner(model, "int8", threads, None)
    inputs = np.random.default_rng(0).random((1, preprocess.channels, preprocess.input_height,
                                              preprocess.input_width), dtype=np.float32)
    command = np.zeros(1, np.int64)
    return time_calls(lambda: runner(inputs, command), iterations, warmup).p50_ms


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
    """What the record keeps of a gate result on the validation frames."""
    return {"miou_drop_points": round(result.miou_drop_points, 3), "steer_mae_rise": round(result.steer_mae_rise, 4),
            "reference": asdict(result.reference), "candidate": asdict(result.candidate),
            "steer_agreement_mae": result.steer_agreement_mae, "class_agreement": result.class_agreement}


@dataclass(frozen=True)
class _Int8Network:
    """A checkpoint's exported graph in OpenVINO, float and quantised once with the base recipe (weights left float
    behind their FakeQuantize, so that any quantised layer can go back to float)."""

    onnx_path: Path
    calibration: CalibrationSet
    fp32: Any  # openvino.Model
    quantised: Any  # openvino.Model, every layer int8
    layer_of: dict[str, str]  # OpenVINO friendly name in `quantised` -> layer
    candidates: dict[str, str]  # quantised layer -> OpenVINO op type
    macs: dict[str, int]  # weighted layer -> multiply-accumulates at batch 1

    @classmethod
    def quantise(cls, checkpoint: Path, network: Any, calibration: CalibrationSet,
                 recipe: Int8Recipe) -> _Int8Network:
        """Export `network` (the checkpoint's torch module) and quantise it per `recipe` for experiments."""
        import onnx

        from msfsu_perception.backends import nncf_quantize, onnx_fp32, openvino_core
        from msfsu_perception.deploy_files import DeployFiles
        from msfsu_perception.int8_recipe import graph_layers, openvino_layer_names

        onnx_path = onnx_fp32(DeployFiles(checkpoint), network)
        layers = graph_layers(onnx.load(str(onnx_path)))
        fp32 = openvino_core().read_model(str(onnx_path))
        quantised = nncf_quantize(fp32, calibration, recipe, onnx_path, compress_weights=False)
        layer_of = openvino_layer_names(quantised, layers)
        return cls(onnx_path, calibration, fp32, quantised, layer_of, quantised_layers(quantised, layer_of),
                   layer_macs(fp32, openvino_layer_names(fp32, layers)))

    def mac_share(self, layers: Iterable[str]) -> float:
        """Share of the network's multiply-accumulates in `layers` (0 for unweighted layers)."""
        return sum(self.macs.get(layer, 0) for layer in layers) / sum(self.macs.values())

    def with_float(self, layers: Collection[str]) -> Any:
        """The all-int8 model with `layers` back in float."""
        return revert_to_float(self.quantised, self.layer_of, layers)

    def build(self, recipe: Int8Recipe) -> Any:
        """The model `recipe` deploys as: NNCF-built (ignored_scope), weights compressed."""
        from msfsu_perception.backends import nncf_quantize

        return nncf_quantize(self.fp32, self.calibration, recipe, self.onnx_path)


def _calibration_frames(checkpoint: Path) -> CalibrationSet:
    """The checkpoint's calibration frames; ValueError when msfsu-calibrate has not written them."""
    from msfsu_perception.deploy_files import CalibrationSet, calibration_path

    calibration = CalibrationSet.for_checkpoint(checkpoint)
    if calibration is None:
        raise ValueError(f"{calibration_path(checkpoint)} is missing: write it first (msfsu-calibrate)")
    return calibration


def _validation_frames(val_bags: Sequence[str], frames: int, preprocess: PreprocessConfig,
                       cache_dir: Path) -> list[HeldOutBag]:
    """`frames` frames in all (0: every frame), spread evenly over the bags of `val_bags` (paths or globs)."""
    from msfsu_perception.bag_topics import BagTopics
    from msfsu_perception.bag_paths import expand_bag_paths

    bags = expand_bag_paths(val_bags)
    frames_per_bag = max(1, math.ceil(frames / len(bags))) if frames else None
    held_out = load_held_out(bags, BagTopics(), preprocess, cache_dir, frames_per_bag)
    print(f"validation: {sum(len(b) for b in held_out)} frames of {len(held_out)} bags", flush=True)
    return held_out


def _damage_when_float(network: _Int8Network, evaluator: _Evaluator,
                       measured: dict[str, Damage]) -> dict[str, Damage]:
    """Damage of the all-int8 model with each quantised layer alone in float; a layer in `measured` (an earlier
    run's) is not scored again."""
    when_float = dict(measured)
    for position, layer in enumerate(network.candidates, 1):
        if layer not in when_float:
            when_float[layer], _ = evaluator.score(network.with_float([layer]))
        print(f"  [{position}/{len(network.candidates)}] {layer}: damage {when_float[layer].total:.2f}", flush=True)
    return when_float


def _step_line(step: SelectionStep) -> str:
    return (f"  float {', '.join(step.keep_float) or '-'}: damage {step.damage.total:.2f}, mIoU drop "
            f"{step.result.miou_drop_points:.2f}, steer MAE rise {step.result.steer_mae_rise:+.1%}"
            f"{'' if step.accepted else ' (not kept)'}{' (passes with margin)' if step.passed else ''}")


def _latencies(network: _Int8Network, base_recipe: Int8Recipe, deployed: Any, preprocess: PreprocessConfig,
               threads: int | None) -> dict[str, float]:
    """p50 (ms) of the all-int8 model and of the recipe's, both as they deploy, and the load they ran under."""
    all_int8 = network.build(base_recipe)
    return {"load_average_1min": load_1min(),
            "all_int8_ms": round(_latency_ms(all_int8, preprocess, threads), 2),
            "recipe_ms": round(_latency_ms(deployed, preprocess, threads), 2)}


def analyse(args: argparse.Namespace) -> dict[str, Any]:
    """The sensitivity record of args.checkpoint: steps 1-3 of the module docstring, recipe not stored."""
    from msfsu_perception.checkpoint import load_checkpoint
    from msfsu_perception.deploy_files import file_digest
    from msfsu_perception.int8_recipe import Int8Recipe

    loaded = load_checkpoint(args.checkpoint)
    calibration = _calibration_frames(args.checkpoint)
    held_out = _validation_frames(args.val_bags, args.frames, loaded.preprocess, args.cache_dir)
    evaluator = _Evaluator(args.checkpoint, held_out, args.threads)
    base_recipe = Int8Recipe(preset=args.preset, fast_bias_correction=args.fast_bias_correction)
    network = _Int8Network.quantise(args.checkpoint, loaded.model, calibration, base_recipe)
    checkpoint_digest, validation = file_digest(args.checkpoint), describe_held_out(held_out)

    all_int8, all_int8_gate = evaluator.score(network.quantised)
    print(f"all int8: damage {all_int8.total:.2f} (segmentation {all_int8.segmentation:.2f}, steer "
          f"{all_int8.steer:.2f}); validation mIoU drop {all_int8_gate.miou_drop_points:.2f} points, steer MAE rise "
          f"{all_int8_gate.steer_mae_rise:+.1%}; {len(network.candidates)} quantised layers", flush=True)
    measured = earlier_ranking(args.ranking_from, checkpoint_digest, calibration.digest, validation,
                               set(network.candidates)) if args.ranking_from else {}
    ranking = rank_layers(all_int8, _damage_when_float(network, evaluator, measured), network.candidates,
                          {layer: network.mac_share([layer]) for layer in network.macs})
    steps = select_keep_float([s.layer for s in ranking if s.recovered > 0],
                              lambda keep: evaluator.score(network.with_float(keep)), args.margin, args.max_layers,
                              [s.layer for s in ranking if is_free(s)], args.max_steer_damage)
    for step in steps:
        print(_step_line(step), flush=True)
    chosen = Int8Recipe(steps_choice(steps).keep_float, args.preset, args.fast_bias_correction)
    deployed = network.build(chosen)
    deployed_damage, deployed_gate = evaluator.score(deployed)
    latency = _latencies(network, base_recipe, deployed, loaded.preprocess, args.threads)
    print(f"recipe ({len(chosen.keep_float)} layers float), NNCF-built: damage {deployed_damage.total:.2f}, mIoU "
          f"drop {deployed_gate.miou_drop_points:.2f}, steer MAE rise {deployed_gate.steer_mae_rise:+.1%}; "
          f"p50 {latency['recipe_ms']} ms vs all int8 {latency['all_int8_ms']} ms", flush=True)
    return {
        "checkpoint": str(args.checkpoint),
        "checkpoint_digest": checkpoint_digest,
        "deploy_format": DEPLOY_FORMAT_VERSION,  # the exported graph the damages were measured on
        "command": args.command,
        "calibration": {"digest": calibration.digest, "frames": len(calibration)},
        "validation": validation,
        "margin": args.margin,
        "max_layers": args.max_layers,
        "max_steer_damage": args.max_steer_damage,
        "all_int8": {"damage": asdict(all_int8), "validation_gate": _gate_summary(all_int8_gate)},
        "ranking": [{**asdict(s), "damage_when_float": asdict(s.damage_when_float)} for s in ranking],
        "selection": [{"keep_float": list(s.keep_float), "damage": asdict(s.damage), "accepted": s.accepted,
                       "passed_with_margin": s.passed, "validation_gate": _gate_summary(s.result)} for s in steps],
        "recipe": chosen.settings(),
        "recipe_digest": chosen.digest,
        "recipe_float_mac_share": network.mac_share(chosen.keep_float),
        "deployed": {"damage": asdict(deployed_damage), "validation_gate": _gate_summary(deployed_gate)},
        "latency": latency,
    }


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
    sensitivity = SensitivityRecord.from_dict(record)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.with_suffix(".json").write_text(sensitivity.to_json())
        args.out.with_suffix(".md").write_text(sensitivity.page())
    if not args.dry_run:
        print(f"wrote {write_recipe(args.checkpoint, Int8Recipe.from_settings(record['recipe']), provenance(record))}")
    print(sensitivity.page())
    return 0


if __name__ == "__main__":
    sys.exit(main())
