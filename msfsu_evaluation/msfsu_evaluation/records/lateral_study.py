"""The lateral study's record (`python -m msfsu_evaluation.lateral_study` -> <out>/lateral_study.json) and its
page (<out>/README.md): the steer errors per command group and network, the paired differences against a reference
network, every branch on the turn approaches and the scene loss's share of the encoder's gradient.

Rules:
- An interval is a 95 % bootstrap interval over command runs, stored as [low, high].
- A paired difference is "shown" when its interval excludes 0 (verdict): which side it lies on, in words.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from typing import Any

from msfsu_common.road_option import RoadOption

RECORD_NAME = "lateral_study.json"
PAGE_NAME = "README.md"


@dataclass(frozen=True)
class SteerErrors:
    """One network's steer error on one group of frames."""

    network: str
    runtime: str  # "openvino/int8": what it ran on
    group: str
    frames: int
    runs: int
    mae: float
    mae_ci95: tuple[float, float]
    signed: float  # mean of network - expert (positive: right of the expert)
    signed_ci95: tuple[float, float]


@dataclass(frozen=True)
class PairedSteer:
    """A network's steer error minus the reference network's, on the same frames of a group."""

    network: str
    reference: str
    group: str
    frames: int
    mae_difference: float
    mae_difference_ci95: tuple[float, float]
    signed_difference: float
    signed_difference_ci95: tuple[float, float]


@dataclass(frozen=True)
class BranchSteer:
    """One branch of a network on the frames of one group, whatever command those frames had."""

    network: str
    group: str
    branch: str  # the RoadOption name whose branch answered
    frames: int
    signed: float  # mean of branch - expert
    signed_ci95: tuple[float, float]


def _side(interval: tuple[float, float], below: str, above: str) -> str | None:
    """`below` when the whole interval is below 0, `above` when above, None when it holds 0."""
    low, high = interval
    return below if high < 0 else above if low > 0 else None


def verdict(row: PairedSteer) -> str:
    """What the paired intervals show: "errs more, left of msf", or "no difference shown"."""
    parts = [_side(row.mae_difference_ci95, "errs less", "errs more"),
             _side(row.signed_difference_ci95, f"left of {row.reference}", f"right of {row.reference}")]
    shown = [part for part in parts if part]
    return ", ".join(shown) if shown else "no difference shown"


@dataclass(frozen=True)
class GradientShare:
    """The scene loss's gradient on the encoder against the control loss's, summed over the same frames."""

    network: str
    frames_of: str  # "all" or a RoadOption name
    frames: int
    control_norm: float
    scene_norm: float
    ratio: float  # scene_norm / control_norm
    cosine: float


@dataclass
class LateralStudy:
    """The record: what ran, on which frames, and what came out."""

    run: dict[str, Any]
    bags: dict[str, Any]
    networks: dict[str, dict[str, str]]  # name -> {"checkpoint", "runtime"}
    reference: str | None
    onset_share: float
    steer: list[SteerErrors] = field(default_factory=list)
    paired: list[PairedSteer] = field(default_factory=list)
    branches: list[BranchSteer] = field(default_factory=list)
    gradients: list[GradientShare] = field(default_factory=list)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1) + "\n"

    @classmethod
    def from_json(cls, text: str) -> LateralStudy:
        fields = json.loads(text)

        def rows(kind: type, items: Iterable[dict]) -> list:
            return [kind(**{k: tuple(v) if k.endswith("_ci95") else v for k, v in item.items()}) for item in items]

        return cls(fields["run"], fields["bags"], fields["networks"], fields["reference"], fields["onset_share"],
                   rows(SteerErrors, fields["steer"]), rows(PairedSteer, fields["paired"]),
                   rows(BranchSteer, fields.get("branches", [])), rows(GradientShare, fields["gradients"]))

    def markdown(self) -> str:
        """The page: the frames, the steer errors per group, the paired differences, the gradient shares."""
        run, bags = self.run, self.bags
        lines = ["# Lateral study: steer error per command branch, and the scene loss's share of the encoder's "
                 "gradient", "",
                 f"Made by `{run['command']}` on {run['machine']}, {run['date_end']} (load average "
                 f"{run['load_start']:.2f} at the start, {run['load_end']:.2f} at the end; the numbers do not depend "
                 f"on it). `python -m msfsu_evaluation.lateral_study --render` rewrites this page from "
                 f"`{RECORD_NAME}`.", "",
                 f"{bags['frames']} frames of {len(bags['bags'])} bags "
                 f"({', '.join(b['bag'] for b in bags['bags'])}); frames per command: "
                 + ", ".join(f"{name} {count}" for name, count in bags["commands"].items()) + ".", "",
                 f"A LEFT or RIGHT run's approach is its frames before the expert's steer first reaches "
                 f"{100 * self.onset_share:.0f} % of the run's peak toward the turn; its turn is the rest. Steer is "
                 "CARLA's (positive right): a negative signed error is left of the expert. Intervals: 95 % bootstrap "
                 "over command runs.", "",
                 "Networks: " + "; ".join(f"{name}: `{n['checkpoint']}` on {n['runtime']}"
                                          for name, n in self.networks.items()) + ".", "",
                 "## Steer error per group", "",
                 "| group | frames | runs | " + " | ".join(self.networks) + " |",
                 "| --- | ---: | ---: |" + " --- |" * len(self.networks)]
        by_group: dict[str, dict[str, SteerErrors]] = {}
        for row in self.steer:
            by_group.setdefault(row.group, {})[row.network] = row
        for group, rows in by_group.items():
            first = next(iter(rows.values()))
            cells = [f"MAE {r.mae:.4f} ({r.mae_ci95[0]:.4f}-{r.mae_ci95[1]:.4f}); signed {r.signed:+.4f} "
                     f"({r.signed_ci95[0]:+.4f} to {r.signed_ci95[1]:+.4f})" for r in
                     (rows[n] for n in self.networks)]
            lines.append(f"| {group} | {first.frames} | {first.runs} | " + " | ".join(cells) + " |")
        if self.paired:
            lines += ["", f"## Paired with {self.reference} on the same frames", "",
                      "Each network's error minus the reference's, frame by frame: MAE difference (positive: the "
                      "network errs more) and signed difference (negative: it steers further left).", "",
                      "| network | group | frames | MAE difference (95 % CI) | signed difference (95 % CI) | shown |",
                      "| --- | --- | ---: | --- | --- | --- |"]
            for p in self.paired:
                lines.append(f"| {p.network} | {p.group} | {p.frames} | {p.mae_difference:+.4f} "
                             f"({p.mae_difference_ci95[0]:+.4f} to {p.mae_difference_ci95[1]:+.4f}) | "
                             f"{p.signed_difference:+.4f} ({p.signed_difference_ci95[0]:+.4f} to "
                             f"{p.signed_difference_ci95[1]:+.4f}) | {verdict(p)} |")
        if self.branches:
            lines += ["", "## Every branch on the turn approaches", "",
                      "The approach frames run through each command's branch: mean signed steer error against the "
                      "expert (negative: left of it), 95 % bootstrap over command runs.", "",
                      "| network | frames of | frames | " + " | ".join(o.name + " branch" for o in RoadOption) + " |",
                      "| --- | --- | ---: |" + " --- |" * len(RoadOption)]
            by_row: dict[tuple[str, str], dict[str, BranchSteer]] = {}
            for b in self.branches:
                by_row.setdefault((b.network, b.group), {})[b.branch] = b
            for (network, group), cells in by_row.items():
                lines.append(f"| {network} | {group} | {next(iter(cells.values())).frames} | " + " | ".join(
                    f"{c.signed:+.4f} ({c.signed_ci95[0]:+.4f} to {c.signed_ci95[1]:+.4f})"
                    for c in (cells[o.name] for o in RoadOption)) + " |")
        if self.gradients:
            lines += ["", "## The scene loss's share of the encoder's gradient", "",
                      "Gradients on the encoder's parameters at the trained weights (eval mode), each loss summed "
                      "over the frames with the training's weights (lambda 10, 1, 2): norms, their ratio and the "
                      "cosine between the two directions.", "",
                      "| network | frames of | frames | control norm | scene norm | scene / control | cosine |",
                      "| --- | --- | ---: | ---: | ---: | ---: | ---: |"]
            for g in self.gradients:
                lines.append(f"| {g.network} | {g.frames_of} | {g.frames} | {g.control_norm:.4g} | "
                             f"{g.scene_norm:.4g} | {g.ratio:.3f} | {g.cosine:+.3f} |")
        return "\n".join(lines) + "\n"
