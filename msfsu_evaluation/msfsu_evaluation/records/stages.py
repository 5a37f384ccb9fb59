"""A staged recipe's hours (msfsu-model-v3, msfsu_evaluation.pipelines): its plan, written before the first stage ran
(docs/results/model_v3/plan.json: the budget, the longest stage allowed, each stage's planned hours), and its record,
one JSON line per finished stage (docs/results/model_v3/stages.jsonl, appended by the recipe when a stage ends),
and its clocks (docs/results/model_v3/clock/<name>/<an invocation's start, epoch s>: the last second it was seen
alive), committed with each stage's progress.

Rules:
- A stage's hours are its wall time summed over every invocation, on every machine (a session's end stops a stage,
  the next resumes it), as the recipe's stage clock measured them.
- Time that is no stage's counts too (OVERHEADS): bags collected again on a new machine, and training lost with one.
- The budget holds the measured hours of the finished stages and the overheads plus the planned hours of the stages
  still to run and of the overheads they are expected to bring: a stage that needs the bags plans the re-collection
  a new machine would make before it (its "re_collect_h"), expected until the stage has finished.
- A plan may be revised once stages have run (plan.json "revised": its date, why, the stages and their hours from
  then on); the first plan stays in the file and its total in the table's notes.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple, Self

from msfsu_evaluation.records._json import JsonRow


@dataclass(kw_only=True)
class StageRecord(JsonRow):
    """One finished stage: a line of stages.jsonl."""

    stage: str
    started_utc: int  # epoch s: the start of its first invocation
    ended_utc: int  # epoch s: when its last invocation ended
    invocations: int
    hours: float
    machine: str
    code: str  # the commit the stage's last invocation ran on

    def to_line(self) -> str:
        return json.dumps(self.to_dict())


def read_stages(path: Path) -> list[StageRecord]:
    """The finished stages in the order they finished; none when the file is absent (no stage has finished)."""
    if not path.is_file():
        return []
    return [StageRecord.from_dict(json.loads(line)) for line in path.read_text().splitlines() if line.strip()]


@dataclass(kw_only=True)
class PlannedStage(JsonRow):
    OPTIONAL = ("re_collect_h",)

    stage: str
    planned_h: float
    re_collect_h: float | None = None  # the bags collected again before it, on a new machine (the stage needs them)


@dataclass(kw_only=True)
class Revision:
    """When and why the plan changed, and what the first plan had planned in all."""

    date: str
    why: str
    first_planned_h: float


@dataclass(kw_only=True)
class StagePlan:
    """plan.json: the budget and the stages in the order the recipe runs them (as last revised)."""

    budget_h: float
    longest_stage_h: float
    stages: list[PlannedStage]
    revision: Revision | None = None

    @classmethod
    def from_json(cls, text: str) -> Self:
        fields = json.loads(text)
        first = [PlannedStage.from_dict(stage) for stage in fields["stages"]]
        plan = cls(budget_h=fields["budget_h"], longest_stage_h=fields["longest_stage_h"], stages=first)
        revised = fields.get("revised")
        if revised is None:
            return plan
        return dataclasses.replace(
            plan, stages=[PlannedStage.from_dict(stage) for stage in revised["stages"]],
            revision=Revision(date=revised["date"], why=revised["why"],
                              first_planned_h=sum(stage.planned_h for stage in first)))

    def names(self) -> list[str]:
        return [stage.stage for stage in self.stages]

    @property
    def planned_h(self) -> float:
        return sum(stage.planned_h for stage in self.stages)

    def expected_overheads_h(self, done: Sequence[StageRecord]) -> dict[str, float]:
        """OVERHEADS' clocks -> the hours the stages not finished are expected to bring (none once they have)."""
        finished = {record.stage for record in done}
        re_collect = sum(stage.re_collect_h or 0.0 for stage in self.stages if stage.stage not in finished)
        return {"re-collect": re_collect} if re_collect > 0 else {}

    def projected_h(self, done: Sequence[StageRecord], overheads: Mapping[str, float] | None = None) -> float:
        """The measured hours of the finished stages and the overheads plus the planned hours of the other stages
        and of the overheads they are expected to bring."""
        measured = {record.stage: record.hours for record in done}
        return (sum(measured.get(stage.stage, stage.planned_h) for stage in self.stages)
                + sum((overheads or {}).values()) + sum(self.expected_overheads_h(done).values()))

    def block(self, done: Sequence[StageRecord], overheads: Mapping[str, float] | None = None) -> str:
        """The docs' table: each stage's planned and measured hours, then the totals against the budget."""
        unknown = sorted({record.stage for record in done} - set(self.names()))
        if unknown:
            raise ValueError(f"stages.jsonl has stages the plan lacks: {', '.join(unknown)}")
        measured = {record.stage: record for record in done}
        lines = ["| stage | planned h | measured h | invocations | finished (UTC) | code |",
                 "| --- | ---: | ---: | ---: | --- | --- |"]
        for stage in self.stages:
            record = measured.get(stage.stage)
            if record is None:
                lines.append(f"| `{stage.stage}` | {stage.planned_h:.1f} | not finished | | | |")
                continue
            ended = datetime.fromtimestamp(record.ended_utc, timezone.utc).strftime("%Y-%m-%d %H:%M")
            over = f" (over the {self.longest_stage_h:g} h stage limit)" if record.hours > self.longest_stage_h else ""
            lines.append(f"| `{stage.stage}` | {stage.planned_h:.1f} | {record.hours:.2f}{over} | "
                         f"{record.invocations} | {ended} | {record.code} |")
        overheads = {name: hours for name, hours in (overheads or {}).items() if hours > 0}
        for name, hours in overheads.items():
            lines.append(f"| {OVERHEADS[name]} | | {hours:.2f} | | | |")
        spent = sum(record.hours for record in done) + sum(overheads.values())
        projected = self.projected_h(done, overheads)
        lines.append(f"| **in all** | **{self.planned_h:.1f}** | **{spent:.2f}** ({len(done)} of {len(self.stages)} "
                     "stages) | | | |")
        machines = sorted({record.machine for record in done})
        expected = "".join(f", {hours:g} h more of {OVERHEADS[name]}" for name, hours
                           in self.expected_overheads_h(done).items())
        lines += ["", f"Budget: {self.budget_h:g} h. Measured so far plus planned for the rest{expected}: "
                  f"{projected:.1f} h ({'within' if projected <= self.budget_h else 'over'} the budget). "
                  f"Machines: {'; '.join(machines) or 'none yet'}."]
        if self.revision is not None:
            lines += ["", f"Plan revised {self.revision.date} (the first plan: {self.revision.first_planned_h:.1f} h "
                      f"of stages): {self.revision.why}"]
        return "\n".join(lines)


PLAN_FILE, STAGES_FILE, CLOCK_DIR = "plan.json", "stages.jsonl", "clock"
# the clocks of time spent outside any stage, and their rows in the table
OVERHEADS = {"re-collect": "bags collected again on a new machine",
             "lost": "training lost with a machine (before the per-epoch snapshots)",
             "refused": "work whose submission was refused for its size (its commits never landed)"}


def clock_hours(directory: Path) -> float:
    """A clock's hours: each invocation's last second seen alive minus its start, summed; 0 when it never ran."""
    if not directory.is_dir():
        return 0.0
    return sum(int(path.read_text()) - int(path.name) for path in directory.iterdir() if path.name.isdigit()) / 3600


class Recipe(NamedTuple):
    plan: StagePlan
    done: list[StageRecord]
    overheads: dict[str, float]  # OVERHEADS' clocks -> hours

    @property
    def spent_h(self) -> float:
        return sum(record.hours for record in self.done) + sum(self.overheads.values())


def read_recipe(directory: Path) -> Recipe:
    """A recipe's record directory (docs/results/model_v3): its plan, its finished stages and its overheads."""
    return Recipe(StagePlan.from_json((directory / PLAN_FILE).read_text()), read_stages(directory / STAGES_FILE),
                  {name: clock_hours(directory / CLOCK_DIR / name) for name in OVERHEADS})


def recipe_block(recipe: Recipe) -> str:
    return recipe.plan.block(recipe.done, recipe.overheads)
