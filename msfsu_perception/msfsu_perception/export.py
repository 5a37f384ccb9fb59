"""ONNX export of a checkpoint, verified against torch with ONNX Runtime.

Graph inputs: `inputs` (B, C, H, W) float32 from preprocess_frame, `command_index` (B,) int64
(RoadOption.branch_index). Outputs: `steer` (B,), `speed` (B,) normalised (multiply by the
checkpoint's speed_scale for m/s), and `segmentation_logits` (B, 5, H, W) unless the variant is MSF.
The batch dimension is dynamic. With `class_ids=True` (what the inference backends deploy) the
segmentation output is `class_ids` (B, H, W) uint8 instead: the argmax runs inside the graph, so a
backend hands back 50 kB of ids instead of 1 MB of logits and no numpy argmax follows.

    msfsu-export-onnx runs/cpu/best.pt runs/cpu/best.onnx
"""

from __future__ import annotations

import argparse
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import nn

from msfsu_perception.checkpoint import load_checkpoint
from msfsu_perception.model import MSFSUNet

INPUT_NAMES = ("inputs", "command_index")
PARITY_TOLERANCE = 1e-4
DEFAULT_OPSET = 18


class OnnxExportError(RuntimeError):
    """The exported graph does not reproduce the torch outputs."""


class TensorOutputs(nn.Module):
    """MSFSUNet with a flat tuple of tensors as output (ONNX has no None / NamedTuple).

    class_ids=True replaces the logits by their argmax as uint8 (the deployed graph).
    """

    def __init__(self, network: MSFSUNet, class_ids: bool = False) -> None:
        super().__init__()
        self.network = network
        self.class_ids = class_ids

    def forward(self, inputs: torch.Tensor, command_index: torch.Tensor) -> tuple[torch.Tensor, ...]:
        output = self.network(inputs, command_index)
        if output.segmentation_logits is None:
            return output.steer, output.speed
        if self.class_ids:
            return output.steer, output.speed, output.segmentation_logits.argmax(1).to(torch.uint8)
        return output.steer, output.speed, output.segmentation_logits


def output_names(network: MSFSUNet, class_ids: bool = False) -> tuple[str, ...]:
    if not network.config.has_segmentation:
        return ("steer", "speed")
    return ("steer", "speed", "class_ids" if class_ids else "segmentation_logits")


def export_onnx(network: MSFSUNet, path: Path | str, opset: int = DEFAULT_OPSET, class_ids: bool = False) -> None:
    """Write `network` (put in eval mode) as one self-contained .onnx file (torch.export based exporter)."""
    config = network.config
    example = (
        torch.rand(2, config.in_channels, config.input_height, config.input_width),
        torch.tensor([0, config.num_commands - 1]),
    )
    batch = torch.export.Dim("batch")
    with warnings.catch_warnings():  # known, harmless exporter noise of torch 2.13
        warnings.filterwarnings("ignore", message=".*axis name: batch will not be used", category=UserWarning)
        warnings.filterwarnings("ignore", message=".*isinstance\\(treespec, LeafSpec\\)", category=FutureWarning)
        torch.onnx.export(
            TensorOutputs(network, class_ids).eval(),
            example,
            str(path),
            input_names=list(INPUT_NAMES),
            output_names=list(output_names(network, class_ids)),
            dynamic_shapes=({0: batch}, {0: batch}),
            opset_version=opset,
            dynamo=True,
            external_data=False,
            verbose=False,
        )


def check_parity(network: MSFSUNet, path: Path | str, batch_size: int = 4, seed: int = 0) -> float:
    """Max |onnxruntime - torch| over all outputs on a random batch with every command; raises above tolerance."""
    import onnxruntime

    config = network.config
    generator = torch.Generator().manual_seed(seed)
    inputs = torch.rand(batch_size, config.in_channels, config.input_height, config.input_width, generator=generator)
    commands = torch.arange(batch_size) % config.num_commands
    with torch.inference_mode():
        expected = TensorOutputs(network).eval()(inputs, commands)
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    actual = session.run(list(output_names(network)), {"inputs": inputs.numpy(), "command_index": commands.numpy()})
    error = max(float(np.max(np.abs(a - e.numpy()))) for a, e in zip(actual, expected))
    if error > PARITY_TOLERANCE:
        raise OnnxExportError(f"ONNX Runtime differs from torch by {error:.2e} (tolerance {PARITY_TOLERANCE:.0e})")
    return error


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="msfsu-export-onnx", description="Export a checkpoint to ONNX.")
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("output", type=Path)
    parser.add_argument("--opset", type=int, default=DEFAULT_OPSET)
    args = parser.parse_args(argv)
    network = load_checkpoint(args.checkpoint).model
    export_onnx(network, args.output, args.opset)
    print(f"wrote {args.output}; max |onnxruntime - torch| = {check_parity(network, args.output):.2e}")


if __name__ == "__main__":
    main()
