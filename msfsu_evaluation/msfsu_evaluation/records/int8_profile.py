"""The int8 layer profile (benchmarks/int8_profile.py -> benchmarks/int8_profile_results.json): OpenVINO's per-layer
counters of a checkpoint's int8 model, exported as deployed and as the torch network is.

Rules:
- A kind is "<layer type> (<kernel>)"; a kernel whose name holds `f32` runs in float, one with `I8` runs int8.
- Per graph, `by_kind` lists the kinds of at least 0.005 ms, slowest first, and `top_layers` the slowest layers.
- The page lists every kind of either graph by its longest time in any graph, then by its time over all
  graphs, then by name.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import Any

from msfsu_evaluation.records._json import CpuRun, JsonRow

AS_IN_TORCH, DEPLOYED = "as in torch", "deployed"  # the graphs, as the record names them


@dataclass(kw_only=True)
class KindTime(JsonRow):
    kind: str
    ms: float  # per inference

    @property
    def in_float(self) -> bool:
        return "f32" in self.kind


@dataclass(kw_only=True)
class LayerTime(JsonRow):
    layer: str
    kind: str
    ms: float


@dataclass(kw_only=True)
class GraphProfile:
    wall_p50_ms: float  # counters off
    layers_ms: float  # the layers' time per inference, counters on
    by_kind: list[KindTime]
    top_layers: list[LayerTime]

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> GraphProfile:
        return cls(wall_p50_ms=fields["wall_p50_ms"], layers_ms=fields["layers_ms"],
                   by_kind=[KindTime.from_dict(row) for row in fields["by_kind"]],
                   top_layers=[LayerTime.from_dict(row) for row in fields["top_layers"]])

    def kind_ms(self, kind: str) -> float | None:
        return next((row.ms for row in self.by_kind if row.kind == kind), None)

    def block_cell(self) -> str:
        in_float = sum(row.ms for row in self.by_kind if row.in_float)
        return f"{self.wall_p50_ms:.1f} ms ({in_float:.1f} ms of {self.layers_ms:.1f} in float kernels)"


@dataclass(kw_only=True)
class ProfiledModel:
    checkpoint: str
    checkpoint_digest: str
    load_before: float  # 1-min load average
    graphs: dict[str, GraphProfile]  # DEPLOYED, AS_IN_TORCH

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> ProfiledModel:
        return cls(**{**fields, "graphs": {name: GraphProfile.from_dict(graph)
                                           for name, graph in fields["graphs"].items()}})

    def page_lines(self) -> list[str]:
        """Both graphs side by side: wall and layer time, each kind slowest first, then the slowest layers."""
        graphs = self.graphs
        names = list(graphs)
        lines = [f"## {self.checkpoint} ({self.checkpoint_digest}); load before {self.load_before}", "",
                 "| | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names),
                 "| wall p50 per inference (counters off) | "
                 + " | ".join(f"{graphs[n].wall_p50_ms:.2f} ms" for n in names) + " |",
                 "| layers' time per inference (counters on) | "
                 + " | ".join(f"{graphs[n].layers_ms:.2f} ms" for n in names) + " |"]
        kinds = sorted({row.kind for n in names for row in graphs[n].by_kind}, key=self._kind_order)
        for kind in kinds:
            cells = [_ms_cell(graphs[n].kind_ms(kind)) for n in names]
            lines.append(f"| {kind} | " + " | ".join(cells) + " |")
        for n in names:
            lines += ["", f"Slowest layers, {n}: " + "; ".join(
                f"`{row.layer}` {row.kind} {row.ms:.2f} ms" for row in graphs[n].top_layers)]
        return lines + [""]

    def _kind_order(self, kind: str) -> tuple[float, float, str]:
        """Slowest first by the kind's longest time in any graph, then by its time over all graphs, then by name."""
        times = [graph.kind_ms(kind) or 0.0 for graph in self.graphs.values()]
        return -max(times), -sum(times), kind

    def block_row(self) -> str:
        torch_graph, deployed = self.graphs[AS_IN_TORCH], self.graphs[DEPLOYED]
        return (f"| `{self.checkpoint}` | {torch_graph.block_cell()} | {deployed.block_cell()} | "
                f"{torch_graph.wall_p50_ms / deployed.wall_p50_ms:.2f}x | {self.load_before} |")


@dataclass(kw_only=True)
class Int8Profile(CpuRun):
    """`date` is the run's start; `iterations` inferences per graph and measurement."""

    models: list[ProfiledModel]

    @classmethod
    def from_json(cls, text: str) -> Int8Profile:
        fields: dict[str, Any] = json.loads(text)
        return cls(**{**fields, "models": [ProfiledModel.from_dict(model) for model in fields["models"]]})

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1) + "\n"

    def page(self) -> str:
        """benchmarks/int8_profile_results.md."""
        lines = [f"# int8 layer profile {self.date}", "", f"Made by `{self.command}`", "",
                 f"{self.machine}, {self.threads} threads, {self.iterations} inferences per graph", ""]
        return "\n".join(lines + [line for model in self.models for line in model.page_lines()])

    def block(self) -> str:
        """The docs' table: int8 wall time and the part in float kernels, per exported graph."""
        rows = ["| checkpoint | OpenVINO int8, exported as in torch | exported as deployed | speed-up | load (1 min) "
                "before |", "| --- | --- | --- | --- | --- |", *(model.block_row() for model in self.models)]
        return "\n".join(rows) + f"\n\n{self.made_by()}"


def _ms_cell(ms: float | None) -> str:
    return "-" if ms is None else f"{ms:.2f} ms"
