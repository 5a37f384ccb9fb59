"""What each generated block of the hand-written pages says, by name: each reads its committed record into its type
(msfsu_evaluation.records, closed_loop.cells, reports.release) and calls that type's renderer.

Paths are the committed records' places in the repository; a generator that takes a path renders another record
(a test's). Links are written relative to the repository's root (reports.blocks rewrites them for the page).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, TypeVar

from msfsu_evaluation.closed_loop.runs import REPOSITORY as ROOT
from msfsu_evaluation.records.closed_loop import ClosedLoopReport, pooled_parts
from msfsu_evaluation.records.default_model import DefaultModelRecipe, TrainingLog
from msfsu_evaluation.records.gate import gate_block, read_gate_records
from msfsu_evaluation.records.gpu import GpuRecord
from msfsu_evaluation.records.int8_profile import Int8Profile
from msfsu_evaluation.deploy.recipe_record import int8_recipes_block, read_sensitivity_records
from msfsu_evaluation.records.lockstep import LockstepResults
from msfsu_evaluation.records.network import NetworkRecord
from msfsu_evaluation.records.perception import PerceptionMachines, read_perception
from msfsu_evaluation.records.simulator import SimulatorResults
from msfsu_evaluation.records.soak import (AebSoaks, headline_latency, read_design_soaks, read_soaks, soak_block,
                                           soak_design_block, soak_stages_block)
from msfsu_evaluation.records.stages import read_recipe, recipe_block
from msfsu_evaluation.records.suite_time import SuiteTime
from msfsu_evaluation.records.training import TrainingResults
from msfsu_evaluation.records.workers import WorkersResults
from msfsu_evaluation.reports import release
from msfsu_evaluation.reports.ability_blocks import abilities_line, abilities_table
from msfsu_evaluation.reports.aeb_goals import aeb_crossing_goals_block, aeb_goals_block, aeb_lines
from msfsu_evaluation.reports.waiting_goals import waiting_goals, waiting_goals_block

BENCHMARKS = ROOT / "benchmarks"
SOAK_DIR = BENCHMARKS / "soak"
SOAK_DESIGN_DIR = SOAK_DIR / "design"
RESULTS = ROOT / "docs" / "results"
WAITING = RESULTS / "waiting"  # msfsu-waiting's record (issue 77)

Record = TypeVar("Record")


def _record_file(from_json: Callable[[str], Record]) -> Callable[[Path], Record]:
    """The reader of a record file: its type's from_json of the file's text."""
    return lambda path: from_json(path.read_text())


@dataclass(frozen=True)
class RecordBlock(Generic[Record]):
    """A block its record type renders: `render(read(path))`; called with another path (a test's), that record's."""

    read: Callable[[Path], Record]
    path: Path  # the committed record: a file, or the directory of a kind's files
    render: Callable[[Record], str]

    def __call__(self, path: Path | None = None) -> str:
        return self.render(self.read(self.path if path is None else path))

    def record(self) -> Record:
        """The committed record."""
        return self.read(self.path)


# the blocks of the benchmark records: name -> (record, its renderer)
RECORD_BLOCKS: dict[str, RecordBlock] = {
    "simulator-speed": RecordBlock(_record_file(SimulatorResults.from_json), BENCHMARKS / "simulator_results.json",
                                   SimulatorResults.block),
    "lockstep-speed": RecordBlock(_record_file(LockstepResults.from_json), BENCHMARKS / "lockstep_results.json",
                                  LockstepResults.block),
    "suite-time": RecordBlock(_record_file(SuiteTime.from_json), BENCHMARKS / "suite_time_results.json",
                              SuiteTime.block),
    "training-speed": RecordBlock(_record_file(TrainingResults.from_json), BENCHMARKS / "training_results.json",
                                  TrainingResults.block),
    "network-size": RecordBlock(_record_file(NetworkRecord.from_json), BENCHMARKS / "network_results.json",
                                NetworkRecord.block),
    "soak": RecordBlock(read_soaks, SOAK_DIR, soak_block),
    "soak-stages": RecordBlock(read_soaks, SOAK_DIR, soak_stages_block),
    "soak-design": RecordBlock(read_design_soaks, SOAK_DESIGN_DIR, soak_design_block),
    "soak-aeb": RecordBlock(AebSoaks.read, SOAK_DIR / "aeb", AebSoaks.block),
    "perception-speed": RecordBlock(read_perception, BENCHMARKS, PerceptionMachines.block),
    "perception-gate": RecordBlock(read_gate_records, ROOT, gate_block),
    "int8-recipes": RecordBlock(read_sensitivity_records, BENCHMARKS / "int8_recipes", int8_recipes_block),
    "int8-profile": RecordBlock(_record_file(Int8Profile.from_json), BENCHMARKS / "int8_profile_results.json",
                                Int8Profile.block),
    "gpu-speed": RecordBlock(_record_file(GpuRecord.from_json), BENCHMARKS / "gpu_results.json", GpuRecord.block),
    "gpu-gate": RecordBlock(_record_file(GpuRecord.from_json), BENCHMARKS / "gpu_results.json", GpuRecord.gate_block),
    "model-v3-stages": RecordBlock(read_recipe, RESULTS / "model_v3", recipe_block),
    "waiting-stages": RecordBlock(read_recipe, WAITING, recipe_block),
    "benchmark-workers": RecordBlock(_record_file(WorkersResults.from_json), BENCHMARKS / "workers_results.json",
                                     WorkersResults.block),
}
soak, soak_stages, soak_design = (RECORD_BLOCKS[name] for name in ("soak", "soak-stages", "soak-design"))

DATA_RECORD = RESULTS / "data" / "data.json"
TRAINING_RECORDS = RESULTS / "training"


def default_model() -> str:
    """The recipe's data (docs/results/data/data.json) and training runs (docs/results/training/*/metrics.csv)."""
    return DefaultModelRecipe.read(DATA_RECORD, TRAINING_RECORDS).block()


def paper_training() -> str:
    """docs/results/training/paper_short/: the rate of the int8 gate's short run of the paper preset."""
    log = TrainingLog.read(TRAINING_RECORDS / "paper_short")
    if log is None:
        return "The paper preset has no training record yet: `bash scripts/int8_gate.sh` writes its short run's."
    return log.paper_line()


CLOSED_LOOP_RESULTS = RESULTS / "closed_loop" / "results.json"
CLOSED_LOOP_V3_RESULTS = RESULTS / "closed_loop_v3" / "results.json"
GRAPH2 = RESULTS / "closed_loop_v3_graph2"
CURRENT_RESULTS = GRAPH2 / "results.json"  # the current simulator revision (4) and node graph revision (2)
CURRENT_RUN = GRAPH2 / "records" / "networks" / "run.json"
CURRENT_LINK = " ([results](docs/results/README.md#closed-loop-routes-v3-simulator-revision-4-node-graph-revision-2))."
FREE_RUNNING_RESULTS = RESULTS / "free_running" / "results.json"
MODEL_V3 = RESULTS / "model_v3"
MODEL_V3_RESULTS = RESULTS / "closed_loop_v3_model_v3" / "results.json"


def _report(path: Path) -> ClosedLoopReport:
    return ClosedLoopReport.read(path, ROOT)


def current_progress() -> str:
    """"" when the current run has every planned agent on every route; else what it has so far (it resumes)."""
    progress = _report(CURRENT_RESULTS).progress(json.loads(CURRENT_RUN.read_text())["agents"])
    return progress + "; `NETWORKS=1 WORKERS=2 bash scripts/results.sh` resumes the run." if progress else ""


def _with_progress(body: str) -> str:
    progress = current_progress()
    return ((progress + "\n\n") if progress else "") + body


def closed_loop(path: Path | None = None) -> str:
    """docs/results/closed_loop/results.json: success per task, condition and agent with Wilson 95 % intervals."""
    from msfsu_evaluation.closed_loop.suites import TASKS  # the suites' task order

    path = CLOSED_LOOP_RESULTS if path is None else path
    if not path.exists():
        return "No closed-loop records yet: `bash scripts/results.sh` writes `docs/results/closed_loop/`."
    return _report(path).success_table(list(TASKS))


def closed_loop_v3() -> str:
    """docs/results/closed_loop_v3/results.json: the routes v3 table (the agents run on v3 so far)."""
    return closed_loop(CLOSED_LOOP_V3_RESULTS)


def closed_loop_current() -> str:
    """docs/results/closed_loop_v3_graph2/results.json: the routes v3 table on the current revisions."""
    return _with_progress(closed_loop(CURRENT_RESULTS))


def against_paper(agents: Sequence[str] | None = None) -> str:
    """docs/results/closed_loop_v3_graph2/results.json (the current simulator and graph revisions): every network
    (or `agents`) against the paper's MSFSU and the v3 goals, as its results.md says it."""
    if not CURRENT_RESULTS.exists():
        return "No records of the current revisions yet: `NETWORKS=1 bash scripts/results.sh` writes them."
    from msfsu_evaluation.closed_loop.markdown import against_paper_markdown
    from msfsu_evaluation.closed_loop.runner import EXPERT

    found = _report(CURRENT_RESULTS).against_paper
    chosen = {a: x for a, x in found.items() if a != EXPERT and (agents is None or a in agents)}
    return _with_progress("\n".join(against_paper_markdown(chosen, title=False)).rstrip())


def closed_loop_precision() -> str:
    """docs/results/closed_loop_v3_graph2/results.json: MSFSU as deployed against its very checkpoint on another
    precision, paired per suite and condition and over all routes (the deployed precision's closed-loop check)."""
    report = _report(CURRENT_RESULTS)
    if not report.precision_rows("msfsu"):
        return "No agent has driven MSFSU's checkpoint on another precision on the current revisions yet."
    return report.precision_table("msfsu", "benchmark v3, simulator revision 4, node graph revision 2; "
                                           "`docs/results/closed_loop_v3_graph2`")


def ablation_line() -> str:
    """The pooled paired rows of MSFSU against each other network, held out and in training conditions; then MSFSU
    as deployed against the same checkpoint on another precision (the deployed precision's closed-loop check)."""
    report = _report(CURRENT_RESULTS)
    rows = report.pooled("msfsu")
    if not rows:
        return "- **Ablation**: no network pair has driven the same routes yet."
    same = report.same_checkpoint_as("msfsu")
    others = [row for row in rows if row.b not in same]
    lines = [("- **Ablation**, MSFSU minus the other network in success points on the same routes (Newcombe 95 % "
              "interval, exact McNemar p): " + pooled_parts(others) + CURRENT_LINK)] if others else []
    precision = [row for row in rows if row.b in same]
    if precision:
        lines.append(f"- **Deployed precision**, MSFSU as the node deploys it ({report.runtime('msfsu', 'auto')}) "
                     "minus the same checkpoint on " + ", ".join(sorted(f"{b} ({report.runtime(b, '?')})"
                                                                        for b in {row.b for row in precision}))
                     + " on the same routes: " + pooled_parts(precision) + CURRENT_LINK)
    return "\n".join(lines)


def free_running(path: Path | None = None) -> str:
    """docs/results/free_running/results.json: the default model free-running beside its lockstep episodes."""
    path = FREE_RUNNING_RESULTS if path is None else path
    if not path.exists():
        return "No free-running records yet: `bash scripts/free_running.sh` writes `docs/results/free_running/`."
    from msfsu_evaluation.closed_loop.markdown import free_running_markdown

    report = _report(path)
    return (report.free_running_progress(sorted(report.free_running)) + "\n\n" + closed_loop(path) + "\n\n"
            + "\n".join(free_running_markdown(report.free_running)[2:]).strip())


def recipe_line(record: Path, title: str, budget_of: str, page: str) -> tuple[str, str | None]:
    """A recipe pipeline's README line so far (how many stages finished, the hours spent, its page), and the release
    rule's verdict once its release stage wrote one (None before)."""
    recipe = read_recipe(record)
    line = (f"- **{title}** ({budget_of} on a {recipe.plan.budget_h:g} h budget): {len(recipe.done)} of "
            f"{len(recipe.plan.stages)} stages finished, {recipe.spent_h:.1f} h spent ({page})")
    released = record / "release.json"
    return line, (release.ReleaseVerdict.from_json(released.read_text()).line() if released.exists() else None)


def model_v3_line() -> str:
    """Model v3 (issue 58): how far its stages are, then, once judged, v3 MSFSU against the shipped MSFSU paired over
    the routes both drove, and what the release rule says (reports.release, its pair and its rule)."""
    line, verdict = recipe_line(MODEL_V3, "Model v3", "issue 58: the shipped models trained further",
                                "[plan and hours](docs/training.md#model-v3-issue-58)")
    if verdict is not None:
        return line + "; " + verdict
    (baseline_run, baseline_agent), (run, agent) = (release.run_and_agent(side) for side in (release.BASELINE,
                                                                                            release.CANDIDATE))
    candidate = release.successes((ROOT / run, agent)) if (ROOT / run).is_dir() else {}
    if not candidate:
        return line + "; v3 MSFSU not judged yet."
    rows = release.paired_rows(release.successes((ROOT / baseline_run, baseline_agent)), candidate)
    would, _ = release.verdict(rows)
    return (line + f"; v3 MSFSU minus the shipped one: {rows[0].difference_text()} (McNemar p {rows[0].mcnemar_p:.3f}, "
            f"{rows[0].routes} routes); the release rule {'would release' if would else 'would not release'} it "
            "([v3 against v2](docs/results/closed_loop_v3_model_v3/v3_change.md)).")


def waiting_line() -> str:
    """A network that waits (issue 77): how far its stages are, then the release rule's verdict once it ran (the
    goals and the before/after tables: docs/training.md's waiting-goals block)."""
    line, verdict = recipe_line(WAITING, "A network that waits",
                                "issue 77: the shipped MSFSU trained to stop where the expert stops,",
                                "[plan, hours and goals](docs/training.md#a-network-that-waits-issue-77-the-plan)")
    goals = waiting_goals()
    conflicts = goals.conflicts_text() if goals is not None else None
    return line + ("; " + verdict if verdict is not None else ".") + (f" The candidate: {conflicts}." if conflicts else "")


def model_v3_ablation_line() -> str:
    """Model v3's ablation (issue 58): v3 MSFSU against the v3 MSF and SU (the same data, steps and schedule) on the
    routes both drove, pooled per condition; empty until a v3 network beside v3 MSFSU has been judged."""
    rows = _report(MODEL_V3_RESULTS).pooled("msfsu_v3") if MODEL_V3_RESULTS.exists() else []
    rows = [row for row in rows if row.b != "expert"]
    if not rows:
        return ""
    return ("- **Ablation, model v3**, v3 MSFSU minus the other v3 network in success points on the same routes "
            "(Newcombe 95 % interval, exact McNemar p): " + pooled_parts(rows)
            + " ([v3 results](docs/results/closed_loop_v3_model_v3/results.md"
            "#ablation-paired-comparison-on-the-same-routes)).")


def headline() -> str:
    """The README's results: the shipped MSFSU against the paper (the against-paper block's table), then one line
    each for the ablation, the deployed precision, model v3 (and its ablation once judged), perception speed,
    real-time latency and simulator speed, each with the page that has the whole table."""
    lines = [ablation_line(), model_v3_line(), model_v3_ablation_line(), waiting_line(), abilities_line(), *aeb_lines(),
             RECORD_BLOCKS["perception-speed"].record().main.headline(),
             headline_latency(RECORD_BLOCKS["soak"].record()), RECORD_BLOCKS["simulator-speed"].record().headline()]
    return against_paper(("msfsu",)) + "\n\n" + "\n".join(line for line in lines if line)


GENERATORS: dict[str, Callable[[], str]] = {
    "default-model": default_model, "paper-training": paper_training, "closed-loop": closed_loop,
    "closed-loop-v3": closed_loop_v3, "closed-loop-current": closed_loop_current, "against-paper": against_paper,
    "closed-loop-precision": closed_loop_precision, "free-running": free_running, "headline": headline,
    "abilities": abilities_table, "aeb-goals": aeb_goals_block, "aeb-crossing-goals": aeb_crossing_goals_block,
    "waiting-goals": waiting_goals_block, **RECORD_BLOCKS}
