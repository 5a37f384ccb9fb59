"""What the perception node and bag replay call: one preprocessed frame + command -> Prediction.

Kept thin on purpose: other backends (ONNX Runtime, OpenVINO) can stand behind the same
`from_checkpoint` / `predict` interface later.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from msfsu_common.road_option import RoadOption
from msfsu_perception.checkpoint import load_checkpoint
from msfsu_perception.model import MSFSUNet
from msfsu_perception.preprocessing import PreprocessConfig


@dataclass(frozen=True)
class Prediction:
    steer: float  # [-1, 1], clipped
    target_speed: float  # m/s, >= 0
    class_ids: np.ndarray | None  # (h, w) uint8 argmax of the segmentation; None for MSF


class DrivingModel:
    """A trained network in eval mode with the preprocessing constants it was trained with."""

    def __init__(
        self, network: MSFSUNet, preprocess: PreprocessConfig, speed_scale: float, class_names: tuple[str, ...]
    ) -> None:
        self.network = network.eval()
        self.preprocess = preprocess
        self.speed_scale = speed_scale
        self.class_names = class_names
        self.has_segmentation = network.config.has_segmentation
        self._input_shape = (preprocess.channels, preprocess.input_height, preprocess.input_width)

    @classmethod
    def from_checkpoint(cls, path: Path | str, num_threads: int | None = None) -> DrivingModel:
        """Load a checkpoint (CheckpointError if unusable); num_threads sets torch's process-wide pool."""
        if num_threads is not None:
            torch.set_num_threads(num_threads)
        loaded = load_checkpoint(path)
        return cls(loaded.model, loaded.preprocess, loaded.speed_scale, loaded.class_names)

    def predict(self, inputs: np.ndarray, command: RoadOption) -> Prediction:
        """inputs: (C, h, w) float32 from `preprocess_frame` with `self.preprocess`."""
        if inputs.shape != self._input_shape or inputs.dtype != np.float32:
            raise ValueError(f"inputs must be {self._input_shape} float32, got {inputs.shape} {inputs.dtype}")
        with torch.inference_mode():
            output = self.network(torch.from_numpy(inputs)[None], torch.tensor([command.branch_index]))
            class_ids = None
            if output.segmentation_logits is not None:
                class_ids = output.segmentation_logits[0].argmax(0).to(torch.uint8).numpy()
        return Prediction(
            steer=float(np.clip(output.steer.item(), -1.0, 1.0)),
            target_speed=max(0.0, output.speed.item() * self.speed_scale),
            class_ids=class_ids,
        )
