"""The lockstep record (benchmarks/lockstep.py -> benchmarks/lockstep_results.json): per route, the simulator alone
with the expert in-process, then the network through the node graph in lockstep.

Rules:
- A per-frame time is summarised as msfsu_common.benchmark_run.percentiles with "mean", "p50" and "p95" (ms); a
  segment with no answered frame is absent from the JSON and rendered as "-".
- The stage rows are msfsu_evaluation.latency_trace.stage_rows of the answered frames.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Self

from msfsu_evaluation.records._json import JsonRow, RecordList, without_absent

STEP_STATISTICS = ("mean", "p50", "p95")  # of a per-frame time, ms
# the graph's segments: JSON key -> field
_SEGMENT_KEYS = {"publish frame ms": "publish_frame_ms", "round trip ms": "round_trip_ms"}
_SEGMENT_NAMES = {name: key for key, name in _SEGMENT_KEYS.items()}


@dataclass(kw_only=True)
class ExpertDrive(JsonRow):
    """The route driven by the expert in-process: the simulator alone."""

    frames: int
    frames_per_s: float
    reset_s: float
    simulator_step_ms: dict[str, float]
    load_1min: float


@dataclass(kw_only=True)
class GraphDrive(JsonRow):
    """The route driven by the network through the graph, one frame at a time."""

    OPTIONAL = tuple(_SEGMENT_NAMES)

    frames: int
    frames_per_s: float
    reset_s: float
    unanswered_frames: int
    load_1min: float
    simulator_step_ms: dict[str, float]
    publish_frame_ms: dict[str, float] | None = None  # publish_frame's own time
    round_trip_ms: dict[str, float] | None = None  # publish started -> the frame's VehicleControl taken
    stages: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> Self:
        return cls(**{_SEGMENT_KEYS.get(key, key): value for key, value in fields.items()})

    def to_dict(self) -> dict[str, Any]:
        return {_SEGMENT_NAMES.get(name, name): value for name, value in super().to_dict().items()}


@dataclass(kw_only=True)
class LockstepRoute(JsonRow):
    """One route; `graph` is None until the graph has driven it."""

    OPTIONAL = ("graph",)

    route: str
    town: str
    weather: str
    traffic: str
    expert_in_process: ExpertDrive
    graph: GraphDrive | None = None

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> Self:
        graph = fields.get("graph")
        return cls(**{**fields, "expert_in_process": ExpertDrive.from_dict(fields["expert_in_process"]),
                      "graph": None if graph is None else GraphDrive.from_dict(graph)})

    def to_dict(self) -> dict[str, Any]:
        fields = {**asdict(self), "graph": None if self.graph is None else self.graph.to_dict()}
        return without_absent(fields, self.OPTIONAL)

    def driven(self) -> GraphDrive:
        """`graph`, which every committed route has; an error before the graph drove the route."""
        if self.graph is None:
            raise ValueError(f"route {self.route} was not driven through the graph")
        return self.graph


@dataclass(frozen=True)
class LockstepSetup:
    """What the page says of the run that the record does not hold."""

    date_end: str
    command: str
    width: int
    height: int
    checkpoint: str
    steps: int  # most frames per route
    graph_start_s: float  # launch, torch import, model load


def _stats(stats: dict[str, float] | None) -> str:
    return "-" if stats is None else f"{stats['mean']} / {stats['p50']} / {stats['p95']}"


class LockstepResults(RecordList[LockstepRoute]):
    """benchmarks/lockstep_results.json: a row per route, in the order driven."""

    ROW = LockstepRoute

    def page(self, setup: LockstepSetup) -> str:
        """benchmarks/lockstep_results.md: frames/s per route, the per-frame times, then the stages' p50 / p95."""
        lines = [f"# Lockstep closed loop through the node graph ({setup.date_end})", "",
                 f"`{setup.command}`: {setup.width}x{setup.height} cameras, checkpoint `{setup.checkpoint}`, up to "
                 f"{setup.steps} frames per route; graph start (launch, torch import, model load) "
                 f"{setup.graph_start_s:.1f} s.", "",
                 "| route | town, weather, traffic | expert in-process (simulator only) frames/s | network through the "
                 "graph frames/s | frames | unanswered | reset s | load (1 min) |",
                 "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for r in self.rows:
            graph = r.driven()
            lines.append(f"| {r.route} | {r.town}, {r.weather}, {r.traffic} | {r.expert_in_process.frames_per_s} | "
                         f"{graph.frames_per_s} | {graph.frames} | {graph.unanswered_frames} | {graph.reset_s} | "
                         f"{graph.load_1min} |")
        lines += ["", "Per frame through the graph, ms (mean / p50 / p95):", "",
                  "| route | simulator step | publish frame | round trip |", "| --- | --- | --- | --- |"]
        lines += [f"| {r.route} | {_stats(r.driven().simulator_step_ms)} | {_stats(r.driven().publish_frame_ms)} | "
                  f"{_stats(r.driven().round_trip_ms)} |" for r in self.rows]
        lines += ["", "Where the round trip goes (stage marks of perception and control; the simulator is the camera "
                  "and the measurer), p50 / p95 ms:", "",
                  "| stage | " + " | ".join(r.route for r in self.rows) + " |", "| --- |" + " --- |" * len(self.rows)]
        names = list(dict.fromkeys(row["stage"] for r in self.rows for row in r.driven().stages))
        for name in names:
            rows = [next((row for row in r.driven().stages if row["stage"] == name), {}) for r in self.rows]
            lines.append(f"| {name} | " + " | ".join(f"{row['p50']} / {row['p95']}" if "p50" in row else "-"
                                                     for row in rows) + " |")
        return "\n".join(lines) + "\n"

    def block(self) -> str:
        """The docs' table: the simulator alone against the network through the graph, and the round trip."""
        rows = ["| route (traffic) | frames | simulator alone, frames/s | network through the graph, frames/s | "
                "graph round trip p50 / p95 ms | load (1 min) |", "| --- | --- | --- | --- | --- | --- |"]
        for r in self.rows:
            graph = r.driven()
            trip = graph.round_trip_ms or {}
            rows.append(f"| {r.route} ({r.traffic}) | {graph.frames} | {r.expert_in_process.frames_per_s} | "
                        f"{graph.frames_per_s} | {trip.get('p50', '-')} / {trip.get('p95', '-')} | {graph.load_1min} |")
        return "\n".join(rows)
