"""`msfsu-model-v3` (`make model-v3`): model v3 (issue 58), the shipped v2 models trained further on this machine's
budget in stages of at most ~2.5 h, each stage's product committed when it ends (docs/training.md, "Model v3": the
plan, its hours, the levers).

    msfsu-model-v3                        every stage not yet done, in order
    msfsu-model-v3 STAGE...               these stages (and, first, the stages whose products they read)
    msfsu-model-v3 train-su --epochs 5    a stage's parameter (`msfsu-model-v3 help train-su` lists them)
    msfsu-model-v3 list / info STAGE      the stages; one stage's inputs, products and parameters
    COMMIT=1 msfsu-model-v3               also `git commit` each stage's product (and only it) when it ends

A stage is done when its line is in docs/results/model_v3/stages.jsonl (its wall hours over every invocation,
machine and code commit) and its products exist. The data stages run whenever asked, and before a training stage
that runs: on a new machine the bags are gone, the recipe is deterministic and msfsu-collect writes them again (the
first measurement of the stage stays the record; the time counts under the clock "re-collect"). A training stage
resumes from its run's last.pt; without it (a new machine) from its snapshot, committed after every epoch
(checkpoints/v3/progress/<run>: fp16 weights, run and schedule state, metrics; a fresh optimizer), else from the
start: the weights it starts from (models/*.pt, the shipped v2) are committed. A lost machine costs an epoch. A
benchmark stage resumes from its committed episodes, committed every 5 looks while it drives.

The recipe, the same for the three variants (the ablation compares networks):
  data-expert  round 0 as the v2 recipe collects it (the same episodes, seeds and noise): 3 routes per training
               town x weather x traffic, and the validation bags, and the held-out gate bags
  data-dagger  one on-policy round: the shipped MSFSU (models/msfsu_default.pt) drives each step the expert does not
               (--beta: the expert drives a step with that probability), the expert labels every frame;
               --dagger-episodes routes per town x weather x traffic
  train-V      warm start from the shipped model of variant V with a fresh optimizer and schedule, on both rounds,
               the on-policy focus frames (crash approaches, near misses) --focus-copies more times, --epochs epochs
               under the cosine schedule; its best validation checkpoint in fp16 is checkpoints/v3/V.pt, the count of
               the bags it trained on, then its accuracy gate (while the bags are on the machine)
  judge-*      benchmark v3 (350 routes per network; the expert beside MSFSU) of the v3 checkpoints (one not yet gated
               is gated first, on bags collected for it), and their pages: the report of every judged run, each v3
               network paired with its shipped v2 (v3_change.md)
  release      the release rule (msfsu-model-v3-release): models/ takes the v3 models only if v3 MSFSU beats the
               shipped one, paired over the 350 routes

Settings (environment): DATA (data/v3), RUNS (runs/v3), WORKERS (2), RECORD (docs/results/model_v3), CHECKPOINTS
(checkpoints/v3), JUDGED, REPORT, BASELINE (the judged runs, their pages, the shipped models' run), COMMIT,
PROGRESS_POLL_S (60: seconds between the progress committer's looks), PROGRESS_LIMIT_MIB (160 of a submission's 256:
room left for a stage's product), SUBMIT_BASE (where the unsubmitted commits start, on a checkout that outlives a
landed submission; the log's first line with COMMIT names the base and the MiB counted).
"""

from __future__ import annotations

import shutil
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from msfsu_evaluation.pipelines.recording import Recording
from msfsu_evaluation.pipelines.runner import Parameter, Pipeline, Stage, StageRun, environment, main as run_pipeline

COMMAND = "msfsu-model-v3"
SHIPPED = {"msfsu": "models/msfsu_default.pt", "msf": "models/msf.pt", "su": "models/su.pt"}
STAGES = ("data-expert", "data-dagger", "train-msfsu", "train-su", "train-msf", "judge-msfsu", "judge-msf-su",
          "release")
JUDGED_AGENTS = (("msfsu_v3", "msfsu"), ("msf_v3", "msf"), ("su_v3", "su"))  # v3 agent, the shipped one it started from

BETA = Parameter("beta", "BETA", 0.25, "the probability that the expert drives a step")
DAGGER_EPISODES = Parameter("dagger_episodes", "DAGGER_EPISODES", 2, "routes per town x weather x traffic")
EPOCHS = Parameter("epochs", "EPOCHS", 4, "epochs of the two rounds' ~2,510 batches, down a cosine from 3e-4")
FOCUS_COPIES = Parameter("focus_copies", "FOCUS_COPIES", 3, "extra copies of the on-policy focus frames")


@dataclass(frozen=True)
class Settings:
    tag: str  # names this round's gate pages, int8 recipes and training pages (v3: ..._v3_<name>)
    data: str
    runs: str
    workers: int
    record: str
    checkpoints: str
    judged: str
    report: str
    baseline: str  # the shipped models on today's graph
    commit: bool
    poll_s: int
    progress_limit_mib: int

    @classmethod
    def from_environment(cls) -> Settings:
        return cls(tag="v3", data=environment("DATA", "data/v3"), runs=environment("RUNS", "runs/v3"),
                   workers=environment("WORKERS", 2), record=environment("RECORD", "docs/results/model_v3"),
                   checkpoints=environment("CHECKPOINTS", "checkpoints/v3"),
                   judged=environment("JUDGED", "docs/results/closed_loop_v3_model_v3/records"),
                   report=environment("REPORT", "docs/results/closed_loop_v3_model_v3"),
                   baseline=environment("BASELINE", "docs/results/closed_loop_v3_graph2/records/networks"),
                   commit=bool(environment("COMMIT", "")), poll_s=environment("PROGRESS_POLL_S", 60),
                   progress_limit_mib=environment("PROGRESS_LIMIT_MIB", 160))


class ModelV3:
    """The recipe's commands, stage by stage."""

    def __init__(self, settings: Settings) -> None:
        self.s = settings

    # the data
    def collect_expert(self, run: StageRun) -> None:
        s = self.s
        run.tool("msfsu-collect", "--output", s.data, "--split", "train", "--episodes", "3", "--max-steps", "900",
                 "--workers", str(s.workers))
        run.tool("msfsu-collect", "--output", s.data, "--split", "validation", "--episodes", "1", "--traffic",
                 "regular", "dense", "--max-steps", "400", "--no-noise", "--workers", str(s.workers))
        run.command("bash", "scripts/gate_bags.sh",  # the held-out bags of the accuracy gate
                    env={"GATE_DATA": f"{s.data}/gate", "WORKERS": str(s.workers)})

    def collect_dagger(self, run: StageRun) -> None:
        s = self.s
        run.tool("msfsu-collect", "--output", s.data, "--split", "train", "--episodes",
                 str(run.options["dagger_episodes"]), "--max-steps", "900", "--workers", str(s.workers), "--driver",
                 SHIPPED["msfsu"], "--beta", str(run.options["beta"]), "--round", "1")

    def bags(self) -> int:
        return sum(1 for _ in Path(self.s.data).rglob("metadata.yaml")) if Path(self.s.data).is_dir() else 0

    def data_stage(self, collect: Callable[[StageRun], None]) -> Callable[[StageRun], None]:
        def stage(run: StageRun) -> None:
            before = self.bags()
            run.log(f"collection into {self.s.data}")
            collect(run)
            # the data report: of a new stage, or of bags collected again (on a new machine a network's route may
            # differ) once the last data stage has them (the expert round's alone would replace the report of both)
            again = self.bags() != before and (run.stage.name == "data-dagger"
                                               or not run.pipeline.recording.done("data-dagger"))
            if not run.recorded or again:
                run.tool("msfsu-dataset-report", self.s.data, "--out", self.s.record)
        return stage

    # training and the gate
    def gate(self, run: StageRun, checkpoint: str) -> None:
        """The checkpoint's accuracy gate as the shipped models had theirs (calibration frames, int8 recipe, verdicts
        beside it), so that it drives on the precision the perception node deploys it on, as the shipped models in
        the baseline did; on the bags (collected here if missing), unless its verdicts exist. With COMMIT its
        records are committed (not the converted models: .gitignore)."""
        name, tag = Path(checkpoint).stem, self.s.tag
        page = f"benchmarks/perception_gate_results_{tag}_{name}.md"
        if Path(page).exists():
            return
        self.collect_expert(run)
        run.log(f"accuracy gate of {checkpoint}")
        s = self.s
        run.tool("msfsu-gate", checkpoint, "--bags", f"{s.data}/gate/test/*", "--calibration-bags", f"{s.data}/train/*",
                 "--calibration-frames", "300", "--val-bags", f"{s.data}/validation/*", "--recipe-frames", "400",
                 "--recipe-out", f"benchmarks/int8_recipes/{tag}_{name}", "--out", page)
        run.commit(f"the accuracy gate of {checkpoint}",
                   [f"{checkpoint}.calibration.npz", f"{checkpoint}.deploy",
                    f"benchmarks/int8_recipes/{tag}_{name}.json", f"benchmarks/int8_recipes/{tag}_{name}.md", page])

    def train_stage(self, variant: str, name: str | None = None,
                    extra: Callable[[StageRun], Sequence[str]] = lambda run: ()) -> Callable[[StageRun], None]:
        """Train `variant` from its shipped weights into checkpoints/<name>.pt (name: the variant's), with the recipe's
        arguments and `extra(run)`'s, then gate it."""
        name = name or variant

        def stage(run: StageRun) -> None:
            s, options = self.s, run.options
            out, snapshots = f"{s.runs}/{name}", f"{s.checkpoints}/progress/{name}"
            resume = Path(out, "last.pt").exists() or Path(snapshots, "last.pt").exists()
            run.log(f"{name} from {SHIPPED[variant]}, {options['epochs']} epochs{' (resumed)' if resume else ''}")
            # after every epoch (last.pt still for a third of a look: the epoch's files are all written)
            with run.progress("the snapshot after an epoch", snapshots, f"{snapshots}/last.pt", s.poll_s,
                              s.poll_s // 3):
                run.tool("msfsu-train", "--train-bags", f"{s.data}/train/*", "--val-bags", f"{s.data}/validation/*",
                         "--preset", "cpu", "--variant", variant, "--init-from", SHIPPED[variant], "--epochs",
                         str(options["epochs"]), "--num-threads", "2", "--schedule", "cosine", "--focus-copies",
                         str(options["focus_copies"]), "--out", out, "--snapshots", snapshots, "--evict-caches",
                         *extra(run), *(["--resume"] if resume else []))
            # the best validation loss's weights in fp16, over every machine
            checkpoint = Path(s.checkpoints, f"{name}.pt")
            shutil.copyfile(Path(snapshots, "best.pt"), checkpoint.with_name(checkpoint.name + ".new"))
            checkpoint.with_name(checkpoint.name + ".new").replace(checkpoint)
            results = Path(f"docs/results/training/{s.tag}_{name}")
            results.mkdir(parents=True, exist_ok=True)
            for file in ("metrics.csv", "loss_curves.png", "balancing.png", "args.json"):
                shutil.copyfile(Path(out, file), results / file)
            # the bags it trained on, counted (data.json, data.md): an on-policy round collected again on another CPU
            # is not record for record the first (the driving network's float results differ, the route follows them)
            run.tool("msfsu-dataset-report", s.data, "--out", str(results))
            self.gate(run, str(checkpoint))  # in the stage's hours
            # the stage's product commit does not take the snapshot again (its commit stands: 2 x 28 MB more)
        return stage

    # judging and the release
    def judge_stage(self, networks: Sequence[tuple[str, str]], expert: bool) -> Callable[[StageRun], None]:
        """Drives NAME=CHECKPOINT of each network (gated first), the expert beside them when `expert` (another judge
        stage drives it otherwise); the episodes so far committed every 5 looks: a session's end costs minutes."""
        def stage(run: StageRun) -> None:
            s, name = self.s, run.stage.name
            arguments = [] if expert else ["--no-expert"]
            for network, checkpoint in networks:
                self.gate(run, checkpoint)  # a checkpoint whose training stage could not gate it
                arguments += ["--checkpoint", f"{network}={checkpoint}"]
            run.log(f"benchmark v3 of {' '.join(f'{n}={c}' for n, c in networks)}")
            self.benchmark(run, f"{s.judged}/{name}", *arguments, "--suite", "corl2017", "nocrash", "--conditions",
                           "train", "heldout")
            self.v3_pages(run)
        return stage

    def benchmark(self, run: StageRun, records: str, *arguments: str) -> None:
        """msfsu-benchmark with `arguments` on the recipe's workers into `records`, its episodes so far committed every
        5 looks (COMMIT): a session's end costs minutes."""
        s = self.s
        with run.progress("its episodes so far", records, f"{records}/episodes.jsonl", s.poll_s * 5, 0):
            run.tool("msfsu-benchmark", *arguments, "--workers", str(s.workers), "--out", records)

    def v3_pages(self, run: StageRun) -> None:
        """The judged runs' report (results.md: the networks, the expert beside them, against the paper) and each v3
        network paired per route with the shipped model it started from, on the baseline's routes: v3_change.md
        (every network's suites and conditions) and v3_change_<network>.md (every route and flip)."""
        s = self.s
        judged = sorted(f"{s.judged}/{path.name}" for path in Path(s.judged).iterdir() if path.is_dir())

        def drives(judged_run: str, agent: str) -> bool:
            episodes = Path(judged_run, "episodes.jsonl")
            return episodes.is_file() and f'"agent": "{agent}"' in episodes.read_text()

        # the expert drives in judge-msfsu only (the same simulator, so the same episodes); where several runs hold
        # it, the first one's records are its
        expert_runs = [judged_run for judged_run in judged if drives(judged_run, "expert")]
        prefer = ["--prefer", f"expert={expert_runs[0]}"] if len(expert_runs) > 1 else []
        run.tool("msfsu-benchmark-report", *judged, *prefer, "--out", s.report)
        changed: list[str] = []
        for agent, shipped in JUDGED_AGENTS:
            for judged_run in judged:
                if not drives(judged_run, agent):
                    continue
                run.tool("python", "scripts/revision_change.py", f"{s.baseline}:{shipped}", f"{judged_run}:{agent}",
                         "--out", f"{s.report}/v3_change_{agent}.md", quiet=True)
                changed += [agent, f"{s.baseline}:{shipped}", f"{judged_run}:{agent}"]
        if changed:
            run.tool("python", "scripts/graph_change_table.py", *changed, "--labels", "v2", "v3", "--pages",
                     "v3_change_<network>.md", "--out", f"{s.report}/v3_change.md", quiet=True)

    def release(self, run: StageRun) -> None:
        s = self.s
        run.tool("msfsu-model-v3-release", "--baseline", f"{s.baseline}:msfsu", "--candidate",
                 f"{s.judged}/judge-msfsu:msfsu_v3", "--checkpoints", s.checkpoints, "--out",
                 f"{s.record}/release.json")

    def data_stages(self) -> list[Stage]:
        """data-expert and data-dagger: the two rounds a training stage reads (their report in the record)."""
        data = (f"{self.s.record}/data.json", f"{self.s.record}/data.md")
        return [
            Stage("data-expert", "round 0 by the v2 recipe's episode plan, the validation bags, the gate's bags",
                  self.data_stage(self.collect_expert), updates=data, always=True, rerun_clock="re-collect"),
            Stage("data-dagger", "one on-policy round: the shipped MSFSU drives, the expert labels every frame",
                  self.data_stage(self.collect_dagger), updates=data, inputs=(SHIPPED["msfsu"],),
                  params=(BETA, DAGGER_EPISODES), always=True, rerun_clock="re-collect"),
        ]

    def stages(self) -> list[Stage]:
        s = self.s
        stages = self.data_stages()
        for variant in ("msfsu", "su", "msf"):
            stages.append(Stage(
                f"train-{variant}", f"{variant} from its shipped weights on both rounds, then its accuracy gate",
                self.train_stage(variant),
                products=(f"{s.checkpoints}/{variant}.pt", f"docs/results/training/v3_{variant}"),
                inputs=(SHIPPED[variant],), needs=("data-expert", "data-dagger"), params=(EPOCHS, FOCUS_COPIES)))
        checkpoint = {variant: f"{s.checkpoints}/{variant}.pt" for variant in SHIPPED}
        stages += [
            Stage("judge-msfsu", "benchmark v3 of v3 MSFSU, the expert beside it",
                  self.judge_stage([("msfsu_v3", checkpoint["msfsu"])], expert=True),
                  products=(f"{s.judged}/judge-msfsu",), updates=(s.report,), inputs=(checkpoint["msfsu"], s.baseline),
                  after=("train-msfsu",)),
            Stage("judge-msf-su", "benchmark v3 of v3 MSF and SU (the expert's episodes are judge-msfsu's)",
                  self.judge_stage([("msf_v3", checkpoint["msf"]), ("su_v3", checkpoint["su"])], expert=False),
                  products=(f"{s.judged}/judge-msf-su",), updates=(s.report,),
                  inputs=(checkpoint["msf"], checkpoint["su"]),
                  after=("train-msf", "train-su")),
            Stage("release", "the release rule: models/ takes the v3 models only if v3 MSFSU beats the shipped one",
                  self.release, products=(f"{s.record}/release.json",), updates=("models",),
                  inputs=(s.baseline, *checkpoint.values()), after=("judge-msfsu", "train-su", "train-msf")),
        ]
        assert tuple(stage.name for stage in stages) == STAGES
        return stages


def staged_pipeline(name: str, title: str, command: str, settings: Settings, stages: list[Stage]) -> Pipeline:
    """A recipe on these settings: its stage records in settings.record, doit's state in settings.runs."""
    return Pipeline(name=name, title=title, command=command, stages=stages, recording=Recording(Path(settings.record)),
                    state=Path(settings.runs, ".doit.json"), commit=settings.commit,
                    progress_limit_mib=settings.progress_limit_mib)


def pipeline() -> Pipeline:
    settings = Settings.from_environment()
    return staged_pipeline("model-v3", "Model v3", COMMAND, settings, ModelV3(settings).stages())


def main(argv: Sequence[str] | None = None) -> int:
    return run_pipeline(pipeline, argv, COMMAND)


if __name__ == "__main__":
    sys.exit(main())
