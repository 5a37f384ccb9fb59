"""Every inference backend reproduces torch fp32; derived models are cached per checkpoint content; fallbacks.

Tolerances: the largest steer / speed error relative to the spread (max - min) of the torch fp32
outputs over the test frames, and the least share of pixels with the same class id. fp32: 1e-4 and
99.9 % (argmax ties may flip on rounding; measured ~1e-6 and 100 %); bf16 (8-bit mantissa): 5 % and
97 % (measured <= 1 % and 99.4 %); int8 (post-training quantisation on 16 random calibration frames):
25 % and 85 % (measured <= 5 % and 91 %). Whether int8 keeps a trained network's accuracy is the gate's job.
"""

import logging
import subprocess
import sys

import numpy as np
import pytest
import torch

from msfsu_common.road_option import RoadOption
from msfsu_perception import backends
from msfsu_perception.backends import (
    BACKENDS,
    SUPPORTED_PRECISIONS,
    BackendUnavailableError,
    cpu_precisions,
    int8_build,
    is_installed,
)
from msfsu_perception.checkpoint import save_checkpoint
from msfsu_perception.deploy_files import DeployFiles, calibration_path
from msfsu_perception.gate_verdicts import GateResult, HeldOutScores, record_gate_results
from msfsu_perception.int8_recipe import Int8Recipe, write_recipe
from msfsu_perception.inference import DrivingModel, resolve_backend, resolve_precision
from msfsu_perception.model import MSFSUConfig, build_model
from msfsu_perception.preprocessing import PreprocessConfig

SIZE = 64
TOLERANCE = {"fp32": (1e-4, 0.999), "bf16": (0.05, 0.97), "int8": (0.25, 0.85)}  # relative error, agreement
PATHS = [(b, p) for b in BACKENDS for p in SUPPORTED_PRECISIONS[b] if (b, p) != ("torch", "fp32")]


def write_checkpoint(path, seed: int, decoder_layout: str = "v2"):
    torch.manual_seed(seed)
    network = build_model(MSFSUConfig(backbone="resnet18v2", input_height=SIZE, input_width=SIZE,
                                      decoder_layout=decoder_layout))
    with torch.no_grad():  # BN statistics away from their initial values: outputs spread like a trained net's
        network(torch.rand(8, 4, SIZE, SIZE), torch.arange(8) % 4)
    save_checkpoint(path, network.eval(), PreprocessConfig(SIZE, SIZE))
    return path


def write_random_calibration(checkpoint, frames: int = 16):
    rng = np.random.default_rng(0)
    np.savez(calibration_path(checkpoint), rgb=rng.integers(0, 256, (frames, 3, SIZE, SIZE), np.uint8),
             depth=rng.random((frames, 1, SIZE, SIZE)).astype(np.float16), command_index=np.arange(frames) % 4)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    path = write_checkpoint(tmp_path_factory.mktemp("backends") / "model.pt", seed=0)
    write_random_calibration(path)
    return path


def frames(count: int = 6):
    rng = np.random.default_rng(1)
    return [(rng.random((4, SIZE, SIZE), dtype=np.float32), list(RoadOption)[i % 4]) for i in range(count)]


def outputs(model: DrivingModel):
    predictions = [model.predict(inputs, command) for inputs, command in frames()]
    steer = np.array([p.steer for p in predictions])
    speed = np.array([p.target_speed for p in predictions]) / model.speed_scale
    return steer, speed, np.stack([p.class_ids for p in predictions])


@pytest.mark.parametrize(("backend", "precision"), PATHS)
def test_backend_reproduces_torch_fp32_within_its_precision_tolerance(checkpoint, backend, precision):
    if not is_installed(backend):
        pytest.skip(f"{backend} is not installed")
    if precision not in cpu_precisions():
        pytest.skip(f"this CPU does not run {precision}")
    steer, speed, class_ids = outputs(DrivingModel.from_checkpoint(checkpoint, 1))
    assert np.ptp(steer) > 0.01 and np.ptp(speed) > 0.01 and len(np.unique(class_ids)) > 1  # outputs vary
    model = DrivingModel.from_checkpoint(checkpoint, 1, backend, precision)
    assert (model.backend, model.precision) == (backend, precision)
    fast_steer, fast_speed, fast_class_ids = outputs(model)
    relative_tolerance, min_agreement = TOLERANCE[precision]
    assert np.abs(fast_steer - steer).max() <= relative_tolerance * np.ptp(steer)
    assert np.abs(fast_speed - speed).max() <= relative_tolerance * np.ptp(speed)
    assert fast_class_ids.dtype == np.uint8 and np.mean(fast_class_ids == class_ids) >= min_agreement


@pytest.mark.parametrize("backend", ["onnxruntime", "openvino"])
def test_v1_decoder_of_the_shipped_checkpoints_runs_on_every_backend_in_fp32(tmp_path, backend):
    if not is_installed(backend):
        pytest.skip(f"{backend} is not installed")
    path = write_checkpoint(tmp_path / "v1.pt", seed=0, decoder_layout="v1")
    steer, speed, class_ids = outputs(DrivingModel.from_checkpoint(path, 1))
    fast_steer, fast_speed, fast_class_ids = outputs(DrivingModel.from_checkpoint(path, 1, backend, "fp32"))
    relative_tolerance, min_agreement = TOLERANCE["fp32"]
    assert np.abs(fast_steer - steer).max() <= relative_tolerance * np.ptp(steer)
    assert np.abs(fast_speed - speed).max() <= relative_tolerance * np.ptp(speed)
    assert len(np.unique(class_ids)) > 1 and np.mean(fast_class_ids == class_ids) >= min_agreement


@pytest.mark.skipif(not is_installed("onnxruntime"), reason="onnxruntime is not installed")
def test_changed_checkpoint_gets_a_fresh_export_and_the_unchanged_one_reuses_it(tmp_path, monkeypatch):
    path = write_checkpoint(tmp_path / "model.pt", seed=0)
    DrivingModel.from_checkpoint(path, 1, "onnxruntime", "fp32")
    first_export = DeployFiles(path).directory / f"{DeployFiles(path).prefix}-fp32.onnx"
    assert first_export.is_file()

    write_checkpoint(path, seed=1)  # retrained in place: same file name, new weights
    steer, speed, class_ids = outputs(DrivingModel.from_checkpoint(path, 1))
    fast_steer, fast_speed, fast_class_ids = outputs(DrivingModel.from_checkpoint(path, 1, "onnxruntime", "fp32"))
    assert np.abs(fast_steer - steer).max() <= 1e-4 and np.abs(fast_speed - speed).max() <= 1e-4
    assert not first_export.exists()  # the old version's files are gone

    def no_export(*args, **kwargs):
        raise AssertionError("exported again although the checkpoint did not change")

    monkeypatch.setattr(backends.model_files, "export_onnx", no_export)
    DrivingModel.from_checkpoint(path, 1, "onnxruntime", "fp32")


def test_missing_backend_falls_back_to_torch_with_a_warning(checkpoint, monkeypatch, caplog):
    monkeypatch.setitem(backends.MODULE_OF, "openvino", "msfsu_no_such_module")
    assert resolve_backend("auto") == "onnxruntime"
    with caplog.at_level(logging.WARNING):
        model = DrivingModel.from_checkpoint(checkpoint, 1, "openvino", "fp32")
    assert model.backend == "torch" and "openvino is not installed" in caplog.text
    with pytest.raises(BackendUnavailableError, match="openvino is not installed"):
        backends.create_runner(build_model(MSFSUConfig(backbone="resnet18v2", input_height=SIZE, input_width=SIZE)),
                               checkpoint, "openvino", "fp32")


def test_unsupported_precision_and_missing_calibration_raise_clear_errors(tmp_path):
    path = write_checkpoint(tmp_path / "model.pt", seed=0)
    with pytest.raises(BackendUnavailableError, match="onnxruntime does not run bf16"):
        DrivingModel.from_checkpoint(path, 1, "onnxruntime", "bf16")
    with pytest.raises(BackendUnavailableError, match="model.pt.calibration.npz is missing"):
        DrivingModel.from_checkpoint(path, 1, "onnxruntime", "int8")


def _gate_result(backend: str, precision: str, passed: bool, checkpoint=None) -> GateResult:
    """A verdict; an int8 one names the build (calibration frames + recipe) beside `checkpoint` now."""
    candidate_miou = 0.60 if passed else 0.50
    build = int8_build(checkpoint) if precision == "int8" and checkpoint is not None else None
    return GateResult(backend, precision, 10, HeldOutScores(0.1, 0.6), HeldOutScores(0.1, candidate_miou), 0.0, 1.0,
                      build=None if build is None else build.to_dict())


def test_auto_precision_uses_the_fastest_path_that_passed_the_gate_on_these_weights(tmp_path, cpu_reports):
    cpu_reports("BF16", "FP32", "INT8")  # a CPU that runs every precision
    path = write_checkpoint(tmp_path / "model.pt", seed=0)
    assert resolve_precision(path, "openvino", "auto") == "fp32"  # nothing gated yet
    record_gate_results(path, [_gate_result("openvino", "int8", passed=False), _gate_result("openvino", "bf16", True)])
    assert resolve_precision(path, "openvino", "auto") == "bf16"
    record_gate_results(path, [_gate_result("openvino", "int8", passed=True)])
    assert resolve_precision(path, "openvino", "auto") == "bf16"  # int8 passed, but no calibration frames
    write_random_calibration(path)
    assert resolve_precision(path, "openvino", "auto") == "bf16"  # ... and its verdict names no build
    record_gate_results(path, [_gate_result("openvino", "int8", passed=True, checkpoint=path)])
    assert resolve_precision(path, "openvino", "auto") == "int8"
    write_random_calibration(path, frames=8)
    assert resolve_precision(path, "openvino", "auto") == "bf16"  # not the frames int8 was gated with
    calibration_path(path).write_bytes(b"damaged")
    assert resolve_precision(path, "openvino", "auto") == "bf16"  # unreadable frames: no int8
    write_random_calibration(path)
    write_recipe(path, Int8Recipe(keep_float=("decoder.layers.0",)), {})
    assert resolve_precision(path, "openvino", "auto") == "bf16"  # nor the recipe
    DeployFiles(path).int8_recipe.unlink()
    assert resolve_precision(path, "openvino", "auto") == "int8"
    assert resolve_precision(path, "torch", "auto") == "fp32"  # verdicts are per backend
    assert resolve_precision(path, "openvino", "bf16") == "bf16"  # an explicit choice is kept
    write_checkpoint(path, seed=1)
    assert resolve_precision(path, "openvino", "auto") == "fp32"  # verdicts of other weights do not count


def test_auto_precision_takes_the_fastest_gated_path_this_cpu_runs(tmp_path, cpu_reports, caplog):
    path = write_checkpoint(tmp_path / "model.pt", seed=0)
    write_random_calibration(path)
    record_gate_results(path, [_gate_result("openvino", "int8", True, path), _gate_result("openvino", "bf16", True),
                               _gate_result("torch", "bf16", True)])
    cpu_reports("FP32", "BF16")  # avx512_bf16 but no int8 kernels
    assert resolve_precision(path, "openvino", "auto") == "bf16"
    cpu_reports("FP32", "INT8")  # VNNI but no avx512_bf16 / AMX
    assert resolve_precision(path, "openvino", "auto") == "int8"
    with caplog.at_level(logging.WARNING):
        assert resolve_precision(path, "torch", "auto") == "fp32"
    assert "bf16 passed the accuracy gate for model.pt on torch, but this CPU cannot run it" in caplog.text
    assert resolve_precision(path, "torch", "bf16") == "bf16"  # explicit: create_runner says why it cannot
    with pytest.raises(BackendUnavailableError, match="this CPU cannot run bf16 .* use precision fp32, or auto"):
        DrivingModel.from_checkpoint(path, 1, "torch", "bf16")


def test_openvino_telemetry_is_opted_out_before_nncf_runs(tmp_path, monkeypatch):
    consent = tmp_path / "intel" / "openvino_telemetry"
    monkeypatch.setattr(backends.openvino_runner, "TELEMETRY_CONSENT", consent)
    backends.ensure_openvino_telemetry_off()
    assert consent.read_text() == "0"  # "0" = declined: openvino_telemetry sends nothing


# Two OpenVINO Cores ended out of creation order used to leave the main thread on an unmapped alternate signal stack
# (the CPU plugin swaps in its own): the next signal segfaulted the process, e.g. Ctrl-C of a gate run with an fp32 and
# an int8 runner, or a pytest process after the in-process graph tests. In a child process: a crash here is the bug.
OUT_OF_ORDER_RUNNERS = """
import gc, os, signal
import openvino, openvino.opset13 as ops
from msfsu_perception.backends import OpenVinoRunner, cpu_capabilities

def tiny():
    x = ops.parameter([1, 4, 8, 8], openvino.Type.f32, name="inputs")
    command = ops.parameter([1], openvino.Type.i64, name="command_index")
    return openvino.Model([ops.relu(x), ops.convert(command, openvino.Type.f32)], [x, command], "tiny")

first = OpenVinoRunner(tiny(), "fp32", 1, None)
cpu_capabilities()
second = OpenVinoRunner(tiny(), "fp32", 1, None)
del first
gc.collect()
cpu_capabilities()
del second
gc.collect()
handled = []
signal.signal(signal.SIGTERM, lambda signum, frame: handled.append(signum))
os.kill(os.getpid(), signal.SIGTERM)
print("handled", len(handled))
"""


@pytest.mark.skipif(not is_installed("openvino"), reason="openvino is not installed")
def test_a_signal_after_openvino_runners_ended_out_of_order_is_handled_not_a_crash():
    child = subprocess.run([sys.executable, "-c", OUT_OF_ORDER_RUNNERS], capture_output=True, text=True, timeout=120)
    assert (child.returncode, child.stdout.strip()) == (0, "handled 1"), child.stderr[-2000:]
