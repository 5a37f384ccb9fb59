"""The gate verdict record (`msfsu-gate`, benchmarks/perception.py --record-gate, benchmarks/gpu.py --record-gate ->
<checkpoint>.deploy/<hash>-gate.json, -gate-cuda.json on a GPU): every fast path scored against torch fp32 on the
pooled held-out frames.

Rules:
- msfsu_perception.gate_verdicts owns the format: it writes the record (record_gate_results) and reads it for the
  node (gate_verdicts, gated_precisions); this type reads the scores through its results_from_record and writes
  back what record_gate_results writes.
- A verdict shown is the one stored (`passed`): the one the node acts on.
- The gate's pages (benchmarks/perception_gate_results*.md) are deploy.gate_report's, from these results.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from msfsu_perception.gate_verdicts import GateResult, results_from_record

# the committed gate records, in the docs' order: the shipped models, then the paper network's short run
GATE_RECORDS = ("models/msfsu_default.pt.deploy/*-gate.json", "models/msf.pt.deploy/*-gate.json",
                "models/su.pt.deploy/*-gate.json", "benchmarks/gate_records/*-gate.json")


@dataclass(frozen=True)
class GateVerdict:
    """One path's scores and the verdict stored with them."""

    result: GateResult
    passed: bool

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self.result), "passed": self.passed}

    def block_row(self, checkpoint: str, held_out: dict[str, Any]) -> str:
        result = self.result
        reference, candidate = result.reference, result.candidate
        miou = ("-" if reference.mean_iou is None else f"{reference.mean_iou:.4f} -> {candidate.mean_iou:.4f} "
                f"(drop {result.miou_drop_points:.2f})")
        return (f"| {checkpoint} | {held_out['frames']} ({held_out['turn_frames']}) | {result.backend} "
                f"{result.precision} | {miou} | {reference.steer_mae:.4f} -> {candidate.steer_mae:.4f} (change "
                f"{result.steer_mae_change:+.4f}, rise {result.steer_mae_rise:+.1%}) | "
                f"{'pass' if self.passed else 'FAIL'} |")


@dataclass(kw_only=True)
class GateRecord:
    format: int
    held_out: dict[str, Any]  # deploy.scoring.describe_held_out of the pooled frames
    paths: dict[str, GateVerdict]  # "<backend>/<precision>" -> verdict, in the order scored
    checkpoint: str  # as its caller named it; the file name holds its content hash
    command: str | None = None  # how to run the gate again

    @classmethod
    def from_json(cls, text: str) -> GateRecord:
        fields: dict[str, Any] = json.loads(text)
        verdicts = [GateVerdict(result, entry["passed"])
                    for result, entry in zip(results_from_record(fields), fields["paths"].values())]
        return cls(**{**fields, "paths": dict(zip(fields["paths"], verdicts))})

    def to_json(self) -> str:
        fields = {**asdict(self), "paths": {key: verdict.to_dict() for key, verdict in self.paths.items()}}
        if self.command is None:
            del fields["command"]
        return json.dumps(fields, indent=1) + "\n"

    def results(self) -> list[GateResult]:
        return [verdict.result for verdict in self.paths.values()]

    def block_rows(self) -> list[str]:
        return [verdict.block_row(self.checkpoint, self.held_out) for verdict in self.paths.values()]


def read_gate_records(root: Path) -> list[GateRecord]:
    """The committed gate records under `root` (GATE_RECORDS), each pattern's files by name."""
    return [GateRecord.from_json(path.read_text()) for pattern in GATE_RECORDS for path in sorted(root.glob(pattern))]


def gate_block(records: Sequence[GateRecord]) -> str:
    """The docs' table: the pooled verdict of every fast path per checkpoint."""
    rows = ["| checkpoint | held-out frames (LEFT/RIGHT) | path | mIoU torch fp32 -> path (drop, points) | "
            "steer MAE torch fp32 -> path | verdict |", "| --- | --- | --- | --- | --- | --- |"]
    return "\n".join(rows + [row for record in records for row in record.block_rows()])
