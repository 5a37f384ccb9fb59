from types import SimpleNamespace

import numpy as np
import pytest

from msfsu_perception.preprocessing import (
    InvalidDepthError,
    PreprocessConfig,
    preprocess_frame,
    preprocess_labels,
    sanitize_depth,
)

CONFIG = PreprocessConfig(input_height=32, input_width=48, max_depth_m=50.0)


def test_crops_top_half_resizes_and_scales_to_unit_range():
    rgb = np.zeros((60, 80, 3), np.uint8)
    rgb[:30] = 255  # the top half (sky) must disappear
    rgb[30:, :, 0] = 51  # red channel 0.2 in the kept half
    depth = np.full((60, 80), 25.0, np.float32)
    depth[:30] = 1.0
    out = preprocess_frame(rgb, depth, CONFIG)
    assert out.shape == (4, 32, 48) and out.dtype == np.float32
    np.testing.assert_allclose(out[0], 0.2, atol=1e-6)
    np.testing.assert_allclose(out[1:3], 0.0)
    np.testing.assert_allclose(out[3], 0.5, atol=1e-6)


def test_depth_is_clipped_to_max_range_and_buffer_is_reused():
    rgb = np.zeros((10, 10, 3), np.uint8)
    depth = np.full((10, 10), np.inf, np.float32)
    buffer = np.empty((4, 32, 48), np.float32)
    out = preprocess_frame(rgb, depth, CONFIG, out=buffer)
    assert out is buffer
    np.testing.assert_allclose(out[3], 1.0)


def test_rgb_only_config_has_three_channels():
    config = PreprocessConfig(input_height=16, input_width=16, use_depth=False)
    assert preprocess_frame(np.zeros((20, 20, 3), np.uint8), None, config).shape == (3, 16, 16)


def test_rejects_mismatched_depth():
    with pytest.raises(ValueError, match="depth must be"):
        preprocess_frame(np.zeros((20, 20, 3), np.uint8), np.zeros((10, 10), np.float32), CONFIG)


def test_labels_use_the_same_crop_and_nearest_neighbour():
    labels = np.zeros((60, 80), np.uint8)
    labels[30:, 40:] = 3
    out = preprocess_labels(labels, CONFIG)
    assert out.shape == (32, 48) and set(np.unique(out)) == {0, 3}
    assert (out[:, :24] == 0).all() and (out[:, 24:] == 3).all()


def test_sanitize_depth_tolerates_a_share_of_invalid_pixels():
    depth = np.full((10, 10), 5.0, np.float32)
    depth[0, :5] = np.nan
    with pytest.raises(InvalidDepthError, match="5.0%"):
        sanitize_depth(depth, max_invalid_fraction=0.01)
    cleaned, invalid_share = sanitize_depth(depth, max_invalid_fraction=0.05)
    assert np.isinf(cleaned[0, :5]).all() and (cleaned[1:] == 5.0).all() and invalid_share == 0.05


def test_a_real_sensors_holes_are_read_as_the_far_clip_by_default():
    """RealSense/OpenNI 16UC1 zeros and a 3 % NaN patch in 32FC1 keep their frame; a dead sensor does not."""
    from msfsu_common.image_codec import decode_depth, encode_image

    millimetres = np.full((60, 80), 4000, np.uint16)
    millimetres[::3, ::2] = 0  # a sixth of the pixels without a return, spread over the frame
    metres = np.full((60, 80), 4.0, np.float32)
    metres[40:49, 60:76] = np.nan  # 9 x 16 = 3 % of the frame
    for encoding, pixels in (("16UC1", millimetres), ("32FC1", metres)):
        depth = decode_depth(SimpleNamespace(**encode_image(pixels, encoding)))
        cleaned, invalid_share = sanitize_depth(depth)
        assert invalid_share == pytest.approx(np.mean(~np.isfinite(depth))) and invalid_share > 0.02
        out = preprocess_frame(np.zeros((60, 80, 3), np.uint8), cleaned, CONFIG)
        assert np.isfinite(out).all() and out[3].min() == pytest.approx(4.0 / 50.0) and out[3].max() > 0.5  # far
    with pytest.raises(InvalidDepthError):
        sanitize_depth(np.full((60, 80), np.nan, np.float32))
