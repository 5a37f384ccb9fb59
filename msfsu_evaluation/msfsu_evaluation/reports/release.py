"""Model v3's release rule (issue 58): models/ takes the v3 models only if v3 MSFSU beats the shipped MSFSU, paired
over the benchmark's routes.

    msfsu-model-v3-release [--baseline RUN:AGENT] [--candidate RUN:AGENT] --checkpoints DIR \\
        --out docs/results/model_v3/release.json [--dry-run]

Released when both hold: over all routes both drove, the candidate finishes more of them with an exact McNemar
p < 0.05; and in no suite and condition is it worse by more than its interval (the upper end of the paired difference's
95 % interval, candidate - baseline, below zero). The verdict, with every paired row, goes to --out; on release the
v3 checkpoints (DIR/msfsu.pt, msf.pt, su.pt) replace models/msfsu_default.pt, msf.pt and su.pt, with their
accuracy-gate records (calibration frames, the verdicts and int8 recipes in <checkpoint>.deploy/, keyed by the
checkpoint's content: docs/deployment.md); the old models' records go. --dry-run: the verdict only.

The same rule serves later rounds (issue 77's `msfsu-waiting`): `--release FILE=SHIPPED` (repeatable) names which of
--checkpoints' files replace which of models/ (default: the three above), and `--abilities RUN` adds the per-ability
scenario suite (msfsu-benchmark --suite abilities, both agents in RUN by the same names): then no ability, over both
conditions, may be worse by more than its interval either.
"""

from __future__ import annotations

import argparse
import json
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from msfsu_evaluation.closed_loop.cells import PairedRow
from msfsu_evaluation.closed_loop.statistics import paired_comparison
from msfsu_evaluation.reports.paired_runs import episodes, run_and_agent, suite_and_condition, task_of

PROG = "msfsu-model-v3-release"

P_RELEASE = 0.05
BASELINE = "docs/results/closed_loop_v3_graph2/records/networks:msfsu"  # the shipped MSFSU on today's graph (issue 57)
CANDIDATE = "docs/results/closed_loop_v3_model_v3/records/judge-msfsu:msfsu_v3"  # msfsu-model-v3's judge-msfsu stage
RELEASED_AS = {"msfsu.pt": "msfsu_default.pt", "msf.pt": "msf.pt", "su.pt": "su.pt"}  # checkpoints/v3 -> models/


@dataclass(frozen=True)
class ReleaseVerdict:
    """release.json: the two sides (RUN:AGENT), whether the rule released, why, and every paired row."""

    baseline: str
    candidate: str
    released: bool
    reasons: list[str]
    paired: list[PairedRow]
    abilities: list[PairedRow] = field(default_factory=list)  # per ability, both conditions (with --abilities)

    def to_json(self) -> str:
        record = {"baseline": self.baseline, "candidate": self.candidate, "released": self.released,
                  "reasons": self.reasons, "paired": [row.to_json() for row in self.paired]}
        if self.abilities:
            record["abilities"] = [row.to_json() for row in self.abilities]
        return json.dumps(record, indent=1) + "\n"

    @classmethod
    def from_json(cls, text: str) -> ReleaseVerdict:
        record = json.loads(text)
        return cls(baseline=record["baseline"], candidate=record["candidate"], released=record["released"],
                   reasons=list(record["reasons"]), paired=[PairedRow.from_json(row) for row in record["paired"]],
                   abilities=[PairedRow.from_json(row) for row in record.get("abilities", [])])

    def line(self) -> str:
        """The README's words for it: released or not, and why."""
        return f"release: {'released' if self.released else 'not released'}, " + "; ".join(self.reasons) + "."


def successes(run_agent: tuple[Path, str]) -> dict[str, bool]:
    """Whether each route of a RUN:AGENT's episodes (by route key) was a success."""
    return {key: episode.success for key, episode in episodes(*run_agent).items()}


def _paired_row(baseline: Mapping[str, bool], candidate: Mapping[str, bool], keys: Sequence[str], suite: str,
                condition: str) -> PairedRow | None:
    """Candidate (a) against baseline (b) on `keys`, labelled suite and condition (None: no route to pair)."""
    comparison = paired_comparison({k: candidate[k] for k in keys}, {k: baseline[k] for k in keys})
    return None if comparison is None else PairedRow.of("candidate", "baseline", suite, condition, comparison)


def paired_rows(baseline: Mapping[str, bool], candidate: Mapping[str, bool]) -> list[PairedRow]:
    """Candidate (a) against baseline (b): all routes, then each suite x condition (route key suite/task/condition/n)."""
    common = candidate.keys() & baseline.keys()
    cells = sorted({suite_and_condition(key) for key in common})
    rows = []
    for suite, condition in [("all", "all"), *cells]:
        keys = [k for k in common if suite == "all" or suite_and_condition(k) == (suite, condition)]
        rows.append(_paired_row(baseline, candidate, keys, suite, condition))
    return [row for row in rows if row is not None]


def ability_rows(baseline: Mapping[str, bool], candidate: Mapping[str, bool]) -> list[PairedRow]:
    """Candidate (a) against baseline (b) per ability of the scenario suite (route key abilities/ability/condition/n),
    both conditions pooled: suite "abilities/<ability>", condition "all"."""
    common = candidate.keys() & baseline.keys()
    rows = []
    for ability in sorted({task_of(key) for key in common}):
        keys = [k for k in common if task_of(k) == ability]
        rows.append(_paired_row(baseline, candidate, keys, f"abilities/{ability}", "all"))
    return [row for row in rows if row is not None]


def verdict(rows: Sequence[PairedRow], abilities: Sequence[PairedRow] = ()) -> tuple[bool, list[str]]:
    """Whether the rule releases, and why (one reason per line)."""
    pooled, cells = rows[0], rows[1:]
    reasons = [f"all routes: {pooled.a_successes} against {pooled.b_successes} of {pooled.routes}, difference "
               f"{pooled.difference_text()}, McNemar p {pooled.mcnemar_p:.3f}"]
    beats = pooled.difference > 0 and pooled.mcnemar_p < P_RELEASE
    if not beats:
        reasons.append(f"not released: the candidate does not beat the baseline at p < {P_RELEASE}")
    worse = [row for row in (*cells, *abilities) if row.difference_ci95.high < 0]
    for row in worse:
        reasons.append(f"not released: worse in {row.suite}/{row.condition} by more than its interval "
                       f"({row.difference_text()})")
    return beats and not worse, reasons


def release(checkpoint: Path, shipped: Path) -> None:
    """`checkpoint` becomes `shipped`, with its gate's records (and none of the old model's)."""
    shipped_deploy = shipped.with_name(shipped.name + ".deploy")
    shutil.rmtree(shipped_deploy, ignore_errors=True)
    shipped.with_name(shipped.name + ".calibration.npz").unlink(missing_ok=True)
    shutil.copyfile(checkpoint, shipped)
    calibration = checkpoint.with_name(checkpoint.name + ".calibration.npz")
    if calibration.is_file():
        shutil.copyfile(calibration, shipped.with_name(shipped.name + ".calibration.npz"))
    records = sorted(checkpoint.with_name(checkpoint.name + ".deploy").glob("*.json"))
    if records:
        shipped_deploy.mkdir()
        for record in records:
            shutil.copyfile(record, shipped_deploy / record.name)


def file_and_shipped(text: str) -> tuple[str, str]:
    """FILE=SHIPPED: a checkpoint file name and the models/ file name it replaces."""
    name, separator, shipped = text.partition("=")
    if not (separator and name and shipped) or "/" in name + shipped:
        raise argparse.ArgumentTypeError(f"{text!r}: give FILE=SHIPPED, two file names "
                                         "(e.g. msfsu.pt=msfsu_default.pt)")
    return name, shipped


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", type=run_and_agent, default=run_and_agent(BASELINE),
                        help=f"RUN:AGENT of the shipped model (default {BASELINE})")
    parser.add_argument("--candidate", type=run_and_agent, default=run_and_agent(CANDIDATE),
                        help=f"RUN:AGENT of v3 MSFSU (default {CANDIDATE})")
    parser.add_argument("--checkpoints", type=Path, required=True,
                        help="the candidate checkpoints (v3: msfsu.pt, msf.pt, su.pt)")
    parser.add_argument("--release", type=file_and_shipped, action="append", metavar="FILE=SHIPPED",
                        help="--checkpoints' FILE replaces models/SHIPPED on release (repeatable; default: "
                             + ", ".join(f"{a}={b}" for a, b in RELEASED_AS.items()) + ")")
    parser.add_argument("--abilities", type=Path, metavar="RUN",
                        help="a scenario-suite run holding both agents: no ability may be worse either")
    parser.add_argument("--out", type=Path, required=True, help="the verdict (JSON)")
    parser.add_argument("--dry-run", action="store_true", help="write the verdict, copy nothing")
    args = parser.parse_args(argv)
    released_as = dict(args.release) if args.release else RELEASED_AS
    baseline, candidate = successes(args.baseline), successes(args.candidate)
    rows = paired_rows(baseline, candidate)
    if not rows:
        parser.exit(1, f"{PROG}: {args.candidate} and {args.baseline} share no route\n")
    abilities: list[PairedRow] = []
    if args.abilities is not None:
        abilities = ability_rows(successes((args.abilities, args.baseline[1])),
                                 successes((args.abilities, args.candidate[1])))
        if not abilities:
            parser.exit(1, f"{PROG}: {args.abilities} holds no scenario both {args.baseline[1]} and "
                           f"{args.candidate[1]} drove\n")
    released, reasons = verdict(rows, abilities)
    missing = [name for name in released_as if not (args.checkpoints / name).is_file()]
    if released and missing:
        parser.exit(1, f"{PROG}: the rule releases, but {args.checkpoints} lacks {', '.join(missing)}\n")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(ReleaseVerdict(":".join(map(str, args.baseline)), ":".join(map(str, args.candidate)),
                                       released, reasons, rows, abilities).to_json())
    print("\n".join(reasons))
    if released and not args.dry_run:
        for name, shipped_as in released_as.items():
            release(args.checkpoints / name, Path("models") / shipped_as)
        print("released: " + ", ".join(f"models/{name}" for name in released_as.values()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
