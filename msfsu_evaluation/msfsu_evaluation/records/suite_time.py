"""The suite-time record (benchmarks/suite_time.py -> benchmarks/suite_time_results.json): every leg msfsu-benchmark
recorded in its run directories' run.json, with its agents' episodes.

Rules:
- The goal is issue 27's: one network agent's full suite in at most `GOAL_H` hours. Only a leg that drove one network
  agent's whole suite from start to end (every route of the full suite to run and finished) is held against it; the
  fastest such leg decides.
"""

from __future__ import annotations

from dataclasses import dataclass

from msfsu_evaluation.closed_loop.suites import full_suite_routes
from msfsu_evaluation.records._json import JsonRow, RecordList

GOAL_H = 1.0  # issue 27: one network agent's suite with the best worker count
FULL_SUITE_ROUTES = full_suite_routes()


@dataclass(kw_only=True)
class SuiteLeg(JsonRow):
    """One invocation of msfsu-benchmark (the run.json's leg) and what its agents drove."""

    started: str  # ISO 8601, UTC
    workers: int
    load_1min_start: float
    agents: list[str]
    to_run: int  # episodes
    finished: int
    ended: str
    load_1min_end: float
    wall_s: float
    run: str  # the run directory
    simulator_revision: int | None
    machines: list[str]
    routes: int  # episodes of the leg's agents in episodes.jsonl
    steps: int
    simulated_s: float
    network: bool  # an agent of the leg drives a network

    @property
    def wall_h(self) -> float:
        return self.wall_s / 3600

    def block_row(self) -> str:
        return (f"| {', '.join(self.agents)} | {self.simulator_revision} | {self.workers} | {self.finished} of "
                f"{self.to_run} | {self.wall_h:.2f} | {self.simulated_s / self.wall_s:.1f}x | {self.load_1min_start} "
                f"/ {self.load_1min_end} |")

    def whole_network_suite(self) -> bool:
        """One network agent's full suite in this one leg, from start to end."""
        return (self.network and len(self.agents) == 1
                and self.finished == self.to_run == FULL_SUITE_ROUTES)


class SuiteTime(RecordList[SuiteLeg]):
    """benchmarks/suite_time_results.json: every leg of the run directories, in the order they were given."""

    ROW = SuiteLeg

    def fastest_whole_suite(self) -> SuiteLeg | None:
        whole = [leg for leg in self.rows if leg.whole_network_suite()]
        return min(whole, key=lambda leg: leg.wall_s) if whole else None

    def met_goal(self) -> bool | None:
        """Whether the fastest whole network suite took at most GOAL_H; None without one."""
        best = self.fastest_whole_suite()
        return None if best is None else best.wall_h <= GOAL_H

    def page(self, command: str) -> str:
        """benchmarks/suite_time_results.md (`command`: the benchmark's command line)."""
        lines = ["# Closed-loop suites: wall time", "", f"`{command}`", "",
                 "| run | agents | workers | episodes finished / to run | steps | wall h | simulated / wall | "
                 "load (1 min) start / end | started (UTC) |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        lines += [f"| `{leg.run}` | {', '.join(leg.agents)} | {leg.workers} | {leg.finished} / {leg.to_run} | "
                  f"{leg.steps:,} | {leg.wall_h:.2f} | {leg.simulated_s / leg.wall_s:.1f}x | {leg.load_1min_start} / "
                  f"{leg.load_1min_end} | {leg.started[:16].replace('T', ' ')} |" for leg in self.rows]
        machines = sorted({machine for leg in self.rows for machine in leg.machines})
        lines += ["", f"Machines: {'; '.join(machines) or 'not recorded'}. Simulator revisions: "
                  f"{', '.join(str(r) for r in sorted({leg.simulator_revision for leg in self.rows}))}."]
        best = self.fastest_whole_suite()
        if best is not None:
            lines += ["", f"One network agent's full suite ({FULL_SUITE_ROUTES} routes, one leg from start to end): "
                      f"{best.wall_h:.2f} h with {best.workers} workers ({', '.join(best.agents)}); "
                      f"the goal, at most {GOAL_H:.0f} h: **{'met' if self.met_goal() else 'not met'}**."]
        return "\n".join(lines) + "\n"

    def block(self) -> str:
        """The docs' table: each leg's wall time and how much faster than real time it simulated."""
        return "\n".join(["| agents | simulator revision | workers | routes | wall h | simulated / wall | load (1 min) "
                          "start / end |", "| --- |" + " --- |" * 6, *(leg.block_row() for leg in self.rows)])
