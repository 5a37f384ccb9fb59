"""The accuracy gate's verdicts as markdown: the pooled frames, every path, every bag."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from msfsu_perception.gate_verdicts import MAX_MIOU_DROP_POINTS, MAX_STEER_MAE_RISE, BagComparison, GateResult


def held_out_lines(held_out: Mapping[str, Any]) -> list[str]:
    """Frames per navigation command of each held-out bag, then of the pooled frames."""
    lines = ["| held-out bag | frames | LEFT | RIGHT | STRAIGHT | LANE_FOLLOW | mean abs steer (expert) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for bag in held_out["bags"]:
        commands = bag["commands"]
        lines.append(f"| {bag['bag']} | {bag['frames']} | {commands['LEFT']} | {commands['RIGHT']} | "
                     f"{commands['STRAIGHT']} | {commands['LANE_FOLLOW']} | {bag['mean_abs_steer']:.4f} |")
    commands = held_out["commands"]
    lines.append(f"| **pooled** | {held_out['frames']} | {commands['LEFT']} | {commands['RIGHT']} | "
                 f"{commands['STRAIGHT']} | {commands['LANE_FOLLOW']} | |")
    return lines


def _change_cells(result: GateResult | BagComparison) -> str:
    reference, candidate = result.reference, result.candidate
    miou = "-" if reference.mean_iou is None else f"{reference.mean_iou:.4f} -> {candidate.mean_iou:.4f}"
    return (f"{miou} | {result.miou_drop_points:.2f} | {reference.steer_mae:.4f} -> {candidate.steer_mae:.4f} | "
            f"{result.steer_mae_change:+.5f} | {result.steer_mae_rise:+.1%}")


def _path_rows(results: Sequence[GateResult]) -> list[str]:
    rows = []
    for result in results:
        agreement = "-" if result.class_agreement is None else f"{result.class_agreement:.4f}"
        rows.append(f"| {result.backend} {result.precision} | {result.frames} | {_change_cells(result)} | "
                    f"{result.steer_agreement_mae:.4f} | {agreement} | {'pass' if result.passed else 'FAIL'} |")
    return rows


def _build_lines(results: Sequence[GateResult]) -> list[str]:
    lines = []
    for result in (r for r in results if r.build):
        kept = ", ".join(result.build["keep_float"]) or "nothing"
        lines += ["", f"{result.backend} int8 built from calibration {result.build['calibration']} and recipe "
                      f"{result.build['recipe']} (kept in float: {kept})"]
    return lines


def _per_bag_rows(results: Sequence[GateResult]) -> list[str]:
    return [f"| {result.backend} {result.precision} | {bag.bag} | {bag.frames} | {_change_cells(bag)} | "
            f"{'pass' if bag.passed else 'fail'} |" for result in results for bag in result.per_bag]


def gate_lines(checkpoint: Path, results: Sequence[GateResult], held_out: Mapping[str, Any]) -> list[str]:
    """The pooled verdicts, then every path on every bag (absolute and relative changes)."""
    return [f"Accuracy gate of {checkpoint} on {len(held_out['bags'])} held-out bags, frames pooled "
            f"({held_out['frames']} frames, {held_out['turn_frames']} of them LEFT/RIGHT): pass = mIoU drop <= "
            f"{MAX_MIOU_DROP_POINTS} point and steer MAE rise <= {MAX_STEER_MAE_RISE:.0%} vs torch fp32", "",
            *held_out_lines(held_out), "",
            "| backend / precision | frames | mIoU ref -> cand | drop (points) | steer MAE ref -> cand | change | "
            "rise | steer |cand - ref| | class agreement | gate |",
            "|---|---:|---|---:|---|---:|---:|---:|---:|---|", *_path_rows(results), *_build_lines(results),
            "", "Per bag (informative; the pooled frames decide):", "",
            "| backend / precision | bag | frames | mIoU ref -> cand | drop (points) | steer MAE ref -> cand | "
            "change | rise | alone |", "|---|---|---:|---|---:|---|---:|---:|---|", *_per_bag_rows(results)]
