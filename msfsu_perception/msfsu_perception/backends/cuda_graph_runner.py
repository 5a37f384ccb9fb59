"""The network on a CUDA GPU, captured once in a CUDA graph: only the camera frame goes in, only the outputs come back.

`CudaGraphRunner` holds the deployed graph (export.TensorOutputs with the argmax inside, class ids as uint8) on the
GPU in fp32, fp16 or bf16 (weights and activations in that type; channels-last, cuDNN's preferred layout for
tensor cores), with its input and command in fixed device tensors. At construction it warms the network up on a
side stream and captures one forward pass in a `torch.cuda.CUDAGraph`; every frame then costs one graph launch
instead of some 200 kernel launches from Python (eager against graph: benchmarks/gpu_results.md).

Two ways in, one network:
  - `__call__(inputs, command_index)`: the Runner protocol of backends.base, a preprocessed float32 frame from the CPU
    (bag replay, the accuracy gate);
  - `prepare(rgb, depth)` then `__call__(runner.inputs, ...)`: the camera's uint8 RGB and float32 depth go to the GPU
    and `device_preprocessing.DevicePreprocessor` crops, resizes and scales them there, into the graph's input.
Outputs come back through pinned host buffers after one stream synchronisation per frame.
"""

from __future__ import annotations

import copy

import numpy as np
import torch

from msfsu_perception.backends.base import RawOutputs
from msfsu_perception.device_preprocessing import DevicePreprocessor
from msfsu_perception.export import TensorOutputs
from msfsu_perception.model import MSFSUNet
from msfsu_perception.preprocessing import PreprocessConfig

DTYPES: dict[str, torch.dtype] = {"fp32": torch.float32, "fp16": torch.float16, "bf16": torch.bfloat16}
WARM_UP_PASSES = 3  # cuDNN picks its algorithms and the caching allocator settles before the capture


class CudaGraphRunner:
    """One network on one CUDA device at one precision, batch 1; `graph=False` runs it eagerly (the same kernels
    launched one by one: the baseline of benchmarks/gpu.py)."""

    def __init__(self, network: MSFSUNet, precision: str, preprocess: PreprocessConfig,
                 device: torch.device | str = "cuda", graph: bool = True) -> None:
        if precision not in DTYPES:
            raise ValueError(f"a GPU runs {', '.join(DTYPES)}, not {precision!r}")
        self.device = torch.device(device)
        if self.device.type != "cuda":
            raise ValueError(f"CudaGraphRunner needs a CUDA device, got {self.device}")
        self.preprocess, self.precision = preprocess, precision
        dtype = DTYPES[precision]
        torch.backends.cudnn.benchmark = True  # fixed shapes: the fastest convolution algorithm is found once
        self.module = TensorOutputs(copy.deepcopy(network), class_ids=True)  # the caller's network stays as it is
        self.module.eval().to(self.device, dtype)
        self.module.to(memory_format=torch.channels_last)
        shape = (1, preprocess.channels, preprocess.input_height, preprocess.input_width)
        self.inputs = torch.zeros(shape, dtype=dtype, device=self.device).contiguous(memory_format=torch.channels_last)
        self.command = torch.zeros(1, dtype=torch.int64, device=self.device)
        self._preprocessors: dict[tuple[int, int], DevicePreprocessor] = {}
        self.graph: torch.cuda.CUDAGraph | None = None
        with torch.inference_mode():
            side = torch.cuda.Stream(self.device)
            side.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(side):
                for _ in range(WARM_UP_PASSES):
                    outputs = self.module(self.inputs, self.command)
            torch.cuda.current_stream(self.device).wait_stream(side)
            if graph:
                self.graph = torch.cuda.CUDAGraph()
                with torch.cuda.graph(self.graph):
                    outputs = self.module(self.inputs, self.command)
        self._device_outputs: tuple[torch.Tensor, ...] = outputs
        self._host_outputs = tuple(torch.empty(o.shape, dtype=o.dtype if o.dtype == torch.uint8 else torch.float32,
                                               pin_memory=True) for o in outputs)

    def prepare(self, rgb: np.ndarray, depth: np.ndarray | None) -> torch.Tensor:
        """`preprocess_frame` on the GPU, written into the graph's input; returns that input (`self.inputs`)."""
        height, width = rgb.shape[:2]
        preprocessor = self._preprocessors.get((height, width))
        if preprocessor is None:  # one per camera size (its resize weights: 2 MB at 1920x1080)
            preprocessor = DevicePreprocessor(self.preprocess, height, width, self.device)
            self._preprocessors[(height, width)] = preprocessor
        with torch.inference_mode():
            self.inputs.copy_(preprocessor(rgb, depth))
        return self.inputs

    def __call__(self, inputs: np.ndarray | torch.Tensor, command_index: np.ndarray) -> RawOutputs:
        """inputs: (1, C, h, w) float32 from the CPU, or `self.inputs` as `prepare` left it."""
        with torch.inference_mode():
            if inputs is not self.inputs:
                self.inputs.copy_(torch.as_tensor(inputs), non_blocking=False)
            self.command.copy_(torch.from_numpy(command_index))
            if self.graph is not None:
                self.graph.replay()
                outputs = self._device_outputs
            else:
                outputs = self.module(self.inputs, self.command)
            for host, output in zip(self._host_outputs, outputs):
                host.copy_(output, non_blocking=True)
            torch.cuda.current_stream(self.device).synchronize()
        steer, speed, *class_ids = self._host_outputs
        return RawOutputs(float(steer[0]), float(speed[0]),
                          class_ids[0][0].numpy().copy() if class_ids else None)  # a copy the caller may keep
