"""What the perception node and bag replay call: one preprocessed frame + command -> Prediction.

The network runs on one of the backends of the backends package (torch eager fp32 is the reference).
"auto" picks by measurement (benchmarks/perception.py): the fastest installed backend, and the
fastest precision of it that passed the accuracy gate for this very checkpoint (gate_verdicts.py) and that this
CPU runs (backends.cpu_precisions: no bf16 without avx512_bf16/AMX); fp32 when none has, so a fast
path that failed or never ran the gate, or that this CPU lacks, is not used by default.

Device "auto" is a CUDA GPU when torch sees one, else the CPU. On the GPU, backend "auto" is torch in a CUDA graph
(backends/cuda_graph_runner.py; the ONNX Runtime GPU providers are used when named) and precision "auto" the fastest of fp16, bf16
that passed the GPU's own gate record for this checkpoint, else fp32; the frame is preprocessed on the GPU
(`prepare`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from msfsu_common.road_option import RoadOption

from msfsu_perception.backends import (
    DEVICES,
    Backend,
    BackendUnavailableError,
    Device,
    Precision,
    Runner,
    cpu_capabilities,
    cpu_precisions,
    create_runner,
    cuda_available,
    cuda_unavailable_reason,
    int8_build,
    is_installed,
    supported_precisions,
)
from msfsu_perception.checkpoint import load_checkpoint
from msfsu_perception.deploy_files import CalibrationSet, calibration_path
from msfsu_perception.gate_verdicts import gate_verdicts, gated_precisions
from msfsu_perception.preprocessing import PreprocessConfig, preprocess_frame

AUTO_BACKEND_ORDER: tuple[Backend, ...] = ("openvino", "onnxruntime", "torch")  # fastest first, measured
PRECISION_SPEED_ORDER: tuple[Precision, ...] = ("int8", "bf16", "fp32")  # fastest first, measured
CUDA_PRECISION_SPEED_ORDER: tuple[Precision, ...] = ("fp16", "bf16", "fp32")  # benchmarks/gpu_results.md

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Prediction:
    steer: float  # [-1, 1], clipped
    target_speed: float  # m/s, >= 0
    class_ids: np.ndarray | None  # (h, w) uint8 argmax of the segmentation; None for MSF


def resolve_device(requested: Device | Literal["auto"]) -> Device:
    """"auto": a CUDA GPU when torch sees one, else the CPU. "cuda" without one: BackendUnavailableError (why)."""
    if requested not in (*DEVICES, "auto"):
        raise ValueError(f"unknown device {requested!r}; choose from auto, {', '.join(DEVICES)}")
    if requested == "auto":
        return "cuda" if cuda_available() else "cpu"
    if requested == "cuda" and not cuda_available():
        raise BackendUnavailableError(f"device cuda: {cuda_unavailable_reason()}")
    return requested


def resolve_backend(requested: Backend | Literal["auto"], device: Device = "cpu") -> Backend:
    """"auto": the fastest installed backend (on a GPU: torch); a named one that is missing falls back to torch
    (logged)."""
    if requested == "auto" and device == "cuda":
        return "torch"
    if requested == "auto":
        return next(backend for backend in AUTO_BACKEND_ORDER if is_installed(backend))
    if not is_installed(requested):
        log.warning("backend %s is not installed; falling back to torch (the reference)", requested)
        return "torch"
    return requested


def resolve_precision(checkpoint: Path, backend: Backend, requested: Precision | Literal["auto"],
                      device: Device = "cpu") -> Precision:
    """"auto": the fastest precision of `backend` that passed the accuracy gate on this checkpoint and that
    this CPU runs, else fp32; a gated precision left out for the hardware is logged (warning).

    int8 also needs the checkpoint's calibration frames, and counts only if they and the int8 recipe are
    the ones its verdict was measured with (a verdict may be shipped without the frames).
    An explicit request is returned as it is (create_runner refuses what the CPU cannot run, with the reason).
    """
    if requested != "auto":
        return requested
    if device == "cuda":
        passed = gated_precisions(checkpoint, backend, device="cuda")
        return next(precision for precision in CUDA_PRECISION_SPEED_ORDER
                    if precision in supported_precisions(backend, "cuda") and (precision == "fp32" or precision in passed))
    build = int8_build(checkpoint)
    passed = gated_precisions(checkpoint, backend, build)
    if "int8" not in passed and _int8_verdict_passed(checkpoint, backend):
        if build is None:
            log.info("int8 passed the gate on %s but %s is missing or unreadable: not used", checkpoint,
                     calibration_path(checkpoint).name)
        else:
            log.warning("int8 passed the gate on %s with other calibration frames or another int8 recipe than "
                        "the files beside it now: not used (run the gate again)", checkpoint)
    capabilities = cpu_capabilities()
    runnable = cpu_precisions(capabilities)
    for precision in PRECISION_SPEED_ORDER:
        if precision not in supported_precisions(backend) or (precision != "fp32" and precision not in passed):
            continue
        if precision in runnable:
            return precision
        log.warning("precision auto: %s passed the accuracy gate for %s on %s, but this CPU cannot run it "
                    "(it reports %s); trying the next one", precision, checkpoint.name, backend, ", ".join(capabilities))
    return "fp32"  # not reached: every backend and every CPU runs fp32


def _int8_verdict_passed(checkpoint: Path, backend: Backend) -> bool:
    """Did int8 of `backend` pass the gate on this checkpoint, whatever its model was built from?"""
    verdict = gate_verdicts(checkpoint).get((backend, "int8"))
    return bool(verdict and verdict["passed"])


class DrivingModel:
    """A trained network on one backend, with the preprocessing constants it was trained with."""

    def __init__(
        self,
        runner: Runner,
        preprocess: PreprocessConfig,
        speed_scale: float,
        class_names: tuple[str, ...],
        has_segmentation: bool,
        backend: Backend = "torch",
        precision: Precision = "fp32",
        device: Device = "cpu",
    ) -> None:
        self.runner = runner
        self.preprocess = preprocess
        self.speed_scale = speed_scale
        self.class_names = class_names
        self.has_segmentation = has_segmentation
        self.backend = backend
        self.precision = precision
        self.device = device
        self._input_buffer = np.empty((preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32)
        self._input_shape = self._input_buffer.shape
        self._command_index = np.zeros(1, np.int64)  # reused: no per-frame allocation

    @classmethod
    def from_checkpoint(
        cls,
        path: Path | str,
        num_threads: int | None = None,
        backend: Backend | Literal["auto"] = "torch",
        precision: Precision | Literal["auto"] = "fp32",
        channels_last: bool = False,
        device: Device | Literal["auto"] = "cpu",
    ) -> DrivingModel:
        """Load a checkpoint (CheckpointError if unusable) onto a backend (BackendUnavailableError if it cannot).

        num_threads: intra-op threads of the backend (None: library default); it also sets torch's
        process-wide pool, so torch and the backend never run two pools side by side.
        int8 needs `<checkpoint>.calibration.npz` (calibration.py). device: cpu, cuda, or auto (cuda when torch
        sees a GPU).
        """
        path = Path(path)
        if num_threads is not None:
            torch.set_num_threads(num_threads)
        chosen_device = resolve_device(device)
        loaded = load_checkpoint(path)
        chosen_backend = resolve_backend(backend, chosen_device)
        chosen_precision = resolve_precision(path, chosen_backend, precision, chosen_device)
        try:
            calibration = CalibrationSet.for_checkpoint(path) if chosen_precision == "int8" else None
        except ValueError as error:  # a damaged calibration file
            raise BackendUnavailableError(str(error)) from None
        runner = create_runner(loaded.model, path, chosen_backend, chosen_precision, num_threads, calibration,
                               channels_last, chosen_device, loaded.preprocess)
        return cls(runner, loaded.preprocess, loaded.speed_scale, loaded.class_names,
                   loaded.model.config.has_segmentation, chosen_backend, chosen_precision, chosen_device)

    def prepare(self, rgb: np.ndarray, depth: np.ndarray | None) -> np.ndarray | torch.Tensor:
        """A camera frame -> the network's input, where the network runs: `preprocess_frame` into a reused buffer
        on the CPU; on a GPU runner with `prepare` (torch in a CUDA graph) the same function on the GPU, into the
        graph's input. Only valid until the next call. Depth must have gone through `sanitize_depth`."""
        device_prepare = getattr(self.runner, "prepare", None)
        if device_prepare is not None:
            return device_prepare(rgb, depth)
        return preprocess_frame(rgb, depth, self.preprocess, out=self._input_buffer)

    def predict(self, inputs: np.ndarray | torch.Tensor, command: RoadOption) -> Prediction:
        """inputs: (C, h, w) float32 from `preprocess_frame` with `self.preprocess`, or what `prepare` returned."""
        self._command_index[0] = command.branch_index
        if isinstance(inputs, torch.Tensor):
            if inputs is not getattr(self.runner, "inputs", None):
                raise ValueError("a tensor input must be the one `prepare` returned")
            output = self.runner(inputs, self._command_index)
        else:
            if inputs.shape != self._input_shape or inputs.dtype != np.float32:
                raise ValueError(f"inputs must be {self._input_shape} float32, got {inputs.shape} {inputs.dtype}")
            output = self.runner(np.ascontiguousarray(inputs)[None], self._command_index)
        return Prediction(
            steer=float(np.clip(output.steer, -1.0, 1.0)),
            target_speed=max(0.0, output.speed * self.speed_scale),
            class_ids=output.class_ids,
        )


def input_rgb(inputs: np.ndarray | torch.Tensor) -> np.ndarray:
    """The RGB the network saw, (h, w, 3) uint8 (for overlays), from a CPU or GPU input."""
    if isinstance(inputs, torch.Tensor):
        inputs = inputs[0, :3].float().cpu().numpy()
    return (inputs[:3].transpose(1, 2, 0) * 255.0).round().astype(np.uint8)


__all__ = ["BackendUnavailableError", "DrivingModel", "Prediction", "input_rgb", "resolve_backend",
           "resolve_device", "resolve_precision"]
