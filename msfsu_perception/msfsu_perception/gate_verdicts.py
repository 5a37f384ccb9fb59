"""The accuracy gate's verdicts: may a fast inference path (backend + precision) replace torch fp32?
Thresholds, the verdict, and the verdicts recorded per checkpoint.

A fast path may replace the reference only if, on a held-out bag, segmentation mIoU drops by at most
1 point and the steer MAE against the expert rises by at most 5 %. Results are recorded per checkpoint
content (`<checkpoint>.deploy/<hash>-gate.json`), so "auto" precision (inference.py) only ever uses a
path that passed on these very weights. Scoring the paths on a bag: msfsu_evaluation.gate_evaluation.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

from msfsu_perception.deploy_files import DeployFiles

MAX_MIOU_DROP_POINTS = 1.0  # percentage points of mIoU (0-100 scale)
MAX_STEER_MAE_RISE = 0.05  # relative rise of the steer MAE against the expert


@dataclass(frozen=True)
class HeldOutScores:
    """One inference path on the held-out frames."""

    steer_mae: float  # vs the expert's steer, normalised [-1, 1] units
    mean_iou: float | None  # [0, 1]; None for the MSF variant (no segmentation)


@dataclass(frozen=True)
class GateResult:
    backend: str
    precision: str
    frames: int
    reference: HeldOutScores  # torch fp32
    candidate: HeldOutScores
    steer_agreement_mae: float  # mean |candidate steer - reference steer|
    class_agreement: float | None  # share of pixels where both predict the same class

    @property
    def miou_drop_points(self) -> float:
        if self.reference.mean_iou is None or self.candidate.mean_iou is None:
            return 0.0
        return 100.0 * (self.reference.mean_iou - self.candidate.mean_iou)

    @property
    def steer_mae_rise(self) -> float:
        """Relative rise; a perfect reference (MAE 0) tolerates no error at all."""
        reference, candidate = self.reference.steer_mae, self.candidate.steer_mae
        if reference == 0.0:
            return 0.0 if candidate == 0.0 else math.inf
        return candidate / reference - 1.0

    @property
    def passed(self) -> bool:
        return self.miou_drop_points <= MAX_MIOU_DROP_POINTS and self.steer_mae_rise <= MAX_STEER_MAE_RISE


def _record_path(checkpoint: Path) -> Path:
    return DeployFiles(checkpoint).gate_record


def record_gate_results(checkpoint: Path, results: list[GateResult]) -> Path:
    """Add results to the checkpoint's gate record (replacing earlier ones of the same path)."""
    path = _record_path(checkpoint)
    records = json.loads(path.read_text()) if path.is_file() else {}
    for result in results:
        records[f"{result.backend}/{result.precision}"] = {**asdict(result), "passed": result.passed}
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.partial")
    temporary.write_text(json.dumps(records, indent=1))
    temporary.replace(path)
    return path


def gated_precisions(checkpoint: Path, backend: str) -> set[str]:
    """Precisions of `backend` that passed the gate on this checkpoint's current content."""
    path = _record_path(checkpoint)
    if not path.is_file():
        return set()
    records = json.loads(path.read_text())
    return {record["precision"] for record in records.values() if record["backend"] == backend and record["passed"]}
