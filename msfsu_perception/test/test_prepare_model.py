"""prepare_model builds ahead of time what the perception node builds at configure (the Docker image's int8 step):
the node's own loading code writes the derived files, and a later load finds them instead of building them again."""

import shutil
import subprocess
import sys
from pathlib import Path

from msfsu_perception.deploy_files import DeployFiles, calibration_path
from msfsu_perception.inference import DrivingModel
from msfsu_perception.prepare_model import main

REPO = Path(__file__).resolve().parents[2]


def derived(checkpoint: Path) -> dict[str, float]:
    """The derived files beside `checkpoint` (name -> modification time)."""
    directory = DeployFiles(checkpoint).directory
    return {path.name: path.stat().st_mtime for path in directory.rglob("*") if path.is_file()}


def test_prepare_builds_what_the_node_loads_and_a_second_load_builds_nothing(tiny_checkpoint, tmp_path, capsys):
    checkpoint = tmp_path / "tiny.pt"
    shutil.copy(tiny_checkpoint, checkpoint)
    assert main([str(checkpoint), "--backend", "openvino", "--precision", "fp32"]) == 0
    [line] = capsys.readouterr().out.strip().splitlines()
    assert line.startswith(f"{checkpoint}: openvino fp32 built in ") and line.endswith(
        f"its derived files are in {DeployFiles(checkpoint).directory}")
    built = derived(checkpoint)
    assert any(name.endswith("-fp32.onnx") for name in built), built
    DrivingModel.from_checkpoint(checkpoint, backend="openvino", precision="fp32")  # what the node's configure does
    assert derived(checkpoint) == built  # found, not built again


def test_a_checkpoint_it_cannot_use_is_one_line(tmp_path):
    broken = tmp_path / "broken.pt"
    broken.write_bytes(b"not a checkpoint")
    result = subprocess.run([sys.executable, "-m", "msfsu_perception.prepare_model", str(broken)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 1 and result.stdout == ""
    [line] = result.stderr.strip().splitlines()
    assert line.startswith(f"prepare_model: cannot use checkpoint '{broken}': ")


def test_the_images_int8_step_leaves_the_node_nothing_to_quantise(tmp_path, capsys):
    """The Dockerfile's step on a copy of the shipped default model (its calibration frames and int8 recipe beside it):
    the int8 network is built (NNCF: about 8 s here), and loading it as the node does then builds nothing again."""
    shipped = REPO / "models" / "msfsu_default.pt"
    checkpoint = tmp_path / shipped.name
    shutil.copy(shipped, checkpoint)
    shutil.copy(calibration_path(shipped), calibration_path(checkpoint))
    DeployFiles(checkpoint).directory.mkdir()
    shutil.copy(DeployFiles(shipped).int8_recipe, DeployFiles(checkpoint).int8_recipe)
    assert main([str(checkpoint), "--precision", "int8"]) == 0
    assert " int8 built in " in capsys.readouterr().out
    built = derived(checkpoint)
    assert any("-int8-" in name and name.endswith(".xml") for name in built), built
    model = DrivingModel.from_checkpoint(checkpoint, backend="openvino", precision="int8")
    assert model.precision == "int8" and derived(checkpoint) == built  # loaded and compiled, not quantised again
