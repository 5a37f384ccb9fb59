"""The perception speed record (benchmarks/perception.py -> benchmarks/perception_results.json, and
perception_results_avx2.json: the same benchmark on a CPU with AVX2 only): per model the p50/p95 of every timed path,
the gate verdicts it counted and the fastest path that passed; the end-to-end runs through DDS.

Rules:
- A path's Hz is 1000 / its p50 ms as stored (the record's rounded `hz` can round the other way).
- A path the run could not time (not installed, unsupported by the CPU) is absent from `paths`; a model with random
  weights has no checkpoint, no verdicts and no fastest gated path (None).
- The page (benchmarks/perception_results*.md) is written by the benchmark as it runs: it also holds what the record
  does not (why a path was not timed, preprocessing time, the gate's report, the load before each section).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from msfsu_evaluation.records._json import CpuRun, JsonRow

SHIPPED_MODEL = "models/msfsu_default.pt"
PAGE_AVX2 = "benchmarks/perception_results_avx2.md"


def hz_text(p50_ms: float) -> str:
    return f"{1e3 / p50_ms:.0f} Hz"


@dataclass(kw_only=True)
class PathLatency(JsonRow):
    p50_ms: float
    p95_ms: float

    def cell(self) -> str:
        return f"{self.p50_ms:.1f} ms ({hz_text(self.p50_ms)})"


@dataclass(kw_only=True)
class GatedPath(JsonRow):
    """The fastest path that passed the gate, torch fp32 (the reference) included."""

    path: str  # "<backend> <precision>"
    p50_ms: float
    hz: float
    speedup_vs_torch_fp32: float

    def summary(self) -> str:
        return f"{self.path}: {self.p50_ms:.1f} ms, {hz_text(self.p50_ms)}, {self.speedup_vs_torch_fp32:.1f}x"


@dataclass(kw_only=True)
class PerceptionModel:
    model: str  # "<role> <backbone> <H>x<W>"
    checkpoint: str | None  # None: random weights
    checkpoint_digest: str | None
    load_average_before: list[float]  # 1, 5, 15 min
    paths: dict[str, PathLatency]  # path label -> latency, in the order timed
    verdicts: dict[str, bool]  # "<backend> <precision>" -> passed
    verdict_source: str
    fastest_gated: GatedPath | None

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> PerceptionModel:
        best = fields["fastest_gated"]
        return cls(**{**fields, "paths": {label: PathLatency.from_dict(p) for label, p in fields["paths"].items()},
                      "fastest_gated": None if best is None else GatedPath.from_dict(best)})

    def block_row(self) -> str:
        def cell(label: str) -> str:
            latency = self.paths.get(label)
            return "-" if latency is None else latency.cell()

        gated = "-" if self.fastest_gated is None else f"**{self.fastest_gated.summary()}**"
        return (f"| {self.model} (`{self.checkpoint or 'random'}`) | {cell('torch fp32')} | {cell('openvino fp32')} | "
                f"{cell('openvino bf16')} | {cell('openvino int8')} | {gated} | {self.load_average_before[0]} |")


@dataclass(kw_only=True)
class EndToEndRun(JsonRow):
    """Camera stamp -> VehicleControl through DDS; p50/p95 None when no control arrived."""

    backend: str
    precision: str
    sent: int
    dropped: int
    p50_ms: float | None
    p95_ms: float | None


@dataclass(kw_only=True)
class PerceptionRecord(CpuRun):
    """`date` is the run's end."""

    torch: str
    models: list[PerceptionModel]
    end_to_end: list[EndToEndRun]

    @classmethod
    def from_json(cls, text: str) -> PerceptionRecord:
        fields: dict[str, Any] = json.loads(text)
        return cls(**{**fields, "models": [PerceptionModel.from_dict(model) for model in fields["models"]],
                      "end_to_end": [EndToEndRun.from_dict(run) for run in fields["end_to_end"]]})

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1) + "\n"

    def block(self) -> str:
        """The docs' table: per model the main paths and the fastest one that passed the gate."""
        rows = ["| model (weights) | torch fp32 | OpenVINO fp32 | OpenVINO bf16 | OpenVINO int8 | fastest path that "
                "passed the gate | load (1 min) before |", "| --- | --- | --- | --- | --- | --- | --- |"]
        rows += [model.block_row() for model in self.models]
        return "\n".join(rows) + f"\n\n{self.made_by()}"

    def headline(self) -> str:
        """The README's perception line: the shipped model's fastest gated path."""
        best = next(m for m in self.models if m.checkpoint == SHIPPED_MODEL).fastest_gated
        return (f"- **Perception**, the shipped model on {self.machine} ({self.threads} threads), batch 1: "
                f"{best.path} {best.p50_ms:.1f} ms ({hz_text(best.p50_ms)}), {best.speedup_vs_torch_fp32:.1f}x torch "
                "fp32 ([deployment.md](docs/deployment.md#latency-on-the-cpu)).")


@dataclass(frozen=True)
class PerceptionMachines:
    """The benchmark on the machine of the other records and, when measured, on a CPU with AVX2 only (no AVX-512,
    VNNI, bf16 or AMX: the int8 path on plain AVX2)."""

    main: PerceptionRecord
    avx2: PerceptionRecord | None

    def block(self) -> str:
        """The main machine's table, then the AVX2 machine's (a table of its own: another machine)."""
        blocks = [self.main.block()]
        if self.avx2 is not None:
            blocks.append(f"On a CPU with AVX2 only (no AVX-512, VNNI, bf16 or AMX; `{PAGE_AVX2}`):\n\n"
                          f"{self.avx2.block()}")
        return "\n\n".join(blocks)


def read_perception(directory: Path) -> PerceptionMachines:
    """perception_results.json and, when there is one, perception_results_avx2.json of `directory`."""
    avx2 = directory / "perception_results_avx2.json"
    return PerceptionMachines(PerceptionRecord.from_json((directory / "perception_results.json").read_text()),
                              PerceptionRecord.from_json(avx2.read_text()) if avx2.exists() else None)
