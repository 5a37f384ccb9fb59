"""msfsu-waiting (msfsu_evaluation.pipelines.waiting, model v3's machinery) trains both levers of issue 77 on one
recipe, judges the candidate the scenario suite chooses beside the shipped MSFSU in one run, and releases it only by
the release rule with the scenario suite. Its commands are stood in for as in test_model_v3_script (the same checkout
fixture); the benchmark's scenario episodes are the committed abilities baseline's, its agents renamed."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from test_model_v3_script import RECORDER, ROOT, executable, tree  # noqa: F401 (tree: the checkout fixture)

from msfsu_evaluation.pipelines.waiting import CANDIDATES, STAGES, choose
from msfsu_evaluation.reports.paired_runs import episodes
from msfsu_evaluation.reports.release import ability_rows, main as release_main, paired_rows, verdict

COMMAND = str(Path(sys.executable).with_name("msfsu-waiting"))
ABILITIES = ROOT / "docs/results/abilities_v1/records/baseline"
NETWORKS = ROOT / "docs/results/closed_loop_v3_graph2/records/networks"
# on the scenario suite the stand-in drives the committed baseline's MSF as msfsu_weighted (46 % of the conflicts) and
# its MSFSU as msfsu_stop (27 %): the weighted candidate is chosen
BENCHMARK = (f"#!{sys.executable}\nimport json, os, pathlib, sys\nargs = sys.argv[1:]\n"
             'open(os.environ["CALLS"], "a").write("msfsu-benchmark " + " ".join(args) + "\\n")\n'
             'out = pathlib.Path(args[-1]); out.mkdir(parents=True, exist_ok=True)\n'
             'names = {"msfsu_weighted": "msf", "msfsu_stop": "msfsu", "msfsu": "msfsu"}\n'
             'agents = [a.split("=")[0] for i, a in enumerate(args) if i and args[i - 1] == "--checkpoint"]\n'
             f'source = pathlib.Path("{ABILITIES}/episodes.jsonl").read_text().splitlines()\n'
             'lines = []\n'
             'for agent in agents:\n'
             '    for line in source:\n'
             '        record = json.loads(line)\n'
             '        if record["agent"] == names.get(agent):\n'
             '            lines.append(json.dumps({**record, "agent": agent}))\n'
             '(out / "episodes.jsonl").write_text("\\n".join(lines) + "\\n")\n')
PYTHON = (f'#!/usr/bin/env bash\nif [ "$1 $2" = "-m msfsu_evaluation.stopping_study" ]; then\n'
          '  echo "stopping_study ${*:3}" >> "$CALLS"; exit 0\nfi\n'
          f'exec {sys.executable} "$@"\n')


def run(tree: Path, *stages: str) -> tuple[int, list[str]]:  # noqa: F811 (tree: the fixture)
    calls = tree / "calls"
    calls.write_text("")
    executable(tree / ".venv/bin/msfsu-benchmark", BENCHMARK)
    executable(tree / ".venv/bin/python", PYTHON)
    environment = {**os.environ, "CALLS": str(calls)}
    completed = subprocess.run([COMMAND, *stages], cwd=tree, env=environment, capture_output=True, text=True,
                               timeout=120)
    assert "Traceback" not in completed.stderr, completed.stderr
    return completed.returncode, calls.read_text().splitlines()


def test_both_levers_train_on_one_recipe_the_suite_chooses_and_the_choice_is_judged_and_released(tree):  # noqa: F811
    status, calls = run(tree)
    assert status == 0, calls
    recorded = [json.loads(line)["stage"] for line in
                (tree / "docs/results/waiting/stages.jsonl").read_text().splitlines()]
    assert recorded == list(STAGES)
    trains = [call for call in calls if call.startswith("msfsu-train")]
    assert len(trains) == 2
    stop, weighted = (next(c for c in trains if f"--out runs/waiting/{name} " in c) for name in CANDIDATES)
    for call in (stop, weighted):
        assert "--variant msfsu --init-from models/msfsu_default.pt" in call and "--schedule cosine" in call
    # the same data, steps, schedule and focus weighting: the two differ in their lever only
    assert stop.replace(" --stop-output --stop-weight 1.0", "").replace("msfsu_stop", "X") == \
        weighted.replace(" --stop-speed-weight 10.0", "").replace("msfsu_weighted", "X")
    gates = [call.split()[1] for call in calls if call.startswith("msfsu-gate")]
    assert gates == ["checkpoints/waiting/msfsu_stop.pt", "checkpoints/waiting/msfsu_weighted.pt"]
    drives = [call for call in calls if call.startswith("msfsu-benchmark ")]
    assert "--suite abilities --conditions train" in drives[0]
    assert "msfsu_stop=checkpoints/waiting/msfsu_stop.pt" in drives[0]
    selection = json.loads((tree / "docs/results/waiting/selection.json").read_text())
    assert selection["chosen"] == "msfsu_weighted"
    # each judged run's page is the benchmark's own, in its records (the waiting-goals block reads them there)
    assert not [call for call in calls if call.startswith("msfsu-benchmark-report")]
    for drive, suite in zip(drives[1:], ("--suite corl2017 nocrash", "--suite abilities"), strict=True):
        assert ("--checkpoint msfsu=models/msfsu_default.pt --checkpoint "
                "msfsu_weighted=checkpoints/waiting/msfsu_weighted.pt --no-expert " + suite) in drive
    study = next(call for call in calls if call.startswith("stopping_study"))
    assert "--network msfsu=models/msfsu_default.pt --network msfsu_stop=checkpoints/waiting/msfsu_stop.pt" in study
    release = next(call for call in calls if call.startswith("msfsu-model-v3-release")).split()
    judged = "docs/results/waiting/records"
    assert release[1:11] == ["--baseline", f"{judged}/judge-routes:msfsu", "--candidate",
                             f"{judged}/judge-routes:msfsu_weighted", "--abilities", f"{judged}/judge-abilities",
                             "--checkpoints", "checkpoints/waiting", "--release", "msfsu_weighted.pt=msfsu_default.pt"]


def test_the_candidate_that_solves_more_conflicts_is_chosen_whatever_its_place():
    for order in (("msf", "msfsu"), ("msfsu", "msf")):
        selection = choose(ABILITIES, order)
        assert selection["chosen"] == "msf"  # 46 % of the conflicts against 27 % in the baseline page
        assert selection["candidates"]["msf"]["scenarios"] == 192
    with pytest.raises(ValueError, match="no conflict scenario of msfsu_stop"):
        choose(ABILITIES, ("msfsu_stop", "msf"))


def test_the_release_rule_with_the_scenario_suite_refuses_a_candidate_worse_in_one_ability(tmp_path):
    keys = [f"corl2017/task/{condition}/{n:02d}" for condition in ("train", "heldout") for n in range(50)]
    baseline, candidate = {k: k.endswith("0") for k in keys}, {k: True for k in keys}  # a clear win on the routes
    scenarios = [f"abilities/{ability}/{condition}/{n:02d}" for ability in ("lead_braking", "cut_in")
                 for condition in ("train", "heldout") for n in range(16)]
    before = {k: True for k in scenarios}
    after = {k: not k.startswith("abilities/cut_in/") for k in scenarios}  # loses every cut-in
    released, reasons = verdict(paired_rows(baseline, candidate), ability_rows(before, after))
    assert not released and reasons[-1].startswith("not released: worse in abilities/cut_in/all by")
    assert verdict(paired_rows(baseline, candidate), ability_rows(before, before))[0]
    # the tool: the committed baseline's MSF against its MSFSU (routes) and on the suite; --release names the files
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "candidate.pt").write_text("w")
    assert release_main(["--baseline", f"{NETWORKS}:msfsu", "--candidate", f"{NETWORKS}:msf", "--abilities",
                         str(ABILITIES), "--checkpoints", str(tmp_path / "c"), "--release",
                         "candidate.pt=msfsu_default.pt", "--out", str(tmp_path / "release.json"), "--dry-run"]) == 0
    record = json.loads((tmp_path / "release.json").read_text())
    assert [row["suite"] for row in record["abilities"]] == sorted(
        f"abilities/{a}" for a in {k.split("/")[1] for k in episodes(ABILITIES, "msf")})
    with pytest.raises(SystemExit):
        release_main(["--checkpoints", "c", "--out", "x", "--release", "no-equals-sign"])
