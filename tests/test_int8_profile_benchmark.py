"""benchmarks/int8_profile.py: the int8 model's layer times, exported as deployed and as in torch, side by side."""

import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from msfsu_perception.deploy_files import calibration_path

BENCHMARK = Path(__file__).parents[1] / "benchmarks" / "int8_profile.py"


def _benchmark():
    spec = importlib.util.spec_from_file_location("int8_profile", BENCHMARK)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_stride_4_deconvolution_runs_float_as_in_torch_and_int8_as_deployed(tiny_checkpoint, tmp_path):
    checkpoint = tmp_path / "tiny.pt"
    shutil.copy(tiny_checkpoint, checkpoint)
    rng = np.random.default_rng(0)
    np.savez(calibration_path(checkpoint), rgb=rng.integers(0, 256, (4, 3, 64, 64), np.uint8),
             depth=rng.random((4, 1, 64, 64)).astype(np.float16), command_index=np.arange(4))
    assert _benchmark().main([str(checkpoint), "--iterations", "3", "--out", str(tmp_path / "r.md"),
                              "--json", str(tmp_path / "r.json")]) == 0
    graphs = json.loads((tmp_path / "r.json").read_text())["models"][0]["graphs"]
    kinds = {name: {row["kind"] for row in graph["by_kind"]} for name, graph in graphs.items()}
    float_deconvolution = {kind for kind in kinds["as in torch"]
                           if kind.startswith("ConvolutionBackpropData") and "f32" in kind}
    assert float_deconvolution, kinds["as in torch"]  # OpenVINO: no int8 kernel for a stride-4 deconvolution
    assert not any(k.startswith("ConvolutionBackpropData") and "f32" in k for k in kinds["deployed"]), kinds["deployed"]
    assert any(kind.startswith("DepthToSpace") for kind in kinds["deployed"])
    assert all(graph["wall_p50_ms"] > 0 and graph["layers_ms"] > 0 for graph in graphs.values())
    assert "| wall p50 per inference (counters off) |" in (tmp_path / "r.md").read_text()


def test_a_checkpoint_without_calibration_frames_is_one_line(tiny_checkpoint, tmp_path, capsys):
    checkpoint = tmp_path / "bare.pt"
    shutil.copy(tiny_checkpoint, checkpoint)
    with pytest.raises(SystemExit) as exit_info:
        _benchmark().main([str(checkpoint)])
    assert exit_info.value.code == 2 and "no calibration frames beside" in capsys.readouterr().err
