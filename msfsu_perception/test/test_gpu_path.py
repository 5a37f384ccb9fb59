"""The GPU path's rules that hold on any machine: device resolution, refusals with their reason, the GPU's own
gate record, `prepare` on the CPU. The GPU itself: test_gpu_runner.py (marker gpu)."""

import numpy as np
import pytest
import torch
from msfsu_common.road_option import RoadOption
from msfsu_perception.backends import (
    BackendUnavailableError,
    onnxruntime_gpu_providers,
    supported_precisions,
)
from msfsu_perception.checkpoint import save_checkpoint
from msfsu_perception.deploy_files import DeployFiles
from msfsu_perception.gate_verdicts import (
    GateResult,
    HeldOutScores,
    gated_precisions,
    record_gate_results,
)
from msfsu_perception.inference import (
    DrivingModel,
    input_rgb,
    resolve_backend,
    resolve_device,
    resolve_precision,
)
from msfsu_perception.model import MSFSUConfig, build_model
from msfsu_perception.preprocessing import PreprocessConfig, preprocess_frame

from msfsu_perception import backends

SIZE = 64
no_cuda = pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device")


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    torch.manual_seed(0)
    network = build_model(MSFSUConfig(backbone="resnet18v2", input_height=SIZE, input_width=SIZE))
    path = tmp_path_factory.mktemp("gpu_path") / "model.pt"
    save_checkpoint(path, network.eval(), PreprocessConfig(SIZE, SIZE))
    return path


def _passed(backend: str, precision: str) -> GateResult:
    scores = HeldOutScores(0.1, 0.5)
    return GateResult(backend, precision, 10, scores, scores, 0.0, 1.0)


def test_precisions_per_device():
    assert supported_precisions("torch", "cuda") == ("fp32", "fp16", "bf16")
    assert "fp16" not in supported_precisions("torch", "cpu")
    assert supported_precisions("openvino", "cuda") == ()


@no_cuda
def test_device_auto_is_the_cpu_without_cuda_and_cuda_is_refused_with_the_way_out(checkpoint):
    assert resolve_device("auto") == "cpu"
    assert DrivingModel.from_checkpoint(checkpoint, device="auto").device == "cpu"
    with pytest.raises(BackendUnavailableError, match="device cuda: .*(TORCH=cuda|no CUDA device)"):
        DrivingModel.from_checkpoint(checkpoint, device="cuda")
    with pytest.raises(ValueError, match="unknown device 'tpu'"):
        resolve_device("tpu")


def test_what_a_gpu_does_not_run_is_refused_before_looking_for_one(checkpoint):
    network = build_model(MSFSUConfig(backbone="resnet18v2", input_height=SIZE, input_width=SIZE))
    with pytest.raises(BackendUnavailableError, match="openvino on a CUDA GPU runs nothing"):
        backends.create_runner(network, checkpoint, "openvino", "fp32", device="cuda")
    with pytest.raises(BackendUnavailableError, match="torch on a CUDA GPU runs fp32, fp16, bf16, not int8"):
        backends.create_runner(network, checkpoint, "torch", "int8", device="cuda")
    with pytest.raises(BackendUnavailableError, match="torch does not run fp16"):  # fp16 is a GPU precision
        backends.create_runner(network, checkpoint, "torch", "fp16", device="cpu")


def test_onnxruntime_gpu_providers_are_those_the_installed_build_has(monkeypatch):
    import onnxruntime

    monkeypatch.setattr(onnxruntime, "get_available_providers", lambda: ["CPUExecutionProvider"])
    assert onnxruntime_gpu_providers() == []
    monkeypatch.setattr(onnxruntime, "get_available_providers",
                        lambda: ["CUDAExecutionProvider", "TensorrtExecutionProvider", "CPUExecutionProvider"])
    assert onnxruntime_gpu_providers() == ["TensorrtExecutionProvider", "CUDAExecutionProvider"]


def test_on_a_gpu_auto_is_torch_and_its_precision_comes_from_the_gpu_gate_alone(tmp_path):
    checkpoint = tmp_path / "model.pt"
    torch.manual_seed(0)
    save_checkpoint(checkpoint, build_model(MSFSUConfig(backbone="resnet18v2", input_height=SIZE, input_width=SIZE)),
                    PreprocessConfig(SIZE, SIZE))
    assert resolve_backend("auto", "cuda") == "torch"
    assert resolve_precision(checkpoint, "torch", "auto", "cuda") == "fp32"  # nothing gated yet
    record_gate_results(checkpoint, [_passed("torch", "bf16")], {"bags": ["cpu frames"]})  # a CPU verdict
    assert resolve_precision(checkpoint, "torch", "auto", "cuda") == "fp32"
    record_gate_results(checkpoint, [_passed("torch", "bf16"), _passed("torch", "fp16")], {"bags": ["gpu frames"]},
                        device="cuda")
    files = DeployFiles(checkpoint)
    assert files.gate_record_of("cuda").is_file() and files.gate_record_of("cuda") != files.gate_record
    assert gated_precisions(checkpoint, "torch", device="cuda") == {"bf16", "fp16"}
    assert gated_precisions(checkpoint, "torch") == {"bf16"}  # the CPU record keeps its own frames and verdicts
    assert resolve_precision(checkpoint, "torch", "auto", "cuda") == "fp16"  # the fastest that passed


def test_prepare_on_the_cpu_is_preprocess_frame(checkpoint):
    model = DrivingModel.from_checkpoint(checkpoint, device="cpu")
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (120, 160, 3), np.uint8)
    depth = rng.uniform(1.0, 60.0, (120, 160)).astype(np.float32)
    inputs = model.prepare(rgb, depth)
    np.testing.assert_array_equal(inputs, preprocess_frame(rgb, depth, model.preprocess))
    assert input_rgb(inputs).shape == (SIZE, SIZE, 3)
    first = model.predict(inputs, RoadOption.LEFT)
    assert first.steer == model.predict(preprocess_frame(rgb, depth, model.preprocess), RoadOption.LEFT).steer
    with pytest.raises(ValueError, match="the one `prepare` returned"):
        model.predict(torch.zeros(1, 4, SIZE, SIZE), RoadOption.LEFT)
