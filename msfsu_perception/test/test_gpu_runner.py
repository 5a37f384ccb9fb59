"""The network on a CUDA GPU (backends.cuda_graph_runner.CudaGraphRunner) against torch fp32 on the CPU, the reference.

Runs only where torch sees a CUDA device (marker `gpu`; `pytest -m gpu`); the CPU-side rules of the GPU path
(refusals, device resolution, the GPU's own gate record) are in test_gpu_path.py and run everywhere.
Self-contained (no conftest fixtures): the device check runs it with `--noconftest` on a machine without ROS.

Tolerances as in test_backends.py: the largest steer / speed error relative to the spread of the reference outputs
over the test frames, and the least share of pixels with the same class id. fp32 on the GPU: 1e-3 and 99.5 %
(cuDNN / TF32-free fp32 kernels sum in other orders than oneDNN); fp16 (10-bit mantissa): 2 % and 98 %;
bf16 (8-bit): 5 % and 97 %. Graph against eager on the same GPU: the same kernels, 1e-5 and 100 %.
"""

import numpy as np
import pytest
import torch
from msfsu_common.road_option import RoadOption
from msfsu_perception.backends import TorchRunner
from msfsu_perception.checkpoint import save_checkpoint
from msfsu_perception.gate_verdicts import (
    GateResult,
    HeldOutScores,
    record_gate_results,
)
from msfsu_perception.inference import DrivingModel, resolve_precision
from msfsu_perception.model import MSFSUConfig, build_model
from msfsu_perception.preprocessing import (
    PreprocessConfig,
    preprocess_frame,
    sanitize_depth,
)

pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")]

SIZE = 96
TOLERANCE = {"fp32": (1e-3, 0.995), "fp16": (0.02, 0.98), "bf16": (0.05, 0.97)}


def network_and_config(seed: int = 0):
    torch.manual_seed(seed)
    network = build_model(MSFSUConfig(backbone="resnet18v2", input_height=SIZE, input_width=SIZE))
    with torch.no_grad():  # BN statistics away from their initial values: outputs spread like a trained net's
        network(torch.rand(8, 4, SIZE, SIZE), torch.arange(8) % 4)
    return network.eval(), PreprocessConfig(SIZE, SIZE)


def frames(count: int = 12, seed: int = 1):
    rng = np.random.default_rng(seed)
    for index in range(count):
        inputs = rng.random((1, 4, SIZE, SIZE), np.float32)
        yield inputs, np.array([index % 4], np.int64)


def run_all(runner, inputs):
    outputs = [runner(x, c) for x, c in inputs]
    return (np.array([o.steer for o in outputs]), np.array([o.speed for o in outputs]),
            np.stack([o.class_ids for o in outputs]))


def assert_close(reference, candidate, precision):
    relative, agreement = TOLERANCE[precision]
    for ref, cand in zip(reference[:2], candidate[:2]):
        spread = ref.max() - ref.min()
        assert spread > 0
        assert np.abs(cand - ref).max() <= relative * spread, (precision, np.abs(cand - ref).max() / spread)
    assert np.mean(reference[2] == candidate[2]) >= agreement


@pytest.mark.parametrize("precision", ["fp32", "fp16", "bf16"])
def test_the_cuda_graph_reproduces_torch_fp32_on_the_cpu(precision):
    from msfsu_perception.backends.cuda_graph_runner import CudaGraphRunner

    network, config = network_and_config()
    inputs = list(frames())
    reference = run_all(TorchRunner(network, "fp32"), inputs)
    assert_close(reference, run_all(CudaGraphRunner(network, precision, config), inputs), precision)


def test_each_replay_reads_the_new_input_as_eager_execution_does():
    from msfsu_perception.backends.cuda_graph_runner import CudaGraphRunner

    network, config = network_and_config()
    inputs = list(frames())
    graph = run_all(CudaGraphRunner(network, "fp32", config), inputs)
    eager = run_all(CudaGraphRunner(network, "fp32", config, graph=False), inputs)
    assert len(set(graph[0].round(6))) == len(inputs)  # one answer per frame, not the captured one repeated
    np.testing.assert_allclose(graph[0], eager[0], atol=1e-5 * np.ptp(eager[0]))
    np.testing.assert_array_equal(graph[2], eager[2])


def test_a_camera_frame_preprocessed_on_the_gpu_drives_as_on_the_cpu(tmp_path):
    network, config = network_and_config()
    checkpoint = tmp_path / "model.pt"
    save_checkpoint(checkpoint, network, config)
    model = DrivingModel.from_checkpoint(checkpoint, backend="torch", precision="fp32", device="auto")
    assert (model.device, model.backend, model.precision) == ("cuda", "torch", "fp32")
    reference = DrivingModel.from_checkpoint(checkpoint, backend="torch", precision="fp32", device="cpu")
    rng = np.random.default_rng(2)
    for height, width in ((600, 800), (1080, 1920), (600, 800)):  # a second camera size, then the first again
        rgb = rng.integers(0, 256, (height, width, 3), np.uint8)
        depth = sanitize_depth(rng.uniform(0.5, 80.0, (height, width)).astype(np.float32))[0]
        on_gpu = model.predict(model.prepare(rgb, depth), RoadOption.LEFT)
        on_cpu = reference.predict(preprocess_frame(rgb, depth, config), RoadOption.LEFT)
        assert abs(on_gpu.steer - on_cpu.steer) < 1e-3 and abs(on_gpu.target_speed - on_cpu.target_speed) < 1e-2
        assert np.mean(on_gpu.class_ids == on_cpu.class_ids) > 0.99


def test_auto_precision_on_the_gpu_takes_the_fastest_that_passed_the_gpu_gate(tmp_path):
    network, config = network_and_config()
    checkpoint = tmp_path / "model.pt"
    save_checkpoint(checkpoint, network, config)
    assert DrivingModel.from_checkpoint(checkpoint, device="cuda", precision="auto").precision == "fp32"
    scores = HeldOutScores(0.1, 0.5)
    record_gate_results(checkpoint, [GateResult("torch", "fp16", 10, scores, scores, 0.0, 1.0)], {"bags": ["a"]},
                        device="cuda")
    assert resolve_precision(checkpoint, "torch", "auto", "cuda") == "fp16"
    model = DrivingModel.from_checkpoint(checkpoint, device="cuda", precision="auto")
    assert (model.device, model.precision) == ("cuda", "fp16")
    assert DrivingModel.from_checkpoint(checkpoint, device="cpu", precision="auto").precision == "fp32"
