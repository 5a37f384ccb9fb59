import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from msfsu_common.road_option import RoadOption
from msfsu_common.semantic_classes import CLASS_NAMES
from msfsu_perception.checkpoint import CheckpointError, load_checkpoint, main, save_checkpoint
from msfsu_perception.inference import DrivingModel
from msfsu_perception.model import MSFSUConfig, build_model
from msfsu_perception.preprocessing import PreprocessConfig

CONFIG = MSFSUConfig(variant="msfsu", backbone="resnet18v2", input_height=64, input_width=96)
PREPROCESS = PreprocessConfig(input_height=64, input_width=96, max_depth_m=40.0)


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    network = build_model(CONFIG)
    network.train()
    with torch.no_grad():  # non-trivial BN statistics
        network(torch.rand(4, 4, 64, 96), torch.arange(4))
    return network.eval()


def _outputs(network, x, commands):
    with torch.no_grad():
        return network(x, commands)


def test_round_trip_gives_identical_outputs_and_configuration(model, tmp_path):
    path = tmp_path / "best.pt"
    save_checkpoint(path, model, PREPROCESS, speed_scale=12.5, training={"epoch": 3, "val_loss": 0.25})
    loaded = load_checkpoint(path)
    x, commands = torch.rand(2, 4, 64, 96), torch.tensor([1, 3])
    before, after = _outputs(model, x, commands), _outputs(loaded.model, x, commands)
    for a, b in zip(before, after, strict=True):
        assert (a is None and b is None) or torch.equal(a, b)
    assert loaded.model.config == CONFIG and loaded.preprocess == PREPROCESS
    assert loaded.speed_scale == 12.5 and loaded.class_names == CLASS_NAMES
    assert loaded.training == {"epoch": 3, "val_loss": 0.25}
    assert not loaded.model.training


def test_file_is_plain_data_for_weights_only_load(model, tmp_path):
    save_checkpoint(tmp_path / "c.pt", model, PREPROCESS)
    payload = torch.load(tmp_path / "c.pt", weights_only=True)
    assert payload["command_order"] == ["LEFT", "RIGHT", "STRAIGHT", "LANE_FOLLOW"]
    assert payload["model_config"]["backbone"] == "resnet18v2"


def test_half_storage_is_smaller_and_loads_back_to_fp32(model, tmp_path):
    save_checkpoint(tmp_path / "full.pt", model, PREPROCESS)
    save_checkpoint(tmp_path / "half.pt", model, PREPROCESS, half=True)
    assert (tmp_path / "half.pt").stat().st_size < 0.6 * (tmp_path / "full.pt").stat().st_size
    loaded = load_checkpoint(tmp_path / "half.pt").model
    assert all(p.dtype == torch.float32 for p in loaded.parameters())
    x, commands = torch.rand(1, 4, 64, 96), torch.tensor([3])
    assert torch.allclose(_outputs(model, x, commands).steer, _outputs(loaded, x, commands).steer, atol=1e-2)


def test_release_drops_training_state_and_keeps_configuration_and_metadata(model, tmp_path, capsys):
    state = {"optimizer": {"lr": torch.full((1000,), 3e-4)}}
    save_checkpoint(tmp_path / "best.pt", model, PREPROCESS, speed_scale=12.5, training={"epoch": 7},
                    training_state=state)
    assert main([str(tmp_path / "best.pt"), str(tmp_path / "models" / "release.pt")]) == 0
    assert "MiB (fp16 storage" in capsys.readouterr().out
    payload = torch.load(tmp_path / "models" / "release.pt", weights_only=True)
    assert payload["storage_dtype"] == "float16" and "training_state" not in payload
    released = load_checkpoint(tmp_path / "models" / "release.pt")
    assert released.training == {"epoch": 7} and released.speed_scale == 12.5 and released.preprocess == PREPROCESS


def test_release_of_a_missing_checkpoint_fails_with_the_reason(tmp_path, capsys):
    assert main([str(tmp_path / "nope.pt"), str(tmp_path / "out.pt")]) == 1
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "out.pt").exists()


def test_missing_file_is_a_checkpoint_error(tmp_path):
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "nope.pt")


def test_truncated_file_is_a_checkpoint_error(model, tmp_path):
    path = tmp_path / "c.pt"
    save_checkpoint(path, model, PREPROCESS)
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(CheckpointError, match="corrupt"):
        load_checkpoint(path)


def test_arbitrary_pickle_is_refused(tmp_path):
    path = tmp_path / "evil.pt"
    torch.save({"format": "msfsu-checkpoint", "payload": PreprocessConfig()}, path)
    with pytest.raises(CheckpointError, match="corrupt or not a safe"):
        load_checkpoint(path)


def test_wrong_format_version_is_a_checkpoint_error(model, tmp_path):
    path = tmp_path / "c.pt"
    save_checkpoint(path, model, PREPROCESS)
    payload = torch.load(path, weights_only=True)
    payload["format_version"] = 99
    torch.save(payload, path)
    with pytest.raises(CheckpointError, match="format version 99"):
        load_checkpoint(path)


def test_weights_that_do_not_match_the_configuration_are_a_checkpoint_error(model, tmp_path):
    path = tmp_path / "c.pt"
    save_checkpoint(path, model, PREPROCESS)
    payload = torch.load(path, weights_only=True)
    payload["model_config"]["backbone"] = "resnet34v2"
    torch.save(payload, path)
    with pytest.raises(CheckpointError, match="weights do not match"):
        load_checkpoint(path)


def test_preprocessing_that_does_not_fit_the_network_is_refused(model, tmp_path):
    with pytest.raises(CheckpointError, match="preprocessing produces"):
        save_checkpoint(tmp_path / "c.pt", model, PreprocessConfig(input_height=64, input_width=64))


def test_driving_model_predicts_clipped_steer_speed_in_mps_and_class_ids(model, tmp_path):
    path = tmp_path / "best.pt"
    save_checkpoint(path, model, PREPROCESS, speed_scale=10.0)
    driving = DrivingModel.from_checkpoint(path)
    assert driving.preprocess == PREPROCESS and driving.has_segmentation
    assert driving.class_names == CLASS_NAMES
    inputs = np.random.default_rng(0).random((4, 64, 96), dtype=np.float32)
    prediction = driving.predict(inputs, RoadOption.RIGHT)
    raw = _outputs(model, torch.from_numpy(inputs)[None], torch.tensor([RoadOption.RIGHT.branch_index]))
    assert prediction.steer == pytest.approx(float(raw.steer.clamp(-1, 1)), abs=1e-6)
    assert prediction.target_speed == pytest.approx(max(0.0, float(raw.speed) * 10.0), abs=1e-5)
    assert prediction.class_ids.shape == (64, 96) and prediction.class_ids.dtype == np.uint8
    assert np.array_equal(prediction.class_ids, raw.segmentation_logits[0].argmax(0).numpy())


def test_driving_model_rejects_inputs_of_another_shape(model, tmp_path):
    save_checkpoint(tmp_path / "best.pt", model, PREPROCESS)
    driving = DrivingModel.from_checkpoint(tmp_path / "best.pt")
    with pytest.raises(ValueError, match="inputs must be"):
        driving.predict(np.zeros((3, 64, 96), np.float32), RoadOption.LANE_FOLLOW)


def test_msf_checkpoint_predicts_without_segmentation(tmp_path):
    config = MSFSUConfig(variant="msf", backbone="resnet18v2", input_height=64, input_width=64)
    save_checkpoint(tmp_path / "msf.pt", build_model(config).eval(), PreprocessConfig(64, 64))
    driving = DrivingModel.from_checkpoint(tmp_path / "msf.pt")
    prediction = driving.predict(np.zeros((4, 64, 64), np.float32), RoadOption.LEFT)
    assert not driving.has_segmentation and prediction.class_ids is None
    assert -1.0 <= prediction.steer <= 1.0 and prediction.target_speed >= 0.0


@pytest.mark.parametrize("layout", ["v1", "v2"])
def test_checkpoint_stores_its_decoder_layout(tmp_path, layout):
    config = MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=64, decoder_layout=layout)
    save_checkpoint(tmp_path / "c.pt", build_model(config).eval(), PreprocessConfig(64, 64))
    assert torch.load(tmp_path / "c.pt", weights_only=True)["model_config"]["decoder_layout"] == layout
    assert load_checkpoint(tmp_path / "c.pt").model.config.decoder_layout == layout


def _papers_kernel_3_decoder(decoder: nn.Module, features: torch.Tensor) -> torch.Tensor:
    """The v1 decoder written out: kernel 3, padding 1, output_padding stride - 1 (the code that trained
    the shipped models), with the decoder's own weights, BN and ReLU."""
    for layer in decoder.layers:
        if isinstance(layer, nn.ConvTranspose2d):
            stride = layer.stride[0]
            assert layer.weight.shape[2:] == (3, 3)
            features = F.conv_transpose2d(features, layer.weight, layer.bias, stride=stride, padding=1,
                                          output_padding=stride - 1)
        else:
            features = layer(features)
    return features


@pytest.mark.parametrize("variant", ["msfsu", "su"])
def test_a_checkpoint_without_a_decoder_layout_loads_as_v1_with_unchanged_outputs(variant, legacy_checkpoint):
    path = legacy_checkpoint(MSFSUConfig(variant=variant, backbone="resnet18v2", input_height=64, input_width=96,
                                         decoder_layout="v1"))
    assert "decoder_layout" not in torch.load(path, weights_only=True)["model_config"]  # written before the field
    model = load_checkpoint(path).model
    assert model.config.decoder_layout == "v1" and model.config.decoder_filters == (512, 128, 64, 16, 5)
    config = model.config
    inputs = torch.rand(2, config.in_channels, config.input_height, config.input_width,
                        generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        features = model.encoder(inputs)
        output = model(inputs, torch.tensor([0, 3]))
        assert torch.equal(output.segmentation_logits, _papers_kernel_3_decoder(model.decoder, features))
    assert output.segmentation_logits.shape == (2, 5, config.input_height, config.input_width)
