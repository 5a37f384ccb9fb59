"""Test-session environment: ROS traffic stays on this host, and the session owns a ROS domain id;
fixtures every test directory uses.

Set here (the repository root) so it applies to every test directory and to the processes tests start.
"""

import os
from datetime import timedelta
from pathlib import Path

import pytest
from domain_coordinator import domain_id
from hypothesis import settings

from msfsu_common.ros_env import configure_ros_environment

configure_ros_environment()
_domain = domain_id()

# Fuzz tests (hypothesis): each sets its max_examples; no example database written into the work tree;
# an example slower than the deadline fails (a hang on hostile input is a bug too).
settings.register_profile("msfsu", database=None, deadline=timedelta(seconds=5), print_blob=True)
settings.load_profile("msfsu")


def pytest_configure(config: pytest.Config) -> None:
    os.environ["ROS_DOMAIN_ID"] = str(_domain.__enter__())


def pytest_unconfigure(config: pytest.Config) -> None:
    _domain.__exit__(None, None, None)


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory) -> Path:
    """A randomly initialised MSFSU (ResNet-18 V2, 64x64) written the way msfsu-train writes checkpoints."""
    from msfsu_perception.checkpoint import save_checkpoint
    from msfsu_perception.model import MSFSUConfig, build_model
    from msfsu_perception.preprocessing import PreprocessConfig

    path = tmp_path_factory.mktemp("checkpoints") / "tiny.pt"
    model = build_model(MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=64))
    save_checkpoint(path, model, PreprocessConfig(input_height=64, input_width=64))
    return path


@pytest.fixture(scope="session")
def constant_policy_checkpoint(tiny_checkpoint, tmp_path_factory):
    """`constant_policy_checkpoint(steer, speed_mps)`: a checkpoint of the tiny network whose every command branch
    answers exactly that steer and target speed (m/s), whatever it sees (its last layer's weights zeroed)."""
    import torch

    from msfsu_perception.checkpoint import DEFAULT_SPEED_SCALE_MPS, load_checkpoint, save_checkpoint

    directory = tmp_path_factory.mktemp("constant_policies")

    def make(steer: float, speed_mps: float) -> Path:
        path = directory / f"steer{steer:+.3f}_speed{speed_mps:.3f}.pt"
        if not path.exists():
            loaded = load_checkpoint(tiny_checkpoint)
            with torch.no_grad():
                for branch in loaded.model.policy.branches:
                    branch[-1].weight.zero_()
                    branch[-1].bias.copy_(torch.tensor([steer, speed_mps / DEFAULT_SPEED_SCALE_MPS]))
            save_checkpoint(path, loaded.model, loaded.preprocess, DEFAULT_SPEED_SCALE_MPS)
        return path

    return make


@pytest.fixture
def cpu_reports(monkeypatch):
    """`cpu_reports("FP32", "INT8")`: from then on OpenVINO reports exactly these CPU capabilities.

    The one fake of the hardware: a CPU without avx512_bf16/AMX (no "BF16") or without int8 kernels (no
    "INT8"), which this machine may not be. Only the capability report changes; the rest runs for real.
    """
    import openvino

    real_get_property = openvino.Core.get_property

    def report(*capabilities: str) -> None:
        def get_property(self, *args):
            if args and args[-1] == "OPTIMIZATION_CAPABILITIES":
                return list(capabilities)
            return real_get_property(self, *args)

        monkeypatch.setattr(openvino.Core, "get_property", get_property)

    return report
