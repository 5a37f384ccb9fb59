"""The accuracy gate's verdicts: may a fast inference path (backend + precision) replace torch fp32?
Thresholds, the verdict, and the verdicts recorded per checkpoint.

A fast path may replace the reference only if, on held-out frames, segmentation mIoU drops by at most
1 point and the steer MAE against the expert rises by at most 5 %. The frames are pooled from several
held-out bags (junction turns and traffic); the pooled scores decide, the per-bag scores are kept beside
them. Results are recorded per checkpoint content (`<checkpoint>.deploy/<hash>-gate.json`), so "auto"
precision (inference.py) only ever uses a path that passed on these very weights; an int8 verdict also names
what its model was built from (calibration frames + int8 recipe) and counts only while those are unchanged.
Scoring the paths on bags: msfsu_evaluation.deploy.scoring.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from msfsu_perception.deploy_files import DeployFiles
from msfsu_perception.int8_recipe import Int8Build

MAX_MIOU_DROP_POINTS = 1.0  # percentage points of mIoU (0-100 scale)
MAX_STEER_MAE_RISE = 0.05  # relative rise of the steer MAE against the expert
RECORD_FORMAT = 2  # {"held_out", "checkpoint", "command", "paths": {"backend/precision": verdict}}
REFERENCE = ("torch", "fp32")


@dataclass(frozen=True)
class HeldOutScores:
    """One inference path on the held-out frames."""

    steer_mae: float  # vs the expert's steer, normalised [-1, 1] units
    mean_iou: float | None  # [0, 1]; None for the MSF variant (no segmentation)


class _Changes:
    """Changes of a candidate's scores against the reference's (both attributes of the dataclass below)."""

    reference: HeldOutScores
    candidate: HeldOutScores

    @property
    def miou_drop_points(self) -> float:
        if self.reference.mean_iou is None or self.candidate.mean_iou is None:
            return 0.0
        return 100.0 * (self.reference.mean_iou - self.candidate.mean_iou)

    @property
    def steer_mae_change(self) -> float:
        """Absolute change of the steer MAE (normalised steer units)."""
        return self.candidate.steer_mae - self.reference.steer_mae

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


@dataclass(frozen=True)
class BagComparison(_Changes):
    """One held-out bag's share of a gate run (informative: the pooled frames decide)."""

    bag: str
    frames: int
    reference: HeldOutScores
    candidate: HeldOutScores
    steer_agreement_mae: float
    class_agreement: float | None


@dataclass(frozen=True)
class GateResult(_Changes):
    backend: str
    precision: str
    frames: int
    reference: HeldOutScores  # torch fp32
    candidate: HeldOutScores
    steer_agreement_mae: float  # mean |candidate steer - reference steer|
    class_agreement: float | None  # share of pixels where both predict the same class
    build: dict[str, Any] | None = None  # int8: Int8Build.to_dict() of the model that was scored
    per_bag: tuple[BagComparison, ...] = ()


def _record_path(checkpoint: Path, device: str = "cpu") -> Path:
    return DeployFiles(checkpoint).gate_record_of(device)


def gate_record(checkpoint: Path, device: str = "cpu") -> dict[str, Any]:
    """The checkpoint's gate record of one device's paths ({} when none is stored for its current content)."""
    path = _record_path(checkpoint, device)
    if not path.is_file():
        return {}
    record = json.loads(path.read_text())
    return record if record.get("format") == RECORD_FORMAT else {}


def record_gate_results(checkpoint: Path, results: list[GateResult], held_out: Mapping[str, Any] | None = None,
                        command: str | None = None, device: str = "cpu") -> Path:
    """Add results to the checkpoint's gate record (replacing earlier ones of the same path).

    held_out describes the frames (bags, frame counts, commands); verdicts from another held-out set are
    dropped, so a record never mixes frames. command: how to run the gate again.
    """
    path = _record_path(checkpoint, device)
    record = gate_record(checkpoint, device)
    held_out = dict(held_out or {})
    if not record or record.get("held_out") != held_out:
        record = {"format": RECORD_FORMAT, "held_out": held_out, "paths": {}}
    _add_results(record, checkpoint, results, command)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.partial")
    temporary.write_text(json.dumps(record, indent=1) + "\n")
    temporary.replace(path)
    return path


def run_record(checkpoint: Path, results: list[GateResult], held_out: Mapping[str, Any] | None = None,
               command: str | None = None) -> dict[str, Any]:
    """A gate record of these results alone, laid out as record_gate_results stores them (results_from_record reads
    it back): what `msfsu-gate --json` writes for a caller that reads the verdicts without recording them."""
    record: dict[str, Any] = {"format": RECORD_FORMAT, "held_out": dict(held_out or {}), "paths": {}}
    return _add_results(record, checkpoint, results, command)


def _add_results(record: dict[str, Any], checkpoint: Path, results: list[GateResult],
                 command: str | None) -> dict[str, Any]:
    """`record` with the checkpoint's name, the command and each result (replacing an earlier one of its path)."""
    record["checkpoint"] = str(checkpoint)  # as named by the caller; the file name holds its content hash
    if command is not None:
        record["command"] = command
    for result in results:
        record["paths"][f"{result.backend}/{result.precision}"] = {**asdict(result), "passed": result.passed}
    return record


def results_from_record(record: Mapping[str, Any]) -> list[GateResult]:
    """The GateResults a gate record stores (record_gate_results), in its order."""
    results = []
    for entry in record.get("paths", {}).values():
        per_bag = tuple(BagComparison(bag["bag"], bag["frames"], HeldOutScores(**bag["reference"]),
                                      HeldOutScores(**bag["candidate"]), bag["steer_agreement_mae"],
                                      bag["class_agreement"]) for bag in entry.get("per_bag", ()))
        results.append(GateResult(entry["backend"], entry["precision"], entry["frames"],
                                  HeldOutScores(**entry["reference"]), HeldOutScores(**entry["candidate"]),
                                  entry["steer_agreement_mae"], entry["class_agreement"], entry.get("build"), per_bag))
    return results


def gate_verdicts(checkpoint: Path, device: str = "cpu") -> dict[tuple[str, str], dict[str, Any]]:
    """{(backend, precision): recorded verdict} of this checkpoint's current content on `device`."""
    return {(entry["backend"], entry["precision"]): entry
            for entry in gate_record(checkpoint, device).get("paths", {}).values()}


def gated_precisions(checkpoint: Path, backend: str, int8_build: Int8Build | None = None,
                     device: str = "cpu") -> set[str]:
    """Precisions of `backend` that passed the gate on this checkpoint's current content.

    int8 counts only when `int8_build` (what its model would be built from now) is the one that was scored.
    """
    passed = set()
    for (entry_backend, precision), entry in gate_verdicts(checkpoint, device).items():
        if entry_backend != backend or not entry["passed"]:
            continue
        if precision == "int8" and (int8_build is None or not int8_build.matches(entry.get("build"))):
            continue
        passed.add(precision)
    return passed


def fastest_passing(p50_ms: Mapping[tuple[str, str], float], passed: Mapping[tuple[str, str], bool]
                    ) -> tuple[str, str] | None:
    """The fastest (lowest p50) path that passed the gate, torch fp32 (the reference) included; None if untimed.

    p50_ms: measured paths; passed: gate verdicts (paths without a verdict do not count, except the reference).
    """
    eligible = [path for path in p50_ms if path == REFERENCE or passed.get(path, False)]
    return min(eligible, key=lambda path: p50_ms[path]) if eligible else None
