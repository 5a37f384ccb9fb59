"""msfsu-model-v3 (msfsu_evaluation.pipelines.model_v3, run by doit) runs model v3's stages in order, skips a stage
whose record is committed, resumes a stopped training stage, gives the three variants one recipe, and with COMMIT=1
commits each stage's product alone. Its commands (collection, training, benchmark: hours each) are stood in for by
recorders that log their arguments in a checkout of its own; the pipeline under test is the real one. The release rule
(msfsu-model-v3-release) is tested on committed benchmark records."""

import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
COMMAND = str(Path(sys.executable).with_name("msfsu-model-v3"))  # as make setup installs it beside the interpreter

from msfsu_evaluation.reports.paired_runs import episodes  # noqa: E402
from msfsu_evaluation.reports.release import (BASELINE, CANDIDATE, main as release_main, paired_rows,  # noqa: E402
                                              verdict)

STAGES = ["data-expert", "data-dagger", "train-msfsu", "train-su", "train-msf", "judge-msfsu", "judge-msf-su",
          "release"]
# every stand-in logs "name args..." to $CALLS; msfsu-train stops (exit 1, last.pt written) once when $STOP_TRAIN names
# its --out, as a session's end leaves a run
RECORDER = r"""#!/usr/bin/env bash
echo "$(basename "$0") $*" >> "$CALLS"
"""
TRAIN = RECORDER + r"""
out=; snapshots=; while [ $# -gt 0 ]; do case $1 in --out) out=$2;; --snapshots) snapshots=$2;; esac; shift; done
mkdir -p "$out"; touch "$out/last.pt" "$out/metrics.csv" "$out/loss_curves.png" "$out/balancing.png" "$out/args.json"
if [ -n "${STOP_TRAIN:-}" ] && [ "$(basename "$out")" = "$STOP_TRAIN" ] && [ ! -e "$out/stopped" ]; then
  touch "$out/stopped"; exit 1
fi
echo "weights of $out" > "$out/best.pt"
mkdir -p "$snapshots"; echo "weights of $out" > "$snapshots/best.pt"; touch "$snapshots/last.pt" "$snapshots/metrics.csv"
"""
REPORT = RECORDER + 'out=$3; mkdir -p "$out"; echo "{}" > "$out/data.json"; echo report > "$out/data.md"\n'
# the benchmark's records hold an episode of each --checkpoint NAME=PATH and of the expert (unless --no-expert)
BENCHMARK = RECORDER + r"""out=${@: -1}; mkdir -p "$out"; : > "$out/episodes.jsonl"
[[ " $* " == *" --no-expert "* ]] || echo '{"agent": "expert"}' > "$out/episodes.jsonl"
while [ $# -gt 0 ]; do [ "$1" = --checkpoint ] && echo "{\"agent\": \"${2%%=*}\"}" >> "$out/episodes.jsonl"; shift; done
"""
BENCHMARK_REPORT = RECORDER + 'while [ $# -gt 0 ]; do [ "$1" = --out ] && mkdir -p "$2" && echo page > "$2/results.md"; shift; done\n'
# scripts/revision_change.py and graph_change_table.py: their arguments to $CALLS, a page to --out
PAGE = ('import os, pathlib, sys\nwith open(os.environ["CALLS"], "a") as calls:\n'
        '    calls.write(pathlib.Path(sys.argv[0]).name + " " + " ".join(sys.argv[1:]) + "\\n")\n'
        'pathlib.Path(sys.argv[sys.argv.index("--out") + 1]).write_text("page\\n")\n')
GATE = RECORDER + ('checkpoint=$1; mkdir -p "$checkpoint.deploy"; echo v > "$checkpoint.deploy/h-v3-gate.json"; '
                   'echo onnx > "$checkpoint.deploy/h-v3-fp32.onnx"; echo f > "$checkpoint.calibration.npz"\n'
                   'while [ $# -gt 0 ]; do case $1 in --recipe-out) mkdir -p "${2%/*}"; echo r > "$2.json"; echo r > "$2.md";; '
                   '--out) echo page > "$2";; esac; shift; done\n')
# msfsu-results-blocks: docs/training.md's block of the stages' hours, here the count of finished stages
BLOCKS = (f'#!{sys.executable}\nimport pathlib, sys\nif "--list" in sys.argv:\n    print("docs/training.md\\nREADME.md")\n    sys.exit(0)\n'
          'file = pathlib.Path("docs/results/model_v3/stages.jsonl")\n'
          'stages = file.read_text().splitlines() if file.exists() else []\n'
          'pathlib.Path("docs/training.md").write_text(f"{len(stages)} stages\\n")\n'
          'pathlib.Path("README.md").write_text(f"{len(stages)} stages\\n")\n')
RELEASE = (f'#!{sys.executable}\nimport os, pathlib, sys\nout = pathlib.Path(sys.argv[sys.argv.index("--out") + 1])\n'
           'out.write_text("{\\"released\\": false}\\n")\n'
           'open(os.environ["CALLS"], "a").write("msfsu-model-v3-release " + " ".join(sys.argv[1:]) + "\\n")\n')


def executable(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    """A checkout with stand-ins for the project's commands, the shipped models and their baseline run."""
    (tmp_path / "scripts").mkdir()
    for name in ("revision_change.py", "graph_change_table.py"):
        (tmp_path / "scripts" / name).write_text(PAGE)
    bin_dir = tmp_path / ".venv" / "bin"
    executable(bin_dir / "msfsu-model-v3-release", RELEASE)
    executable(bin_dir / "msfsu-results-blocks", BLOCKS)
    for name in ("msfsu-collect", "msfsu-release-checkpoint"):
        executable(bin_dir / name, RECORDER + ('/bin/cp "$1" "$2"\n' if "release" in name else ""))
    executable(bin_dir / "msfsu-train", TRAIN)
    executable(bin_dir / "msfsu-dataset-report", REPORT)
    executable(bin_dir / "msfsu-benchmark", BENCHMARK)
    executable(bin_dir / "msfsu-benchmark-report", BENCHMARK_REPORT)
    executable(bin_dir / "msfsu-gate", GATE)
    executable(tmp_path / "scripts" / "gate_bags.sh", RECORDER)
    (tmp_path / ".gitignore").write_text((ROOT / ".gitignore").read_text())
    executable(bin_dir / "python", f'#!/usr/bin/env bash\nexec {sys.executable} "$@"\n')
    (tmp_path / "docs/results/closed_loop_v3_graph2/records/networks").mkdir(parents=True)
    (tmp_path / "models").mkdir()
    for name in ("msfsu_default", "msf", "su"):
        (tmp_path / "models" / f"{name}.pt").write_text(f"shipped {name}\n")
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "--allow-empty", "-m", "start"],
                   cwd=tmp_path, check=True)
    return tmp_path


def run_script(tree: Path, *stages: str, **env: str) -> subprocess.CompletedProcess[str]:
    """One run of the pipeline in the checkout `tree` (its log on stdout); the commands the stages called go to
    tree/calls."""
    calls = tree / "calls"
    calls.write_text("")
    environment = {**os.environ, "CALLS": str(calls), "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t",
                   "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t", **env}
    completed = subprocess.run([COMMAND, *stages], cwd=tree, env=environment, capture_output=True, text=True,
                               timeout=120)
    assert "Traceback" not in completed.stderr, completed.stderr
    return completed


def run(tree: Path, *stages: str, **env: str) -> tuple[int, list[str]]:
    """(exit status, the commands the stages called) of one run of the pipeline."""
    completed = run_script(tree, *stages, **env)
    return completed.returncode, (tree / "calls").read_text().splitlines()


def recorded_stages(tree: Path) -> list[str]:
    lines = (tree / "docs/results/model_v3/stages.jsonl").read_text().splitlines()
    return [json.loads(line)["stage"] for line in lines]


def test_the_stages_run_in_order_each_recorded_once_and_the_variants_share_one_recipe(tree):
    status, calls = run(tree)
    assert status == 0
    assert recorded_stages(tree) == STAGES
    record = json.loads((tree / "docs/results/model_v3/stages.jsonl").read_text().splitlines()[2])
    assert record["hours"] >= 0 and "CPUs" in record["machine"]
    trains = [call for call in calls if call.startswith("msfsu-train")]
    assert len(trains) == 3
    for variant, shipped in (("msfsu", "msfsu_default"), ("su", "su"), ("msf", "msf")):
        call = next(c for c in trains if f"--out runs/v3/{variant} " in c)
        assert f"--variant {variant} --init-from models/{shipped}.pt" in call
    # one step budget and one focus weighting for all; the scene branch differs in its scene weight only
    assert len({c.split("--epochs ")[1].split()[0] for c in trains}) == 1 and "--max-steps" not in " ".join(trains)
    assert len({c.split("--focus-copies ")[1].split()[0] for c in trains}) == 1
    assert not any("--scene-weight" in c for c in trains)
    assert (tree / "checkpoints/v3/msfsu.pt").read_text() == "weights of runs/v3/msfsu\n"
    benchmarks = [call for call in calls if call.startswith("msfsu-benchmark")]
    assert "--checkpoint msfsu_v3=checkpoints/v3/msfsu.pt" in benchmarks[0]
    # each checkpoint is gated in its training stage (the bags are there), once, before it is judged
    gates = [call.split()[1] for call in calls if call.startswith("msfsu-gate")]
    assert gates == ["checkpoints/v3/msfsu.pt", "checkpoints/v3/su.pt", "checkpoints/v3/msf.pt"]
    assert calls.index(next(c for c in calls if c.startswith("msfsu-gate"))) < calls.index(trains[1])
    assert "--schedule cosine" in trains[0]
    # the judged runs' report (the first run's expert) and each v3 network paired with the shipped model it started from
    reports = [call for call in calls if call.startswith("msfsu-benchmark-report")]
    judged = "docs/results/closed_loop_v3_model_v3"
    assert reports[-1] == (f"msfsu-benchmark-report {judged}/records/judge-msf-su {judged}/records/judge-msfsu "
                           f"--out {judged}")  # the expert in one run: nothing to prefer
    drives = [call for call in calls if call.startswith("msfsu-benchmark ")]
    assert "--no-expert" not in drives[0] and "--no-expert" in drives[1]  # judge-msfsu drives the expert
    table = [call for call in calls if call.startswith("graph_change_table.py")][-1].split()
    baseline = "docs/results/closed_loop_v3_graph2/records/networks"
    assert table[1:10] == ["msfsu_v3", f"{baseline}:msfsu", f"{judged}/records/judge-msfsu:msfsu_v3",
                           "msf_v3", f"{baseline}:msf", f"{judged}/records/judge-msf-su:msf_v3",
                           "su_v3", f"{baseline}:su", f"{judged}/records/judge-msf-su:su_v3"]
    assert table[10:] == ["--labels", "v2", "v3", "--pages", "v3_change_<network>.md", "--out", f"{judged}/v3_change.md"]
    assert sum(c.startswith("revision_change.py") for c in calls) == 1 + 3  # after each judge stage, all so far
    # the release rule judges the pair it names as its defaults (what the README's model v3 line reads)
    release = next(call for call in calls if call.startswith("msfsu-model-v3-release")).split()
    assert release[1:5] == ["--baseline", BASELINE, "--candidate", CANDIDATE]
    # on-policy data: the shipped MSFSU drives
    assert any("--driver models/msfsu_default.pt" in call for call in calls if call.startswith("msfsu-collect"))

    status, calls = run(tree)  # all done: only the data stages look at their bags again, nothing is trained
    assert status == 0 and not [c for c in calls if c.startswith(("msfsu-train", "msfsu-benchmark"))]
    assert recorded_stages(tree) == STAGES


def test_a_stopped_training_stage_resumes_from_its_last_checkpoint(tree):
    status, _ = run(tree, "data-expert", "data-dagger", "train-su", STOP_TRAIN="su")
    assert status != 0 and "train-su" not in recorded_stages(tree)
    time.sleep(1.1)  # the next invocation starts in another second
    status, calls = run(tree, "train-su")
    assert status == 0 and recorded_stages(tree)[-1] == "train-su"
    assert [c for c in calls if c.startswith("msfsu-train")][0].endswith("--resume")
    # the stage's hours are the sum of both invocations' (docs/results/model_v3/clock/train-su/<start>: last seen
    # alive, committed with the stage's progress)
    record = json.loads((tree / "docs/results/model_v3/stages.jsonl").read_text().splitlines()[-1])
    assert record["invocations"] == 2 and record["hours"] >= 0
    assert len(list((tree / "docs/results/model_v3/clock/train-su").iterdir())) == 2


# msfsu-train as a stop finds it: busy with a batch; a stop signal is logged, and last.pt is saved a second later
SAVING_TRAIN = RECORDER + r"""
out=; while [ $# -gt 0 ]; do [ "$1" = --out ] && out=$2; shift; done; mkdir -p "$out"
stop() { echo "$1" >> "$out/signals"; kill "$busy"; sleep 1; echo "in epoch 1 after batch 7" > "$out/last.pt"; exit 1; }
trap 'stop INT' INT; trap 'stop TERM' TERM
sleep 60 & busy=$!; echo started > "$out/started"; wait
"""


def ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a non-interactive shell starts a background job (`cmd &`)


@pytest.mark.parametrize("stop", ["sigint-to-the-pipeline", "sigterm-to-the-pipeline", "ctrl-c-to-the-group",
                                  "sigint-to-a-background-pipeline"])
def test_a_stop_signal_reaches_the_training_once_and_the_pipeline_waits_for_its_save(tree, stop):
    """`kill -INT` / `kill -TERM` to the pipeline alone used to kill the training (subprocess.run's SIGKILL on an
    interrupt), which lost the epoch's batches since its last save; a Ctrl-C (the whole process group) gave it no
    time to save. Now the signal reaches the command once, and the pipeline waits for it and stops in one line. A
    pipeline started with SIGINT ignored (a shell's background job) passed SIGINT on to a command that had inherited
    the ignoring (a shell script cannot trap it then): the command now starts with the default."""
    executable(tree / ".venv/bin/msfsu-train", SAVING_TRAIN)
    assert run(tree, "data-expert", "data-dagger")[0] == 0
    out = tree / "runs/v3/su"
    (tree / "calls").write_text("")
    environment = {**os.environ, "CALLS": str(tree / "calls")}
    with subprocess.Popen([COMMAND, "train-su"], cwd=tree, env=environment, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True, start_new_session=True,
                          preexec_fn=ignore_sigint if stop == "sigint-to-a-background-pipeline" else None) as pipeline:
        deadline = time.monotonic() + 60
        while not (out / "started").exists():
            assert time.monotonic() < deadline and pipeline.poll() is None, pipeline.communicate()
            time.sleep(0.05)
        if stop == "ctrl-c-to-the-group":
            os.killpg(pipeline.pid, signal.SIGINT)
        else:
            pipeline.send_signal(signal.SIGTERM if stop == "sigterm-to-the-pipeline" else signal.SIGINT)
        _, stderr = pipeline.communicate(timeout=30)
    assert (out / "last.pt").read_text() == "in epoch 1 after batch 7\n"
    assert (out / "signals").read_text() == ("TERM\n" if stop == "sigterm-to-the-pipeline" else "INT\n")
    assert pipeline.returncode != 0 and "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1].startswith("msfsu-model-v3: stage train-su: stopped by SIG"), stderr
    assert "train-su" not in recorded_stages(tree)


def test_with_commit_each_stage_is_one_commit_of_its_own_product(tree):
    status, _ = run(tree, "data-expert", "train-msfsu", "judge-msfsu", COMMIT="1")
    assert status == 0
    def commit(revision: str) -> list[str]:  # subject, then the files
        shown = subprocess.run(["git", "show", "--name-only", "--format=%s", revision], cwd=tree, capture_output=True,
                               text=True, check=True).stdout
        return [line for line in shown.splitlines() if line]

    def clocks(name: str) -> list[str]:
        return [str(path.relative_to(tree)) for path in (tree / "docs/results/model_v3/clock" / name).iterdir()]

    def products(files: list[str], stage: str) -> set[str]:
        """A commit's files but its stage's clock (whose last value a progress commit may have taken already)."""
        assert set(files) & set(clocks(stage)) <= set(clocks(stage))
        return set(files) - set(clocks(stage))

    # every clock's last value is committed: with the stage's product, or with its last progress if the same
    clock_status = subprocess.run(["git", "status", "--porcelain", "--", "docs/results/model_v3/clock"], cwd=tree,
                                  capture_output=True, text=True, check=True).stdout
    committed_clocks = subprocess.run(["git", "ls-files", "docs/results/model_v3/clock"], cwd=tree, capture_output=True,
                                      text=True, check=True).stdout.split()
    assert clock_status == "" and set(committed_clocks) == {
        *clocks("data-expert"), *clocks("data-dagger"), *clocks("train-msfsu"), *clocks("judge-msfsu")}

    subjects = subprocess.run(["git", "log", "--format=%s"], cwd=tree, capture_output=True, text=True,
                              check=True).stdout.splitlines()
    # each stage's product after its progress (the stopped committers' last looks: the snapshot, the episodes); the
    # training stage's bags come first: the on-policy round, not yet collected, is a stage of its own
    assert [subject.split(": ", 1)[-1].split(" (")[0] for subject in reversed(subjects)] == [
        "start", "its product and hours", "its product and hours", "the snapshot after an epoch",
        "the accuracy gate of checkpoints/v3/msfsu.pt", "its product and hours", "its episodes so far",
        "its product and hours"]
    judged, episodes, last, gated, snapshot, dagger, before = (commit(f"HEAD~{n}") for n in range(7))
    # the benchmark's records
    report = "docs/results/closed_loop_v3_model_v3"
    assert judged[0] == "Model v3, stage judge-msfsu: its product and hours (msfsu-model-v3)"
    assert products(judged[1:], "judge-msfsu") == {"docs/results/model_v3/stages.jsonl", "docs/training.md",
                                                   "README.md", f"{report}/results.md", f"{report}/v3_change.md",
                                                   f"{report}/v3_change_msfsu_v3.md"}
    assert "docs/results/closed_loop_v3_model_v3/records/judge-msfsu/episodes.jsonl" in episodes
    # the gate's records, in the training stage (not the converted models: .gitignore)
    assert set(gated[1:]) == {"checkpoints/v3/msfsu.pt.calibration.npz", "checkpoints/v3/msfsu.pt.deploy/h-v3-gate.json",
                              "benchmarks/int8_recipes/v3_msfsu.json", "benchmarks/int8_recipes/v3_msfsu.md",
                              "benchmarks/perception_gate_results_v3_msfsu.md"}
    assert last[0] == "Model v3, stage train-msfsu: its product and hours (msfsu-model-v3)"
    assert products(last[1:], "train-msfsu") == {
        "checkpoints/v3/msfsu.pt", "docs/results/model_v3/stages.jsonl", "docs/training.md", "README.md",
        *(f"docs/results/training/v3_msfsu/{name}" for name in
          ("metrics.csv", "loss_curves.png", "balancing.png", "args.json", "data.json", "data.md"))}
    assert {f"checkpoints/v3/progress/msfsu/{name}" for name in ("best.pt", "last.pt", "metrics.csv")} < set(snapshot)
    assert before[0].startswith("Model v3, stage data-expert") and "docs/results/model_v3/data.json" in before
    assert dagger[0].startswith("Model v3, stage data-dagger") and set(clocks("data-dagger")) < set(dagger)
    assert (tree / "docs/training.md").read_text() == "4 stages\n"  # each commit carries the stages' block
    time.sleep(1.1)  # a clock's invocation is named by its start second
    status, _ = run(tree, "data-expert", COMMIT="1")  # a data stage run again: only its time, as re-collection
    again = commit("HEAD")
    assert status == 0 and again[0] == "Model v3, stage data-expert: its product and hours (msfsu-model-v3)"
    assert len(again) == 2 and again[1].startswith("docs/results/model_v3/clock/re-collect/")


# msfsu-train over two epochs: after each, the snapshot's files (random, so that git cannot shrink them); after the
# first a pause in which the progress committer (polling every second) sees them still. Its --out comes after the
# committer's first look (reading the bags takes a while), as on a new machine, where runs/ did not exist before it.
EPOCHS_TRAIN = RECORDER + r"""
out=; snapshots=; while [ $# -gt 0 ]; do case $1 in --out) out=$2;; --snapshots) snapshots=$2;; esac; shift; done
sleep 2; mkdir -p "$out" "$snapshots"
for epoch in 0 1; do
  head -c 1500000 /dev/urandom > "$snapshots/last.pt"; cp "$snapshots/last.pt" "$snapshots/best.pt"
  echo "$epoch" >> "$snapshots/metrics.csv"
  [ "$epoch" = 1 ] && break  # the run ends at once: the committer's last look, when stopped, commits this epoch
  sleep 3; [ -z "${BETWEEN_EPOCHS:-}" ] || bash -c "$BETWEEN_EPOCHS"
done
touch "$out/metrics.csv" "$out/loss_curves.png" "$out/balancing.png" "$out/args.json"
cp "$snapshots/best.pt" "$out/best.pt"
"""


def test_bags_collected_again_are_reported_once_the_last_data_stage_has_them(tree):
    """On a new machine the data stages collect their bags again: the data report is made again (a network's route
    may differ between CPUs) after the on-policy round, not after the expert round alone, whose report would
    replace the one of both rounds."""
    executable(tree / ".venv/bin/msfsu-collect", RECORDER + r"""out=; while [ $# -gt 0 ]; do [ "$1" = --output ] && out=$2; shift; done
mkdir -p "$out"; bag=$(mktemp -d "$out/bag_XXXXXX"); touch "$bag/metadata.yaml"  # a bag each call
""")
    status, calls = run(tree, "data-expert", "data-dagger")
    assert status == 0 and sum(call.startswith("msfsu-dataset-report") for call in calls) == 2  # first measurements
    subprocess.run(["rm", "-r", str(tree / "data")], check=True)  # a new machine
    status, calls = run(tree, "data-expert")
    assert status == 0 and not any(call.startswith("msfsu-dataset-report") for call in calls)
    status, calls = run(tree, "data-dagger")
    assert status == 0 and sum(call.startswith("msfsu-dataset-report") for call in calls) == 1


def snapshot_commits(tree: Path) -> list[str]:
    """The hashes of the commits named as a snapshot after an epoch, newest first."""
    return subprocess.run(["git", "log", "--format=%h", "--grep", "the snapshot after an epoch"], cwd=tree,
                          capture_output=True, text=True, check=True).stdout.split()


def test_a_stage_s_snapshots_are_one_commit_amended_after_each_epoch_within_the_submission_limit(tree):
    """A submission takes 256 MiB of diffs: the snapshot commit is amended after every epoch while it is the newest
    (else a new one follows the commit made in between), and one that would take the unsubmitted commits past
    PROGRESS_LIMIT_MIB is undone, the snapshot left on disk."""
    executable(tree / ".venv/bin/msfsu-train", EPOCHS_TRAIN)
    snapshot = tree / "checkpoints/v3/progress/msfsu"
    snapshot.mkdir(parents=True)
    (snapshot / "last.pt").write_bytes(os.urandom(1000))  # an earlier session's, committed: the first look sees it
    git_env = {**os.environ, "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
               "GIT_COMMITTER_EMAIL": "t@t"}
    subprocess.run(["git", "add", "checkpoints"], cwd=tree, check=True)
    subprocess.run(["git", "commit", "-q", "-m", "an earlier session's epoch"], cwd=tree, check=True, env=git_env)
    status, _ = run(tree, "train-msfsu", COMMIT="1", PROGRESS_POLL_S="1")
    assert status == 0
    assert len(snapshot_commits(tree)) == 1  # two epochs, one commit
    shown = subprocess.run(["git", "show", f"{snapshot_commits(tree)[0]}:checkpoints/v3/progress/msfsu/metrics.csv"],
                           cwd=tree, capture_output=True, text=True, check=True).stdout
    assert shown == "0\n1\n" == (snapshot / "metrics.csv").read_text()  # the last epoch's

    # a commit made between two epochs: the next epoch's snapshot is a commit of its own
    subprocess.run(["git", "rm", "-q", "-r", "--cached", "checkpoints/v3/msfsu.pt"], cwd=tree, check=True)
    (tree / "docs/results/model_v3/stages.jsonl").write_text("")  # the stage runs again
    subprocess.run(["git", "commit", "-q", "-am", "again"], cwd=tree, check=True, env=git_env)
    between = 'echo code > code.py && git add code.py && git commit -q -m code -- code.py'
    status, _ = run(tree, "train-msfsu", COMMIT="1", PROGRESS_POLL_S="1", BETWEEN_EPOCHS=between)
    assert status == 0 and len(snapshot_commits(tree)) == 3

    (tree / "docs/results/model_v3/stages.jsonl").write_text("")
    before = snapshot_commits(tree)
    completed = run_script(tree, "train-msfsu", COMMIT="1", PROGRESS_POLL_S="1", PROGRESS_LIMIT_MIB="0")
    assert completed.returncode == 0 and snapshot_commits(tree) == before  # none made: over the limit
    assert "the snapshot after an epoch not committed" in completed.stdout and "over the 256 MiB" not in completed.stdout

    # a checkout that outlives a landed submission names where the unsubmitted commits start; the log says which
    landed = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=tree, capture_output=True, text=True,
                            check=True).stdout.strip()
    (tree / "docs/results/model_v3/stages.jsonl").write_text("")
    completed = run_script(tree, "train-msfsu", COMMIT="1", PROGRESS_POLL_S="1", SUBMIT_BASE=landed)
    assert completed.returncode == 0
    assert f"commits not yet submitted: after {landed} (0 MiB of diffs" in completed.stdout


# msfsu-benchmark whose episodes take a while: one, a pause in which the committer (a look every 5 s) commits it, another
SLOW_BENCHMARK = RECORDER + r"""out=${@: -1}; mkdir -p "$out"; echo '{"agent": "expert"}' > "$out/episodes.jsonl"
sleep 8; git show "HEAD:$out/episodes.jsonl" > committed_while_driving 2>&1
echo '{"agent": "msfsu_v3"}' >> "$out/episodes.jsonl"
"""


def test_a_judge_stage_commits_its_episodes_while_it_drives(tree):
    """A benchmark stage takes hours: its episodes so far are committed every 5 looks, so that a session's end costs
    minutes of it (the benchmark resumes from its episodes); the stage's product commit has them all."""
    status, _ = run(tree, "data-expert", "data-dagger", "train-msfsu", COMMIT="1")
    assert status == 0
    executable(tree / ".venv/bin/msfsu-benchmark", SLOW_BENCHMARK)
    status, calls = run(tree, "judge-msfsu", COMMIT="1", PROGRESS_POLL_S="1")
    assert status == 0
    # the training stage it reads is done and gated its checkpoint: no bags are collected, nothing is trained
    assert not [call for call in calls if call.startswith(("msfsu-collect", "msfsu-train", "msfsu-gate"))]
    episodes = "docs/results/closed_loop_v3_model_v3/records/judge-msfsu/episodes.jsonl"
    progress = subprocess.run(["git", "log", "--format=%h", "--grep", "its episodes so far"], cwd=tree,
                              capture_output=True, text=True, check=True).stdout.split()
    assert len(progress) == 1  # amended, at the last when the benchmark ended
    assert (tree / "committed_while_driving").read_text().splitlines() == ['{"agent": "expert"}']
    assert subprocess.run(["git", "show", f"HEAD:{episodes}"], cwd=tree, capture_output=True, text=True,
                          check=True).stdout.count("\n") == 2


def test_an_unknown_stage_or_a_bad_parameter_is_a_one_line_error(tree):
    completed = run_script(tree, "train-everything")
    assert completed.returncode == 3 and (tree / "calls").read_text() == ""  # doit's: before any stage ran
    assert completed.stderr.count("\n") == 1 and 'no stage "train-everything" (stages: data-expert,' in completed.stderr
    completed = run_script(tree, "train-su", "--epochs", "four")
    assert completed.returncode == 3 and (tree / "calls").read_text() == ""
    assert completed.stderr.count("\n") == 1 and "'four'" in completed.stderr
    completed = run_script(tree, "train-su", EPOCHS="four")
    assert completed.returncode == 2 and (tree / "calls").read_text() == ""
    assert completed.stderr == "msfsu-model-v3: EPOCHS='four' is not int (epochs: epochs of the two rounds' ~2,510 " \
                               "batches, down a cosine from 3e-4)\n"
    # a failed command ends its stage with one line, and the run with doit's status of a failed task
    executable(tree / ".venv/bin/msfsu-collect", RECORDER + "exit 3\n")
    completed = run_script(tree, "data-expert")
    assert completed.returncode == 1
    assert completed.stderr == "msfsu-model-v3: stage data-expert: msfsu-collect exited with status 3\n"


def test_a_stage_s_parameter_comes_from_the_command_line_else_its_variable_and_list_names_the_stages(tree):
    status, calls = run(tree, "data-expert", "data-dagger", "--beta", "0.5", "train-su", "--epochs", "7",
                        DAGGER_EPISODES="5", EPOCHS="6")
    assert status == 0
    collect = next(call for call in calls if "--driver" in call)
    assert "--episodes 5 " in collect and "--beta 0.5 " in collect
    assert "--epochs 7 " in next(call for call in calls if call.startswith("msfsu-train"))
    listed = run_script(tree, "list").stdout.splitlines()
    assert [line.split()[0] for line in listed] == STAGES  # the order they run in, each with what it does
    assert all(len(line.split()) > 3 for line in listed)


NETWORKS = ROOT / "docs/results/closed_loop_v3_graph2/records/networks"
GRAPH1 = ROOT / "docs/results/closed_loop_v3_rev4/records/msfsu_v2"


def test_the_release_rule_needs_a_pooled_win_at_p_005_and_no_cell_worse_by_its_interval(tmp_path, monkeypatch):
    graph1 = {k: e.success for k, e in episodes(GRAPH1, "msfsu_v2").items()}
    graph2 = {k: e.success for k, e in episodes(NETWORKS, "msfsu").items()}
    released, reasons = verdict(paired_rows(graph1, graph2))  # graph 2 over graph 1: +6 points, p < 0.001
    assert released and len(reasons) == 1
    released, reasons = verdict(paired_rows(graph2, graph1))
    assert not released and "does not beat" in reasons[1]
    # a pooled win (50 routes won, 20 lost) with one suite and condition worse by more than its interval: no release
    keys = [f"{suite}/task/{condition}/{n:02d}" for suite in ("corl2017", "nocrash") for condition in ("train", "heldout")
            for n in range(50)]
    baseline = {k: not k.startswith("corl2017/task/train/") for k in keys}
    candidate = {k: not (k.startswith("nocrash/task/heldout/") and int(k[-2:]) < 20) for k in keys}
    released, reasons = verdict(paired_rows(baseline, candidate))
    assert not released and len(reasons) == 2 and reasons[1].startswith("not released: worse in nocrash/heldout by")
    candidate = {k: True for k in keys}  # the same win, no cell worse
    assert verdict(paired_rows(baseline, candidate))[0]

    monkeypatch.chdir(tmp_path)  # the release copies into ./models
    (tmp_path / "models").mkdir()
    (tmp_path / "v3").mkdir()
    for name in ("msfsu.pt", "msf.pt", "su.pt"):
        (tmp_path / "v3" / name).write_text(name)
        (tmp_path / "v3" / f"{name}.deploy").mkdir()
        (tmp_path / "v3" / f"{name}.deploy" / "new-v3-gate.json").write_text("{}")
        (tmp_path / "v3" / f"{name}.deploy" / "new-v3-fp32.onnx").write_text("onnx")
    (tmp_path / "models" / "msf.pt.deploy").mkdir()
    (tmp_path / "models" / "msf.pt.deploy" / "old-v3-gate.json").write_text("{}")
    assert release_main(["--baseline", f"{GRAPH1}:msfsu_v2", "--candidate", f"{NETWORKS}:msfsu", "--checkpoints", "v3",
                         "--out", "release.json"]) == 0
    assert json.loads((tmp_path / "release.json").read_text())["released"] is True
    assert (tmp_path / "models" / "msfsu_default.pt").read_text() == "msfsu.pt"
    assert sorted(p.name for p in (tmp_path / "models" / "msf.pt.deploy").iterdir()) == ["new-v3-gate.json"]
