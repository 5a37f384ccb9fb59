"""The closed-loop throughput record (benchmarks/workers.py -> benchmarks/workers_results.json): one row per worker
count, the benchmark's episodes per hour, wall and simulated time per agent, memory.

Rules:
- Speed-ups are against the one-worker row (the first row when none ran with one worker).
- Rows written before 2026-11-28 carry neither the machine nor the time: absent from the JSON, and the page says
  "not recorded" rather than guess.
- The projection for a full suite uses the measured mean wall time per episode and the best measured rate.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Self

from msfsu_evaluation.records._json import JsonRow, RecordList, without_absent


@dataclass(kw_only=True)
class AgentThroughput(JsonRow):
    """One agent's episodes of a run."""

    episodes: int
    mean_wall_s: float
    mean_sim_s: float
    successes: int


@dataclass(kw_only=True)
class WorkersRun(JsonRow):
    """One run of msfsu-benchmark with a worker count."""

    OPTIONAL = ("machine", "date")

    workers: int
    episodes: int
    wall_s: float
    episodes_per_hour: float
    peak_used_memory_gb: float  # the machine's, MemTotal - MemAvailable
    memory_before_gb: float
    worker_peak_rss_gb: float  # the largest simulator process
    agents: dict[str, AgentThroughput]
    load_1min_after: float
    machine: str | None = None
    date: str | None = None

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> Self:
        agents = {name: AgentThroughput.from_dict(agent) for name, agent in fields["agents"].items()}
        return cls(**{**fields, "agents": agents})

    def to_dict(self) -> dict[str, Any]:
        return without_absent(asdict(self), self.OPTIONAL)


@dataclass(frozen=True)
class WorkersSetup:
    """What the page says of the run that the record does not hold."""

    command: str
    suites: tuple[str, ...]
    routes_per_task: int
    checkpoint: str
    full_suite_routes: int  # routes of a full suite, for the projection


class WorkersResults(RecordList[WorkersRun]):
    """benchmarks/workers_results.json: a row per worker count, in the order they ran."""

    ROW = WorkersRun

    def one_worker(self) -> WorkersRun:
        return next((run for run in self.rows if run.workers == 1), self.rows[0])

    def speedup(self, run: WorkersRun) -> str:
        return f"{run.episodes_per_hour / self.one_worker().episodes_per_hour:.2f}x"

    def page(self, setup: WorkersSetup) -> str:
        """benchmarks/workers_results.md: throughput and memory per worker count, per agent, and the projection."""
        machines = sorted({run.machine for run in self.rows if run.machine is not None})
        date = max((run.date for run in self.rows if run.date is not None), default="time not recorded")
        lines = [f"# Closed-loop benchmark throughput ({date})", "",
                 f"`{setup.command}`: suites {' '.join(setup.suites)}, "
                 f"{setup.routes_per_task} route(s) per task and condition, agents `expert` and `network` "
                 f"(`{setup.checkpoint}`); machine: {'; '.join(machines) or 'not recorded'}.", "",
                 "| workers | episodes | wall s | episodes/h | speed-up | peak memory used (machine) GB | "
                 "simulator process peak RSS GB |", "| --- | --- | --- | --- | --- | --- | --- |"]
        for run in self.rows:
            lines.append(f"| {run.workers} | {run.episodes} | {run.wall_s} | {run.episodes_per_hour} | "
                         f"{self.speedup(run)} | {run.peak_used_memory_gb} "
                         f"(before: {run.memory_before_gb}) | {run.worker_peak_rss_gb} |")
        lines += ["", "| workers | agent | episodes | successes | mean wall s per episode | mean simulated s |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for run in self.rows:
            for name, agent in run.agents.items():
                lines.append(f"| {run.workers} | {name} | {agent.episodes} | {agent.successes} | "
                             f"{agent.mean_wall_s} | {agent.mean_sim_s} |")
        return "\n".join(lines + self._projection(setup)) + "\n"

    def _projection(self, setup: WorkersSetup) -> list[str]:
        routes = setup.full_suite_routes
        best = max(self.rows, key=lambda run: run.episodes_per_hour)
        hours = 2 * routes / best.episodes_per_hour
        network_hours = {run.workers: routes * run.agents["network"].mean_wall_s / run.workers / 3600
                         for run in self.rows if "network" in run.agents}
        lines = []
        if network_hours:
            fastest = min(network_hours, key=network_hours.get)
            lines += ["", f"Projection, one network agent alone: {routes} routes x its mean wall time per "
                      f"episode / workers = {network_hours[fastest]:.2f} h with {fastest} worker(s) ("
                      + ", ".join(f"{w} worker(s): {h:.2f} h" for w, h in sorted(network_hours.items())) + ")."]
        return lines + ["", f"Projection: a full suite of {routes} routes for one network plus the expert reference "
                        f"({2 * routes} episodes) at the best rate measured here ({best.workers} workers, "
                        f"{best.episodes_per_hour} episodes/h) takes {hours:.1f} h; the routes measured are "
                        f"{'a sample' if setup.routes_per_task < 25 else 'the full suite'} of the suites above, so "
                        "the mix of route lengths differs from the full suite."]

    def block(self) -> str:
        """The docs' table: episodes/h per worker count, its speed-up, wall time per episode, memory, load."""
        rows = ["| workers | episodes/h | speed-up | mean wall s per episode (expert / network) | simulator process "
                "peak RSS GB | load (1 min) after |", "| --- | --- | --- | --- | --- | --- |"]
        for run in self.rows:
            rows.append(f"| {run.workers} | {run.episodes_per_hour} | {self.speedup(run)} | "
                        f"{run.agents['expert'].mean_wall_s} / {run.agents['network'].mean_wall_s} | "
                        f"{run.worker_peak_rss_gb} | {run.load_1min_after} |")
        return "\n".join(rows)
