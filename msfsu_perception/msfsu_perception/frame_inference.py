"""One camera frame + command -> the network's prediction: what the perception node does per frame, and the
collector's network driver through the same function.

Rules, in order:
- depth is read only by a network that uses it (`preprocess.use_depth`);
- depth goes through `sanitize_depth`: invalid pixels (NaN/inf, 16UC1 zeros) read as the far clip, and more than
  `max_invalid_depth_fraction` of them rejects the frame (InvalidDepthError, a ValueError);
- depth of another size than the RGB rejects the frame (ValueError);
- the frame is preprocessed where the network runs (`DrivingModel.prepare`: on the GPU for a GPU runner) and
  predicted with the command.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from msfsu_perception.preprocessing import MAX_INVALID_DEPTH_FRACTION, sanitize_depth

if TYPE_CHECKING:
    import torch

    from msfsu_common.road_option import RoadOption
    from msfsu_perception.inference import DrivingModel, Prediction


@dataclass(frozen=True)
class FrameInference:
    """A frame's prediction, the input the network saw and the share of invalid depth pixels read as far."""

    prediction: Prediction
    inputs: np.ndarray | torch.Tensor  # valid until the model's next `prepare`
    depth_invalid_share: float | None  # None when the network reads no depth


def _no_mark(stage: str) -> None:
    return None


def infer_frame(model: DrivingModel, rgb: np.ndarray, depth: np.ndarray | None, command: RoadOption,
                max_invalid_depth_fraction: float = MAX_INVALID_DEPTH_FRACTION,
                mark: Callable[[str], None] = _no_mark) -> FrameInference:
    """(H, W, 3) uint8 RGB + (H, W) float32 metres (or None) -> FrameInference, by the rules of the module
    docstring (ValueError rejects the frame). `mark` is called with "preprocessed" and "inferred" as they end."""
    invalid_share = None
    if depth is not None and model.preprocess.use_depth:
        depth, invalid_share = sanitize_depth(depth, max_invalid_depth_fraction)
        if depth.shape != rgb.shape[:2]:
            raise ValueError(f"depth {depth.shape[1]}x{depth.shape[0]} does not match "
                             f"rgb {rgb.shape[1]}x{rgb.shape[0]}")
    else:
        depth = None
    inputs = model.prepare(rgb, depth)
    mark("preprocessed")
    prediction = model.predict(inputs, command)
    mark("inferred")
    return FrameInference(prediction, inputs, invalid_share)
