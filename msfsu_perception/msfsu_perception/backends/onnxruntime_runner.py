"""ONNX Runtime: the exported network on the CPU execution provider (fp32, int8 by its static QDQ quantiser), or on
its TensorRT / CUDA providers where the installed build has them (onnxruntime-gpu, fp32)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from msfsu_perception.backends.base import RawOutputs, raw_outputs
from msfsu_perception.backends.model_files import calibration_feeds, onnx_fp32
from msfsu_perception.deploy_files import CalibrationSet, DeployFiles
from msfsu_perception.int8_recipe import Int8Recipe, graph_layers, onnx_nodes_to_exclude
from msfsu_perception.model import MSFSUNet

GPU_PROVIDERS = ("TensorrtExecutionProvider", "CUDAExecutionProvider")  # preferred first


def gpu_providers() -> list[str]:
    """The GPU execution providers of the installed ONNX Runtime, preferred first ([] for the CPU-only build)."""
    import onnxruntime

    available = set(onnxruntime.get_available_providers())
    return [provider for provider in GPU_PROVIDERS if provider in available]


class OnnxRuntimeRunner:
    """providers: ONNX Runtime execution providers, preferred first; the CPU provider is always last."""

    def __init__(self, model: Path, num_threads: int | None, providers: Sequence[str] = ()) -> None:
        import onnxruntime

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = num_threads or 0  # 0: one per physical core
        options.inter_op_num_threads = 1  # one graph at a time: no second pool competing for the cores
        options.execution_mode = onnxruntime.ExecutionMode.ORT_SEQUENTIAL
        self.session = onnxruntime.InferenceSession(str(model), options, providers=[*providers, "CPUExecutionProvider"])

    def __call__(self, inputs: np.ndarray, command_index: np.ndarray) -> RawOutputs:
        return raw_outputs(self.session.run(None, {"inputs": inputs, "command_index": command_index}))


def onnxruntime_int8(store: DeployFiles, network: MSFSUNet, calibration: CalibrationSet,
                      recipe: Int8Recipe) -> Path:
    def quantise(path: Path) -> None:
        import onnx
        from onnxruntime.quantization import (
            CalibrationDataReader,
            QuantFormat,
            QuantType,
            quantize_static,
        )

        class Reader(CalibrationDataReader):
            def __init__(self) -> None:
                self.feeds = calibration_feeds(calibration)

            def get_next(self) -> dict[str, np.ndarray] | None:
                return next(self.feeds, None)

        onnx_model = onnx_fp32(store, network)
        excluded = onnx_nodes_to_exclude(graph_layers(onnx.load(str(onnx_model))), recipe)
        quantize_static(str(onnx_model), str(path), Reader(), quant_format=QuantFormat.QDQ,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True,
                        nodes_to_exclude=excluded)

    return store.get(f"int8-{calibration.digest}-{recipe.digest}.onnx", quantise)
