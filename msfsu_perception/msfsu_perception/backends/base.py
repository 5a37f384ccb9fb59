"""What every backend shares: the names of backends, precisions and devices, the runner's call and its outputs."""

from __future__ import annotations

from typing import Literal, NamedTuple, Protocol

import numpy as np

Backend = Literal["torch", "onnxruntime", "openvino"]
Precision = Literal["fp32", "fp16", "bf16", "int8"]
Device = Literal["cpu", "cuda"]


class BackendUnavailableError(RuntimeError):
    """The backend is not installed, or does not run the requested precision on this machine."""


class RawOutputs(NamedTuple):
    steer: float  # network output, not clipped
    speed: float  # normalised: multiply by the checkpoint's speed_scale for m/s
    class_ids: np.ndarray | None  # (H, W) uint8, None for the MSF variant


class Runner(Protocol):
    def __call__(self, inputs: np.ndarray, command_index: np.ndarray) -> RawOutputs:
        """inputs (1, C, H, W) float32 C-contiguous, command_index (1,) int64."""


def raw_outputs(outputs: list[np.ndarray] | tuple[np.ndarray, ...]) -> RawOutputs:
    """(steer (1,), speed (1,)[, class ids (1, H, W)]) arrays -> RawOutputs."""
    class_ids = np.array(outputs[2][0], np.uint8) if len(outputs) > 2 else None  # a copy the caller may keep
    return RawOutputs(float(outputs[0][0]), float(outputs[1][0]), class_ids)
