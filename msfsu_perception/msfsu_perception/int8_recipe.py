"""How the int8 model of a checkpoint is made: which layers stay in float, and how NNCF / ONNX Runtime are told.

A *layer* is one operation of the exported graph (export.py) that post-training quantisation can put quantisers
in front of, named so that a person can find it in model.py and so that the name survives the exporters:

    encoder.stem.0, encoder.stages.3.1.conv2, decoder.layers.12, policy.branches.0.0   weighted: the weight's name
    encoder.stages.1.0:Add, encoder.stages.2.0.norm1:BatchNormalization                 others: module scope:op type

`Int8Recipe.keep_float` lists the layers that stay in float (fp32 at run time): NNCF's `ignored_scope` for
OpenVINO (resolved to the OpenVINO operations of those layers) and `nodes_to_exclude` for ONNX Runtime (the ONNX
nodes). The recipe of a checkpoint lives beside its gate verdicts (deploy_files.DeployFiles.int8_recipe), is
chosen by per-layer sensitivity on validation frames (`msfsu-int8-recipe`, msfsu_evaluation.deploy.recipe)
and is part of what the gate verdict of int8 was measured with; without a recipe file every layer is quantised.
"""

from __future__ import annotations

import ast
import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from msfsu_perception.deploy_files import DeployFiles

RECIPE_FORMAT = 1
# ONNX operations whose second input is a weight (quantised per output channel)
ONNX_WEIGHTED = frozenset({"Conv", "ConvTranspose", "Gemm", "MatMul"})
# The same operations as OpenVINO's ONNX frontend builds them
OPENVINO_WEIGHTED = frozenset({"Convolution", "GroupConvolution", "ConvolutionBackpropData", "MatMul"})
# Operations between a weight constant and its consumer: FakeQuantize of weights kept as float constants
# (nncf_quantize(compress_weights=False)), Convert of fp16 weights
_WEIGHT_PATH = frozenset({"FakeQuantize", "Convert", "Reshape", "Transpose"})
TORCH_WRAPPER_PREFIX = "network."  # export.TensorOutputs keeps the MSFSUNet as `.network`


class RecipeError(ValueError):
    """A recipe that does not fit the graph (a layer it names is not there) or a malformed recipe file."""


@dataclass(frozen=True)
class GraphLayer:
    name: str  # stable label (see the module docstring)
    onnx_node: str  # node name in the exported ONNX graph
    op_type: str  # ONNX op type
    weight: str | None  # initializer name of the weight, weighted layers only


@dataclass(frozen=True)
class Int8Recipe:
    """Post-training quantisation settings of one checkpoint (NNCF defaults when nothing is kept in float)."""

    keep_float: tuple[str, ...] = ()  # layer names left unquantised
    preset: Literal["performance", "mixed"] = "performance"  # NNCF: symmetric / asymmetric activations
    fast_bias_correction: bool = True

    def __post_init__(self) -> None:
        if self.preset not in ("performance", "mixed"):
            raise RecipeError(f"unknown NNCF preset {self.preset!r} (performance or mixed)")
        object.__setattr__(self, "keep_float", tuple(sorted(set(self.keep_float))))

    @property
    def digest(self) -> str:
        """Content hash of the settings (part of the int8 model's file name and of its gate verdict)."""
        canonical = json.dumps(self.settings(), sort_keys=True)
        return hashlib.sha256(canonical.encode()).hexdigest()[:16]

    def settings(self) -> dict[str, Any]:
        return {"keep_float": list(self.keep_float), "preset": self.preset,
                "fast_bias_correction": self.fast_bias_correction}

    @classmethod
    def from_settings(cls, settings: dict[str, Any]) -> Int8Recipe:
        try:
            return cls(tuple(settings["keep_float"]), settings["preset"], bool(settings["fast_bias_correction"]))
        except (KeyError, TypeError) as error:
            raise RecipeError(f"malformed int8 recipe settings {settings!r}: {error}") from None


def load_recipe(checkpoint: Path) -> Int8Recipe:
    """The recipe stored for this checkpoint's content, or NNCF's defaults (every layer int8) when none is."""
    path = DeployFiles(checkpoint).int8_recipe
    if not path.is_file():
        return Int8Recipe()
    try:
        stored = json.loads(path.read_text())
        return Int8Recipe.from_settings(stored["settings"])
    except (json.JSONDecodeError, KeyError, TypeError) as error:
        raise RecipeError(f"{path} is not an int8 recipe ({error}): delete it or write it again "
                          "(msfsu-int8-recipe)") from None


def write_recipe(checkpoint: Path, recipe: Int8Recipe, provenance: dict[str, Any]) -> Path:
    """Store `recipe` for this checkpoint's content; `provenance` says how it was chosen (kept with it)."""
    path = DeployFiles(checkpoint).int8_recipe
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"format": RECIPE_FORMAT, "digest": recipe.digest, "settings": recipe.settings(),
              "provenance": provenance}
    temporary = path.with_name(f".{path.name}.partial")
    temporary.write_text(json.dumps(record, indent=1) + "\n")
    temporary.replace(path)
    return path


# --- layer names ---------------------------------------------------------------------------------------
def _module_path(name: str) -> str:
    return name.removeprefix(TORCH_WRAPPER_PREFIX)


def _scope(node: Any) -> str | None:
    """Deepest torch module the exporter recorded for an ONNX node (`pkg.torch.onnx.name_scopes`)."""
    metadata = {prop.key: prop.value for prop in node.metadata_props}
    raw = metadata.get("pkg.torch.onnx.name_scopes")
    if raw is None:
        return None
    try:
        scopes = ast.literal_eval(raw)  # ['', 'network', 'network.encoder', ..., '<fx node name>']
    except (ValueError, SyntaxError):
        return None
    modules = [scope for scope in scopes[:-1] if scope]
    return _module_path(modules[-1]) if modules else None


def graph_layers(onnx_model: Any) -> list[GraphLayer]:
    """Every node of an ONNX model (onnx.ModelProto) with its stable layer name, in graph order.

    Weighted nodes are named after their weight (`network.encoder.stem.0.weight` -> `encoder.stem.0`), others
    `<module scope>:<op type>`; a name that would repeat (or a node without scope) gets its ONNX node name.
    """
    initializers = {initializer.name for initializer in onnx_model.graph.initializer}
    candidates: list[tuple[str, Any, str | None]] = []
    for node in onnx_model.graph.node:
        weight = None
        if node.op_type in ONNX_WEIGHTED and len(node.input) > 1 and node.input[1] in initializers:
            weight = node.input[1]
        if weight is not None:
            name = _module_path(weight.removesuffix(".weight"))
        else:
            scope = _scope(node)
            name = f"{scope}:{node.op_type}" if scope else node.name
        candidates.append((name, node, weight))
    counts: dict[str, int] = {}
    for name, _, _ in candidates:
        counts[name] = counts.get(name, 0) + 1
    return [GraphLayer(name if counts[name] == 1 else node.name, node.name, node.op_type, weight)
            for name, node, weight in candidates]


def _weight_constant(op: Any) -> str | None:
    """Friendly name of the Constant feeding input 1 of an OpenVINO weighted op (through dequantisation)."""
    if op.get_type_name() not in OPENVINO_WEIGHTED or op.get_input_size() < 2:
        return None
    node = op.input(1).get_source_output().get_node()
    for _ in range(6):
        if node.get_type_name() == "Constant":
            return node.get_friendly_name()
        if node.get_type_name() not in _WEIGHT_PATH:
            return None
        node = node.input(0).get_source_output().get_node()
    return None


def openvino_layer_names(ov_model: Any, layers: list[GraphLayer]) -> dict[str, str]:
    """{OpenVINO op friendly name: layer name} for the ops of `ov_model` (read from the ONNX of `layers`).

    The model must still have its float weights (as read, or quantised with compress_weights=False): int8
    weights lose their names. Op names survive quantisation, so the map also names a deployed int8 model's ops.
    """
    by_weight = {layer.weight: layer.name for layer in layers if layer.weight is not None}
    by_node = {layer.onnx_node: layer.name for layer in layers}
    names = {}
    for op in ov_model.get_ordered_ops():
        weight = _weight_constant(op)
        name = by_weight.get(weight) if weight is not None else by_node.get(op.get_friendly_name())
        if name is not None:
            names[op.get_friendly_name()] = name
    return names


def _check_known(keep_float: tuple[str, ...], known: set[str], where: str) -> None:
    unknown = [name for name in keep_float if name not in known]
    if unknown:
        raise RecipeError(f"the int8 recipe keeps {', '.join(unknown)} in float, but {where} has no such layer "
                          "(was the network changed? write the recipe again: msfsu-int8-recipe)")


def openvino_ignored_names(ov_model: Any, layers: list[GraphLayer], recipe: Int8Recipe) -> list[str]:
    """OpenVINO op names for NNCF's IgnoredScope(names=...): every op of the layers the recipe keeps in float."""
    names = openvino_layer_names(ov_model, layers)
    _check_known(recipe.keep_float, set(names.values()), "the OpenVINO model")
    keep = set(recipe.keep_float)
    return sorted(op for op, layer in names.items() if layer in keep)


def onnx_nodes_to_exclude(layers: list[GraphLayer], recipe: Int8Recipe) -> list[str]:
    """ONNX node names for ONNX Runtime's quantize_static(nodes_to_exclude=...)."""
    _check_known(recipe.keep_float, {layer.name for layer in layers}, "the ONNX graph")
    keep = set(recipe.keep_float)
    return [layer.onnx_node for layer in layers if layer.name in keep]


@dataclass(frozen=True)
class Int8Build:
    """What an int8 model is made from besides the checkpoint: recorded with its gate verdict."""

    calibration: str  # digest of <checkpoint>.calibration.npz
    recipe: str  # Int8Recipe.digest
    keep_float: tuple[str, ...] = field(default=())  # for the reader of the verdict

    def matches(self, other: dict[str, Any] | None) -> bool:
        return bool(other) and other.get("calibration") == self.calibration and other.get("recipe") == self.recipe

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "keep_float": list(self.keep_float)}
