"""Write the measured figures of the README and of docs/ from the committed result records (never typed by hand).

    python scripts/readme_results.py           # rewrite the marked blocks of every page
    python scripts/readme_results.py --check   # exit 1 if a page differs from the records (a test runs this)
    python scripts/readme_results.py --list    # the pages that hold a block, one a line (what to commit with them)

A block is `<!-- results:NAME -->` ... `<!-- /results:NAME -->`, on any of the hand-written pages (`pages()`:
README.md, docs/*.md, docs/results/README.md), wherever its topic is; NAME picks the generator below, which reads
the JSON a benchmark wrote next to its markdown (`benchmarks/*_results.json`). The blocks of a typed record
(`RECORD_BLOCKS`: name -> record, renderer) are rendered by its type in msfsu_evaluation.records, as its benchmark's
page is; the other generators read their JSON here. Each generator's block stands on exactly one page. Generators
write links relative to the repository's root; a block's links are rewritten relative to the page it stands on.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

import model_v3_release  # scripts/ (it puts scripts/ on the path for revision_change)
from revision_change import run_and_agent

from msfsu_evaluation.records.gate import gate_block, read_gate_records
from msfsu_evaluation.records.gpu import GpuRecord
from msfsu_evaluation.records.int8_profile import Int8Profile
from msfsu_evaluation.records.int8_recipe import int8_recipes_block, read_sensitivity_records
from msfsu_evaluation.records.lockstep import LockstepResults
from msfsu_evaluation.records.network import NetworkRecord
from msfsu_evaluation.records.perception import PerceptionMachines, read_perception
from msfsu_evaluation.records.simulator import SimulatorResults
from msfsu_evaluation.records.soak import (headline_latency, read_design_soaks, read_soaks, soak_block,
                                           soak_design_block, soak_stages_block)
from msfsu_evaluation.records.stages import read_recipe, recipe_block
from msfsu_evaluation.records.suite_time import SuiteTime
from msfsu_evaluation.records.training import TrainingResults

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
BENCHMARKS = ROOT / "benchmarks"
SOAK_DIR = BENCHMARKS / "soak"
SOAK_DESIGN_DIR = SOAK_DIR / "design"


def pages(root: Path = ROOT) -> list[Path]:
    """The hand-written pages: README.md, docs/*.md and docs/results/README.md (the rest of docs/results/ is written
    by its own commands)."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md")), root / "docs" / "results" / "README.md"]


def _load(name: str) -> Any:
    return json.loads((ROOT / "benchmarks" / name).read_text())


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


# the blocks of the typed records: name -> (record, its renderer)
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
    "perception-speed": RecordBlock(read_perception, BENCHMARKS, PerceptionMachines.block),
    "perception-gate": RecordBlock(read_gate_records, ROOT, gate_block),
    "int8-recipes": RecordBlock(read_sensitivity_records, BENCHMARKS / "int8_recipes", int8_recipes_block),
    "int8-profile": RecordBlock(_record_file(Int8Profile.from_json), BENCHMARKS / "int8_profile_results.json",
                                Int8Profile.block),
    "gpu-speed": RecordBlock(_record_file(GpuRecord.from_json), BENCHMARKS / "gpu_results.json", GpuRecord.block),
    "gpu-gate": RecordBlock(_record_file(GpuRecord.from_json), BENCHMARKS / "gpu_results.json", GpuRecord.gate_block),
    "model-v3-stages": RecordBlock(read_recipe, ROOT / "docs" / "results" / "model_v3", recipe_block),
}
soak, soak_stages, soak_design = (RECORD_BLOCKS[name] for name in ("soak", "soak-stages", "soak-design"))


def benchmark_workers() -> str:
    results = _load("workers_results.json")
    one = next((r for r in results if r["workers"] == 1), results[0])
    rows = ["| workers | episodes/h | speed-up | mean wall s per episode (expert / network) | simulator process "
            "peak RSS GB | load (1 min) after |", "| --- | --- | --- | --- | --- | --- |"]
    for r in results:
        agents = r["agents"]
        rows.append(f"| {r['workers']} | {r['episodes_per_hour']} | {r['episodes_per_hour'] / one['episodes_per_hour']:.2f}x | "
                    f"{agents['expert']['mean_wall_s']} / {agents['network']['mean_wall_s']} | {r['worker_peak_rss_gb']} | "
                    f"{r['load_1min_after']} |")
    return "\n".join(rows)


DATA_RECORD = ROOT / "docs" / "results" / "data" / "data.json"
TRAINING_RECORDS = ROOT / "docs" / "results" / "training"
VARIANT_NAMES = {"msfsu": "MSFSU (`models/msfsu_default.pt`)", "msf": "MSF (`models/msf.pt`)", "su": "SU (`models/su.pt`)"}


def _training_time_and_rate(epochs: list[dict[str, str]]) -> tuple[float, float]:
    """Seconds of training steps over a run's metrics.csv rows and its mean samples/s, weighted by epoch time."""
    seconds = sum(float(row["epoch_time_s"]) for row in epochs)
    return seconds, sum(float(row["samples_per_s"]) * float(row["epoch_time_s"]) for row in epochs) / seconds


def default_model() -> str:
    """The recipe's data (docs/results/data/data.json) and training runs (docs/results/training/*/metrics.csv)."""
    import csv

    if not DATA_RECORD.exists():
        return "Not collected yet: `make default-model` writes `docs/results/data/data.json`."
    record = json.loads(DATA_RECORD.read_text())
    rows = ["| step | what | result |", "| --- | --- | --- |"]
    groups = sorted({(b["split"], b["round"]) for b in record["bags"]})
    for split, round_index in groups:
        bags = [b for b in record["bags"] if (b["split"], b["round"]) == (split, round_index)]
        dropped = [d for d in record["dropped"] if (d["split"], d["round"]) == (split, round_index)]
        frames = sum(b["frames"] for b in bags)
        slow = sum(b["slow_frames"] for b in bags)
        network = sum(b["network_frames"] for b in bags)
        drivers = sorted({b["driver"] for b in bags})
        who = "expert" if drivers == ["expert"] else f"network ({', '.join(drivers)}) and expert"
        rows.append(f"| collect {split}, round {round_index} | {len(bags)} of {len(bags) + len(dropped)} episodes kept, "
                    f"driven by the {who} | {frames:,} frames ({frames / 36000:.2f} h), {100 * slow / frames:.1f} % "
                    f"labelled < 1 m/s{f', {100 * network / frames:.0f} % driven by the network' if network else ''} |")
    for variant in ("msfsu", "msf", "su"):
        path = TRAINING_RECORDS / variant / "metrics.csv"
        if not path.exists():
            rows.append(f"| train {VARIANT_NAMES[variant]} | not trained on this data yet | the file shipped is the v1 model |")
            continue
        epochs = list(csv.DictReader(path.open()))
        best = min(epochs, key=lambda row: float(row["val_total"]))
        seconds, rate = _training_time_and_rate(epochs)
        hours = seconds / 3600
        parts = ", ".join(f"{name} {float(best[f'val_{name}']):.4f}" for name in ("steer", "speed", "scene")
                          if best.get(f"val_{name}") not in (None, "", "nan"))
        rows.append(f"| train {VARIANT_NAMES[variant]} | {len(epochs)} epochs, {rate:.0f} samples/s, {hours:.2f} h of "
                    f"training steps | best validation loss {float(best['val_total']):.4f} at epoch "
                    f"{int(best['epoch'])} ({parts}) |")
    return "\n".join(rows)


def paper_training() -> str:
    """docs/results/training/paper_short/: the rate of the int8 gate's short run of the paper preset."""
    import csv

    record = TRAINING_RECORDS / "paper_short"
    if not (record / "metrics.csv").exists():
        return "The paper preset has no training record yet: `bash scripts/int8_gate.sh` writes its short run's."
    epochs = list(csv.DictReader((record / "metrics.csv").open()))
    args = json.loads((record / "args.json").read_text())
    seconds, rate = _training_time_and_rate(epochs)
    precision = " + ".join(name for name, on in (("bf16", args["bf16"]), ("channels-last", args["channels_last"])) if on)
    return (f"Training on 2 cores, paper preset: {rate:.1f} samples/s ({precision or 'fp32'}, decoder "
            f"{args['decoder_layout']}; the int8 gate's short run, {args['max_steps']} steps in {seconds / 60:.1f} min, "
            "`docs/results/training/paper_short/`).")


CLOSED_LOOP_RESULTS = ROOT / "docs" / "results" / "closed_loop" / "results.json"
CLOSED_LOOP_V3_RESULTS = ROOT / "docs" / "results" / "closed_loop_v3" / "results.json"


def closed_loop_v3() -> str:
    """docs/results/closed_loop_v3/results.json: the routes v3 table (the agents run on v3 so far)."""
    return closed_loop(CLOSED_LOOP_V3_RESULTS)


GRAPH2 = ROOT / "docs" / "results" / "closed_loop_v3_graph2"
CURRENT_RESULTS = GRAPH2 / "results.json"  # the current simulator revision (4) and node graph revision (2)
CURRENT_RUN = GRAPH2 / "records" / "networks" / "run.json"


def current_progress() -> str:
    """"" when the current run has every planned agent on every route; else what it has so far (it resumes)."""
    planned = list(json.loads(CURRENT_RUN.read_text())["agents"])
    sources = json.loads(CURRENT_RESULTS.read_text())["sources"]
    driven = {agent: sum(sources.get(agent, {}).values()) for agent in planned}
    routes = max(driven.values())
    if all(count == routes for count in driven.values()):
        return ""
    return (f"In progress: {sum(driven.values())} of {routes * len(planned)} episodes driven ("
            + ", ".join(f"{agent} {count}" for agent, count in driven.items())
            + "); `NETWORKS=1 WORKERS=2 bash scripts/results.sh` resumes the run.")


def against_paper(agents: Sequence[str] | None = None) -> str:
    """docs/results/closed_loop_v3_graph2/results.json (the current simulator and graph revisions): every network
    (or `agents`) against the paper's MSFSU and the v3 goals, as its results.md says it."""
    if not CURRENT_RESULTS.exists():
        return "No records of the current revisions yet: `NETWORKS=1 bash scripts/results.sh` writes them."
    from msfsu_evaluation.closed_loop.markdown import against_paper_markdown
    from msfsu_evaluation.closed_loop.runner import EXPERT

    found = json.loads(CURRENT_RESULTS.read_text())["against_paper"]
    chosen = {a: x for a, x in found.items() if a != EXPERT and (agents is None or a in agents)}
    progress = current_progress()
    return ((progress + "\n\n") if progress else "") + "\n".join(
        against_paper_markdown(chosen, title=False)).rstrip()


def closed_loop_current() -> str:
    """docs/results/closed_loop_v3_graph2/results.json: the routes v3 table on the current revisions."""
    progress = current_progress()
    return ((progress + "\n\n") if progress else "") + closed_loop(CURRENT_RESULTS)


def _same_network_as_msfsu(record: dict) -> set[str]:
    """The agents that drove MSFSU's very checkpoint (by content digest), on another backend or precision."""
    digests: dict[str, str] = {}
    for directory in record.get("records", []):
        run = ROOT / directory / "run.json"
        if run.exists():
            digests.update(json.loads(run.read_text()).get("checkpoint_digests", {}))
    return {agent for agent, digest in digests.items() if agent != "msfsu" and digest == digests.get("msfsu")}


def _ran_as(record: dict) -> dict[str, str]:
    """What each network of a results.json ran as on its machines ('cpu openvino/int8')."""
    return {agent: ", ".join(runtime.get("ran_as", [])) for agent, runtime in record["run"].get("runtimes", {}).items()}


def ablation_line() -> str:
    """The pooled paired rows of MSFSU against each other network, held out and in training conditions; then MSFSU
    as deployed against the same checkpoint on another precision (the deployed precision's closed-loop check)."""
    record = json.loads(CURRENT_RESULTS.read_text())
    rows = _pooled_against(record, "msfsu")
    if not rows:
        return "- **Ablation**: no network pair has driven the same routes yet."
    same = _same_network_as_msfsu(record)
    ran_as = _ran_as(record)

    link = " ([results](docs/results/README.md#closed-loop-routes-v3-simulator-revision-4-node-graph-revision-2))."
    others = [row for row in rows if row["b"] not in same]
    lines = [("- **Ablation**, MSFSU minus the other network in success points on the same routes (Newcombe 95 % "
              "interval, exact McNemar p): " + _pooled_parts(others) + link)] if others else []
    precision = [row for row in rows if row["b"] in same]
    if precision:
        lines.append(f"- **Deployed precision**, MSFSU as the node deploys it ({ran_as.get('msfsu', 'auto')}) minus "
                     "the same checkpoint on " + ", ".join(sorted(f"{b} ({ran_as.get(b, '?')})"
                                                                  for b in {row["b"] for row in precision}))
                     + " on the same routes: " + _pooled_parts(precision) + link)
    return "\n".join(lines)


def _pooled_against(record: dict, first: str) -> list[dict]:
    """A results.json's paired rows over all suites (one per condition) of network `first` against each other agent,
    with `first` as A."""
    return [_msfsu_first(row, first) for row in record.get("paired", [])
            if row["suite"] == "all" and first in (row["a"], row["b"])]


def _pooled_parts(rows: list[dict]) -> str:
    """Pooled paired rows as "B condition A - B (interval) (p, routes)", by B then training conditions first."""
    from msfsu_evaluation.closed_loop.cells import difference_text

    return "; ".join(f"{row['b']} {row['condition']} {difference_text(row)} (p {row['mcnemar_p']:.3f}, "
                     f"{row['routes']} routes)"
                     for row in sorted(rows, key=lambda row: (row["b"], row["condition"] != "train")))


def closed_loop_precision() -> str:
    """docs/results/closed_loop_v3_graph2/results.json: MSFSU as deployed against its very checkpoint on another
    precision, paired per suite and condition and over all routes (the deployed precision's closed-loop check)."""
    from msfsu_evaluation.closed_loop.cells import difference_text

    record = json.loads(CURRENT_RESULTS.read_text())
    same = _same_network_as_msfsu(record)
    rows = [_msfsu_first(row) for row in record.get("paired", []) if {row["a"], row["b"]} & same
            and "msfsu" in (row["a"], row["b"])]
    if not rows:
        return "No agent has driven MSFSU's checkpoint on another precision on the current revisions yet."
    ran_as = _ran_as(record)
    lines = [f"MSFSU as the node deploys it (`msfsu`: {ran_as.get('msfsu', 'auto')}) against the same checkpoint on "
             + ", ".join(f"`{b}`: {ran_as.get(b, '?')}" for b in sorted(same)) + ", on the routes both drove "
             "(benchmark v3, simulator revision 4, node graph revision 2; `docs/results/closed_loop_v3_graph2`):", "",
             "| other | suite | condition | routes | msfsu | other | only msfsu | only other | msfsu - other (95 % CI) "
             "| McNemar p |", "| --- |" + " --- |" * 9]
    order = {"corl2017": 0, "nocrash": 1, "all": 2}
    for row in sorted(rows, key=lambda r: (r["b"], order.get(r["suite"], 3), r["condition"] != "train")):
        lines.append(f"| {row['b']} | {row['suite']} | {row['condition']} | {row['routes']} | {row['a_successes']} | "
                     f"{row['b_successes']} | {row['only_a']} | {row['only_b']} | {difference_text(row)} | "
                     f"{row['mcnemar_p']:.3f} |")
    return "\n".join(lines)


def closed_loop(path: Path | None = None) -> str:
    """docs/results/closed_loop/results.json: success per task, condition and agent with Wilson 95 % intervals."""
    path = CLOSED_LOOP_RESULTS if path is None else path
    if not path.exists():
        return "No closed-loop records yet: `bash scripts/results.sh` writes `docs/results/closed_loop/`."
    from msfsu_evaluation.closed_loop.cells import difference_text
    from msfsu_evaluation.closed_loop.suites import TASKS  # the suites' task order

    record = json.loads(path.read_text())
    agents, results = record["agents"], record["results"]
    conditions = ("train", "heldout")
    header = [f"{condition}: {agent}" for condition in conditions for agent in agents]
    rows = ["| suite / task | " + " | ".join(header) + " |", "| --- |" + " --- |" * len(header)]
    tasks = sorted({(suite, task) for agent in agents for suite in results[agent] for task in results[agent][suite]},
                   key=lambda key: (key[0], list(TASKS).index(key[1]) if key[1] in TASKS else len(TASKS)))
    for suite, task in tasks:
        cells = []
        for condition in conditions:
            for agent in agents:
                cell = results[agent].get(suite, {}).get(task, {}).get(condition)
                if cell is None:
                    cells.append("-")
                    continue
                low, high = (round(100 * bound) for bound in cell["success_ci95"])
                cells.append(f"{cell['successes']}/{cell['episodes']} ({100 * cell['success_rate']:.0f} %; {low}-{high})")
        rows.append(f"| {suite} / {task} | " + " | ".join(cells) + " |")
    pooled = [_msfsu_first(row) for row in record.get("paired", []) if row["suite"] == "all"]
    if pooled:
        rows += ["", "Paired over all tasks (the routes both drove; A - B in points with the Newcombe 95 % interval, "
                 "exact McNemar p):", "",
                 "| A vs B | condition | routes | A | B | only A | only B | A - B (95 % CI) | McNemar p |",
                 "| --- |" + " --- |" * 8]
        for row in sorted(pooled, key=lambda row: (row["a"], row["b"], conditions.index(row["condition"]))):
            rows.append(f"| {row['a']} vs {row['b']} | {row['condition']} | {row['routes']} | {row['a_successes']} | "
                        f"{row['b_successes']} | {row['only_a']} | {row['only_b']} | {difference_text(row)} | "
                        f"{row['mcnemar_p']:.3f} |")
    return "\n".join(rows)


FREE_RUNNING_RESULTS = ROOT / "docs" / "results" / "free_running" / "results.json"


def free_running(path: Path | None = None) -> str:
    """docs/results/free_running/results.json: the default model free-running beside its lockstep episodes."""
    path = FREE_RUNNING_RESULTS if path is None else path
    if not path.exists():
        return "No free-running records yet: `bash scripts/free_running.sh` writes `docs/results/free_running/`."
    from msfsu_evaluation.closed_loop.markdown import free_running_markdown

    record = json.loads(path.read_text())
    episodes = {agent: sum(cell["episodes"] for suite in tasks.values() for task in suite.values()
                           for cell in task.values()) for agent, tasks in record["results"].items()}
    free = sorted(record.get("free_running", {}))
    lockstep = [agent for agent in record["agents"] if agent not in free]
    progress = (f"Routes driven: {', '.join(f'{a} {episodes[a]}' for a in free)} free-running, "
                f"{', '.join(f'{a} {episodes[a]}' for a in lockstep)} in lockstep"
                + (" (the free-running run is not finished: `bash scripts/free_running.sh` resumes it)."
                   if any(episodes[a] < max(episodes.values()) for a in free) else "."))
    return (progress + "\n\n" + closed_loop(path) + "\n\n"
            + "\n".join(free_running_markdown(record.get("free_running", {}))[2:]).strip())


MODEL_V3 = ROOT / "docs" / "results" / "model_v3"


def model_v3_line() -> str:
    """Model v3 (issue 58): how far its stages are, then, once judged, v3 MSFSU against the shipped MSFSU paired over
    the routes both drove, and what the release rule says (scripts/model_v3_release.py, its pair and its rule)."""
    recipe = read_recipe(MODEL_V3)
    plan, done, spent = recipe.plan, recipe.done, recipe.spent_h
    line = (f"- **Model v3** (issue 58: the shipped models trained further on a {plan.budget_h:g} h budget): "
            f"{len(done)} of {len(plan.stages)} stages finished, {spent:.1f} h spent "
            "([plan and hours](docs/training.md#model-v3-issue-58))")
    released = MODEL_V3 / "release.json"
    if released.exists():
        verdict = json.loads(released.read_text())
        return (line + f"; release: {'released' if verdict['released'] else 'not released'}, "
                + "; ".join(verdict["reasons"]) + ".")
    (baseline_run, baseline_agent), (run, agent) = (run_and_agent(side) for side in (model_v3_release.BASELINE,
                                                                                    model_v3_release.CANDIDATE))
    candidate = model_v3_release.successes((ROOT / run, agent)) if (ROOT / run).is_dir() else {}
    if not candidate:
        return line + "; v3 MSFSU not judged yet."
    rows = model_v3_release.paired_rows(model_v3_release.successes((ROOT / baseline_run, baseline_agent)), candidate)
    would, _ = model_v3_release.verdict(rows)
    return (line + f"; v3 MSFSU minus the shipped one: {rows[0].difference_text()} (McNemar p {rows[0].mcnemar_p:.3f}, "
            f"{rows[0].routes} routes); the release rule {'would release' if would else 'would not release'} it "
            "([v3 against v2](docs/results/closed_loop_v3_model_v3/v3_change.md)).")


MODEL_V3_RESULTS = ROOT / "docs" / "results" / "closed_loop_v3_model_v3" / "results.json"


def model_v3_ablation_line() -> str:
    """Model v3's ablation (issue 58): v3 MSFSU against the v3 MSF and SU (the same data, steps and schedule) on the
    routes both drove, pooled per condition; empty until a v3 network beside v3 MSFSU has been judged."""
    rows = _pooled_against(json.loads(MODEL_V3_RESULTS.read_text()), "msfsu_v3") if MODEL_V3_RESULTS.exists() else []
    rows = [row for row in rows if row["b"] != "expert"]
    if not rows:
        return ""
    return ("- **Ablation, model v3**, v3 MSFSU minus the other v3 network in success points on the same routes "
            "(Newcombe 95 % interval, exact McNemar p): " + _pooled_parts(rows)
            + " ([v3 results](docs/results/closed_loop_v3_model_v3/results.md"
            "#ablation-paired-comparison-on-the-same-routes)).")


def headline() -> str:
    """The README's results: the shipped MSFSU against the paper (the against-paper block's table), then one line
    each for the ablation, the deployed precision, model v3 (and its ablation once judged), perception speed,
    real-time latency and simulator speed, each with the page that has the whole table."""
    lines = [RECORD_BLOCKS["perception-speed"].record().main.headline(),
             headline_latency(RECORD_BLOCKS["soak"].record()), RECORD_BLOCKS["simulator-speed"].record().headline()]
    lines = [ablation_line(), model_v3_line(), model_v3_ablation_line(), *lines]
    return against_paper(("msfsu",)) + "\n\n" + "\n".join(line for line in lines if line)


def _msfsu_first(row: dict, first: str = "msfsu") -> dict:
    """A paired row with MSFSU (the paper's network; `first` names it) as A, so every difference reads "MSFSU minus
    the other"."""
    if row["b"] != first:
        return row
    low, high = row["difference_ci95"]
    return {**row, "a": row["b"], "b": row["a"], "a_successes": row["b_successes"], "b_successes": row["a_successes"],
            "only_a": row["only_b"], "only_b": row["only_a"], "difference": -row["difference"],
            "difference_ci95": [-high, -low]}


GENERATORS: dict[str, Callable[[], str]] = {"default-model": default_model, "paper-training": paper_training, "closed-loop": closed_loop, "closed-loop-v3": closed_loop_v3, "closed-loop-current": closed_loop_current, "against-paper": against_paper, "closed-loop-precision": closed_loop_precision,
                                            "benchmark-workers": benchmark_workers, "free-running": free_running,
                                            "headline": headline, **RECORD_BLOCKS}
BLOCK = re.compile(r"(<!-- results:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(<!-- /results:(?P=name) -->)", re.S)


_LINK_TARGET = re.compile(r"(\]\()([^)\s#]+)")


def relocate(body: str, page: Path) -> str:
    """`body`'s relative link targets, written from the repository's root, as seen from `page`."""
    def rewrite(match: re.Match) -> str:
        target = match.group(2)
        if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("/"):
            return match.group(0)
        return match.group(1) + Path(os.path.relpath(ROOT / target, page.parent)).as_posix()

    return _LINK_TARGET.sub(rewrite, body)


def render(text: str, page: Path = README) -> str:
    """`text` of `page` with every block rewritten from its generator."""
    def replace(match: re.Match) -> str:
        name = match.group("name")
        if name not in GENERATORS:
            raise KeyError(f"{page.name}: block '{name}' has no generator (known: {', '.join(GENERATORS)})")
        return f"{match.group(1)}{relocate(GENERATORS[name](), page)}\n{match.group(4)}"

    return BLOCK.sub(replace, text)


def placement(texts: dict[Path, str]) -> list[str]:
    """Problems with where the blocks stand: a generator whose block is on no page or on more than one."""
    where: dict[str, list[str]] = {name: [] for name in GENERATORS}
    for page, text in texts.items():
        for match in BLOCK.finditer(text):
            where.setdefault(match.group("name"), []).append(page.relative_to(ROOT).as_posix())
    problems = [f"block '{name}' is on no page: place it with its topic or remove its generator"
                for name, found in where.items() if not found]
    problems += [f"block '{name}' stands on {len(found)} pages ({', '.join(found)}): keep one"
                 for name, found in where.items() if len(found) > 1]
    return problems


def rewrite_page(page: Path, render_page: Callable[[str], str], script: str, description: str,
                 argv: list[str] | None = None) -> int:
    """The command line of `script`, which writes the generated blocks of `page`: rewrite them, or with --check
    compare only and exit 1 when the page is stale (`render_page`: the page's text -> its text as it should be)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--check", action="store_true", help=f"compare only; exit 1 when {page.name} is stale")
    args = parser.parse_args(argv)
    text = page.read_text()
    updated = render_page(text)
    if args.check:
        if updated != text:
            print(f"{page.relative_to(ROOT)} is stale: run python {script}", file=sys.stderr)
            return 1
        return 0
    page.write_text(updated)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare only; exit 1 when a page is stale")
    parser.add_argument("--list", action="store_true", help="print the pages that hold a block, one a line")
    args = parser.parse_args(argv)
    texts = {page: page.read_text() for page in pages() if page.exists()}
    if args.list:
        print("\n".join(str(page.relative_to(ROOT)) for page, text in texts.items() if "<!-- results:" in text))
        return 0
    problems = placement(texts)
    for page, text in texts.items():
        updated = render(text, page)
        if updated == text:
            continue
        if args.check:
            problems.append(f"{page.relative_to(ROOT)} is stale: run python scripts/readme_results.py")
        else:
            page.write_text(updated)
    for problem in problems:
        print(problem, file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
