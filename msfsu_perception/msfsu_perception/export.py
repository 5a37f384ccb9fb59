"""ONNX export of a checkpoint, verified against torch with ONNX Runtime.

Graph inputs: `inputs` (B, C, H, W) float32 from preprocess_frame, `command_index` (B,) int64
(RoadOption.branch_index). Outputs: `steer` (B,), `speed` (B,) normalised (multiply by the
checkpoint's speed_scale for m/s), and `segmentation_logits` (B, 5, H, W) unless the variant is MSF.
The batch dimension is dynamic. With `class_ids=True` (what the inference backends deploy) the
segmentation output is `class_ids` (B, H, W) uint8 instead: the argmax runs inside the graph, so a
backend hands back 50 kB of ids instead of 1 MB of logits and no numpy argmax follows.

The exported graph computes exactly what the torch network computes, in a form the inference runtimes run
fast: a non-overlapping transposed convolution (kernel = stride) with a stride above 3 (the v2 decoder's
first layer) is written as the 1x1 convolution + depth-to-space it is (`NonOverlappingDeconv`). OpenVINO's CPU
plugin runs no int8 transposed convolution with a stride above 3 (`Deconvolution::canBeExecutedInInt8`): the
paper network's 2048 -> 512, stride-4 layer stayed in fp32 inside the int8 model, 44 % of its time; as a 1x1
convolution it is an int8 GEMM like the encoder's. The stride-2 layers run int8 as they are and stay (the
rewrite would only add three depth-to-space copies at high resolution).

    msfsu-export-onnx runs/cpu/best.pt runs/cpu/best.onnx
"""

from __future__ import annotations

import argparse
import copy
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import nn

from msfsu_perception.checkpoint import load_checkpoint
from msfsu_perception.model import MSFSUNet

INPUT_NAMES = ("inputs", "command_index")
INT8_DECONV_MAX_STRIDE = 3  # the largest transposed-convolution stride OpenVINO's CPU plugin runs in int8
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


class NonOverlappingDeconv(nn.Conv2d):
    """nn.ConvTranspose2d with kernel = stride k, no padding, one group: a 1x1 convolution to C_out * k * k
    channels, then depth-to-space (ONNX DepthToSpace, CRD order) by k. Every output pixel comes from one input
    pixel, so the two are the same function; the weights are the deconvolution's, rearranged.

    A subclass of nn.Conv2d at the deconvolution's module path: the exported weight keeps its name
    (`network.decoder.layers.0.weight`), so int8 recipes name the layer as before (`decoder.layers.0`).
    """

    def __init__(self, deconv: nn.ConvTranspose2d) -> None:
        if not is_non_overlapping(deconv):
            raise ValueError(f"not a non-overlapping transposed convolution: {deconv}")
        k = deconv.stride[0]
        super().__init__(deconv.in_channels, deconv.out_channels * k * k, 1, bias=deconv.bias is not None)
        self.upscale = k
        with torch.no_grad():  # (C_in, C_out, k, k) -> (C_out * k * k, C_in, 1, 1): output channel (o, p, q)
            self.weight.copy_(deconv.weight.detach().permute(1, 2, 3, 0).reshape(-1, deconv.in_channels, 1, 1))
            if deconv.bias is not None:
                self.bias.copy_(deconv.bias.detach().repeat_interleave(k * k))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return nn.functional.pixel_shuffle(super().forward(x), self.upscale)


def is_non_overlapping(module: nn.Module) -> bool:
    """A transposed convolution whose output pixels each come from exactly one input pixel (kernel = stride)."""
    return (isinstance(module, nn.ConvTranspose2d) and module.kernel_size == module.stride
            and module.stride[0] == module.stride[1] > 1 and module.padding == (0, 0)
            and module.output_padding == (0, 0) and module.dilation == (1, 1) and module.groups == 1)


def deploy_graph(network: MSFSUNet) -> MSFSUNet:
    """A copy of `network` (eval mode) in the form that is exported: the non-overlapping transposed convolutions
    that OpenVINO would run in fp32 inside an int8 model rewritten as NonOverlappingDeconv."""
    graph = copy.deepcopy(network).eval()
    for name, module in list(graph.named_modules()):
        if is_non_overlapping(module) and module.stride[0] > INT8_DECONV_MAX_STRIDE:
            graph.set_submodule(name, NonOverlappingDeconv(module))
    return graph


def output_names(network: MSFSUNet, class_ids: bool = False) -> tuple[str, ...]:
    if not network.config.has_segmentation:
        return ("steer", "speed")
    return ("steer", "speed", "class_ids" if class_ids else "segmentation_logits")


def export_onnx(network: MSFSUNet, path: Path | str, opset: int = DEFAULT_OPSET, class_ids: bool = False,
                rewrite: bool = True) -> None:
    """Write `network` (its deploy_graph; as it is with rewrite=False, for comparisons) as one self-contained .onnx
    file (torch.export based exporter)."""
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
            TensorOutputs(deploy_graph(network) if rewrite else network, class_ids).eval(),
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
