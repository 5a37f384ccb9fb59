"""The GPU record (benchmarks/gpu.py -> benchmarks/gpu_results.json): the network per path, a camera frame end to end
per stage, and the gate of the GPU precisions against torch fp32 on the CPU.

Rules:
- A latency is msfsu_evaluation.metrics.LatencySummary with its ms to 3 decimals.
- The gate's rows are the verdicts stored in the checkpoint's GPU gate record (`recorded`, relative to the
  repository), so `benchmarks/gpu.py --from-record` rewrites them without a GPU; None when the run skipped the gate.
- A missing value (the MSF variant's mIoU, a path a model was not timed on) renders as "–".
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from dataclasses import fields as dataclass_fields
from typing import Any, ClassVar

from msfsu_evaluation.records._json import JsonRow

PAGE = "benchmarks/gpu_results.md"
FRAME_STAGES = ("preprocess", "network + outputs back", "frame")  # a camera frame's stages, as the JSON names them
WHOLE_CALL = "numpy in, numpy out"  # the measure of a network call the node makes


@dataclass(kw_only=True)
class GpuEnvironment(JsonRow):
    gpu: str
    torch: str
    cuda: str
    cpus: int
    load_before: float  # 1-min load average
    load_after: float


@dataclass(kw_only=True)
class Latency(JsonRow):
    frames: int
    p50_ms: float
    p95_ms: float
    max_ms: float
    mean_ms: float


@dataclass(kw_only=True)
class NetworkCall:
    """One model on one path, batch 1: the whole call (WHOLE_CALL) or a CUDA graph's replay alone; the JSON row
    holds the latency's keys beside the others."""

    model: str
    path: str  # "eager fp32", "graph <precision>"
    measure: str
    latency: Latency

    @classmethod
    def from_dict(cls, row: dict[str, Any]) -> NetworkCall:
        latency = Latency.from_dict({field.name: row[field.name] for field in dataclass_fields(Latency)})
        return cls(model=row["model"], path=row["path"], measure=row["measure"], latency=latency)

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, "path": self.path, "measure": self.measure, **self.latency.to_dict()}

    def cell(self) -> str:
        return f"{self.latency.p50_ms:.2f} ms ({1e3 / self.latency.p50_ms:.0f} Hz)"


@dataclass(kw_only=True)
class CameraFrame:
    """A camera frame as the node runs it, each stage timed with synchronisation after it."""

    KEYS: ClassVar[tuple[str, ...]] = ("model", "precision", "camera", "preprocessing on")

    model: str
    precision: str
    camera: str  # WxH
    preprocessing_on: str  # "gpu" or "cpu"
    stages: dict[str, Latency]  # FRAME_STAGES -> latency

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> CameraFrame:
        model, precision, camera, where = (fields[key] for key in cls.KEYS)
        return cls(model=model, precision=precision, camera=camera, preprocessing_on=where,
                   stages={stage: Latency.from_dict(fields[stage]) for stage in FRAME_STAGES})

    def to_dict(self) -> dict[str, Any]:
        named = dict(zip(self.KEYS, (self.model, self.precision, self.camera, self.preprocessing_on)))
        return {**named, **{stage: latency.to_dict() for stage, latency in self.stages.items()}}


@dataclass(kw_only=True)
class GpuGatePath(JsonRow):
    path: str  # "<backend>/<precision> (cuda)"
    frames: int
    steer_mae_reference: float
    steer_mae: float
    steer_mae_rise: float
    miou_reference: float | None
    miou: float | None
    miou_drop_points: float
    steer_agreement_mae: float
    class_agreement: float | None
    passed: bool

    def page_row(self) -> str:
        miou = "–" if self.miou is None else f"{100 * self.miou_reference:.2f} -> {100 * self.miou:.2f}"
        agreement = "–" if self.class_agreement is None else f"{100 * self.class_agreement:.3f} %"
        return (f"| {self.path} | {self.steer_mae_reference:.4f} -> {self.steer_mae:.4f} | "
                f"{100 * self.steer_mae_rise:+.2f} % | {miou} | {self.miou_drop_points:+.3f} | "
                f"{self.steer_agreement_mae:.5f} | {agreement} | {'yes' if self.passed else 'no'} |")

    def block_row(self) -> str:
        return (f"| {self.path} | {100 * self.steer_mae_rise:+.2f} % | {self.miou_drop_points:+.3f} | "
                f"{100 * self.class_agreement:.3f} % | {'yes' if self.passed else 'no'} |")


@dataclass(kw_only=True)
class GpuGate:
    held_out: dict[str, Any]  # deploy.scoring.describe_held_out of the frames
    recorded: str | None  # the GPU gate record the rows come from
    paths: list[GpuGatePath]

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> GpuGate:
        return cls(**{**fields, "paths": [GpuGatePath.from_dict(path) for path in fields["paths"]]})

    def bags(self) -> str:
        return ", ".join(bag["bag"] for bag in self.held_out["bags"])


@dataclass(kw_only=True)
class GpuRecord:
    date: str  # the run's end
    command: str
    environment: GpuEnvironment
    network: list[NetworkCall]
    end_to_end: list[CameraFrame]
    gate: GpuGate | None

    @classmethod
    def from_json(cls, text: str) -> GpuRecord:
        fields: dict[str, Any] = json.loads(text)
        return cls(date=fields["date"], command=fields["command"],
                   environment=GpuEnvironment.from_dict(fields["environment"]),
                   network=[NetworkCall.from_dict(row) for row in fields["network"]],
                   end_to_end=[CameraFrame.from_dict(row) for row in fields["end_to_end"]],
                   gate=None if fields["gate"] is None else GpuGate.from_dict(fields["gate"]))

    def to_json(self) -> str:
        fields = {"date": self.date, "command": self.command, "environment": self.environment.to_dict(),
                  "network": [row.to_dict() for row in self.network],
                  "end_to_end": [row.to_dict() for row in self.end_to_end],
                  "gate": None if self.gate is None else asdict(self.gate)}
        return json.dumps(fields, indent=1) + "\n"

    def page(self) -> str:
        """benchmarks/gpu_results.md: every network row, every camera frame, the gate's verdicts."""
        env = self.environment
        lines = ["# The perception network on a CUDA GPU", "",
                 f"{env.gpu}, torch {env.torch} (CUDA {env.cuda}), {env.cpus} CPUs; load average {env.load_before} "
                 f"before, {env.load_after} after; {self.date}; `{self.command}`", "",
                 "## Network, batch 1 (ms per call)", "",
                 "| model | path | measure | p50 | p95 | max | Hz (p50) |",
                 "| --- | --- | --- | ---: | ---: | ---: | ---: |"]
        lines += [f"| {r.model} | {r.path} | {r.measure} | {r.latency.p50_ms:.2f} | {r.latency.p95_ms:.2f} | "
                  f"{r.latency.max_ms:.2f} | {1e3 / r.latency.p50_ms:.0f} |" for r in self.network]
        lines += ["", "## A camera frame, as the node runs it (ms, p50 / p95; synchronised after each stage)", "",
                  "| model | precision | camera | preprocessing on | preprocess | network + outputs back | frame |",
                  "| --- | --- | --- | --- | ---: | ---: | ---: |"]
        for row in self.end_to_end:
            cells = " | ".join(f"{row.stages[s].p50_ms:.2f} / {row.stages[s].p95_ms:.2f}" for s in FRAME_STAGES)
            lines.append(f"| {row.model} | {row.precision} | {row.camera} | {row.preprocessing_on} | {cells} |")
        return "\n".join(lines + self._gate_lines()) + "\n"

    def _gate_lines(self) -> list[str]:
        if self.gate is None:
            return []
        lines = ["", f"## Accuracy gate of the GPU precisions ({self.gate.held_out['frames']} held-out frames of "
                 f"{self.gate.bags()}; reference torch fp32 on the CPU)", "",
                 "| path | steer MAE (ref -> path) | rise | mIoU (ref -> path) | drop, points | steer agreement MAE | "
                 "class agreement | passed |", "| --- | --- | ---: | --- | ---: | ---: | ---: | --- |",
                 *(path.page_row() for path in self.gate.paths)]
        if self.gate.recorded:
            lines += ["", f"The verdicts stored in `{self.gate.recorded}` (this table is generated from them: "
                      "`python benchmarks/gpu.py --from-record`)."]
        return lines

    def block(self) -> str:
        """The docs' table: the network per path (the whole call) and the default model's fp16 camera frame."""
        calls = [row for row in self.network if row.measure == WHOLE_CALL]
        paths = list(dict.fromkeys(row.path for row in calls))
        rows = ["| model | " + " | ".join(paths) + " |", "| --- |" + " ---: |" * len(paths)]
        for model in dict.fromkeys(row.model for row in calls):
            cells = {row.path: row.cell() for row in calls if row.model == model}
            rows.append(f"| {model} | " + " | ".join(cells.get(path, "–") for path in paths) + " |")
        rows += ["", "| camera frame (default model, fp16) | preprocessing on | preprocess | network + outputs back | "
                 "frame p50 / p95 |", "| --- | --- | ---: | ---: | ---: |"]
        rows += [f"| {row.camera} | {row.preprocessing_on} | {row.stages['preprocess'].p50_ms:.2f} ms | "
                 f"{row.stages['network + outputs back'].p50_ms:.2f} ms | {row.stages['frame'].p50_ms:.2f} / "
                 f"{row.stages['frame'].p95_ms:.2f} ms |" for row in self.end_to_end if row.precision == "fp16"]
        env = self.environment
        return ("\n".join(rows) + f"\n\n{env.gpu}, torch {env.torch} (CUDA {env.cuda}), {env.cpus} CPUs, load "
                f"average {env.load_before} before; {self.date}: `{self.command}` ([{PAGE}]({PAGE}))")

    def gate_block(self) -> str:
        """The docs' table of the GPU precisions' gate."""
        if self.gate is None:
            raise ValueError("this GPU record has no gate: run benchmarks/gpu.py --from-record for its verdicts")
        rows = ["| path | steer MAE rise | mIoU drop, points | class agreement with the reference | passed |",
                "| --- | ---: | ---: | ---: | --- |", *(path.block_row() for path in self.gate.paths)]
        return ("\n".join(rows) + f"\n\n{self.gate.held_out['frames']} frames of `bags/{self.gate.bags()}`; reference "
                "torch fp32 on the CPU.")
