"""int8 recipes: layer names from the exported graph, the ignored scope / excluded nodes they become, the file
beside the checkpoint, and an int8 model that really leaves the recipe's layers in float."""

import json

import numpy as np
import onnx
import pytest

from msfsu_perception.backends import onnx_fp32, int8_build, is_installed
from msfsu_perception.checkpoint import load_checkpoint
from msfsu_perception.deploy_files import DeployFiles, calibration_path
from msfsu_perception.inference import DrivingModel
from msfsu_perception.int8_recipe import (
    Int8Recipe,
    RecipeError,
    graph_layers,
    load_recipe,
    onnx_nodes_to_exclude,
    openvino_ignored_names,
    openvino_layer_names,
    write_recipe,
)

SIZE = 64


@pytest.fixture(scope="module")
def exported(tiny_checkpoint):
    """(checkpoint, its fp32 ONNX file, the layers of that graph)."""
    onnx_path = onnx_fp32(DeployFiles(tiny_checkpoint), load_checkpoint(tiny_checkpoint).model)
    return tiny_checkpoint, onnx_path, graph_layers(onnx.load(str(onnx_path)))


def test_layers_are_named_after_their_weights_or_module_scope_and_are_unique(exported):
    _, _, layers = exported
    names = {layer.name: layer for layer in layers}
    assert len(names) == len(layers)
    assert names["encoder.stem.0"].op_type == "Conv" and names["encoder.stem.0"].weight == "network.encoder.stem.0.weight"
    assert names["decoder.layers.0"].op_type == "Conv"  # stride 4: exported as a 1x1 convolution + depth-to-space
    assert names["decoder.layers.0:DepthToSpace"].weight is None
    assert names["decoder.layers.3"].op_type == "ConvTranspose"
    assert names["decoder.layers.12"].op_type == "ConvTranspose"  # the last one: the class logits
    assert names["policy.branches.3.6"].op_type == "Gemm"  # the steer/speed output of the 4th command's branch
    assert names["encoder.stages.1.0:Add"].weight is None  # a residual addition of the second stage
    assert names["encoder.stem.1:MaxPool"].op_type == "MaxPool"


def test_the_ignored_scope_names_the_openvino_ops_of_the_kept_layers(exported):
    import openvino

    _, onnx_path, layers = exported
    model = openvino.Core().read_model(str(onnx_path))
    recipe = Int8Recipe(keep_float=("decoder.layers.3", "encoder.stages.1.0:Add"))
    ignored = openvino_ignored_names(model, layers, recipe)
    ops = {op.get_friendly_name(): op for op in model.get_ordered_ops()}
    assert sorted(ops[name].get_type_name() for name in ignored) == ["Add", "ConvolutionBackpropData"]
    deconvolution = next(ops[name] for name in ignored if ops[name].get_type_name() == "ConvolutionBackpropData")
    assert deconvolution.input(1).get_source_output().get_node().get_friendly_name() == "network.decoder.layers.3.weight"
    assert set(openvino_layer_names(model, layers).values()) >= {"decoder.layers.0", "encoder.stages.1.0:Add"}


def test_onnx_runtime_excludes_the_onnx_nodes_of_the_kept_layers(exported):
    _, _, layers = exported
    excluded = onnx_nodes_to_exclude(layers, Int8Recipe(keep_float=("encoder.stem.0",)))
    assert excluded == [next(layer.onnx_node for layer in layers if layer.name == "encoder.stem.0")]


def test_a_recipe_naming_a_layer_the_graph_lacks_is_refused(exported):
    import openvino

    _, onnx_path, layers = exported
    recipe = Int8Recipe(keep_float=("decoder.layers.99",))
    with pytest.raises(RecipeError, match="keeps decoder.layers.99 in float, but the ONNX graph has no such layer"):
        onnx_nodes_to_exclude(layers, recipe)
    with pytest.raises(RecipeError, match="the OpenVINO model has no such layer"):
        openvino_ignored_names(openvino.Core().read_model(str(onnx_path)), layers, recipe)


def test_the_recipe_digest_follows_its_settings_not_their_order():
    assert Int8Recipe(("b", "a")).digest == Int8Recipe(("a", "b", "a")).digest
    assert Int8Recipe(("a",)).digest != Int8Recipe(("a", "b")).digest
    assert Int8Recipe(("a",)).digest != Int8Recipe(("a",), preset="mixed").digest
    with pytest.raises(RecipeError, match="unknown NNCF preset"):
        Int8Recipe(preset="fast")


def test_the_recipe_file_round_trips_and_a_damaged_one_is_refused(tmp_path, tiny_checkpoint):
    checkpoint = tmp_path / "model.pt"
    checkpoint.write_bytes(tiny_checkpoint.read_bytes())
    assert load_recipe(checkpoint) == Int8Recipe()  # none stored: every layer int8
    recipe = Int8Recipe(("decoder.layers.0",), "mixed", fast_bias_correction=False)
    path = write_recipe(checkpoint, recipe, {"command": "msfsu-int8-recipe ..."})
    assert path == DeployFiles(checkpoint).int8_recipe and load_recipe(checkpoint) == recipe
    assert json.loads(path.read_text())["digest"] == recipe.digest
    path.write_text("{not json")
    with pytest.raises(RecipeError, match="is not an int8 recipe"):
        load_recipe(checkpoint)


@pytest.mark.skipif(not is_installed("openvino"), reason="openvino is not installed")
def test_the_int8_model_leaves_the_recipe_layers_in_float_and_names_its_build(tmp_path, tiny_checkpoint):
    import openvino

    checkpoint = tmp_path / "model.pt"
    checkpoint.write_bytes(tiny_checkpoint.read_bytes())
    rng = np.random.default_rng(0)
    np.savez(calibration_path(checkpoint), rgb=rng.integers(0, 256, (8, 3, SIZE, SIZE), np.uint8),
             depth=rng.random((8, 1, SIZE, SIZE)).astype(np.float16), command_index=np.arange(8) % 4)
    recipe = Int8Recipe(keep_float=("decoder.layers.12", "encoder.stem.0"))
    write_recipe(checkpoint, recipe, {})
    model = DrivingModel.from_checkpoint(checkpoint, 1, "openvino", "int8")
    assert model.precision == "int8"
    [ir] = DeployFiles(checkpoint).directory.glob(f"*-int8-*-{recipe.digest}.xml")
    core = openvino.Core()
    onnx_path = next(ir.parent.glob("*fp32.onnx"))
    # op names survive quantisation, weight names do not (int8 weights): name the ops on the float model
    names = openvino_layer_names(core.read_model(str(onnx_path)), graph_layers(onnx.load(str(onnx_path))))
    quantised = core.read_model(str(ir))
    fed_by_fake_quantize = {names.get(op.get_friendly_name()) for op in quantised.get_ordered_ops()
                            if op.get_type_name() != "FakeQuantize" and any(
                                port.get_source_output().get_node().get_type_name() == "FakeQuantize"
                                for port in op.inputs())}
    assert "encoder.stages.0.0.conv1" in fed_by_fake_quantize  # the rest is int8
    assert not fed_by_fake_quantize & set(recipe.keep_float)
    build = int8_build(checkpoint)
    assert (build.recipe, build.keep_float) == (recipe.digest, recipe.keep_float)
