"""`msfsu-waiting` (`make waiting`): a network that waits (issue 77), the shipped MSFSU trained further with the lever
the stopping study points at, in stages of at most ~2.5 h, each stage's product committed when it ends
(docs/training.md, "A network that waits (issue 77): the plan": the diagnosis, the levers, the hours).

    msfsu-waiting                         every stage not yet done, in order
    msfsu-waiting STAGE...                these stages (and, first, the stages whose products they read)
    msfsu-waiting train-stop --epochs 5   a stage's parameter (`msfsu-waiting help train-stop` lists them)
    msfsu-waiting list / info STAGE       the stages; one stage's inputs, products and parameters
    COMMIT=1 msfsu-waiting                also `git commit` each stage's product (and only it) when it ends

The machinery is model v3's (msfsu_evaluation.pipelines.model_v3: the data stages, a training stage and its accuracy
gate, the stage clocks and records, progress commits); so are its rules for a stage that stops or a machine that is
lost. The recipe:
  data-expert     round 0 as the v2 and v3 recipes collect it, the validation bags, the held-out gate bags
  data-dagger     one on-policy round: the shipped MSFSU drives, the expert labels every frame (the focus frames:
                  where it crashed or drove on while the expert was held by a vehicle or a pedestrian)
  train-stop      MSFSU with a stop output (msfsu-train --stop-output), warm-started from the shipped weights
  train-weighted  MSFSU without one, its speed loss weighting the stop frames (--stop-speed-weight): the same data,
                  epochs, schedule and focus copies
  select          both candidates on the scenario suite's training-condition scenarios; the one that solves more
                  conflicts (a tie: the stop output) is judged (selection.json; the run's page: the benchmark's own,
                  records/select/); and the stopping study on the held-out gate bags of the shipped network and
                  both candidates (its page: stopping_study/)
  judge-routes    the shipped MSFSU and the chosen candidate, one run (each route's pair on one machine; a resume
                  on another CPU drives the pair again): the 350 routes of benchmark v3
  judge-abilities the same two on the whole scenario suite (both conditions); each judge run's page is the
                  benchmark's own (records/judge-*/results.md)
  release         model v3's release rule on the routes (paired, McNemar p < 0.05, no suite and condition worse by
                  more than its interval) and no ability worse by more than its interval: the candidate replaces
                  models/msfsu_default.pt (msfsu-model-v3-release --release --abilities)

Settings (environment): DATA (data/waiting), RUNS (runs/waiting), WORKERS (2), RECORD (docs/results/waiting),
CHECKPOINTS (checkpoints/waiting), JUDGED (docs/results/waiting/records), COMMIT, PROGRESS_POLL_S, PROGRESS_LIMIT_MIB,
SUBMIT_BASE (as model v3's).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from msfsu_evaluation.closed_loop.abilities import ABILITIES
from msfsu_evaluation.pipelines.model_v3 import EPOCHS, FOCUS_COPIES, SHIPPED, ModelV3, Settings, staged_pipeline
from msfsu_evaluation.pipelines.runner import Parameter, Pipeline, Stage, StageRun, environment, main as run_pipeline
from msfsu_evaluation.reports.paired_runs import episodes, task_of
from msfsu_evaluation.reports.waiting_goals import JUDGED, RECORD
from msfsu_sim.scenario_spec import CLEAR_ROAD

COMMAND = "msfsu-waiting"
STAGES = ("data-expert", "data-dagger", "train-stop", "train-weighted", "select", "judge-routes", "judge-abilities",
          "release")
BASELINE_AGENT = "msfsu"  # the shipped MSFSU, driven again beside the candidate
CANDIDATES = ("msfsu_stop", "msfsu_weighted")  # agent = checkpoint name; the first wins a tie
CONFLICTS = tuple(name for name, ability in ABILITIES.items() if ability.kind != CLEAR_ROAD)

STOP_WEIGHT = Parameter("stop_weight", "STOP_WEIGHT", 1.0, "weight of the stop output's cross-entropy in the total")
STOP_SPEED_WEIGHT = Parameter("stop_speed_weight", "STOP_SPEED_WEIGHT", 10.0,
                              "times a stop frame's squared speed error counts (stops are about a tenth of the frames)")


def settings_from_environment() -> Settings:
    record = environment("RECORD", str(RECORD))
    judged = environment("JUDGED", f"{record}/{JUDGED.relative_to(RECORD)}")
    return Settings(tag="waiting", data=environment("DATA", "data/waiting"), runs=environment("RUNS", "runs/waiting"),
                    workers=environment("WORKERS", 2), record=record,
                    checkpoints=environment("CHECKPOINTS", "checkpoints/waiting"), judged=judged, report=record,
                    baseline=f"{judged}/judge-routes", commit=bool(environment("COMMIT", "")),
                    poll_s=environment("PROGRESS_POLL_S", 60),
                    progress_limit_mib=environment("PROGRESS_LIMIT_MIB", 160))


def conflicts_solved(run: Path, agent: str) -> tuple[int, int]:
    """(successes, scenarios) of `agent` over the conflict abilities (every ability but the clear road) in `run`."""
    driven = [episode for key, episode in episodes(run, agent).items() if task_of(key) in CONFLICTS]
    return sum(episode.success for episode in driven), len(driven)


def choose(run: Path, candidates: Sequence[str] = CANDIDATES) -> dict:
    """selection.json: each candidate's conflicts solved in `run`, and the one judged (the larger share solved; a tie:
    the first of `candidates`)."""
    solved = {agent: conflicts_solved(run, agent) for agent in candidates}
    missing = [agent for agent, (_, scenarios) in solved.items() if scenarios == 0]
    if missing:
        raise ValueError(f"{run} holds no conflict scenario of {', '.join(missing)}")
    chosen = max(candidates, key=lambda agent: (solved[agent][0] / solved[agent][1], -candidates.index(agent)))
    return {"run": str(run), "rule": "the candidate that solves the larger share of the conflict scenarios of the "
                                     "training conditions; a tie: " + candidates[0],
            "candidates": {agent: {"conflicts_solved": k, "scenarios": n} for agent, (k, n) in solved.items()},
            "chosen": chosen}


class Waiting:
    """The recipe's commands, stage by stage (model v3's for the data, the training and the gate)."""

    def __init__(self, settings: Settings) -> None:
        self.s = settings
        self.v3 = ModelV3(settings)

    def checkpoint(self, agent: str) -> str:
        return f"{self.s.checkpoints}/{agent}.pt"

    @property
    def selection(self) -> Path:
        return Path(self.s.record, "selection.json")

    def chosen(self) -> str:
        return json.loads(self.selection.read_text())["chosen"]

    def select(self, run: StageRun) -> None:
        s = self.s
        records = f"{s.judged}/select"
        arguments = [arg for agent in CANDIDATES for arg in ("--checkpoint", f"{agent}={self.checkpoint(agent)}")]
        for agent in CANDIDATES:
            self.v3.gate(run, self.checkpoint(agent))  # a checkpoint whose training stage could not gate it
        run.log(f"the scenario suite's training conditions: {', '.join(CANDIDATES)}")
        self.v3.benchmark(run, records, *arguments, "--no-expert", "--suite", "abilities", "--conditions", "train")
        selection = choose(Path(records))
        self.selection.write_text(json.dumps(selection, indent=1) + "\n")
        run.log(f"chosen: {selection['chosen']} ({selection['candidates']})")
        networks = [f"{BASELINE_AGENT}={SHIPPED['msfsu']}", *(f"{a}={self.checkpoint(a)}" for a in CANDIDATES)]
        run.tool("python", "-m", "msfsu_evaluation.stopping_study", "--bags", f"{s.data}/gate/test/*",
                 *(arg for network in networks for arg in ("--network", network)), "--out",
                 f"{s.record}/stopping_study")

    def judge_stage(self, suite: Sequence[str], name: str) -> Callable[[StageRun], None]:
        """The shipped MSFSU and the chosen candidate in one run, each route's pair on one machine; the episodes so far
        committed every 5 looks. The run's page is the benchmark's own (records/<stage>/results.md, .json)."""
        def stage(run: StageRun) -> None:
            s, chosen = self.s, self.chosen()
            records = f"{s.judged}/{name}"
            run.log(f"{' '.join(suite)}: {BASELINE_AGENT} (shipped) and {chosen}")
            self.v3.benchmark(run, records, "--checkpoint", f"{BASELINE_AGENT}={SHIPPED['msfsu']}", "--checkpoint",
                              f"{chosen}={self.checkpoint(chosen)}", "--no-expert", "--suite", *suite)
        return stage

    def release(self, run: StageRun) -> None:
        s, chosen = self.s, self.chosen()
        run.tool("msfsu-model-v3-release", "--baseline", f"{s.judged}/judge-routes:{BASELINE_AGENT}", "--candidate",
                 f"{s.judged}/judge-routes:{chosen}", "--abilities", f"{s.judged}/judge-abilities", "--checkpoints",
                 s.checkpoints, "--release", f"{chosen}.pt=msfsu_default.pt", "--out", f"{s.record}/release.json")

    def stages(self) -> list[Stage]:
        s, v3 = self.s, self.v3
        candidates = tuple(self.checkpoint(agent) for agent in CANDIDATES)
        stages = [
            *v3.data_stages(),
            Stage("train-stop", "MSFSU with a stop output from the shipped weights on both rounds, then its gate",
                  v3.train_stage("msfsu", "msfsu_stop", lambda run: ("--stop-output", "--stop-weight",
                                                                     str(run.options["stop_weight"]))),
                  products=(candidates[0], f"docs/results/training/{s.tag}_msfsu_stop"), inputs=(SHIPPED["msfsu"],),
                  needs=("data-expert", "data-dagger"), params=(EPOCHS, FOCUS_COPIES, STOP_WEIGHT)),
            Stage("train-weighted", "MSFSU with the stop frames' speed error weighted, the same data and steps",
                  v3.train_stage("msfsu", "msfsu_weighted", lambda run: ("--stop-speed-weight",
                                                                         str(run.options["stop_speed_weight"]))),
                  products=(candidates[1], f"docs/results/training/{s.tag}_msfsu_weighted"),
                  inputs=(SHIPPED["msfsu"],), needs=("data-expert", "data-dagger"),
                  params=(EPOCHS, FOCUS_COPIES, STOP_SPEED_WEIGHT)),
            Stage("select", "both candidates on the training-condition scenarios; the stopping study of all three",
                  self.select, products=(str(self.selection), f"{s.judged}/select", f"{s.record}/stopping_study"),
                  inputs=candidates, after=("train-stop", "train-weighted"), needs=("data-expert",)),
            Stage("judge-routes", "the shipped MSFSU and the chosen candidate on benchmark v3's 350 routes",
                  self.judge_stage(("corl2017", "nocrash"), "judge-routes"),
                  products=(f"{s.judged}/judge-routes",), after=("select",)),
            Stage("judge-abilities", "the same two on the scenario suite, both conditions",
                  self.judge_stage(("abilities",), "judge-abilities"),
                  products=(f"{s.judged}/judge-abilities",), after=("select",)),
            Stage("release", "the release rule on the routes and no ability worse: the candidate replaces the shipped",
                  self.release, products=(f"{s.record}/release.json",), updates=("models",),
                  after=("judge-routes", "judge-abilities")),
        ]
        assert tuple(stage.name for stage in stages) == STAGES
        return stages


def pipeline() -> Pipeline:
    settings = settings_from_environment()
    return staged_pipeline("waiting", "A network that waits", COMMAND, settings, Waiting(settings).stages())


def main(argv: Sequence[str] | None = None) -> int:
    return run_pipeline(pipeline, argv, COMMAND)


if __name__ == "__main__":
    sys.exit(main())
