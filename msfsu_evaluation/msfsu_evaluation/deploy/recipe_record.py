"""The int8 sensitivity record (`msfsu-int8-recipe`, deploy.recipe.analyse -> benchmarks/int8_recipes/<name>.json):
the all-int8 model against the recipe, the selection step by step and the per-layer ranking.

Rules:
- Damage is in gate units (deploy.sensitivity): 1.0 = one threshold of the gate.
- A layer is free in float by deploy.sensitivity.is_free (the policy head and the pooled features); the docs name
  the free layers the recipe keeps as one group.
- The recipe the node reads (<checkpoint>.deploy/<hash>-int8-recipe.json) is msfsu_perception.int8_recipe's
  record, not this one: it keeps this record's provenance only.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from msfsu_evaluation.deploy.sensitivity import Damage, LayerSensitivity, is_free


@dataclass(kw_only=True)
class ScoredModel:
    """A model of the search on the validation frames: its damage and the gate's summary there."""

    damage: Damage
    validation_gate: dict[str, Any]  # deploy.recipe's gate summary: miou_drop_points, steer_mae_rise, ...

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> ScoredModel:
        return cls(damage=Damage(**fields["damage"]), validation_gate=fields["validation_gate"])

    def page_row(self, label: str, float_mac_share: float) -> str:
        d, g = self.damage, self.validation_gate
        return (f"| {label} | {d.total:.2f} ({d.segmentation:.2f} + {d.steer:.2f}) | {g['miou_drop_points']:.2f} | "
                f"{g['steer_mae_rise']:+.1%} | {float_mac_share:.1%} |")

    def gate_text(self) -> str:
        """The validation gate's mIoU drop and steer MAE rise."""
        return f"{self.validation_gate['miou_drop_points']:.2f}, {self.validation_gate['steer_mae_rise']:+.1%}"


@dataclass(kw_only=True)
class SelectionRow:
    """One step of deploy.sensitivity.select_keep_float."""

    keep_float: list[str]
    damage: Damage
    accepted: bool  # the layers it added lowered the damage: they stay float
    passed_with_margin: bool
    validation_gate: dict[str, Any]

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> SelectionRow:
        return cls(**{**fields, "damage": Damage(**fields["damage"])})


@dataclass(kw_only=True)
class SensitivityRecord:
    checkpoint: str
    checkpoint_digest: str
    deploy_format: int  # the exported graph the damages were measured on
    command: str
    calibration: dict[str, Any]  # digest, frames
    validation: dict[str, Any]  # deploy.scoring.describe_held_out of the validation frames
    margin: float
    max_layers: int
    max_steer_damage: float
    all_int8: ScoredModel
    ranking: list[LayerSensitivity]  # most sensitive first
    selection: list[SelectionRow]
    recipe: dict[str, Any]  # msfsu_perception.int8_recipe.Int8Recipe.settings()
    recipe_digest: str
    recipe_float_mac_share: float
    deployed: ScoredModel  # the recipe, built by NNCF
    latency: dict[str, float]  # load_average_1min, all_int8_ms, recipe_ms

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> SensitivityRecord:
        return cls(**{**fields, "all_int8": ScoredModel.from_dict(fields["all_int8"]),
                      "ranking": [LayerSensitivity.from_record(entry) for entry in fields["ranking"]],
                      "selection": [SelectionRow.from_dict(step) for step in fields["selection"]],
                      "deployed": ScoredModel.from_dict(fields["deployed"])})

    @classmethod
    def from_json(cls, text: str) -> SensitivityRecord:
        return cls.from_dict(json.loads(text))

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1) + "\n"

    def keep_float(self) -> list[str]:
        return self.recipe["keep_float"]

    def page(self) -> str:
        """benchmarks/int8_recipes/<name>.md: the models, the selection, what stays float, the ranking."""
        validation, latency = self.validation, self.latency
        lines = [f"# int8 sensitivity of {self.checkpoint} ({self.checkpoint_digest})", "",
                 f"Made by `{self.command}`", "",
                 f"Validation frames: {validation['frames']} from {len(validation['bags'])} bags "
                 f"({', '.join(f'{k} {v}' for k, v in validation['commands'].items())}); calibration "
                 f"{self.calibration['frames']} frames ({self.calibration['digest']}). Damage is in gate units "
                 "(1.0 = one threshold): segmentation = mIoU points lost against torch fp32's own class ids, steer = "
                 "mean |steer - fp32 steer| per 5 % of fp32's steer MAE.", "",
                 "| model | damage (seg + steer) | validation mIoU drop (points) | steer MAE rise | float MACs |",
                 "|---|---:|---:|---:|---:|", self.all_int8.page_row("all layers int8", 0.0),
                 self.deployed.page_row(f"recipe: {len(self.keep_float())} layers float (NNCF ignored_scope)",
                                        self.recipe_float_mac_share),
                 "", f"Latency p50 (OpenVINO, batch 1, 1-min load {latency['load_average_1min']}): all int8 "
                 f"{latency['all_int8_ms']} ms, recipe {latency['recipe_ms']} ms.", "",
                 "Selection (the free policy head first, then layers back to float in ranking order, kept only if they "
                 f"lower the damage; stops when the validation gate passes with margin {self.margin} and the steer "
                 f"damage is at most {self.max_steer_damage}):", "",
                 "| float layers | last added | damage | mIoU drop | steer MAE rise | kept | passes with margin |",
                 "|---:|---|---:|---:|---:|---|---|", *self._selection_rows(),
                 "", f"Kept in float: {', '.join(self.keep_float()) or 'nothing'}", "",
                 "Per-layer sensitivity (damage of the all-int8 model with only this layer in float):", "",
                 "| rank | layer | op | MACs | damage when float (seg + steer) | recovered |",
                 "|---:|---|---|---:|---:|---:|"]
        for rank, entry in enumerate(self.ranking, 1):
            d = entry.damage_when_float
            lines.append(f"| {rank} | {entry.layer} | {entry.op_type} | {entry.mac_share:.1%} | {d.total:.2f} "
                         f"({d.segmentation:.2f} + {d.steer:.2f}) | {entry.recovered:+.2f} |")
        return "\n".join(lines) + "\n"

    def _selection_rows(self) -> list[str]:
        """A row per step; "last added" is what the step put in float beyond the last accepted step."""
        rows, accepted = [], []
        for step in self.selection:
            new_layers = [layer for layer in step.keep_float if layer not in accepted]
            added = (new_layers[0] if len(new_layers) == 1 else f"{len(new_layers)} free layers (policy head)"
                     ) if step.keep_float else "(all int8)"
            gate = step.validation_gate
            rows.append(f"| {len(step.keep_float)} | {added} | {step.damage.total:.2f} | "
                        f"{gate['miou_drop_points']:.2f} | {gate['steer_mae_rise']:+.1%} | "
                        f"{'yes' if step.accepted else 'no'} | {'yes' if step.passed_with_margin else 'no'} |")
            if step.accepted:
                accepted = step.keep_float
        return rows

    def block_row(self) -> str:
        """The docs' row: the three most sensitive layers and what the recipe keeps float, free layers as one."""
        top = ", ".join(f"`{entry.layer}` {entry.recovered:+.1f}" for entry in self.ranking[:3])
        free = {entry.layer for entry in self.ranking if is_free(entry)}
        kept = [f"`{layer}`" for layer in self.keep_float() if layer not in free]
        head = [layer for layer in self.keep_float() if layer in free]
        kept_text = ", ".join(kept + ([f"the policy head ({len(head)} layers)"] if head else [])) or "nothing"
        return (f"| `{self.checkpoint}` | {self.all_int8.gate_text()} | {top} | {kept_text} "
                f"({self.recipe_float_mac_share:.1%}) | {self.deployed.gate_text()}; "
                f"{self.deployed.damage.steer:.2f} |")


def read_sensitivity_records(directory: Path) -> list[SensitivityRecord]:
    """The sensitivity records of `directory` (benchmarks/int8_recipes/*.json), by file name."""
    return [SensitivityRecord.from_json(path.read_text()) for path in sorted(directory.glob("*.json"))]


def int8_recipes_block(records: list[SensitivityRecord]) -> str:
    """The docs' table: per checkpoint the most sensitive layers and what its recipe keeps float."""
    rows = ["| checkpoint | validation: all int8 (mIoU drop, steer MAE rise) | most sensitive layers (damage "
            "recovered, gate units) | kept in float (share of MACs) | validation: recipe (mIoU drop, steer MAE rise; "
            "steer damage) |", "| --- | --- | --- | --- | --- |"]
    return "\n".join(rows + [record.block_row() for record in records])
