import numpy as np
import pytest

from msfsu_perception.augmentation import OPERATIONS, AugmentationConfig, apply_operation, augment_rgb

IMAGE = np.random.default_rng(0).integers(40, 200, (3, 16, 16), dtype=np.uint8)


def test_each_operation_fires_independently_with_probability_0_1():
    rng = np.random.default_rng(1)
    trials = 20000
    fired = {name: 0 for name in OPERATIONS}
    noise_and_blur = 0
    untouched = 0
    for _ in range(trials):
        applied = augment_rgb(IMAGE, rng, AugmentationConfig()).applied
        for name in applied:
            fired[name] += 1
        noise_and_blur += {"gaussian_noise", "gaussian_blur"} <= set(applied)
        untouched += not applied
    for name in OPERATIONS:
        assert fired[name] / trials == pytest.approx(0.1, abs=0.01)
    assert noise_and_blur / trials == pytest.approx(0.01, abs=0.003)
    assert untouched / trials == pytest.approx(0.9**4, abs=0.015)


@pytest.mark.parametrize("operation", OPERATIONS)
def test_every_operation_changes_the_image_and_keeps_uint8(operation):
    config = AugmentationConfig(contrast_range=(0.5, 0.6), dropout_fraction_max=1.0)
    result = apply_operation(operation, IMAGE, np.random.default_rng(5), config)
    assert result.shape == IMAGE.shape and result.dtype == np.uint8
    assert not np.array_equal(result, IMAGE)


def test_nothing_fires_with_probability_zero():
    result = augment_rgb(IMAGE, np.random.default_rng(0), AugmentationConfig(probability=0.0))
    assert result.applied == () and result.image is IMAGE
