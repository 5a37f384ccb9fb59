"""The sensitivity record of `msfsu-int8-recipe` (deploy.recipe.analyse) as markdown: the all-int8 model against the
recipe, the selection step by step, the per-layer ranking (benchmarks/int8_recipes/*.md are this page)."""

from __future__ import annotations

from typing import Any


def report_markdown(record: dict[str, Any]) -> str:
    """The page of one sensitivity record."""
    all_int8, deployed = record["all_int8"], record["deployed"]
    lines = [f"# int8 sensitivity of {record['checkpoint']} ({record['checkpoint_digest']})", "",
             f"Made by `{record['command']}`", "",
             f"Validation frames: {record['validation']['frames']} from {len(record['validation']['bags'])} bags "
             f"({', '.join(f'{k} {v}' for k, v in record['validation']['commands'].items())}); calibration "
             f"{record['calibration']['frames']} frames ({record['calibration']['digest']}). Damage is in gate units "
             "(1.0 = one threshold): segmentation = mIoU points lost against torch fp32's own class ids, steer = "
             "mean |steer - fp32 steer| per 5 % of fp32's steer MAE.", "",
             "| model | damage (seg + steer) | validation mIoU drop (points) | steer MAE rise | float MACs |",
             "|---|---:|---:|---:|---:|"]

    def row(label: str, part: dict[str, Any], share: float) -> str:
        d, g = part["damage"], part["validation_gate"]
        return (f"| {label} | {d['segmentation'] + d['steer']:.2f} ({d['segmentation']:.2f} + {d['steer']:.2f}) | "
                f"{g['miou_drop_points']:.2f} | {g['steer_mae_rise']:+.1%} | {share:.1%} |")

    lines.append(row("all layers int8", all_int8, 0.0))
    lines.append(row(f"recipe: {len(record['recipe']['keep_float'])} layers float (NNCF ignored_scope)", deployed,
                     record["recipe_float_mac_share"]))
    latency = record["latency"]
    lines += ["", f"Latency p50 (OpenVINO, batch 1, 1-min load {latency['load_average_1min']}): all int8 "
              f"{latency['all_int8_ms']} ms, recipe {latency['recipe_ms']} ms.", "",
              "Selection (the free policy head first, then layers back to float in ranking order, kept only if they "
              f"lower the damage; stops when the validation gate passes with margin {record['margin']} and the steer "
              f"damage is at most {record.get('max_steer_damage', 'inf')}):", "",
              "| float layers | last added | damage | mIoU drop | steer MAE rise | kept | passes with margin |",
              "|---:|---|---:|---:|---:|---|---|"]
    for step in record["selection"]:
        gate, d = step["validation_gate"], step["damage"]
        previous = next((p["keep_float"] for p in reversed(record["selection"][:record["selection"].index(step)])
                         if p["accepted"]), [])
        new_layers = [layer for layer in step["keep_float"] if layer not in previous]
        added = (new_layers[0] if len(new_layers) == 1 else f"{len(new_layers)} free layers (policy head)"
                 ) if step["keep_float"] else "(all int8)"
        lines.append(f"| {len(step['keep_float'])} | {added} | {d['segmentation'] + d['steer']:.2f} | "
                     f"{gate['miou_drop_points']:.2f} | {gate['steer_mae_rise']:+.1%} | "
                     f"{'yes' if step['accepted'] else 'no'} | {'yes' if step['passed_with_margin'] else 'no'} |")
    lines += ["", f"Kept in float: {', '.join(record['recipe']['keep_float']) or 'nothing'}", "",
              "Per-layer sensitivity (damage of the all-int8 model with only this layer in float):", "",
              "| rank | layer | op | MACs | damage when float (seg + steer) | recovered |", "|---:|---|---|---:|---:|---:|"]
    for rank, entry in enumerate(record["ranking"], 1):
        d = entry["damage_when_float"]
        lines.append(f"| {rank} | {entry['layer']} | {entry['op_type']} | {entry['mac_share']:.1%} | "
                     f"{d['segmentation'] + d['steer']:.2f} ({d['segmentation']:.2f} + {d['steer']:.2f}) | "
                     f"{entry['recovered']:+.2f} |")
    return "\n".join(lines) + "\n"
