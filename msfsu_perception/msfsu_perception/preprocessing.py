"""The one preprocessing path of the stack: training, bag replay and the live node all call it.

Paper section III-B: crop away the top half of the camera image, resize to the network input,
scale every channel to [0, 1]. Depth (metres) is clipped to `max_depth_m` before scaling.

Real depth cameras report holes: NaN/inf in 32FC1, 0 in 16UC1 (RealSense / OpenNI: no return, too
near or too far, shadow, glass). Those pixels are read as the far clip (1.0), as a simulator's sky is;
a frame is rejected only when more than MAX_INVALID_DEPTH_FRACTION of it is invalid (a covered or
failed sensor), where the depth channel would say nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


# Default share of invalid depth pixels a frame may have (node parameter max_invalid_depth_fraction,
# training cache): RealSense D4xx / Kinect-style frames outdoors commonly have 5-30 % holes.
MAX_INVALID_DEPTH_FRACTION = 0.5


class InvalidDepthError(ValueError):
    """Too many non-finite depth pixels to trust the frame."""


@dataclass(frozen=True)
class PreprocessConfig:
    input_height: int = 224
    input_width: int = 224
    crop_top_fraction: float = 0.5  # fraction of rows removed from the top (sky, buildings)
    max_depth_m: float = 50.0  # depth beyond this is "far"; scaled depth = min(d, max) / max
    use_depth: bool = True  # False for the RGB-only SU ablation

    @property
    def channels(self) -> int:
        return 4 if self.use_depth else 3


def crop_rows(height: int, config: PreprocessConfig) -> slice:
    """Rows of a camera image kept by the crop."""
    return slice(int(round(height * config.crop_top_fraction)), height)


def sanitize_depth(depth: np.ndarray, max_invalid_fraction: float = MAX_INVALID_DEPTH_FRACTION,
                   ) -> tuple[np.ndarray, float]:
    """(metric depth with invalid pixels set to +inf, i.e. the far clip; share of invalid pixels).

    NaN / +-inf (and 16UC1 zeros, decoded as NaN) are invalid returns. Up to `max_invalid_fraction`
    of them are tolerated and treated as far; above it InvalidDepthError rejects the frame.
    """
    finite = np.isfinite(depth)
    if finite.all():
        return depth, 0.0
    invalid = finite.size - int(np.count_nonzero(finite))
    if invalid > max_invalid_fraction * finite.size:
        raise InvalidDepthError(
            f"{invalid / finite.size:.1%} of depth pixels are NaN/inf (tolerated: {max_invalid_fraction:.1%})"
        )
    return np.where(finite, depth, np.float32(np.inf)).astype(np.float32, copy=False), invalid / finite.size


def preprocess_frame(
    rgb: np.ndarray,
    depth: np.ndarray | None,
    config: PreprocessConfig,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W, 3) uint8 RGB + (H, W) float32 metres -> (C, h, w) float32 in [0, 1].

    Channels are R, G, B(, depth). `out` (C, h, w) float32 may be passed to reuse a buffer.
    Non-finite depth must have gone through `sanitize_depth` (inf is clipped to max range here).
    """
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
    size = (config.input_width, config.input_height)
    rows = crop_rows(rgb.shape[0], config)
    if out is None:
        out = np.empty((config.channels, config.input_height, config.input_width), np.float32)
    resized_rgb = cv2.resize(rgb[rows], size, interpolation=cv2.INTER_AREA)
    np.multiply(resized_rgb.transpose(2, 0, 1), np.float32(1.0 / 255.0), out=out[:3])
    if config.use_depth:
        if depth is None or depth.shape != rgb.shape[:2]:
            shape = None if depth is None else depth.shape
            raise ValueError(f"depth must be (H, W) matching rgb {rgb.shape[:2]}, got {shape}")
        clipped = np.minimum(depth[rows], np.float32(config.max_depth_m))
        resized_depth = cv2.resize(clipped, size, interpolation=cv2.INTER_AREA)
        np.multiply(resized_depth, np.float32(1.0 / config.max_depth_m), out=out[3])
        np.clip(out[3], 0.0, 1.0, out=out[3])
    return out


def preprocess_labels(class_ids: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """(H, W) uint8 class ids -> (h, w) uint8, same crop, nearest-neighbour resize."""
    rows = crop_rows(class_ids.shape[0], config)
    size = (config.input_width, config.input_height)
    return cv2.resize(np.ascontiguousarray(class_ids[rows]), size, interpolation=cv2.INTER_NEAREST)
