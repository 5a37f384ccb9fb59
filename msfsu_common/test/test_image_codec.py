from types import SimpleNamespace

import numpy as np
import pytest

from msfsu_common.image_codec import ImageFormatError, decode_depth, decode_mono8, decode_rgb, encode_image


def message(pixels: np.ndarray, pixel_encoding: str, **overrides) -> SimpleNamespace:
    return SimpleNamespace(**{**encode_image(pixels, pixel_encoding), **overrides})


RGB = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)


@pytest.mark.parametrize("encoding, pixels", [
    ("rgb8", RGB),
    ("bgr8", RGB[..., ::-1]),
    ("rgba8", np.dstack([RGB, np.full((4, 5), 255, np.uint8)])),
    ("bgra8", np.dstack([RGB[..., ::-1], np.full((4, 5), 255, np.uint8)])),
])
def test_every_colour_encoding_decodes_to_rgb(encoding, pixels):
    np.testing.assert_array_equal(decode_rgb(message(pixels, encoding)), RGB)


def test_rgb8_decodes_without_copy():
    msg = message(RGB, "rgb8")
    msg.data = bytearray(msg.data)
    decoded = decode_rgb(msg)
    msg.data[0] = 99
    assert decoded[0, 0, 0] == 99


def test_padded_rows_are_respected():
    padded = np.zeros((4, 16), np.uint8)
    padded[:, :15] = RGB.reshape(4, 15)
    msg = message(RGB, "rgb8", step=16, data=padded.tobytes())
    np.testing.assert_array_equal(decode_rgb(msg), RGB)


def test_depth_encodings():
    metres = np.array([[1.5, 2.0]], np.float32)
    np.testing.assert_array_equal(decode_depth(message(metres, "32FC1")), metres)
    millimetres = np.array([[1500, 0]], np.uint16)
    decoded = decode_depth(message(millimetres, "16UC1"))
    assert decoded[0, 0] == pytest.approx(1.5) and np.isnan(decoded[0, 1])  # 0 = no return (REP 118)


def test_big_endian_depth():
    metres = np.array([[1.5, 2.0]], np.float32)
    msg = message(metres, "32FC1", is_bigendian=1, data=metres.astype(">f4").tobytes())
    np.testing.assert_array_equal(decode_depth(msg), metres)


@pytest.mark.parametrize("overrides, reason", [
    ({"encoding": "yuv422"}, "unsupported encoding"),
    ({"step": 10}, "step 10 < 15"),
    ({"data": bytes(59)}, "expected step\\*height = 60"),
    ({"height": 0}, "empty image"),
])
def test_malformed_images_raise_a_precise_error(overrides, reason):
    with pytest.raises(ImageFormatError, match=reason):
        decode_rgb(message(RGB, "rgb8", **overrides))


def test_depth_decoder_rejects_colour_images():
    with pytest.raises(ImageFormatError, match="accepted: 32FC1, 16UC1"):
        decode_depth(message(RGB, "rgb8"))
    np.testing.assert_array_equal(decode_mono8(message(RGB[..., 0], "mono8")), RGB[..., 0])
