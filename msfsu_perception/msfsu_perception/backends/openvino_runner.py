"""OpenVINO on the CPU: the exported network in fp32, bf16 (its inference hint, avx512_bf16 / AMX) or int8
(NNCF post-training quantisation, weights stored as int8); compiled blobs cached beside the checkpoint."""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import numpy as np

from msfsu_perception.backends.base import Precision, RawOutputs, raw_outputs
from msfsu_perception.backends.model_files import calibration_feeds, onnx_fp32
from msfsu_perception.deploy_files import CalibrationSet, DeployFiles
from msfsu_perception.int8_recipe import (
    Int8Recipe,
    graph_layers,
    openvino_ignored_names,
)
from msfsu_perception.model import MSFSUNet

TELEMETRY_CONSENT = Path.home() / "intel" / "openvino_telemetry"
# OpenVINO CPU plugin OPTIMIZATION_CAPABILITIES entry that says the CPU runs a precision in hardware
CPU_CAPABILITY: dict[Precision, str] = {"bf16": "BF16", "int8": "INT8"}

log = logging.getLogger(__name__)


@functools.cache
def openvino_core():
    """The process's one `openvino.Core`, its CPU plugin loaded: every runner, query and model read goes through it.

    Each Core loads a CPU plugin of its own, and the plugin swaps the calling thread's alternate signal stack
    (sigaltstack, sized for AMX state) for one it maps, putting the previous one back when it is destroyed. Cores
    that end out of creation order leave the thread on an unmapped stack, and the next signal handled there
    (Ctrl-C, the launcher's SIGTERM: Python's handlers run on the alternate stack) is a segmentation fault, with
    no faulthandler report either. One Core for the life of the process holds one plugin, and its stack stays.
    """
    import openvino

    core = openvino.Core()
    core.get_property("CPU", "SUPPORTED_PROPERTIES")  # the plugin now, before any Core a library makes and drops
    return core


def cpu_capabilities() -> list[str]:
    """What the CPU offers, as OpenVINO's CPU plugin reports it (`OPTIMIZATION_CAPABILITIES`), e.g.
    ['BF16', 'FP32', 'INT8', ...]; BF16 only with avx512_bf16 or AMX."""
    return list(openvino_core().get_property("CPU", "OPTIMIZATION_CAPABILITIES"))


class OpenVinoRunner:
    """Static batch-1 shapes, latency hint, one stream; compiled blobs cached (fast restarts).

    `model`: an IR / ONNX file, or an openvino.Model in memory (copied; nothing cached then). perf_count=True
    turns on OpenVINO's per-layer counters (`self.request.profiling_info`; benchmarks/int8_profile.py).
    """

    def __init__(self, model, precision: Precision, num_threads: int | None, cache_dir: Path | None,
                 perf_count: bool = False) -> None:
        core = openvino_core()
        network = core.read_model(str(model)) if isinstance(model, (str, Path)) else model.clone()
        network.reshape({name: [1, *shape[1:]] for name, shape in input_shapes(network).items()})
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
        return raw_outputs(tuple(results.values()))


def input_shapes(network) -> dict[str, list[int]]:
    return {port.get_any_name(): list(port.get_partial_shape().get_min_shape()) for port in network.inputs}


def ensure_openvino_telemetry_off() -> None:
    """NNCF sends usage data unless the OpenVINO consent file says "0"; nothing may leave the machine.

    Writing the file is what `opt_in_out --opt_out` does, minus the "declined" event that tool sends.
    """
    if TELEMETRY_CONSENT.is_file() and TELEMETRY_CONSENT.read_text().strip() == "0":
        return
    TELEMETRY_CONSENT.parent.mkdir(parents=True, exist_ok=True)
    TELEMETRY_CONSENT.write_text("0")
    log.warning("opted out of OpenVINO/NNCF telemetry (%s = 0)", TELEMETRY_CONSENT)


def nncf_quantize(model, calibration: CalibrationSet, recipe: Int8Recipe, onnx_model: Path,
                  compress_weights: bool = True):
    """NNCF post-training quantisation of an openvino.Model read from `onnx_model`, per `recipe`.

    compress_weights=False keeps weights as float constants behind FakeQuantize (for per-layer experiments:
    msfsu_evaluation.deploy.recipe); the deployed model stores them as int8.
    """
    ensure_openvino_telemetry_off()
    import nncf
    import onnx
    from nncf.quantization.advanced_parameters import AdvancedQuantizationParameters

    ignored = openvino_ignored_names(model, graph_layers(onnx.load(str(onnx_model), load_external_data=False)),
                                     recipe)
    feeds = list(calibration_feeds(calibration))
    return nncf.quantize(
        model, nncf.Dataset(feeds), subset_size=len(feeds),
        preset=nncf.QuantizationPreset.MIXED if recipe.preset == "mixed" else nncf.QuantizationPreset.PERFORMANCE,
        fast_bias_correction=recipe.fast_bias_correction,
        ignored_scope=nncf.IgnoredScope(names=ignored) if ignored else None,
        advanced_parameters=AdvancedQuantizationParameters(backend_params={"compress_weights": compress_weights}))


def openvino_int8(store: DeployFiles, network: MSFSUNet, calibration: CalibrationSet, recipe: Int8Recipe) -> Path:
    def quantise(path: Path) -> None:
        import openvino

        onnx_model = onnx_fp32(store, network)
        quantised = nncf_quantize(openvino_core().read_model(str(onnx_model)), calibration, recipe, onnx_model)
        openvino.save_model(quantised, str(path))

    return store.get(f"int8-{calibration.digest}-{recipe.digest}.xml", quantise)
