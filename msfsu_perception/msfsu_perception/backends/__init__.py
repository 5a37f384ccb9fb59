"""Inference backends behind one call: (1, C, H, W) float32 + (1,) command index -> steer, speed, class ids.

One module per backend, each a runner with that one call (`base.Runner`), side by side:
  torch_runner.py        torch eager on the CPU: the reference (fp32), bf16 by autocast
  cuda_graph_runner.py   torch on a CUDA GPU, captured in a CUDA graph: fp32, fp16, bf16; preprocessing on the GPU
  onnxruntime_runner.py  ONNX Runtime: CPU provider (fp32, int8 QDQ), TensorRT / CUDA providers where installed (fp32)
  openvino_runner.py     OpenVINO on the CPU: fp32, bf16, int8 (NNCF)
This module says what runs where and builds the runner (`create_runner`); model_files.py holds the files the
exported-network backends share.

torch eager fp32 is the reference; ONNX Runtime and OpenVINO run the same network exported once to
ONNX with the argmax inside the graph (export.TensorOutputs(class_ids=True)). Derived model files are
cached in `<checkpoint>.deploy/`, named by the checkpoint's content hash (and, for int8, the
calibration set's hash): a changed checkpoint never meets a stale model, and files of older
checkpoints are removed when a new one is written.

Precisions on the CPU: fp32 everywhere; bf16 = torch autocast or OpenVINO's bf16 inference hint (needs
avx512_bf16 or AMX); int8 = post-training quantisation calibrated on training-bag frames
(calibration.py): OpenVINO through NNCF, ONNX Runtime through its static QDQ quantiser, both leaving
the layers of the checkpoint's int8 recipe (int8_recipe.py) in fp32. Whether this
CPU runs bf16 / int8 at all is asked of the hardware once per model load (`cpu_precisions`): a path
the CPU cannot run is refused with the reason, whatever backend was asked for. On a CUDA GPU: torch in fp32, fp16,
bf16; ONNX Runtime fp32 (`make setup TORCH=cuda` installs onnxruntime-gpu); OpenVINO not (its GPU plugin is for
Intel GPUs).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import torch

from msfsu_perception.backends.base import (
    Backend,
    BackendUnavailableError,
    Device,
    Precision,
    RawOutputs,
    Runner,
    raw_outputs,
)
from msfsu_perception.backends.model_files import int8_build, onnx_fp32
from msfsu_perception.backends.onnxruntime_runner import (
    OnnxRuntimeRunner,
    onnxruntime_int8,
)
from msfsu_perception.backends.openvino_runner import (
    CPU_CAPABILITY,
    OpenVinoRunner,
    ensure_openvino_telemetry_off,
    nncf_quantize,
    openvino_core,
    openvino_int8,
)
from msfsu_perception.backends.torch_runner import TorchRunner
from msfsu_perception.deploy_files import CalibrationSet, DeployFiles, calibration_path
from msfsu_perception.int8_recipe import load_recipe
from msfsu_perception.model import MSFSUNet
from msfsu_perception.preprocessing import PreprocessConfig

BACKENDS: tuple[Backend, ...] = ("torch", "onnxruntime", "openvino")
DEVICES: tuple[Device, ...] = ("cpu", "cuda")
SUPPORTED_PRECISIONS: dict[Backend, tuple[Precision, ...]] = {  # on the CPU
    "torch": ("fp32", "bf16"),
    "onnxruntime": ("fp32", "int8"),  # the CPU execution provider has no bf16 kernels
    "openvino": ("fp32", "bf16", "int8"),
}
CUDA_PRECISIONS: dict[Backend, tuple[Precision, ...]] = {  # on a CUDA GPU
    "torch": ("fp32", "fp16", "bf16"),
    "onnxruntime": ("fp32",),
    "openvino": (),
}
MODULE_OF: dict[Backend, str] = {"torch": "torch", "onnxruntime": "onnxruntime", "openvino": "openvino"}


def supported_precisions(backend: Backend, device: Device = "cpu") -> tuple[Precision, ...]:
    return (CUDA_PRECISIONS if device == "cuda" else SUPPORTED_PRECISIONS)[backend]


def is_installed(backend: Backend) -> bool:
    return importlib.util.find_spec(MODULE_OF[backend]) is not None


def cpu_capabilities() -> list[str]:
    """What the CPU offers, as OpenVINO's CPU plugin reports it (`OPTIMIZATION_CAPABILITIES`), e.g.
    ['BF16', 'FP32', 'INT8', ...]; BF16 only with avx512_bf16 or AMX. Without OpenVINO: ['FP32']."""
    if not is_installed("openvino"):
        return ["FP32"]
    from msfsu_perception.backends import openvino_runner

    return openvino_runner.cpu_capabilities()


def cpu_precisions(capabilities: list[str] | None = None) -> frozenset[Precision]:
    """Precisions this CPU runs: fp32 always, bf16 / int8 where the hardware reports them."""
    capabilities = cpu_capabilities() if capabilities is None else capabilities
    return frozenset({"fp32"} | {p for p, capability in CPU_CAPABILITY.items() if capability in capabilities})


def cuda_available() -> bool:
    return torch.cuda.is_available()


def cuda_unavailable_reason() -> str:
    """One line: why this torch has no CUDA device, and what gives it one."""
    if torch.version.cuda is None:
        return (f"this torch ({torch.__version__}) is a CPU build: install the CUDA build with `make setup TORCH=cuda`, "
                "or use device cpu / auto")
    return f"torch {torch.__version__} is a CUDA build, but it finds no CUDA device (driver, CUDA_VISIBLE_DEVICES?)"


def onnxruntime_gpu_providers() -> list[str]:
    """The GPU execution providers of the installed ONNX Runtime, preferred first ([] for the CPU-only build)."""
    if not is_installed("onnxruntime"):
        return []
    from msfsu_perception.backends import onnxruntime_runner

    return onnxruntime_runner.gpu_providers()


def create_runner(
    network: MSFSUNet,
    checkpoint: Path,
    backend: Backend,
    precision: Precision,
    num_threads: int | None = None,
    calibration: CalibrationSet | None = None,
    channels_last: bool = False,
    device: Device = "cpu",
    preprocess: PreprocessConfig | None = None,
) -> Runner:
    """A runner for `network` (loaded from `checkpoint`); BackendUnavailableError says why not.

    device "cuda": `preprocess` (the checkpoint's) sizes the GPU runner's input and its on-device preprocessing.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; choose from {BACKENDS}")
    if device not in DEVICES:
        raise ValueError(f"unknown device {device!r}; choose from {DEVICES}")
    if device == "cuda":
        return _create_cuda_runner(network, checkpoint, backend, precision, num_threads, preprocess)
    if precision not in SUPPORTED_PRECISIONS[backend]:
        raise BackendUnavailableError(
            f"{backend} does not run {precision}; it runs {', '.join(SUPPORTED_PRECISIONS[backend])}")
    if not is_installed(backend):
        raise BackendUnavailableError(f"{backend} is not installed (pip module '{MODULE_OF[backend]}')")
    capabilities = cpu_capabilities()
    if precision not in cpu_precisions(capabilities):
        raise BackendUnavailableError(
            f"this CPU cannot run {precision} (it reports {', '.join(capabilities)}; bf16 needs avx512_bf16 or AMX): "
            "use precision fp32, or auto")
    if backend == "torch":
        return TorchRunner(network, precision, channels_last)
    if precision == "int8" and calibration is None:
        raise BackendUnavailableError(
            f"int8 needs calibration frames: {calibration_path(checkpoint)} is missing "
            "(python -m msfsu_perception.calibration --help)")
    store = DeployFiles(checkpoint)
    recipe = load_recipe(checkpoint) if precision == "int8" else None
    if backend == "onnxruntime":
        model = (onnxruntime_int8(store, network, calibration, recipe) if precision == "int8"
                 else onnx_fp32(store, network))
        return OnnxRuntimeRunner(model, num_threads)
    model = openvino_int8(store, network, calibration, recipe) if precision == "int8" else onnx_fp32(store, network)
    return OpenVinoRunner(model, precision, num_threads, store.openvino_cache)


def _create_cuda_runner(network: MSFSUNet, checkpoint: Path, backend: Backend, precision: Precision,
                        num_threads: int | None, preprocess: PreprocessConfig | None) -> Runner:
    if precision not in CUDA_PRECISIONS[backend]:
        runs = ", ".join(CUDA_PRECISIONS[backend]) or "nothing"
        raise BackendUnavailableError(f"{backend} on a CUDA GPU runs {runs}, not {precision}")
    if not cuda_available():
        raise BackendUnavailableError(f"device cuda: {cuda_unavailable_reason()}")
    if backend == "torch":
        from msfsu_perception.backends.cuda_graph_runner import CudaGraphRunner

        return CudaGraphRunner(network, precision, preprocess or PreprocessConfig())
    providers = onnxruntime_gpu_providers()
    if not providers:
        raise BackendUnavailableError("the installed ONNX Runtime has no CUDA or TensorRT execution provider "
                                      "(it is the CPU build; `make setup TORCH=cuda` installs onnxruntime-gpu)")
    return OnnxRuntimeRunner(onnx_fp32(DeployFiles(checkpoint), network), num_threads, providers)


__all__ = ["BACKENDS", "CUDA_PRECISIONS", "DEVICES", "SUPPORTED_PRECISIONS", "Backend", "BackendUnavailableError",
           "Device", "OnnxRuntimeRunner", "OpenVinoRunner", "Precision", "RawOutputs", "Runner", "TorchRunner",
           "cpu_capabilities", "cpu_precisions", "create_runner", "cuda_available", "cuda_unavailable_reason",
           "ensure_openvino_telemetry_off", "int8_build", "is_installed", "nncf_quantize", "onnx_fp32",
           "onnxruntime_gpu_providers", "openvino_core", "raw_outputs", "supported_precisions"]
