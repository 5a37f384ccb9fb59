"""Benchmark run directories as a report reads them: their episode records merged, compared and attributed, and
what their run.json files say together.

Runs merge only where they do not overlap: an agent's route recorded in two runs is refused unless the caller names
the run whose records of that agent win; within one run a later record of a route replaces an earlier one (a resumed
or repeated route).
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.runner import (RUN_FILE, RunInfo, episode_machine, read_episodes, telemetry_path,
                                                 trajectory_path)
from msfsu_evaluation.closed_loop.telemetry import Telemetry, load
from msfsu_evaluation.usage import UsageError

REPOSITORY = Path(__file__).resolve().parents[3]
# what an episode did, as its record says (EpisodeResult fields; wall time and the worker that ran it aside)
DRIVEN_FIELDS = ("status", "success", "time_s", "steps", "route_completion", "collision_type", "distance_to_goal_m",
                 "solid_line_crossings")


def recorded_path(text: str) -> Path:
    """A path as `relative` recorded it: relative to the repository if it is there, else to the working directory."""
    path = Path(text)
    return path if path.is_absolute() or not (REPOSITORY / path).exists() else REPOSITORY / path


def relative(path: Path | str) -> str:
    """`path` relative to the repository, else to the working directory, else as given."""
    path = Path(path)
    for base in (REPOSITORY, Path.cwd()):
        try:
            return str(path.resolve().relative_to(base.resolve()))
        except ValueError:
            continue
    return str(path)


@dataclass(frozen=True)
class Record:
    """One finished episode and the run directory that holds its trajectory."""

    run: Path
    episode: EpisodeResult

    @property
    def key(self) -> tuple[str, str]:
        return self.episode.agent, self.episode.route

    def trajectory(self) -> np.ndarray:
        return np.load(trajectory_path(self.run, *self.key))

    def telemetry(self) -> Telemetry | None:
        """The episode's per-step telemetry, None for episodes recorded before it was kept."""
        path = telemetry_path(self.run, *self.key)
        return load(path) if path.exists() else None


Records = dict[tuple[str, str], Record]  # (agent, route key) -> its record


def run_records(run: Path, agents: Collection[str] | None = None) -> Records:
    """A run's records of `agents` (None: all); the last record of an (agent, route) wins."""
    return {record.key: record for record in (Record(run, episode) for episode in read_episodes(run))
            if agents is None or record.key[0] in agents}


def merge(runs: Sequence[Path], agents: Collection[str] | None = None,
          prefer: Mapping[str, Path] | None = None) -> Records:
    """The records of several runs (of `agents`; None: all). An (agent, route) may come from one run only, unless
    `prefer` names the run that wins for that agent (UsageError otherwise, naming both runs)."""
    prefer = prefer or {}
    merged: Records = {}
    for run in runs:
        for key, record in run_records(run, agents).items():
            earlier = merged.get(key)
            if earlier is not None:
                agent, route = key
                if prefer.get(agent) not in (earlier.run, run):
                    raise UsageError(f"{agent} drove {route} in both {relative(earlier.run)} and {relative(run)}: "
                                     f"name the run that wins with --prefer {agent}=RUN")
                if earlier.run == prefer[agent]:
                    continue
            merged[key] = record
    return merged


def _same(a: Record, b: Record, fields: Sequence[str]) -> bool:
    return all(getattr(a.episode, field) == getattr(b.episode, field) for field in fields)


def identical(a: Record, b: Record) -> bool:
    """Two records of one agent and route drove the same episode: every DRIVEN_FIELDS value the same and, where both
    runs kept it, the whole trajectory."""
    if not _same(a, b, DRIVEN_FIELDS):
        return False
    paths = [trajectory_path(record.run, *record.key) for record in (a, b)]
    return not all(path.exists() for path in paths) or np.array_equal(np.load(paths[0]), np.load(paths[1]))


def overlaps(runs: Sequence[Path], agents: Collection[str] | None = None) -> dict[str, dict]:
    """Where two runs hold the same agent on the same route (the expert re-driven beside the networks), how often
    they agree: {agent: {"routes", "identical" (every driven field and the whole trajectory), "same_outcome",
    "differ": [routes whose records are not identical]}}. With a deterministic simulator every record is identical."""
    held: dict[tuple[str, str], list[Record]] = {}
    for run in runs:
        for key, record in run_records(run, agents).items():
            held.setdefault(key, []).append(record)
    found: dict[str, dict] = {}
    for (agent, route), records in sorted(held.items()):
        if len(records) < 2:
            continue
        first, *others = records
        same = all(identical(first, other) for other in others)
        entry = found.setdefault(agent, {"routes": 0, "identical": 0, "same_outcome": 0, "differ": []})
        entry["routes"] += 1
        entry["identical"] += same
        entry["same_outcome"] += all(_same(first, o, ("status",)) for o in others)
        if not same:
            entry["differ"].append(route)
    return found


def sources_of(records: Records) -> dict[str, dict[str, int]]:
    """{agent: {run: episodes}}: where each agent's records came from."""
    counts: dict[str, Counter[str]] = {}
    for (agent, _), record in records.items():
        counts.setdefault(agent, Counter())[relative(record.run)] += 1
    return {agent: dict(sorted(runs.items())) for agent, runs in sorted(counts.items())}


def route_machines(run: Path, agents: Collection[str]) -> tuple[dict[str, int], int]:
    """Where a run's routes driven by every one of `agents` were driven: ({CPU model: routes whose agents all drove
    on it}, routes whose agents drove on different CPUs). A CPU is named by its model (describe_cpu up to the first
    comma); an episode recorded without its machine ran on the run's first (runner.episode_machine)."""
    machines = read_run_info(run).get("machines", [])
    by_route: dict[str, dict[str, str | None]] = {}
    for (agent, route), record in run_records(run, agents).items():
        by_route.setdefault(route, {})[agent] = episode_machine(record.episode, machines)
    on_one: Counter[str] = Counter()
    split = 0
    for drivers in by_route.values():
        if len(drivers) < len(set(agents)):
            continue
        if len(set(drivers.values())) == 1:
            on_one[(next(iter(drivers.values())) or "not recorded").split(",")[0]] += 1
        else:
            split += 1
    return dict(on_one.most_common()), split


def read_run_info(run: Path) -> dict:
    path = run / RUN_FILE
    if not path.is_file():
        raise UsageError(f"{run} is no benchmark run directory (no {RUN_FILE})")
    return json.loads(path.read_text())


def ability_run_info(infos: Sequence[dict]) -> dict:
    """What a per-ability report says of the runs it merges: the scenario file and version, and the revisions as
    report_run_info checks them. UsageError where a run is not of the abilities suite or versions would mix."""
    from msfsu_evaluation.closed_loop.abilities import SUITE

    if any(info.get("suite") != SUITE for info in infos):
        raise UsageError(f"not every run is of the {SUITE} suite: a report never mixes it with route suites")
    versions = {info.get("abilities_version") for info in infos}
    if len(versions) != 1:
        raise UsageError(f"the runs are of different scenario versions {sorted(versions)}: never mixed")
    info = report_run_info(infos, None, infos[0]["routes_file"])
    info.pop("routes_version")
    return {"suite": SUITE, "abilities_version": versions.pop(), **info}


def report_run_info(infos: Sequence[dict], routes_version: int | None, routes_file: str) -> dict:
    """What a report says of the runs it merges (results.json "run"): routes, the simulator revision and, where they
    drove networks, the node graph revision (msfsu_bringup.GRAPH_REVISION; absent for the expert alone, who drives
    without the graph). UsageError where runs of different revisions would mix."""
    runs = [RunInfo.of(run) for run in infos]
    revisions = {run.simulator_revision for run in runs}
    if len(revisions) != 1:
        raise UsageError(f"the runs are of different simulator revisions {sorted(revisions)}: never mixed")
    info = {"routes_version": routes_version, "routes_file": routes_file, "simulator_revision": revisions.pop()}
    graphs = {run.graph_revision for run in runs if run.graph_revision is not None}
    if len(graphs) > 1:
        raise UsageError(f"the runs drove networks through different node graph revisions {sorted(graphs)}: "
                         "never mixed")
    info = {**info, "graph_revision": graphs.pop()} if graphs else info
    runtimes = network_runtimes(infos)
    return {**info, "runtimes": runtimes} if runtimes else info


def network_runtimes(infos: Sequence[dict]) -> dict[str, dict]:
    """Per network agent of runs that recorded it (run.json agent_runtimes): the backend and precision asked of its
    perception node and what the node ran on each leg's machine ('cpu openvino/int8'). Empty for older runs."""
    runtimes: dict[str, dict] = {}
    for run in infos:
        for agent, asked in run.get("agent_runtimes", {}).items():
            ran = [leg["runtimes"][agent] for leg in run.get("legs", []) if agent in leg.get("runtimes", {})]
            entry = runtimes.setdefault(agent, {**asked, "ran_as": []})
            entry["ran_as"] = sorted({*entry["ran_as"], *ran})
    return dict(sorted(runtimes.items()))
