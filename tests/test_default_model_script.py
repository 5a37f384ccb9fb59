"""msfsu-default-model (msfsu_evaluation.pipelines.default_model, run by doit) resumes whatever stopped it: the model
recipe runs unattended across many sessions, and a session's end kills it at any instruction. Its commands
(collection, training: hours each) are stood in for by recorders in a checkout of its own; the pipeline under test and
its skip and copy logic are the real ones. A stand-in checkpoint is its lineage, one line per training run that wrote
it, so a test can tell which runs a round's or a branch's model went through."""

import json
import os
import re
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

COMMAND = str(Path(sys.executable).with_name("msfsu-default-model"))  # as make setup installs it
STAGES = ["data", "train-msfsu-round0", "branch-msfsu-round1", "dagger-round1", "train-msfsu-round1", "release"]
LINE = re.compile(r"train out=\S+ rounds=\d epochs=\d+")
ROUND0, ROUND_EPOCHS = 4, 2
ENV = {"DATA": "d", "RUNS": "r", "VARIANTS": "msfsu", "ROUND0_EPOCHS": str(ROUND0), "ROUND_EPOCHS": str(ROUND_EPOCHS),
       "ROUNDS": "1", "BRANCH": "1", "WORKERS": "1"}

# msfsu-train: continues last.pt with --resume (a run already at its epochs adds nothing, as the trainer does), and
# best.pt is the checkpoint as it stands (every epoch improves)
TRAIN = r"""#!/usr/bin/env bash
out=; epochs=; resume=; rounds=0
while [ $# -gt 0 ]; do
  case $1 in --out) out=$2;; --epochs) epochs=$2;; --resume) resume=1;; */train/*_r1) rounds=1;; esac; shift
done
line="train out=$(basename "$out") rounds=$rounds epochs=$epochs"
mkdir -p "$out"
[ -z "$resume" ] && rm -f "$out/last.pt"
[ "$(tail -n 1 "$out/last.pt" 2>/dev/null)" = "$line" ] || echo "$line" >> "$out/last.pt"
/bin/cp "$out/last.pt" "$out/best.pt"
touch "$out/metrics.csv" "$out/loss_curves.png" "$out/balancing.png"
"""
# msfsu-collect: the sample bag when asked for the test split; the round's bags stand for themselves
COLLECT = r"""#!/usr/bin/env bash
out=; split=
while [ $# -gt 0 ]; do case $1 in --output) out=$2;; --split) split=$2;; esac; shift; done
mkdir -p "$out/$split"
[ "$split" = test ] && mkdir -p "$out/test/town_h1_soft_rain_dusk_regular_000" && echo bag > "$out/test/town_h1_soft_rain_dusk_regular_000/b"
[ "$split" = train ] && mkdir -p "$out/train/town_a_clear_noon_dense_000" "$out/train/town_a_clear_noon_dense_000_r1"
true
"""
# sitecustomize of the pipeline's process: every file copy it makes (shutil.copyfile, which shutil.copytree uses too)
# counted in $COPY_COUNT; the KILL_AT-th (0-based) writes 3 bytes of its file and kills the process, as a session's end
STOPS = r"""import os, shutil, signal
_copyfile = shutil.copyfile


def copyfile(source, target, *args, **kwargs):
    with open(os.environ["COPY_COUNT"]) as stream:
        n = int(stream.read())
    with open(os.environ["COPY_COUNT"], "w") as stream:
        stream.write(str(n + 1))
    if n == int(os.environ["KILL_AT"]):
        with open(source, "rb") as read, open(target, "wb") as written:
            written.write(read.read(3))
        os.kill(os.getpid(), signal.SIGKILL)
    return _copyfile(source, target, *args, **kwargs)


shutil.copyfile = copyfile
"""


def executable(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)


def make_tree(root: Path) -> Path:
    """A checkout at `root` with stand-ins for the project's commands."""
    (root / "scripts").mkdir(parents=True)
    (root / "scripts" / "gate_bags.sh").write_text("true\n")
    bin_dir = root / ".venv" / "bin"
    executable(bin_dir / "msfsu-train", TRAIN)
    executable(bin_dir / "msfsu-collect", COLLECT)
    executable(bin_dir / "msfsu-release-checkpoint", '#!/usr/bin/env bash\n/bin/cp "$1" "$2"\n')
    executable(bin_dir / "msfsu-dataset-report", "#!/usr/bin/env bash\ntrue\n")
    executable(bin_dir / "python", f'#!/usr/bin/env bash\nexec {sys.executable} "$@"\n')
    (root / "stops").mkdir()
    (root / "stops" / "sitecustomize.py").write_text(STOPS)
    (root / "models").mkdir()
    (root / "bags").mkdir()
    subprocess.run(["git", "init", "-q"], cwd=root, check=True)
    return root


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    return make_tree(tmp_path)


def run(tree: Path, kill_at: int = -1) -> tuple[int, int]:
    """(exit status, file copies made); kill_at >= 0 stops the pipeline inside that copy."""
    count = tree / "copy_count"
    count.write_text("0")
    env = {**os.environ, **ENV, "COPY_COUNT": str(count), "KILL_AT": str(kill_at), "PYTHONPATH": str(tree / "stops")}
    completed = subprocess.run([COMMAND], cwd=tree, env=env, capture_output=True, text=True, timeout=60)
    assert "Traceback" not in completed.stderr, completed.stderr
    return completed.returncode, int(count.read_text())


def stage_lines(tree: Path) -> dict[str, dict]:
    """The stages' lines of the run's record (RUNS/stages.jsonl), by stage."""
    lines = (tree / "r" / "stages.jsonl").read_text().splitlines()
    return {record["stage"]: record for record in map(json.loads, lines)}


def lineage(path: Path) -> list[str]:
    lines = path.read_text().splitlines()
    assert lines and all(LINE.fullmatch(line) for line in lines), f"{path}: not a whole checkpoint: {lines}"
    return lines


def assert_finished(tree: Path) -> None:
    runs = tree / "r"
    round0 = f"train out=msfsu rounds=0 epochs={ROUND0}"
    after = ROUND0 + ROUND_EPOCHS
    assert lineage(runs / "msfsu" / "round0.pt") == lineage(runs / "msfsu" / "round0.last.pt") == [round0]
    # round 1 continues round 0's run on rounds 0..1; its branch continues the same epoch on round 0 only
    assert lineage(runs / "msfsu" / "round1.last.pt") == [round0, f"train out=msfsu rounds=1 epochs={after}"]
    assert lineage(runs / "msfsu_branch1" / "last.pt") == [round0, f"train out=msfsu_branch1 rounds=0 epochs={after}"]
    assert lineage(runs / "msfsu_branch1" / "round1.pt") == lineage(runs / "msfsu_branch1" / "last.pt")
    assert lineage(tree / "models" / "msfsu_default.pt") == lineage(runs / "msfsu" / "round1.pt")
    assert not list(runs.rglob("*.partial")), "a half-made copy was left behind"


def test_an_unbroken_run_trains_round_one_and_its_same_budget_branch_and_records_each_stage_s_hours(tree):
    status, _ = run(tree)
    assert status == 0
    assert_finished(tree)
    lines = stage_lines(tree)
    assert sorted(lines) == sorted(STAGES)
    assert all(line["invocations"] == 1 and line["hours"] >= 0 and "CPUs" in line["machine"] for line in lines.values())
    listed = subprocess.run([COMMAND, "list"], cwd=tree, env={**os.environ, **ENV}, capture_output=True, text=True)
    assert [line.split()[0] for line in listed.stdout.splitlines()] == [
        "data", "dagger-round1", "train-msfsu-round0", "branch-msfsu-round1", "train-msfsu-round1", "release"]


def test_a_stop_inside_any_copy_resumes_to_the_same_models(tree, tmp_path_factory):
    _, copies = run(tree)  # how many file copies a whole run makes
    assert copies >= 8
    for kill_at in range(copies):
        fresh = make_tree(tmp_path_factory.mktemp(f"stop{kill_at}"))
        status, _ = run(fresh, kill_at)
        assert status != 0, f"copy {kill_at} did not stop the pipeline"
        if kill_at == 0:
            time.sleep(1.1)  # a clock's invocation is named by its start second
        status, _ = run(fresh)
        assert status == 0, f"the run stopped in copy {kill_at} does not resume"
        assert_finished(fresh)
        if kill_at == 0:  # inside the first training stage: its hours are both invocations'
            assert stage_lines(fresh)["train-msfsu-round0"]["invocations"] == 2


def test_msf_alone_needs_msfsu_s_round_to_drive_its_dagger_round(tree):
    completed = subprocess.run([COMMAND], cwd=tree, env={**os.environ, **ENV, "VARIANTS": "msf"}, capture_output=True,
                               text=True, timeout=60)
    assert completed.returncode == 1
    assert completed.stderr == "msfsu-default-model: stage dagger-round1: its input r/msfsu/round0.pt is missing\n"
    completed = subprocess.run([COMMAND], cwd=tree, env={**os.environ, **ENV, "VARIANTS": "msfsu scene"},
                               capture_output=True, text=True, timeout=60)
    assert completed.returncode == 2 and completed.stderr.count("\n") == 1
    assert "VARIANTS='msfsu scene'" in completed.stderr
