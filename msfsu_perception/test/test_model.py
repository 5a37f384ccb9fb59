import pytest
import torch
from torch import nn

from msfsu_perception.model import MSFSUConfig, build_model


@pytest.mark.parametrize("backbone", ["resnet18v2", "resnet34v2", "resnet50v2"])
@pytest.mark.parametrize("variant", ["msfsu", "msf", "su"])
@pytest.mark.parametrize("size", [(64, 96), (96, 64)])
def test_output_shapes_for_every_variant_backbone_and_size(backbone, variant, size):
    config = MSFSUConfig(variant=variant, backbone=backbone, input_height=size[0], input_width=size[1])
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


def test_decoder_is_the_papers_five_transposed_convolutions():
    decoder = build_model(MSFSUConfig(backbone="resnet50v2", input_height=224, input_width=224)).decoder  # the paper's
    layers = [(type(layer), getattr(layer, "out_channels", None)) for layer in decoder.layers]
    deconvs = [layer for layer in decoder.layers if isinstance(layer, nn.ConvTranspose2d)]
    assert [(d.out_channels, d.kernel_size, d.stride) for d in deconvs] == [
        (512, (3, 3), (4, 4)),
        (128, (3, 3), (2, 2)),
        (64, (3, 3), (2, 2)),
        (16, (3, 3), (2, 2)),
        (5, (3, 3), (1, 1)),
    ]
    assert deconvs[0].in_channels == 2048
    expected_types = [nn.ConvTranspose2d, nn.BatchNorm2d, nn.ReLU] * 4 + [nn.ConvTranspose2d]
    assert [kind for kind, _ in layers] == expected_types


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


def test_config_round_trips_through_a_dict():
    config = MSFSUConfig(variant="su", backbone="resnet34v2", input_height=96, policy_hidden=(128,))
    assert MSFSUConfig.from_dict(config.to_dict()) == config
