"""msfsu-gate (msfsu_evaluation.deploy.gate): the committed verdicts, recipes and gate pages are what its code writes
from their records, byte for byte; the command end to end on a tiny network; user mistakes in one line."""

import json
import shlex
import shutil
from pathlib import Path

import pytest

from msfsu_evaluation.deploy import gate, recipe
from msfsu_evaluation.deploy.recipe_record import SensitivityRecord
from msfsu_perception.backends import is_installed
from msfsu_perception.gate_verdicts import gate_record, record_gate_results, results_from_record
from msfsu_perception.int8_recipe import Int8Recipe, write_recipe
from msfsu_perception.synthetic import write_synthetic_bag

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ("msfsu_default", "msf", "su")
GATE_PAGES = {"msfsu_default": "perception_gate_results.md", "msf": "perception_gate_results_msf.md",
              "su": "perception_gate_results_su.md", "paper_short": "perception_gate_results_paper.md"}


def _committed(pattern: str) -> Path:
    [path] = sorted(ROOT.glob(pattern))
    return path


def _gate_record_file(name: str) -> Path:
    if name == "paper_short":
        return _committed("benchmarks/gate_records/paper_short_*-gate.json")
    return _committed(f"models/{name}.pt.deploy/*-v*-gate.json")


def _shipped_copy(name: str, root: Path) -> Path:
    """models/<name>.pt copied under `root` with the same relative name (records name the checkpoint as given)."""
    (root / "models").mkdir(exist_ok=True)
    shutil.copyfile(ROOT / "models" / f"{name}.pt", root / "models" / f"{name}.pt")
    return Path("models") / f"{name}.pt"


@pytest.mark.parametrize("name", SHIPPED)
@pytest.mark.parametrize("device", ["cpu", "cuda"])
def test_a_committed_gate_record_is_what_recording_its_results_writes(name, device, tmp_path, monkeypatch):
    suffix = "gate.json" if device == "cpu" else f"gate-{device}.json"
    committed = sorted((ROOT / "models" / f"{name}.pt.deploy").glob(f"*-v*-{suffix}"))
    if not committed:
        pytest.skip(f"models/{name}.pt has no {device} gate record")
    record = json.loads(committed[0].read_text())
    monkeypatch.chdir(tmp_path)
    checkpoint = _shipped_copy(name, tmp_path)
    written = record_gate_results(checkpoint, results_from_record(record), record["held_out"], record["command"],
                                  device=device)
    assert written.name == committed[0].name
    # the record names the checkpoint as its caller did (benchmarks/gpu.py: an absolute path)
    named = f'"checkpoint": {json.dumps(record["checkpoint"])}'
    expected = committed[0].read_text().replace(named, f'"checkpoint": {json.dumps(str(checkpoint))}')
    assert written.read_text() == expected and named in committed[0].read_text()


@pytest.mark.parametrize("name", GATE_PAGES)
def test_the_committed_gate_pages_verdicts_are_the_gate_report_of_their_records(name):
    record = json.loads(_gate_record_file(name).read_text())
    checkpoint = Path(record["checkpoint"])
    recorded = checkpoint.with_name(checkpoint.name + ".deploy") / _gate_record_file(name).name.removeprefix(
        "paper_short_")
    run = gate.GateRun(results_from_record(record), record["held_out"], recorded)
    page = (ROOT / "benchmarks" / GATE_PAGES[name]).read_text().splitlines()
    first = next(i for i, line in enumerate(page) if line.startswith("Accuracy gate of "))
    lines = gate.report_lines(checkpoint, run)
    assert page[first:first + len(lines)] == lines


@pytest.mark.parametrize("name", SHIPPED)
def test_a_committed_int8_recipe_is_what_its_sensitivity_record_stores(name, tmp_path, monkeypatch):
    text = (ROOT / "benchmarks" / "int8_recipes" / f"{name}.json").read_text()
    sensitivity = json.loads(text)
    assert SensitivityRecord.from_json(text).page() == (ROOT / "benchmarks" / "int8_recipes" / f"{name}.md").read_text()
    monkeypatch.chdir(tmp_path)
    written = write_recipe(_shipped_copy(name, tmp_path), Int8Recipe.from_settings(sensitivity["recipe"]),
                           recipe.provenance(sensitivity))
    assert written.read_bytes() == _committed(f"models/{name}.pt.deploy/*-int8-recipe.json").read_bytes()


def test_the_recipe_step_runs_msfsu_int8_recipe_as_recorded_and_reuses_a_ranking_of_this_checkpoint(
        tmp_path, monkeypatch):
    recorded = json.loads((ROOT / "benchmarks" / "int8_recipes" / "msf.json").read_text())["command"]
    monkeypatch.chdir(tmp_path)
    _shipped_copy("msf", tmp_path)

    def argv() -> list[str]:
        return gate.recipe_argv(Path("models/msf.pt"), ["data/v2/validation/*"], 400,
                                Path("benchmarks/int8_recipes/msf"), 2, Path("data/cache"))

    assert "msfsu-int8-recipe " + shlex.join(argv()) == recorded  # no earlier ranking: the recorded first run
    (tmp_path / "benchmarks").mkdir()
    shutil.copytree(ROOT / "benchmarks" / "int8_recipes", tmp_path / "benchmarks" / "int8_recipes")
    assert argv()[-4:] == ["--ranking-from", "benchmarks/int8_recipes/msf.json", "--out", "benchmarks/int8_recipes/msf"]
    assert not gate.reusable_ranking(Path("benchmarks/int8_recipes/su.json"), Path("models/msf.pt"))


def test_the_cpu_gate_scores_every_installed_fast_path_and_the_gpu_gate_torchs_precisions():
    cpu = gate.candidates("cpu")
    assert ("torch", "fp32") not in cpu and all(is_installed(backend) for backend, _ in cpu)
    if is_installed("openvino"):
        assert [p for b, p in cpu if b == "openvino"] == ["fp32", "bf16", "int8"]
    assert gate.candidates("cuda") == [("torch", "fp32"), ("torch", "fp16"), ("torch", "bf16")]


def _tiny_setup(tiny_checkpoint: Path, tmp_path: Path) -> tuple[Path, Path]:
    """A copy of the tiny checkpoint (the command writes beside it) and synthetic train / validation / test bags."""
    checkpoint = tmp_path / "tiny.pt"
    shutil.copyfile(tiny_checkpoint, checkpoint)
    for split, frames in (("train", 12), ("validation", 6), ("test", 6)):
        write_synthetic_bag(tmp_path / "bags" / split, n_frames=frames, split=split, noise_period_frames=1000)
    return checkpoint, tmp_path / "bags"


@pytest.mark.skipif(not (is_installed("openvino") and is_installed("onnxruntime")), reason="needs both backends")
def test_one_command_writes_calibration_frames_and_the_verdicts_the_node_reads(tiny_checkpoint, tmp_path, capsys):
    from msfsu_perception.backends import int8_build
    from msfsu_perception.deploy_files import DeployFiles, calibration_path

    checkpoint, bags = _tiny_setup(tiny_checkpoint, tmp_path)
    argv = [str(checkpoint), "--bags", str(bags / "test"), "--calibration-bags", str(bags / "train"),
            "--calibration-frames", "8", "--threads", "1", "--cache-dir", str(tmp_path / "cache"),
            "--out", str(tmp_path / "gate.md")]
    assert gate.main(argv) == 0
    deploy = DeployFiles(checkpoint)
    assert calibration_path(checkpoint).is_file() and not deploy.int8_recipe.is_file()  # no --val-bags: no recipe
    record = gate_record(checkpoint)
    assert record["command"] == "msfsu-gate " + shlex.join(argv)
    assert list(record["paths"]) == [f"{b}/{p}" for b, p in gate.candidates("cpu")]
    assert int8_build(checkpoint).matches(record["paths"]["openvino/int8"]["build"])  # what the node would build
    page = (tmp_path / "gate.md").read_text()
    assert f"recorded in {deploy.gate_record}" in page and "| openvino int8 | 6 |" in page
    capsys.readouterr()
    scored = tmp_path / "scored.json"  # what a caller that does not record reads (the benchmarks without --record-gate)
    # calibration frames newer than the checkpoint are kept
    assert gate.main([*argv, "--no-record", "--json", str(scored)]) == 0
    assert "calibration frames kept" in capsys.readouterr().out and gate_record(checkpoint) == record
    written = json.loads(scored.read_text())
    assert {path: entry["passed"] for path, entry in written["paths"].items()} == {
        path: entry["passed"] for path, entry in record["paths"].items()} and written["held_out"] == record["held_out"]


@pytest.mark.slow  # ~2.5 min on 2 loaded cores: the per-layer search of the tiny network, twice
@pytest.mark.skipif(not is_installed("openvino"), reason="the recipe search runs on OpenVINO")
def test_with_validation_bags_the_command_chooses_the_recipe_and_reuses_its_ranking_the_next_time(
        tiny_checkpoint, tmp_path):
    from msfsu_perception.backends import int8_build
    from msfsu_perception.deploy_files import DeployFiles

    checkpoint, bags = _tiny_setup(tiny_checkpoint, tmp_path)
    argv = [str(checkpoint), "--bags", str(bags / "test"), "--calibration-bags", str(bags / "train"),
            "--calibration-frames", "8", "--val-bags", str(bags / "validation"), "--recipe-frames", "4",
            "--recipe-out", str(tmp_path / "recipe"), "--threads", "1", "--cache-dir", str(tmp_path / "cache")]
    assert gate.main(argv) == 0
    assert DeployFiles(checkpoint).int8_recipe.is_file()
    assert int8_build(checkpoint).matches(gate_record(checkpoint)["paths"]["openvino/int8"]["build"])
    assert "--ranking-from" not in json.loads((tmp_path / "recipe.json").read_text())["command"]
    assert gate.main(argv) == 0
    assert "--ranking-from" in json.loads((tmp_path / "recipe.json").read_text())["command"]


def test_mistakes_are_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit, match=r"^msfsu-gate: no checkpoint .*nowhere\.pt$"):
        gate.main([str(tmp_path / "nowhere.pt"), "--bags", "x"])
    checkpoint = tmp_path / "any.pt"
    checkpoint.write_bytes(b"")
    with pytest.raises(SystemExit, match="--device cpu$"):
        gate.main([str(checkpoint), "--bags", "x", "--val-bags", "y", "--device", "cuda"])
    assert gate.main([str(checkpoint), "--bags", str(tmp_path / "no_bag_*")]) == 1
    error = capsys.readouterr().err
    assert error.startswith("msfsu-gate: ") and error.count("\n") == 1
