"""`msfsu-default-model` (`make default-model`): the recipe behind the shipped models/ and bags/sample (issue #12),
with the project's own commands only. On 2 CPU cores: data ~1.5 h, each variant ~2 h of training.

    msfsu-default-model                  every stage not yet done, in order
    msfsu-default-model STAGE...         these stages (and, first, the stages whose products they read)
    msfsu-default-model list / info STAGE / help STAGE

Stages (VARIANTS, ROUNDS and BRANCH say which there are):
  data                 expert data (round 0, steering-noise injection on): training towns x weathers x traffic levels,
                       --train-episodes routes each; validation on the training towns and weathers (clean labels); the
                       held-out gate bags
  train-V-round0       variant V (MSFSU, MSF, SU), --round0-epochs epochs on the expert data
  dagger-roundN        DAgger (Ross et al. 2011) round N's data: MSFSU of the round before drives (beta = 0.5^N), the
                       expert labels every frame; collected before a stage that trains on it
  train-V-roundN       V continues on the aggregate of rounds 0..N up to --round0-epochs + N * --round-epochs epochs:
                       one data set and one budget for the three (the ablation is fair)
  branch-msfsu-roundN  (BRANCH=1) the same budget without round N's data: from round N-1's last epoch, the same epochs
                       on rounds 0..N-1 only (RUNS/msfsu_branch<N>/: round<N>.pt its best, last.pt its last epoch); its
                       last epoch is what round N's last epoch (RUNS/msfsu/round<N>.last.pt) is measured against
                       (scripts/results.sh)
  release              fp16 releases into models/ (at most 30 MB each), a held-out sample bag into bags/sample, the
                       data's report into DATA_REPORT (default docs/results/data)

Every stage resumes: a training stage is done when its round's checkpoints are in RUNS (copied there so that a stop
cannot leave one half-written), and continues from its run's last.pt; collection skips finished bags. Frame caches
(data/cache) that the disk cannot hold beside a new one are deleted, least recently used first, and rebuilt if needed
again. Each stage's wall hours over its invocations: RUNS/stages.jsonl and RUNS/clock/ (this machine's, as the runs
are: nothing here is committed). Settings (environment): DATA (data/v2), RUNS (runs/v2), WORKERS (2), VARIANTS
("msfsu msf su"; MSF and SU alone need RUNS/msfsu/round*.pt, their drivers), ROUNDS (1), BRANCH, DATA_REPORT,
SAMPLE_MAX_STEPS (225), SAMPLE_SEED (2030). Parameters (`msfsu-default-model help STAGE`): TRAIN_EPISODES (3),
ROUND0_EPOCHS (5), ROUND_EPOCHS (5), FOCUS_COPIES (0: plain DAgger; N: each DAgger round's training repeats the
on-policy focus frames N more times, where the network crashed or nearly did: msfsu_perception.bag_index.FocusConfig).
The closed-loop comparison of the rounds (training routes only) and of the variants: scripts/results.sh.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from msfsu_evaluation.pipelines.recording import Recording
from msfsu_evaluation.pipelines.runner import (Parameter, Pipeline, Stage, StageFailed, StageRun, environment,
                                               main as run_pipeline)

COMMAND = "msfsu-default-model"
RELEASED = {"msfsu": "msfsu_default", "msf": "msf", "su": "su"}  # variant -> models/<name>.pt
SAMPLE_BYTES = 25_000_000  # a committed bag weighs at most 25 MB (10^6 bytes)

TRAIN_EPISODES = Parameter("train_episodes", "TRAIN_EPISODES", 3, "expert routes per town x weather x traffic")
ROUND0_EPOCHS = Parameter("round0_epochs", "ROUND0_EPOCHS", 5, "epochs on the expert data")
ROUND_EPOCHS = Parameter("round_epochs", "ROUND_EPOCHS", 5, "epochs more per DAgger round")
FOCUS_COPIES = Parameter("focus_copies", "FOCUS_COPIES", 0, "extra copies of each DAgger round's focus frames")
TRAINING = (ROUND0_EPOCHS, ROUND_EPOCHS, FOCUS_COPIES)


@dataclass(frozen=True)
class Settings:
    data: str
    runs: str
    workers: int
    variants: tuple[str, ...]
    rounds: int
    branch: bool
    data_report: str
    sample_max_steps: int
    sample_seed: int

    @classmethod
    def from_environment(cls) -> Settings:
        variants = tuple(environment("VARIANTS", "msfsu msf su").split())
        unknown = [variant for variant in variants if variant not in RELEASED]
        if unknown or not variants:
            raise ValueError(f"VARIANTS={' '.join(variants)!r}: each one of {', '.join(RELEASED)}")
        rounds = environment("ROUNDS", 1)
        if rounds < 0:
            raise ValueError(f"ROUNDS={rounds}: 0 or more")
        return cls(data=environment("DATA", "data/v2"), runs=environment("RUNS", "runs/v2"),
                   workers=environment("WORKERS", 2), variants=variants, rounds=rounds,
                   branch=bool(environment("BRANCH", "")), data_report=environment("DATA_REPORT", "docs/results/data"),
                   sample_max_steps=environment("SAMPLE_MAX_STEPS", 225), sample_seed=environment("SAMPLE_SEED", 2030))


def publish(source: str | Path, target: str | Path) -> None:
    """A copy that a stop cannot leave half-written (a session's end kills whatever runs): the stages are done when
    their checkpoints exist, so each is copied this way, the one its stage is judged by last."""
    partial = Path(f"{target}.partial")
    shutil.copyfile(source, partial)
    os.replace(partial, target)


class DefaultModel:
    def __init__(self, settings: Settings) -> None:
        self.s = settings

    def run_dir(self, name: str) -> Path:
        return Path(self.s.runs, name)

    def train_bags(self, last_round: int) -> list[str]:
        """Training bags of rounds 0..last_round: round 0 is named <town>_<weather>_<traffic>_<index>, round N adds
        _rN."""
        return [f"{self.s.data}/train/*_[0-9][0-9][0-9]", *(f"{self.s.data}/train/*_r{r}"
                                                             for r in range(1, last_round + 1))]

    def epochs(self, run: StageRun, round_: int) -> int:
        """Round N's epochs in all (the run goes on): one budget for the three variants and the branch."""
        return run.options["round0_epochs"] + round_ * run.options["round_epochs"]

    def train(self, run: StageRun, variant: str, last_round: int, epochs: int, name: str) -> None:
        """Trains `variant` on rounds 0..last_round up to `epochs` in run `name`, continuing its last.pt; the run's
        record (one metrics.csv row per epoch: losses, lr, samples/s, epoch time) copied to be committed."""
        out = self.run_dir(name)
        resume = (out / "last.pt").exists()
        run.log(f"train {name}: variant {variant} on rounds 0..{last_round}, up to {epochs} epochs"
                f"{' (resumed)' if resume else ''}")
        run.tool("msfsu-train", "--train-bags", *self.train_bags(last_round), "--val-bags",
                 f"{self.s.data}/validation/*", "--preset", "cpu", "--variant", variant, "--epochs", str(epochs),
                 "--num-threads", "2", "--focus-copies", str(run.options["focus_copies"]), "--out", str(out),
                 "--evict-caches", *(["--resume"] if resume else []))
        record = Path("docs/results/training", name)
        record.mkdir(parents=True, exist_ok=True)
        for file in ("metrics.csv", "loss_curves.png", "balancing.png"):
            shutil.copyfile(out / file, record / file)

    # the stages' work
    def collect_expert(self, run: StageRun) -> None:
        s = self.s
        run.log(f"expert data into {s.data} (train, validation, gate bags)")
        run.tool("msfsu-collect", "--output", s.data, "--split", "train", "--episodes",
                 str(run.options["train_episodes"]), "--max-steps", "900", "--workers", str(s.workers))
        run.tool("msfsu-collect", "--output", s.data, "--split", "validation", "--episodes", "1", "--traffic",
                 "regular", "dense", "--max-steps", "400", "--no-noise", "--workers", str(s.workers))
        run.command("bash", "scripts/gate_bags.sh", env={"GATE_DATA": f"{s.data}/gate", "WORKERS": str(s.workers)})

    def dagger(self, round_: int) -> Callable[[StageRun], None]:
        def stage(run: StageRun) -> None:
            driver = self.run_dir("msfsu") / f"round{round_ - 1}.pt"
            run.log(f"DAgger round {round_} data: {driver} drives, the expert labels")
            run.tool("msfsu-collect", "--output", self.s.data, "--split", "train", "--episodes", "1", "--max-steps",
                     "900", "--workers", str(self.s.workers), "--driver", str(driver), "--beta", str(0.5 ** round_),
                     "--round", str(round_))
        return stage

    def round_stage(self, variant: str, round_: int) -> Callable[[StageRun], None]:
        """Round 0 on the expert data, round N continuing the run on rounds 0..N; roundN.pt keeps each round's best,
        roundN.last.pt its last epoch (to branch from: the same epochs without DAgger)."""
        def stage(run: StageRun) -> None:
            self.train(run, variant, round_, self.epochs(run, round_), variant)
            out = self.run_dir(variant)
            publish(out / "last.pt", out / f"round{round_}.last.pt")
            publish(out / "best.pt", out / f"round{round_}.pt")
        return stage

    def branch(self, round_: int) -> Callable[[StageRun], None]:
        """From round N-1's last epoch, the same epochs on the data of rounds 0..N-1 only: the same budget without the
        round's on-policy data (its best.pt starts as round N-1's best)."""
        def stage(run: StageRun) -> None:
            fork, msfsu = self.run_dir(f"msfsu_branch{round_}"), self.run_dir("msfsu")
            if not (fork / "last.pt").exists():
                fork.mkdir(parents=True, exist_ok=True)
                publish(msfsu / f"round{round_ - 1}.pt", fork / "best.pt")
                publish(msfsu / f"round{round_ - 1}.last.pt", fork / "last.pt")
            self.train(run, "msfsu", round_ - 1, self.epochs(run, round_), fork.name)
            publish(fork / "best.pt", fork / f"round{round_}.pt")
        return stage

    def release(self, run: StageRun) -> None:
        s = self.s
        run.log("releases into models/ and the sample bag")
        for variant in s.variants:
            run.tool("msfsu-release-checkpoint", str(self.run_dir(variant) / f"round{s.rounds}.pt"),
                     f"models/{RELEASED[variant]}.pt")
        # A held-out town and weather the networks never saw, regular traffic: base seed 2030 draws a 185 m route that
        # turns LEFT, then RIGHT. The bag keeps steps 126-224 (99 frames, 9.9 s, 24.8 MB of the 25 MB allowed): the
        # left turn from its start, cars in view, the RIGHT command of the next junction.
        run.tool("msfsu-collect", "--output", f"{s.data}/sample", "--split", "test", "--towns", "town_h1", "--weathers",
                 "soft_rain_dusk", "--traffic", "regular", "--record-from", "126", "--max-steps",
                 str(s.sample_max_steps), "--seed", str(s.sample_seed), "--no-noise", "--workers", "1")
        sample = Path(s.data, "sample/test/town_h1_soft_rain_dusk_regular_000")
        size = sum(path.lstat().st_size for path in (sample, *sample.rglob("*")))
        if size > SAMPLE_BYTES:
            raise StageFailed(f"the sample bag {sample} is {size} bytes, over 25 MB: delete {s.data}/sample and re-run "
                              "with fewer frames (SAMPLE_MAX_STEPS below 225)")
        partial = Path("bags/sample.partial")
        shutil.rmtree(partial, ignore_errors=True)
        shutil.copytree(sample, partial)
        shutil.rmtree("bags/sample", ignore_errors=True)
        partial.rename("bags/sample")
        run.tool("msfsu-dataset-report", s.data, "--out", s.data_report)
        for path in (*(Path(f"models/{RELEASED[variant]}.pt") for variant in s.variants), Path("bags/sample")):
            files = [path] if path.is_file() else [file for file in path.rglob("*") if file.is_file()]
            run.log(f"{path}: {sum(file.stat().st_size for file in files) / 1e6:.1f} MB")

    def stages(self) -> list[Stage]:
        s = self.s
        stages = [Stage("data", "expert data: training, validation and the gate's held-out bags", self.collect_expert,
                        params=(TRAIN_EPISODES,), always=True)]
        dagger = {}
        for round_ in range(1, s.rounds + 1):
            driver = f"train-msfsu-round{round_ - 1}"
            dagger[round_] = Stage(f"dagger-round{round_}", f"DAgger round {round_}'s data, MSFSU of round "
                                   f"{round_ - 1} driving", self.dagger(round_),
                                   inputs=(str(self.run_dir("msfsu") / f"round{round_ - 1}.pt"),),
                                   after=(driver,) if "msfsu" in s.variants else (), always=True)
            stages.append(dagger[round_])

        def rounds_data(last_round: int) -> tuple[str, ...]:
            return ("data", *(dagger[r].name for r in range(1, last_round + 1)))

        for variant in s.variants:
            out = self.run_dir(variant)
            for round_ in range(s.rounds + 1):
                if s.branch and variant == "msfsu" and round_ > 0:
                    fork = self.run_dir(f"msfsu_branch{round_}")
                    stages.append(Stage(
                        f"branch-msfsu-round{round_}", f"MSFSU round {round_}'s budget without its on-policy data",
                        self.branch(round_), products=(str(fork / f"round{round_}.pt"),),
                        after=(f"train-msfsu-round{round_ - 1}",), needs=rounds_data(round_ - 1), params=TRAINING))
                stages.append(Stage(
                    f"train-{variant}-round{round_}", f"{variant} on rounds 0..{round_}",
                    self.round_stage(variant, round_),
                    products=(str(out / f"round{round_}.last.pt"), str(out / f"round{round_}.pt")),
                    after=(f"train-{variant}-round{round_ - 1}",) if round_ else (), needs=rounds_data(round_),
                    params=TRAINING))
        stages.append(Stage("release", "fp16 releases into models/, the sample bag, the data's report", self.release,
                            after=tuple(f"train-{variant}-round{s.rounds}" for variant in s.variants), always=True))
        return stages


def pipeline() -> Pipeline:
    settings = Settings.from_environment()
    stages = DefaultModel(settings).stages()
    default = [stage.name for stage in stages if not stage.name.startswith("dagger-")]  # collected for a stage
    return Pipeline(name="msfsu", title="Default model", command=COMMAND, stages=stages,
                    recording=Recording(Path(settings.runs)), state=Path(settings.runs, ".doit.json"), default=default,
                    done_by_record=False, pages=False)


def main(argv: Sequence[str] | None = None) -> int:
    return run_pipeline(pipeline, argv, COMMAND)


if __name__ == "__main__":
    sys.exit(main())
