from dataclasses import replace

import pytest
import torch
from torch import nn

from msfsu_perception.checkpoint import load_checkpoint, save_checkpoint
from msfsu_perception.model import ENCODER_STRIDE, PAPER_DECODER_FILTERS, MSFSUConfig, build_model, load_warm_start
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_perception.training_settings import PRESETS, RELEASE_LIMIT_MB

LAYOUTS = ["v1", "v2"]


@pytest.mark.parametrize("backbone", ["resnet18v2", "resnet34v2", "resnet50v2"])
@pytest.mark.parametrize("variant", ["msfsu", "msf", "su"])
@pytest.mark.parametrize("size", [(64, 96), (96, 64)])
@pytest.mark.parametrize("layout", LAYOUTS)
def test_output_shapes_for_every_variant_backbone_size_and_decoder_layout(backbone, variant, size, layout):
    config = MSFSUConfig(variant=variant, backbone=backbone, input_height=size[0], input_width=size[1],
                         decoder_layout=layout)
    model = build_model(config).eval()
    x = torch.rand(2, 3 if variant == "su" else 4, *size)
    with torch.no_grad():
        output = model(x, torch.tensor([0, 3]))
    assert output.steer.shape == (2,) and output.speed.shape == (2,)
    if variant == "msf":
        assert output.segmentation_logits is None
    else:
        assert output.segmentation_logits.shape == (2, 5, *size)


@pytest.mark.parametrize(("backbone", "channels"), [("resnet18v2", 512), ("resnet50v2", 2048)])
def test_encoder_gives_features_at_stride_32(backbone, channels):
    model = build_model(MSFSUConfig(backbone=backbone, input_height=224, input_width=224)).eval()
    with torch.no_grad():
        assert model.encoder(torch.rand(1, 4, 224, 224)).shape == (1, channels, 7, 7)


def _deconvs(decoder: nn.Module) -> list[nn.ConvTranspose2d]:
    return [layer for layer in decoder.layers if isinstance(layer, nn.ConvTranspose2d)]


@pytest.mark.parametrize(("layout", "kernels", "paddings", "output_paddings"), [
    ("v1", (3, 3, 3, 3, 3), (1, 1, 1, 1, 1), (3, 1, 1, 1, 0)),  # the paper's kernel 3 (shipped checkpoints)
    ("v2", (4, 2, 2, 2, 3), (0, 0, 0, 0, 1), (0, 0, 0, 0, 0)),  # kernel = stride, then a 3x3 "same" layer
])
def test_decoder_is_the_papers_five_transposed_convolutions(layout, kernels, paddings, output_paddings):
    config = MSFSUConfig(backbone="resnet50v2", input_height=224, input_width=224, decoder_layout=layout)
    decoder = build_model(config).decoder  # the paper's
    deconvs = _deconvs(decoder)
    assert [(d.out_channels, d.stride[0]) for d in deconvs] == [(512, 4), (128, 2), (64, 2), (16, 2), (5, 1)]
    assert [d.kernel_size for d in deconvs] == [(k, k) for k in kernels]
    assert [d.padding for d in deconvs] == [(p, p) for p in paddings]
    assert [d.output_padding for d in deconvs] == [(p, p) for p in output_paddings]
    assert deconvs[0].in_channels == 2048
    expected_types = [nn.ConvTranspose2d, nn.BatchNorm2d, nn.ReLU] * 4 + [nn.ConvTranspose2d]
    assert [type(layer) for layer in decoder.layers] == expected_types


def tap_counts(layer: nn.ConvTranspose2d, size: int) -> torch.Tensor:
    """How many input positions reach each output position of `layer` on a size x size map: the layer's
    geometry with one channel, all-ones weights and no bias, run on an all-ones input."""
    probe = nn.ConvTranspose2d(1, 1, layer.kernel_size, layer.stride, layer.padding, layer.output_padding, bias=False)
    nn.init.ones_(probe.weight)
    with torch.no_grad():
        return probe(torch.ones(1, 1, size, size))[0, 0].round().long()


def reached_alike(layer: nn.ConvTranspose2d, size: int) -> bool:
    """Every output position is reached by as many input taps as every other one; a stride-1 layer may
    have the zero-padding border of an ordinary "same" convolution, if it is the same on all four sides."""
    counts = tap_counts(layer, size)
    ring = layer.padding[0] if layer.stride[0] == 1 else 0
    inner = counts[ring : counts.shape[0] - ring, ring : counts.shape[1] - ring]
    no_side_special = torch.equal(counts, counts.flip(0)) and torch.equal(counts, counts.flip(1))
    return bool((inner == inner[0, 0]).all()) and no_side_special


def _layers_with_input_sizes(config: MSFSUConfig) -> list[tuple[nn.ConvTranspose2d, int]]:
    """Each decoder layer and the (square) size of the map it gets at the config's input size."""
    size, layers = config.input_height // ENCODER_STRIDE, []
    for layer in _deconvs(build_model(config).decoder):
        layers.append((layer, size))
        size *= layer.stride[0]
    return layers


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_every_output_position_of_every_v2_decoder_layer_is_reached_alike(preset):
    config = PRESETS[preset].model_config("msfsu", "v2")
    layers = _layers_with_input_sizes(config)
    for layer, size in layers:
        assert reached_alike(layer, size), f"{layer} on {size}x{size}:\n{tap_counts(layer, size)}"
    for layer, size in layers[:-1]:  # upsampling: exactly one input pixel per output pixel, no hole, no overlap
        assert torch.equal(tap_counts(layer, size), torch.ones(size * layer.stride[0], size * layer.stride[0],
                                                              dtype=torch.long))
    last, size = layers[-1]  # the 3x3 "same" layer: 9 taps inside, 6 on an edge, 4 in a corner
    along_one_axis = torch.tensor([2] + [3] * (size - 2) + [2])
    assert torch.equal(tap_counts(last, size), along_one_axis[:, None] * along_one_axis[None, :])


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_every_upsampling_layer_of_the_v1_decoder_fails_the_same_check(preset):
    config = PRESETS[preset].model_config("msfsu", "v1")
    layers = _layers_with_input_sizes(config)
    assert [reached_alike(layer, size) for layer, size in layers] == [False, False, False, False, True]


def test_v1_stride_4_layer_leaves_the_last_two_of_16_columns_to_the_bias():
    config = MSFSUConfig(backbone="resnet18v2", input_height=128, input_width=128, decoder_layout="v1")
    first, size = _layers_with_input_sizes(config)[0]
    assert size == 4
    assert tap_counts(first, size)[0].tolist() == [1, 1, 0, 1, 1, 1, 0, 1, 1, 1, 0, 1, 1, 1, 0, 0]
    assert tap_counts(first, size)[:, 0].tolist() == [1, 1, 0, 1, 1, 1, 0, 1, 1, 1, 0, 1, 1, 1, 0, 0]


def _decoder_logits_of_constant_features(layout: str) -> torch.Tensor:
    """(5, 128, 128) logits of the cpu preset's decoder with trained-like random weights (biases and
    BN statistics away from zero) for a spatially constant 4x4 feature map."""
    torch.manual_seed(0)
    config = MSFSUConfig(backbone="resnet18v2", input_height=128, input_width=128, decoder_layout=layout)
    decoder = build_model(config).decoder.eval()
    with torch.no_grad():
        for module in decoder.modules():
            if isinstance(module, nn.ConvTranspose2d):
                module.bias.normal_(0.0, 0.1)
            elif isinstance(module, nn.BatchNorm2d):
                module.running_mean.normal_(0.0, 0.1)
                module.running_var.uniform_(0.5, 2.0)
                module.bias.normal_(0.0, 0.1)
        features = torch.rand(1, 512, 1, 1).expand(1, 512, 4, 4)
        return decoder(features)[0]


def _columns_unlike_one_period_before(logits: torch.Tensor, period: int) -> list[int]:
    """Columns x (off the 1-pixel border ring) whose logits differ from column x - period's."""
    inner = logits[:, 1:-1, :]
    return [x for x in range(period + 1, logits.shape[2] - 1)
            if not torch.allclose(inner[:, :, x], inner[:, :, x - period], rtol=1e-4, atol=1e-5)]


def test_v2_decoder_output_of_constant_features_repeats_up_to_the_border():
    """No border band: every 32x32 tile (the product of the strides) is the same, also the last one."""
    logits = _decoder_logits_of_constant_features("v2")
    assert _columns_unlike_one_period_before(logits, 32) == []
    assert _columns_unlike_one_period_before(logits.transpose(1, 2), 32) == []  # rows
    class_ids = logits.argmax(0)[1:-1, 1:-1]
    assert torch.equal(class_ids[:, :-32], class_ids[:, 32:]) and torch.equal(class_ids[:-32], class_ids[32:])
    assert logits[:, 1:-1, 1:-1].std(dim=(1, 2)).min() > 0  # not trivially constant


def test_v1_decoder_output_of_constant_features_has_a_band_at_the_right_and_bottom():
    """The tiles repeat up to the last 16 columns and rows (the dead 2 of 16 after the stride-4 layer)."""
    logits = _decoder_logits_of_constant_features("v1")
    assert _columns_unlike_one_period_before(logits, 32) == list(range(112, 127))
    assert _columns_unlike_one_period_before(logits.transpose(1, 2), 32) == list(range(112, 127))  # rows


@pytest.mark.parametrize("preset", sorted(PRESETS))
@pytest.mark.parametrize("layout", LAYOUTS)
def test_network_output_has_the_input_size_for_every_preset(preset, layout):
    values = PRESETS[preset]
    config = values.model_config("msfsu", layout)
    with torch.no_grad():
        output = build_model(config).eval()(torch.rand(1, 4, values.input_height, values.input_width),
                                            torch.tensor([0]))
    assert output.segmentation_logits.shape == (1, 5, values.input_height, values.input_width)


def test_stem_takes_rgbd_for_msfsu_and_rgb_for_su():
    assert build_model(MSFSUConfig(variant="msfsu", backbone="resnet18v2")).encoder.stem[0].in_channels == 4
    assert build_model(MSFSUConfig(variant="su", backbone="resnet18v2")).encoder.stem[0].in_channels == 3


def test_command_selects_its_own_branch():
    model = build_model(MSFSUConfig(variant="msf", backbone="resnet18v2", input_height=64, input_width=64)).eval()
    x = torch.rand(1, 4, 64, 64).repeat(4, 1, 1, 1)
    with torch.no_grad():
        mixed = model(x, torch.arange(4))
        latent = model.pool(model.encoder(x[:1])).flatten(1)
        for command in range(4):
            expected = model.policy.branches[command](latent)[0]
            assert torch.allclose(mixed.steer[command], expected[0], atol=1e-6)
            assert torch.allclose(mixed.speed[command], expected[1], atol=1e-6)
    assert not torch.allclose(mixed.steer[0], mixed.steer[1])


def test_policy_branches_have_relu_and_dropout_half_on_hidden_layers():
    branch = build_model(MSFSUConfig(backbone="resnet18v2")).policy.branches[0]
    kinds = [type(layer) for layer in branch]
    assert kinds == [nn.Linear, nn.ReLU, nn.Dropout, nn.Linear, nn.ReLU, nn.Dropout, nn.Linear]
    assert all(layer.p == 0.5 for layer in branch if isinstance(layer, nn.Dropout))
    assert branch[-1].out_features == 2


def test_config_rejects_sizes_the_decoder_cannot_restore():
    with pytest.raises(ValueError, match="multiple of 32"):
        MSFSUConfig(input_height=100)
    with pytest.raises(ValueError, match="unknown variant"):
        MSFSUConfig(variant="rgbd")


@pytest.mark.parametrize("layout", LAYOUTS)
def test_config_round_trips_through_a_dict(layout):
    config = MSFSUConfig(variant="su", backbone="resnet34v2", input_height=96, policy_hidden=(128,),
                         decoder_layout=layout)
    assert MSFSUConfig.from_dict(config.to_dict()) == config


def test_new_configs_get_the_v2_decoder_and_stored_ones_without_a_layout_the_v1():
    assert MSFSUConfig().decoder_layout == "v2"
    stored_before_the_field = {key: value for key, value in MSFSUConfig().to_dict().items() if key != "decoder_layout"}
    assert MSFSUConfig.from_dict(stored_before_the_field).decoder_layout == "v1"
    with pytest.raises(ValueError, match="unknown decoder layout"):
        MSFSUConfig(decoder_layout="keras")


@pytest.mark.parametrize("variant", ["msfsu", "msf", "su"])
def test_a_release_of_every_cpu_preset_variant_fits_the_shipping_limit(tmp_path, variant):
    config = PRESETS["cpu"].model_config(variant)
    path = tmp_path / "release.pt"
    save_checkpoint(path, build_model(config), PreprocessConfig(config.input_height, config.input_width,
                                                                use_depth=config.in_channels == 4), half=True)
    assert path.stat().st_size / 1e6 <= RELEASE_LIMIT_MB
    assert load_checkpoint(path).model.config == config  # the filters travel with the checkpoint


def test_a_configuration_stored_without_decoder_filters_has_the_papers():
    stored = {key: value for key, value in MSFSUConfig().to_dict().items() if key != "decoder_filters"}
    assert MSFSUConfig.from_dict(stored).decoder_filters == PAPER_DECODER_FILTERS
    cpu = PRESETS["cpu"].model_config()
    assert MSFSUConfig.from_dict(cpu.to_dict()) == cpu and cpu.decoder_filters[0] == 256
    with pytest.raises(ValueError, match="one per class"):
        MSFSUConfig(decoder_filters=(512, 128, 64, 16, 4))
    with pytest.raises(ValueError, match="5 positive numbers"):
        MSFSUConfig(decoder_filters=(512, 128, 5))


def test_a_stop_output_answers_speed_0_where_it_says_stop_in_eval_mode_only():
    network = build_model(MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=64, stop_output=True))
    with torch.no_grad():  # command 0 always says stop, command 1 never
        network.policy.branches[0][-1].bias[2] = 100.0
        network.policy.branches[1][-1].bias[2] = -100.0
    inputs, commands = torch.rand(2, 4, 64, 64), torch.tensor([0, 1])
    training = network.train()(inputs, commands)
    assert training.stop_logit.shape == (2,) and training.stop_logit[0] > 0 > training.stop_logit[1]
    assert training.speed[0].item() != 0.0  # the speed head trains on every frame
    evaluated = network.eval()(inputs, commands)
    assert evaluated.speed[0].item() == 0.0 and evaluated.speed[1].item() != 0.0
    assert build_model(MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=64)).eval()(
        inputs, commands).stop_logit is None


def test_a_stop_output_travels_with_the_checkpoint_and_a_network_without_one_stores_no_field(tmp_path):
    config = MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=64, stop_output=True)
    assert MSFSUConfig.from_dict(config.to_dict()) == config
    assert "stop_output" not in MSFSUConfig().to_dict()  # files as before the field
    save_checkpoint(tmp_path / "stop.pt", build_model(config), PreprocessConfig(64, 64))
    assert load_checkpoint(tmp_path / "stop.pt").model.config.stop_output


def test_a_network_without_a_stop_output_warm_starts_one_with_its_other_weights():
    plain_config = MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=64)
    torch.manual_seed(0)
    plain = build_model(plain_config)
    torch.manual_seed(1)
    stopping = build_model(replace(plain_config, stop_output=True))
    fresh_stop_row = stopping.policy.branches[2][-1].weight[2].clone()
    load_warm_start(stopping, plain.state_dict())
    for plain_branch, branch in zip(plain.policy.branches, stopping.policy.branches, strict=True):
        assert torch.equal(branch[-1].weight[:2], plain_branch[-1].weight)
        assert torch.equal(branch[-1].bias[:2], plain_branch[-1].bias)
    assert torch.equal(stopping.policy.branches[2][-1].weight[2], fresh_stop_row)
    inputs, commands = torch.rand(3, 4, 64, 64), torch.tensor([0, 1, 3])
    with torch.no_grad():
        before, after = plain.eval()(inputs, commands), stopping.eval()(inputs, commands)
    assert torch.equal(before.steer, after.steer)
    assert torch.equal(before.segmentation_logits, after.segmentation_logits)
