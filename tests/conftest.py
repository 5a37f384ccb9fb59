import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from ros_graph import RosGraph  # noqa: E402


@pytest.fixture
def graph():
    ros_graph = RosGraph()
    yield ros_graph
    ros_graph.close()


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
