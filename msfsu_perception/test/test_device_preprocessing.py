"""preprocess_frame on a torch device (for a GPU-backed node) against the CPU function every path uses."""

import numpy as np
import pytest
import torch

from msfsu_perception.device_preprocessing import DevicePreprocessor, area_weights
from msfsu_perception.preprocessing import PreprocessConfig, preprocess_frame, sanitize_depth

DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")])]


def camera_frame(height: int, width: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (height, width, 3), np.uint8)
    depth = rng.uniform(0.5, 120.0, (height, width)).astype(np.float32)  # some beyond the 50 m clip
    depth[rng.random((height, width)) < 0.05] = np.nan  # holes
    return rgb, sanitize_depth(depth)[0]


def test_area_weights_average_what_each_output_pixel_covers():
    weights = area_weights(5, 2)  # each output pixel covers 2.5 source pixels
    np.testing.assert_allclose(weights, [[0.4, 0.4, 0.2, 0, 0], [0, 0, 0.2, 0.4, 0.4]])
    np.testing.assert_allclose(area_weights(8, 4).sum(axis=1), 1.0)
    with pytest.raises(ValueError, match="shrinks"):
        area_weights(4, 8)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("camera, network", [((600, 800), (128, 128)), ((300, 400), (128, 128)),
                                             ((1080, 1920), (224, 224)), ((512, 512), (128, 128))])
def test_the_device_preprocessing_is_the_cpu_preprocessing(device, camera, network):
    config = PreprocessConfig(input_height=network[0], input_width=network[1])
    rgb, depth = camera_frame(*camera)
    expected = preprocess_frame(rgb, depth, config)
    actual = DevicePreprocessor(config, *camera, device)(rgb, depth)[0].cpu().numpy()
    assert actual.shape == expected.shape and actual.dtype == np.float32
    rgb_steps = np.abs(actual[:3] - expected[:3]) * 255.0
    assert rgb_steps.max() <= 1.0 + 1e-4  # at most one uint8 step, where the exact mean sits on a half
    assert np.mean(rgb_steps > 0.5) < 0.01
    np.testing.assert_allclose(actual[3], expected[3], atol=1e-5)


def test_rgb_only_and_bad_input():
    config = PreprocessConfig(input_height=64, input_width=64, use_depth=False)
    rgb, _ = camera_frame(240, 320)
    preprocessor = DevicePreprocessor(config, 240, 320, "cpu")
    np.testing.assert_allclose(preprocessor(rgb, None)[0].numpy(), preprocess_frame(rgb, None, config), atol=1.0 / 255)
    with pytest.raises(ValueError, match="rgb must be"):
        preprocessor(rgb[:100], None)
    with pytest.raises(ValueError, match="depth must be"):
        DevicePreprocessor(PreprocessConfig(input_height=64, input_width=64), 240, 320, "cpu")(rgb, None)
