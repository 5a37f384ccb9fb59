"""Tests share two CPU cores with other work: one intra-op thread each."""

import torch

torch.set_num_threads(1)


import pytest  # noqa: E402


@pytest.fixture
def legacy_checkpoint(tmp_path):
    """make(config) -> the path of a checkpoint as written before decoder_layout and decoder_filters existed: a v1
    network with the paper's filters, its model_config without those two keys (the first shipped models)."""
    from msfsu_perception.checkpoint import save_checkpoint
    from msfsu_perception.model import build_model
    from msfsu_perception.preprocessing import PreprocessConfig

    def make(config):
        assert config.decoder_layout == "v1"
        torch.manual_seed(0)
        network = build_model(config)
        with torch.no_grad():  # BN statistics away from their initial values
            network(torch.rand(4, config.in_channels, config.input_height, config.input_width), torch.arange(4))
        path = tmp_path / f"legacy_{config.variant}.pt"
        save_checkpoint(path, network.eval(), PreprocessConfig(config.input_height, config.input_width,
                                                               use_depth=config.in_channels == 4))
        stored = torch.load(path, weights_only=True)
        for key in ("decoder_layout", "decoder_filters"):
            del stored["model_config"][key]
        torch.save(stored, path)
        return path

    return make
