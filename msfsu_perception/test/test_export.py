import onnx
import pytest
import torch

from msfsu_perception.checkpoint import load_checkpoint, save_checkpoint
from msfsu_perception.export import NonOverlappingDeconv, check_parity, export_onnx, is_non_overlapping, main
from msfsu_perception.model import MSFSUConfig, build_model
from msfsu_perception.preprocessing import PreprocessConfig


def _trained_like(config):
    torch.manual_seed(0)
    network = build_model(config)
    with torch.no_grad():  # BN statistics away from their initial values
        network(torch.rand(4, config.in_channels, config.input_height, config.input_width), torch.arange(4))
    return network.eval()


@pytest.mark.parametrize(("variant", "layout"), [("msfsu", "v2"), ("msfsu", "v1"), ("msf", "v2")])
def test_onnx_matches_torch_for_every_command_and_a_dynamic_batch(variant, layout, tmp_path):
    network = _trained_like(MSFSUConfig(variant=variant, backbone="resnet18v2", input_height=64, input_width=96,
                                        decoder_layout=layout))
    path = tmp_path / "model.onnx"
    export_onnx(network, path)
    graph = onnx.load(str(path)).graph
    assert [i.name for i in graph.input] == ["inputs", "command_index"]
    expected_outputs = ["steer", "speed"] + (["segmentation_logits"] if variant == "msfsu" else [])
    assert [o.name for o in graph.output] == expected_outputs
    assert check_parity(network, path, batch_size=5) < 1e-4


def test_cli_exports_a_checkpoint(tmp_path, capsys):
    network = _trained_like(MSFSUConfig(variant="su", backbone="resnet18v2", input_height=64, input_width=64))
    save_checkpoint(tmp_path / "best.pt", network, PreprocessConfig(64, 64, use_depth=False))
    main([str(tmp_path / "best.pt"), str(tmp_path / "best.onnx")])
    assert (tmp_path / "best.onnx").is_file() and "max |onnxruntime - torch|" in capsys.readouterr().out


def test_a_checkpoint_from_before_the_decoder_layout_exports_and_matches_torch(tmp_path, legacy_checkpoint):
    path = legacy_checkpoint(MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=96, decoder_layout="v1"))
    network = load_checkpoint(path).model
    assert network.config.decoder_layout == "v1"
    export_onnx(network, tmp_path / "shipped.onnx")
    assert check_parity(network, tmp_path / "shipped.onnx", batch_size=2) < 1e-4


@pytest.mark.parametrize(("stride", "bias"), [(4, True), (2, False)])
def test_a_non_overlapping_deconvolution_is_a_1x1_convolution_and_depth_to_space(stride, bias):
    torch.manual_seed(stride)
    deconv = torch.nn.ConvTranspose2d(6, 5, stride, stride=stride, bias=bias)
    inputs = torch.randn(2, 6, 3, 7)
    torch.testing.assert_close(NonOverlappingDeconv(deconv)(inputs), deconv(inputs), atol=1e-6, rtol=1e-5)


def test_an_overlapping_deconvolution_is_not_rewritten():
    overlapping = torch.nn.ConvTranspose2d(6, 5, 3, stride=4, padding=1, output_padding=3)  # the v1 layout
    assert not is_non_overlapping(overlapping)
    with pytest.raises(ValueError, match="not a non-overlapping"):
        NonOverlappingDeconv(overlapping)


@pytest.mark.parametrize(("layout", "depth_to_space"), [("v2", 1), ("v1", 0)])
def test_only_the_stride_4_v2_layer_is_exported_as_a_1x1_convolution(layout, depth_to_space, tmp_path):
    network = _trained_like(MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=96,
                                        decoder_layout=layout))
    before = {name: tensor.clone() for name, tensor in network.state_dict().items()}
    export_onnx(network, tmp_path / "model.onnx")
    nodes = onnx.load(str(tmp_path / "model.onnx")).graph.node
    assert sum(node.op_type == "DepthToSpace" for node in nodes) == depth_to_space
    assert sum(node.op_type == "ConvTranspose" for node in nodes) == 5 - depth_to_space
    first = next(node for node in nodes if node.input[1:2] == ["network.decoder.layers.0.weight"])
    assert first.op_type == ("Conv" if layout == "v2" else "ConvTranspose")  # same weight name: recipes still apply
    assert isinstance(network.decoder.layers[0], torch.nn.ConvTranspose2d)  # the network itself is untouched
    assert all(torch.equal(before[name], tensor) for name, tensor in network.state_dict().items())


def test_a_network_with_a_stop_output_exports_its_stops_as_speed_0(tmp_path):
    network = _trained_like(MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=64, stop_output=True))
    with torch.no_grad():  # command 0 always says stop, command 1 never
        network.policy.branches[0][-1].bias[2] = 100.0
        network.policy.branches[1][-1].bias[2] = -100.0
    path = tmp_path / "stop.onnx"
    export_onnx(network, path)
    assert [o.name for o in onnx.load(str(path)).graph.output] == ["steer", "speed", "segmentation_logits"]
    assert check_parity(network, path, batch_size=4) < 1e-4
    inputs = torch.rand(2, 4, 64, 64)
    with torch.no_grad():
        speed = network(inputs, torch.tensor([0, 1])).speed
    assert speed[0].item() == 0.0 and speed[1].item() != 0.0
