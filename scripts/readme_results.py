"""Write the measured figures of the README and of docs/ from the committed result records (never typed by hand).

    python scripts/readme_results.py           # rewrite the marked blocks of every page
    python scripts/readme_results.py --check   # exit 1 if a page differs from the records (a test runs this)

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

from msfsu_evaluation.records.lockstep import LockstepResults
from msfsu_evaluation.records.network import NetworkRecord
from msfsu_evaluation.records.simulator import SimulatorResults
from msfsu_evaluation.records.soak import (headline_latency, read_design_soaks, read_soaks, soak_block,
                                           soak_design_block, soak_stages_block)
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


def _hz(path: dict) -> str:
    """Hz of a path's p50, from the unrounded p50 (the record's rounded `hz` can round the other way)."""
    return f"{1e3 / path['p50_ms']:.0f} Hz"


def _ms_hz(path: dict | None) -> str:
    return "-" if path is None else f"{path['p50_ms']:.1f} ms ({_hz(path)})"


INT8_PROFILE = ROOT / "benchmarks" / "int8_profile_results.json"


def int8_profile(path: Path | None = None) -> str:
    """benchmarks/int8_profile_results.json: int8 wall time and the part in float kernels, per exported graph."""
    path = INT8_PROFILE if path is None else path
    if not path.exists():
        return "Not profiled yet: `python benchmarks/int8_profile.py <checkpoints>` writes it."
    record = json.loads(path.read_text())

    def cell(graph: dict) -> str:
        in_float = sum(row["ms"] for row in graph["by_kind"] if "f32" in row["kind"])
        return f"{graph['wall_p50_ms']:.1f} ms ({in_float:.1f} ms of {graph['layers_ms']:.1f} in float kernels)"

    rows = ["| checkpoint | OpenVINO int8, exported as in torch | exported as deployed | speed-up | load (1 min) before |",
            "| --- | --- | --- | --- | --- |"]
    for model in record["models"]:
        torch_graph, deployed = model["graphs"]["as in torch"], model["graphs"]["deployed"]
        rows.append(f"| `{model['checkpoint']}` | {cell(torch_graph)} | {cell(deployed)} | "
                    f"{torch_graph['wall_p50_ms'] / deployed['wall_p50_ms']:.2f}x | {model['load_before']} |")
    return "\n".join(rows) + f"\n\n{record['date']}, {record['machine']}, {record['threads']} threads: `{record['command']}`"


PERCEPTION_RESULTS = ROOT / "benchmarks" / "perception_results.json"
PERCEPTION_COMMAND = ("python benchmarks/perception.py --checkpoint runs/paper_short/best.pt --cpu-checkpoint "
                      "models/msfsu_default.pt --out benchmarks/perception_results.md --json "
                      "benchmarks/perception_results.json")


# The same benchmark on a CPU without AVX-512, bf16 or VNNI (the cpu preset only: the int8 path on plain AVX2)
PERCEPTION_RESULTS_AVX2 = ROOT / "benchmarks" / "perception_results_avx2.json"


def perception_speed(path: Path | None = None) -> str:
    """benchmarks/perception_results.json: per model the main paths and the fastest one that passed the gate; then
    the AVX2-only machine's record when there is one (a table of its own: another machine)."""
    if path is None:
        blocks = [perception_speed(PERCEPTION_RESULTS)]
        if PERCEPTION_RESULTS_AVX2.exists():
            blocks.append("On a CPU with AVX2 only (no AVX-512, VNNI, bf16 or AMX; `benchmarks/perception_results_avx2.md`):"
                          f"\n\n{perception_speed(PERCEPTION_RESULTS_AVX2)}")
        return "\n\n".join(blocks)
    if not path.exists():
        return f"Not measured yet with the gated models: `{PERCEPTION_COMMAND}` (on a quiet machine) writes it."
    record = json.loads(path.read_text())
    rows = ["| model (weights) | torch fp32 | OpenVINO fp32 | OpenVINO bf16 | OpenVINO int8 | fastest path that passed "
            "the gate | load (1 min) before |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for model in record["models"]:
        paths, best = model["paths"], model["fastest_gated"]
        weights = model["checkpoint"] or "random"
        gated = "-" if best is None else (f"**{best['path']}: {best['p50_ms']:.1f} ms, {_hz(best)}, "
                                          f"{best['speedup_vs_torch_fp32']:.1f}x**")
        rows.append(f"| {model['model']} (`{weights}`) | {_ms_hz(paths.get('torch fp32'))} | "
                    f"{_ms_hz(paths.get('openvino fp32'))} | {_ms_hz(paths.get('openvino bf16'))} | "
                    f"{_ms_hz(paths.get('openvino int8'))} | {gated} | {model['load_average_before'][0]} |")
    return "\n".join(rows) + f"\n\n{record['date']}, {record['machine']}, {record['threads']} threads: `{record['command']}`"


GATE_RECORDS = ("models/msfsu_default.pt.deploy/*-gate.json", "models/msf.pt.deploy/*-gate.json",
                "models/su.pt.deploy/*-gate.json", "benchmarks/gate_records/*-gate.json")


def perception_gate() -> str:
    """The committed gate records: pooled verdict of every fast path per checkpoint."""
    rows = ["| checkpoint | held-out frames (LEFT/RIGHT) | path | mIoU torch fp32 -> path (drop, points) | "
            "steer MAE torch fp32 -> path | verdict |", "| --- | --- | --- | --- | --- | --- |"]
    for pattern in GATE_RECORDS:
        for path in sorted(ROOT.glob(pattern)):
            record = json.loads(path.read_text())
            held_out = record["held_out"]
            name = record.get("checkpoint", path.name)
            for key, verdict in record["paths"].items():
                reference, candidate = verdict["reference"], verdict["candidate"]
                if reference["mean_iou"] is None:
                    miou = "-"
                else:
                    drop = 100 * (reference["mean_iou"] - candidate["mean_iou"])
                    miou = f"{reference['mean_iou']:.4f} -> {candidate['mean_iou']:.4f} (drop {drop:.2f})"
                rise = candidate["steer_mae"] / reference["steer_mae"] - 1
                change = candidate["steer_mae"] - reference["steer_mae"]
                rows.append(f"| {name} | {held_out['frames']} ({held_out['turn_frames']}) | {key.replace('/', ' ')} | "
                            f"{miou} | {reference['steer_mae']:.4f} -> {candidate['steer_mae']:.4f} "
                            f"(change {change:+.4f}, rise {rise:+.1%}) | {'pass' if verdict['passed'] else 'FAIL'} |")
    return "\n".join(rows)


def _free(entry: dict) -> bool:
    """msfsu_evaluation.deploy.sensitivity.is_free of one entry of a sensitivity record's ranking."""
    from msfsu_evaluation.deploy.sensitivity import LayerSensitivity, is_free

    return is_free(LayerSensitivity.from_record(entry))


def int8_recipes() -> str:
    """benchmarks/int8_recipes/*.json (msfsu-int8-recipe): the most sensitive layers and what the recipe keeps float."""
    rows = ["| checkpoint | validation: all int8 (mIoU drop, steer MAE rise) | most sensitive layers (damage recovered, "
            "gate units) | kept in float (share of MACs) | validation: recipe (mIoU drop, steer MAE rise; steer damage) |",
            "| --- | --- | --- | --- | --- |"]
    for path in sorted((ROOT / "benchmarks" / "int8_recipes").glob("*.json")):
        record = json.loads(path.read_text())
        before, after = record["all_int8"]["validation_gate"], record["deployed"]["validation_gate"]
        top = ", ".join(f"`{entry['layer']}` {entry['recovered']:+.1f}" for entry in record["ranking"][:3])
        free = {entry["layer"] for entry in record["ranking"] if _free(entry)}
        kept = [f"`{layer}`" for layer in record["recipe"]["keep_float"] if layer not in free]
        head = [layer for layer in record["recipe"]["keep_float"] if layer in free]
        kept = ", ".join(kept + ([f"the policy head ({len(head)} layers)"] if head else [])) or "nothing"
        rows.append(f"| `{record['checkpoint']}` | {before['miou_drop_points']:.2f}, {before['steer_mae_rise']:+.1%} | "
                    f"{top} | {kept} ({record['recipe_float_mac_share']:.1%}) | {after['miou_drop_points']:.2f}, "
                    f"{after['steer_mae_rise']:+.1%}; {record['deployed']['damage']['steer']:.2f} |")
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


def ablation_line() -> str:
    """The pooled paired rows of MSFSU against each other network, held out and in training conditions."""
    from msfsu_evaluation.closed_loop.cells import difference_text

    rows = [_msfsu_first(row) for row in json.loads(CURRENT_RESULTS.read_text()).get("paired", [])
            if row["suite"] == "all" and "msfsu" in (row["a"], row["b"])]
    rows = [row for row in rows if row["a"] == "msfsu"]
    if not rows:
        return "- **Ablation**: no network pair has driven the same routes yet."
    parts = [f"{row['b']} {row['condition']} {difference_text(row)} (p {row['mcnemar_p']:.3f}, {row['routes']} routes)"
             for row in sorted(rows, key=lambda row: (row["b"], row["condition"] != "train"))]
    return ("- **Ablation**, MSFSU minus the other network in success points on the same routes (Newcombe 95 % "
            "interval, exact McNemar p): " + "; ".join(parts) + " ([results](docs/results/README.md#closed-loop-"
            "routes-v3-simulator-revision-4-node-graph-revision-2)).")


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


def gpu_speed() -> str:
    """benchmarks/gpu_results.json: the network per path (numpy in, numpy out) and a camera frame end to end."""
    record = _load("gpu_results.json")
    env = record["environment"]
    calls = [row for row in record["network"] if row["measure"] == "numpy in, numpy out"]
    paths = list(dict.fromkeys(row["path"] for row in calls))
    rows = ["| model | " + " | ".join(paths) + " |", "| --- |" + " ---: |" * len(paths)]
    for model in dict.fromkeys(row["model"] for row in calls):
        cells = {row["path"]: f"{row['p50_ms']:.2f} ms ({1e3 / row['p50_ms']:.0f} Hz)" for row in calls
                 if row["model"] == model}
        rows.append(f"| {model} | " + " | ".join(cells.get(path, "–") for path in paths) + " |")
    rows += ["", "| camera frame (default model, fp16) | preprocessing on | preprocess | network + outputs back | "
             "frame p50 / p95 |", "| --- | --- | ---: | ---: | ---: |"]
    for row in record["end_to_end"]:
        if row["precision"] == "fp16":
            rows.append(f"| {row['camera']} | {row['preprocessing on']} | {row['preprocess']['p50_ms']:.2f} ms | "
                        f"{row['network + outputs back']['p50_ms']:.2f} ms | {row['frame']['p50_ms']:.2f} / "
                        f"{row['frame']['p95_ms']:.2f} ms |")
    return ("\n".join(rows) + f"\n\n{env['gpu']}, torch {env['torch']} (CUDA {env['cuda']}), {env['cpus']} CPUs, load "
            f"average {env['load_before']} before; {record['date']}: `{record['command']}` "
            "([benchmarks/gpu_results.md](benchmarks/gpu_results.md))")


def gpu_gate() -> str:
    """The GPU precisions' gate (benchmarks/gpu_results.json, its table made from the stored verdicts)."""
    gate = _load("gpu_results.json")["gate"]
    rows = ["| path | steer MAE rise | mIoU drop, points | class agreement with the reference | passed |",
            "| --- | ---: | ---: | ---: | --- |"]
    for p in gate["paths"]:
        rows.append(f"| {p['path']} | {100 * p['steer_mae_rise']:+.2f} % | {p['miou_drop_points']:+.3f} | "
                    f"{100 * p['class_agreement']:.3f} % | {'yes' if p['passed'] else 'no'} |")
    bags = ", ".join(bag["bag"] for bag in gate["held_out"]["bags"])
    return "\n".join(rows) + f"\n\n{gate['held_out']['frames']} frames of `bags/{bags}`; reference torch fp32 on the CPU."


def headline() -> str:
    """The README's results: the shipped MSFSU against the paper (the against-paper block's table), then one line
    each for perception speed, real-time latency and simulator speed, each with the page that has the whole table."""
    perception = json.loads(PERCEPTION_RESULTS.read_text())
    model = next(m for m in perception["models"] if m["checkpoint"] == "models/msfsu_default.pt")
    best = model["fastest_gated"]
    lines = [
        f"- **Perception**, the shipped model on {perception['machine']} ({perception['threads']} threads), batch 1: "
        f"{best['path']} {best['p50_ms']:.1f} ms ({_hz(best)}), {best['speedup_vs_torch_fp32']:.1f}x torch fp32 "
        "([deployment.md](docs/deployment.md#latency-on-the-cpu)).",
        headline_latency(RECORD_BLOCKS["soak"].record()), RECORD_BLOCKS["simulator-speed"].record().headline(),
    ]
    return against_paper(("msfsu",)) + "\n\n" + "\n".join([ablation_line(), *lines])


def _msfsu_first(row: dict) -> dict:
    """A paired row with MSFSU (the paper's network) as A, so every difference reads "MSFSU minus the other"."""
    if row["b"] != "msfsu":
        return row
    low, high = row["difference_ci95"]
    return {**row, "a": row["b"], "b": row["a"], "a_successes": row["b_successes"], "b_successes": row["a_successes"],
            "only_a": row["only_b"], "only_b": row["only_a"], "difference": -row["difference"],
            "difference_ci95": [-high, -low]}


GENERATORS: dict[str, Callable[[], str]] = {"default-model": default_model, "paper-training": paper_training, "closed-loop": closed_loop, "closed-loop-v3": closed_loop_v3, "closed-loop-current": closed_loop_current, "against-paper": against_paper,
                                            "benchmark-workers": benchmark_workers,
                                            "int8-recipes": int8_recipes, "perception-gate": perception_gate,
                                            "perception-speed": perception_speed, "int8-profile": int8_profile,
                                            "free-running": free_running, "gpu-speed": gpu_speed,
                                            "gpu-gate": gpu_gate, "headline": headline, **RECORD_BLOCKS}
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
    args = parser.parse_args(argv)
    texts = {page: page.read_text() for page in pages() if page.exists()}
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
