"""sensor_msgs/Image <-> numpy without cv_bridge (not available as a wheel).

Decoding returns views of the message buffer where the layout allows it (no per-pixel Python),
and raises ImageFormatError with a precise reason for anything malformed.
"""

from __future__ import annotations

from typing import Any, Protocol

import cv2
import numpy as np

# encoding -> (dtype, channels)
ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    "rgb8": (np.dtype(np.uint8), 3),
    "bgr8": (np.dtype(np.uint8), 3),
    "rgba8": (np.dtype(np.uint8), 4),
    "bgra8": (np.dtype(np.uint8), 4),
    "mono8": (np.dtype(np.uint8), 1),
    "32FC1": (np.dtype(np.float32), 1),
    "16UC1": (np.dtype(np.uint16), 1),
}
RGB_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8")
DEPTH_ENCODINGS = ("32FC1", "16UC1")
_TO_RGB = {"bgr8": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_RGBA2RGB, "bgra8": cv2.COLOR_BGRA2RGB}


class ImageFormatError(ValueError):
    """The message cannot be decoded as the image it claims to be."""


class ImageLike(Protocol):
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: Any


def image_to_array(msg: ImageLike, accepted: tuple[str, ...] | None = None) -> np.ndarray:
    """View of the pixels: (H, W) for one channel, (H, W, C) otherwise, in the encoding's dtype."""
    encoding = msg.encoding
    if encoding not in ENCODINGS or (accepted is not None and encoding not in accepted):
        allowed = ", ".join(accepted or ENCODINGS)
        raise ImageFormatError(f"unsupported encoding '{encoding}' (accepted: {allowed})")
    dtype, channels = ENCODINGS[encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = width * channels * dtype.itemsize
    if height <= 0 or width <= 0:
        raise ImageFormatError(f"empty image {width}x{height}")
    if step < row_bytes:
        raise ImageFormatError(f"step {step} < {row_bytes} bytes needed for {width} px of {encoding}")
    buffer = np.frombuffer(msg.data, dtype=np.uint8)
    if buffer.size != step * height:
        raise ImageFormatError(f"data has {buffer.size} bytes, expected step*height = {step * height}")
    rows = buffer.reshape(height, step)[:, :row_bytes]
    pixels = rows.view(dtype.newbyteorder(">" if msg.is_bigendian else "<")) if dtype.itemsize > 1 else rows
    pixels = pixels.reshape(height, width, channels) if channels > 1 else pixels.reshape(height, width)
    return pixels.astype(dtype, copy=False)


def decode_rgb(msg: ImageLike) -> np.ndarray:
    """(H, W, 3) uint8 RGB from rgb8/bgr8/rgba8/bgra8 (a view for rgb8)."""
    pixels = image_to_array(msg, RGB_ENCODINGS)
    conversion = _TO_RGB.get(msg.encoding)
    return pixels if conversion is None else cv2.cvtColor(np.ascontiguousarray(pixels), conversion)


def decode_depth(msg: ImageLike) -> np.ndarray:
    """(H, W) float32 metres from 32FC1 metres or 16UC1 millimetres; invalid pixels (16UC1 zero) are NaN."""
    pixels = image_to_array(msg, DEPTH_ENCODINGS)
    if msg.encoding == "32FC1":
        return pixels
    metres = pixels.astype(np.float32) * np.float32(0.001)
    metres[pixels == 0] = np.nan
    return metres


def decode_mono8(msg: ImageLike) -> np.ndarray:
    """(H, W) uint8 (class ids, masks)."""
    return image_to_array(msg, ("mono8",))


def encode_image(pixels: np.ndarray, encoding: str) -> dict[str, Any]:
    """Fields of a sensor_msgs/Image for `pixels` (assign to a message or pass to its constructor)."""
    dtype, channels = ENCODINGS[encoding]
    array = np.ascontiguousarray(pixels, dtype=dtype)
    expected_ndim = 2 if channels == 1 else 3
    if array.ndim != expected_ndim or (channels > 1 and array.shape[2] != channels):
        raise ImageFormatError(f"array of shape {array.shape} does not fit encoding {encoding}")
    height, width = array.shape[:2]
    return {
        "height": height,
        "width": width,
        "encoding": encoding,
        "is_bigendian": 0,
        "step": width * channels * dtype.itemsize,
        "data": array.tobytes(),
    }
