"""Inference backends behind one call: (1, C, H, W) float32 + (1,) command index -> steer, speed, class ids.

torch eager fp32 is the reference; ONNX Runtime and OpenVINO run the same network exported once to
ONNX with the argmax inside the graph (export.TensorOutputs(class_ids=True)). Derived model files are
cached in `<checkpoint>.deploy/`, named by the checkpoint's content hash (and, for int8, the
calibration set's hash): a changed checkpoint never meets a stale model, and files of older
checkpoints are removed when a new one is written.

Devices: the CPU (every backend), or a CUDA GPU: torch captured in a CUDA graph (gpu_runner.py) in fp32, fp16 or
bf16, ONNX Runtime fp32 through its TensorRT / CUDA execution providers where the installed build has them
(onnxruntime-gpu, `make setup TORCH=cuda`); OpenVINO runs on the CPU only here.

Precisions on the CPU: fp32 everywhere; bf16 = torch autocast or OpenVINO's bf16 inference hint (needs
avx512_bf16 or AMX); int8 = post-training quantisation calibrated on training-bag frames
(calibration.py): OpenVINO through NNCF, ONNX Runtime through its static QDQ quantiser, both leaving
the layers of the checkpoint's int8 recipe (int8_recipe.py) in fp32. Whether this
CPU runs bf16 / int8 at all is asked of the hardware once per model load (`cpu_precisions`): a path
the CPU cannot run is refused with the reason, whatever backend was asked for.
"""

from __future__ import annotations

import importlib.util
import logging
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Literal, NamedTuple, Protocol

import numpy as np
import torch

from msfsu_perception.deploy_files import CalibrationSet, DeployFiles, calibration_path
from msfsu_perception.export import TensorOutputs, export_onnx
from msfsu_perception.int8_recipe import (
    Int8Build,
    Int8Recipe,
    graph_layers,
    load_recipe,
    onnx_nodes_to_exclude,
    openvino_ignored_names,
)
from msfsu_perception.model import MSFSUNet
from msfsu_perception.preprocessing import PreprocessConfig

Backend = Literal["torch", "onnxruntime", "openvino"]
Precision = Literal["fp32", "fp16", "bf16", "int8"]
Device = Literal["cpu", "cuda"]
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
    "openvino": (),  # OpenVINO's GPU plugin is for Intel GPUs
}
ONNXRUNTIME_GPU_PROVIDERS = ("TensorrtExecutionProvider", "CUDAExecutionProvider")  # preferred first
MODULE_OF: dict[Backend, str] = {"torch": "torch", "onnxruntime": "onnxruntime", "openvino": "openvino"}
OPENVINO_TELEMETRY_CONSENT = Path.home() / "intel" / "openvino_telemetry"
# OpenVINO CPU plugin OPTIMIZATION_CAPABILITIES entry that says the CPU runs a precision in hardware
CPU_CAPABILITY: dict[Precision, str] = {"bf16": "BF16", "int8": "INT8"}

log = logging.getLogger(__name__)


class BackendUnavailableError(RuntimeError):
    """The backend is not installed, or does not run the requested precision on this machine."""


class RawOutputs(NamedTuple):
    steer: float  # network output, not clipped
    speed: float  # normalised: multiply by the checkpoint's speed_scale for m/s
    class_ids: np.ndarray | None  # (H, W) uint8, None for the MSF variant


class Runner(Protocol):
    def __call__(self, inputs: np.ndarray, command_index: np.ndarray) -> RawOutputs:
        """inputs (1, C, H, W) float32 C-contiguous, command_index (1,) int64."""


def supported_precisions(backend: Backend, device: Device = "cpu") -> tuple[Precision, ...]:
    return (CUDA_PRECISIONS if device == "cuda" else SUPPORTED_PRECISIONS)[backend]


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
    import onnxruntime

    available = set(onnxruntime.get_available_providers())
    return [provider for provider in ONNXRUNTIME_GPU_PROVIDERS if provider in available]


def is_installed(backend: Backend) -> bool:
    return importlib.util.find_spec(MODULE_OF[backend]) is not None


def cpu_capabilities() -> list[str]:
    """What the CPU offers, as OpenVINO's CPU plugin reports it (`OPTIMIZATION_CAPABILITIES`), e.g.
    ['BF16', 'FP32', 'INT8', ...]; BF16 only with avx512_bf16 or AMX. Without OpenVINO: ['FP32']."""
    if not is_installed("openvino"):
        return ["FP32"]
    import openvino

    return list(openvino.Core().get_property("CPU", "OPTIMIZATION_CAPABILITIES"))


def cpu_precisions(capabilities: list[str] | None = None) -> frozenset[Precision]:
    """Precisions this CPU runs: fp32 always, bf16 / int8 where the hardware reports them."""
    capabilities = cpu_capabilities() if capabilities is None else capabilities
    return frozenset({"fp32"} | {p for p, capability in CPU_CAPABILITY.items() if capability in capabilities})


def _raw_outputs(outputs: list[np.ndarray] | tuple[np.ndarray, ...]) -> RawOutputs:
    class_ids = np.array(outputs[2][0], np.uint8) if len(outputs) > 2 else None  # a copy the caller may keep
    return RawOutputs(float(outputs[0][0]), float(outputs[1][0]), class_ids)


# --- runners ------------------------------------------------------------------------------------
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
        return _raw_outputs([output.float().numpy() for output in outputs])


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
        return _raw_outputs(self.session.run(None, {"inputs": inputs, "command_index": command_index}))


class OpenVinoRunner:
    """Static batch-1 shapes, latency hint, one stream; compiled blobs cached (fast restarts).

    `model`: an IR / ONNX file, or an openvino.Model in memory (copied; nothing cached then). perf_count=True
    turns on OpenVINO's per-layer counters (`self.request.profiling_info`; benchmarks/int8_profile.py).
    """

    def __init__(self, model, precision: Precision, num_threads: int | None, cache_dir: Path | None,
                 perf_count: bool = False) -> None:
        import openvino

        core = openvino.Core()
        network = core.read_model(str(model)) if isinstance(model, (str, Path)) else model.clone()
        network.reshape({name: [1, *shape[1:]] for name, shape in _input_shapes(network).items()})
        config: dict[str, object] = {
            "PERFORMANCE_HINT": "LATENCY",
            "NUM_STREAMS": 1,
            "INFERENCE_PRECISION_HINT": "bf16" if precision == "bf16" else "f32",
            "PERF_COUNT": perf_count,
        }
        if cache_dir is not None:
            config["CACHE_DIR"] = str(cache_dir)
        if num_threads:
            config["INFERENCE_NUM_THREADS"] = num_threads
        self.request = core.compile_model(network, "CPU", config).create_infer_request()

    def __call__(self, inputs: np.ndarray, command_index: np.ndarray) -> RawOutputs:
        results = self.request.infer({"inputs": inputs, "command_index": command_index}, share_inputs=True)
        return _raw_outputs(tuple(results.values()))


def _create_cuda_runner(network: MSFSUNet, checkpoint: Path, backend: Backend, precision: Precision,
                        num_threads: int | None, preprocess: PreprocessConfig | None) -> Runner:
    if precision not in CUDA_PRECISIONS[backend]:
        runs = ", ".join(CUDA_PRECISIONS[backend]) or "nothing"
        raise BackendUnavailableError(f"{backend} on a CUDA GPU runs {runs}, not {precision}")
    if not cuda_available():
        raise BackendUnavailableError(f"device cuda: {cuda_unavailable_reason()}")
    if backend == "torch":
        from msfsu_perception.gpu_runner import CudaGraphRunner

        return CudaGraphRunner(network, precision, preprocess or PreprocessConfig())
    providers = onnxruntime_gpu_providers()
    if not providers:
        raise BackendUnavailableError("the installed ONNX Runtime has no CUDA or TensorRT execution provider "
                                      "(it is the CPU build; `make setup TORCH=cuda` installs onnxruntime-gpu)")
    return OnnxRuntimeRunner(_onnx_fp32(DeployFiles(checkpoint), network), num_threads, providers)


def _input_shapes(network) -> dict[str, list[int]]:
    return {port.get_any_name(): list(port.get_partial_shape().get_min_shape()) for port in network.inputs}


# --- derived model files: msfsu_perception.deploy_files -------------------------------------------
def _onnx_fp32(store: DeployFiles, network: MSFSUNet) -> Path:
    return store.get("fp32.onnx", lambda path: export_onnx(network, path, class_ids=True))


def _calibration_feeds(calibration: CalibrationSet) -> Iterator[dict[str, np.ndarray]]:
    for inputs, command_index in calibration.batches():
        yield {"inputs": inputs, "command_index": command_index}


def ensure_openvino_telemetry_off() -> None:
    """NNCF sends usage data unless the OpenVINO consent file says "0"; nothing may leave the machine.

    Writing the file is what `opt_in_out --opt_out` does, minus the "declined" event that tool sends.
    """
    if OPENVINO_TELEMETRY_CONSENT.is_file() and OPENVINO_TELEMETRY_CONSENT.read_text().strip() == "0":
        return
    OPENVINO_TELEMETRY_CONSENT.parent.mkdir(parents=True, exist_ok=True)
    OPENVINO_TELEMETRY_CONSENT.write_text("0")
    log.warning("opted out of OpenVINO/NNCF telemetry (%s = 0)", OPENVINO_TELEMETRY_CONSENT)


def int8_build(checkpoint: Path, calibration: CalibrationSet | None = None) -> Int8Build | None:
    """What this checkpoint's int8 model is made from now (calibration frames + recipe); None without usable frames."""
    if calibration is None:
        path = calibration_path(checkpoint)
        if not path.is_file():
            return None
        try:
            calibration = CalibrationSet.load(path)
        except ValueError as error:
            log.warning("int8 cannot be built: %s", error)
            return None
    recipe = load_recipe(checkpoint)
    return Int8Build(calibration.digest, recipe.digest, recipe.keep_float)


def nncf_quantize(model, calibration: CalibrationSet, recipe: Int8Recipe, onnx_model: Path,
                  compress_weights: bool = True):
    """NNCF post-training quantisation of an openvino.Model read from `onnx_model`, per `recipe`.

    compress_weights=False keeps weights as float constants behind FakeQuantize (for per-layer experiments:
    msfsu_evaluation.int8_sensitivity); the deployed model stores them as int8.
    """
    ensure_openvino_telemetry_off()
    import nncf
    import onnx
    from nncf.quantization.advanced_parameters import AdvancedQuantizationParameters

    ignored = openvino_ignored_names(model, graph_layers(onnx.load(str(onnx_model), load_external_data=False)),
                                     recipe)
    feeds = list(_calibration_feeds(calibration))
    return nncf.quantize(
        model, nncf.Dataset(feeds), subset_size=len(feeds),
        preset=nncf.QuantizationPreset.MIXED if recipe.preset == "mixed" else nncf.QuantizationPreset.PERFORMANCE,
        fast_bias_correction=recipe.fast_bias_correction,
        ignored_scope=nncf.IgnoredScope(names=ignored) if ignored else None,
        advanced_parameters=AdvancedQuantizationParameters(backend_params={"compress_weights": compress_weights}))


def _openvino_int8(store: DeployFiles, network: MSFSUNet, calibration: CalibrationSet, recipe: Int8Recipe) -> Path:
    def quantise(path: Path) -> None:
        import openvino

        onnx_model = _onnx_fp32(store, network)
        quantised = nncf_quantize(openvino.Core().read_model(str(onnx_model)), calibration, recipe, onnx_model)
        openvino.save_model(quantised, str(path))

    return store.get(f"int8-{calibration.digest}-{recipe.digest}.xml", quantise)


def _onnxruntime_int8(store: DeployFiles, network: MSFSUNet, calibration: CalibrationSet,
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
                self.feeds = _calibration_feeds(calibration)

            def get_next(self) -> dict[str, np.ndarray] | None:
                return next(self.feeds, None)

        onnx_model = _onnx_fp32(store, network)
        excluded = onnx_nodes_to_exclude(graph_layers(onnx.load(str(onnx_model))), recipe)
        quantize_static(str(onnx_model), str(path), Reader(), quant_format=QuantFormat.QDQ,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True,
                        nodes_to_exclude=excluded)

    return store.get(f"int8-{calibration.digest}-{recipe.digest}.onnx", quantise)


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
        model = (_onnxruntime_int8(store, network, calibration, recipe) if precision == "int8"
                 else _onnx_fp32(store, network))
        return OnnxRuntimeRunner(model, num_threads)
    model = _openvino_int8(store, network, calibration, recipe) if precision == "int8" else _onnx_fp32(store, network)
    return OpenVinoRunner(model, precision, num_threads, store.openvino_cache)
