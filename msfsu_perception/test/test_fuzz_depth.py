"""Fuzz (hypothesis) of depth preprocessing: every bit pattern a depth camera may send ends in range or is
refused with InvalidDepthError, never another exception."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from sensor_msgs.msg import Image

from msfsu_common.image_codec import ENCODINGS, decode_depth
from msfsu_perception.preprocessing import InvalidDepthError, PreprocessConfig, preprocess_frame, sanitize_depth


@settings(max_examples=200)
@given(st.integers(1, 24), st.integers(1, 24), st.sampled_from(["32FC1", "16UC1"]), st.data())
def test_any_decoded_depth_is_preprocessed_into_range_or_rejected(height, width, encoding, data):
    """Every bit pattern a depth camera may send (NaN, inf, negative, huge, 0 mm) ends in [0, 1] or is refused."""
    dtype = ENCODINGS[encoding][0]
    raw = data.draw(st.binary(min_size=height * width * dtype.itemsize, max_size=height * width * dtype.itemsize))
    depth = decode_depth(Image(height=height, width=width, encoding=encoding, is_bigendian=data.draw(st.integers(0, 1)),
                               step=width * dtype.itemsize, data=raw))
    rgb = np.frombuffer(data.draw(st.binary(min_size=height * width * 3, max_size=height * width * 3)),
                        np.uint8).reshape(height, width, 3)
    try:
        cleaned, invalid_share = sanitize_depth(depth)
    except InvalidDepthError:
        return
    assert 0.0 <= invalid_share <= 0.5
    out = preprocess_frame(rgb, cleaned, PreprocessConfig(input_height=8, input_width=8))
    assert np.isfinite(out).all() and out.min() >= 0.0 and out.max() <= 1.0
