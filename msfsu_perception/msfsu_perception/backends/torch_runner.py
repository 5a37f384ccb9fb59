"""torch eager on the CPU: the reference (fp32), bf16 by CPU autocast."""

from __future__ import annotations

import numpy as np
import torch

from msfsu_perception.backends.base import Precision, RawOutputs, raw_outputs
from msfsu_perception.export import TensorOutputs
from msfsu_perception.model import MSFSUNet


class TorchRunner:
    """Eager torch; bf16 = CPU autocast, channels_last = NHWC weights and input (oneDNN's preferred layout)."""

    def __init__(self, network: MSFSUNet, precision: Precision, channels_last: bool = False) -> None:
        self.graph = TensorOutputs(network, class_ids=True).eval()
        self.memory_format = torch.channels_last if channels_last else torch.contiguous_format
        self.graph.to(memory_format=self.memory_format)
        self.bf16 = precision == "bf16"

    def __call__(self, inputs: np.ndarray, command_index: np.ndarray) -> RawOutputs:
        with torch.inference_mode(), torch.autocast("cpu", torch.bfloat16, enabled=self.bf16):
            outputs = self.graph(torch.from_numpy(inputs).contiguous(memory_format=self.memory_format),
                                 torch.from_numpy(command_index))
        return raw_outputs([output.float().numpy() for output in outputs])
