"""The simulator speed record (benchmarks/simulator.py -> benchmarks/simulator_results.json): one row per render mode.

Rules:
- "stock" is MetaDrive's own passes and models: every other mode's speed-up is against it; without it, "-".
- Per-mode tables (stages, render passes) have a row per name found in any mode and "-" where a mode lacks it.
"""

from __future__ import annotations

from dataclasses import dataclass

from msfsu_evaluation.records._json import JsonRow, RecordList

STOCK = "stock"
# what each mode renders, as the README says it
MODE_LABELS = {"stock": "MetaDrive's own passes and models (before)",
               "collection": "`collection`: RGB+depth pass, semantic pass",
               "evaluation": "`evaluation`: one RGB+depth pass",
               "evaluation_full_meshes": "`evaluation` with MetaDrive's full traffic models (before the light meshes)",
               "evaluation_metadrive_terrain": "`evaluation` with MetaDrive's terrain shader (before the lean copy)",
               "evaluation_anisotropic_sidewalks": "`evaluation` with MetaDrive's 8x anisotropic sidewalk (revision 3 "
                                                   "and before)"}


@dataclass(kw_only=True)
class SimulatorMode(JsonRow):
    """One render mode's figures."""

    OPTIONAL = ("frames",)

    mode: str
    load_1min: float  # at the mode's start
    steps_per_s: float  # without the ROS messages
    steps_per_s_with_publish: float
    stages_ms: dict[str, float]  # per step
    render_passes_ms: dict[str, float]  # each pass on its own
    frames: list[str] | None = None  # example PNGs, with --frames only
    reset_s: dict[str, float]  # "new engine", "same town", "other town"


@dataclass(frozen=True)
class SimulatorSetup:
    """What the page says of the run that the record does not hold."""

    date_end: str
    command: str
    machine: str
    town: str
    traffic: str
    width: int
    height: int
    steps: int
    warmup: int


class SimulatorResults(RecordList[SimulatorMode]):
    """benchmarks/simulator_results.json: a row per mode, in the order they ran."""

    ROW = SimulatorMode

    def by_mode(self) -> dict[str, SimulatorMode]:
        return {mode.mode: mode for mode in self.rows}

    def speedup(self, mode: SimulatorMode) -> str:
        """'<n>x' against stock, one decimal; '-' without a stock row."""
        stock = self.by_mode().get(STOCK)
        return f"{mode.steps_per_s / stock.steps_per_s:.1f}x" if stock else "-"

    def page(self, setup: SimulatorSetup) -> str:
        """benchmarks/simulator_results.md: speed and resets per mode, then ms per stage and per render pass."""
        lines = [f"# Simulator speed ({setup.date_end})", "",
                 f"`{setup.command}` on {setup.machine}; {setup.town}, {setup.traffic} traffic, "
                 f"{setup.width}x{setup.height} cameras, {setup.steps} steps after {setup.warmup}, expert driving.", "",
                 "| mode | load (1 min) | steps/s | vs stock | steps/s incl. ROS publish | reset: new engine s | "
                 "same town s | other town s |",
                 "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for m in self.rows:
            reset = m.reset_s
            lines.append(f"| {m.mode} | {m.load_1min} | {m.steps_per_s} | {self.speedup(m)} | "
                         f"{m.steps_per_s_with_publish} | {reset['new engine']} | {reset['same town']} | "
                         f"{reset['other town']} |")
        lines += self._per_mode_table("ms per step, by stage", "stage", {m.mode: m.stages_ms for m in self.rows})
        lines += self._per_mode_table("Render passes, ms each on its own", "pass",
                                      {m.mode: m.render_passes_ms for m in self.rows})
        return "\n".join(lines) + "\n"

    @staticmethod
    def _per_mode_table(title: str, row_name: str, values: dict[str, dict[str, float]]) -> list[str]:
        """Lines of one table: a row per name in any mode, a column per mode."""
        names = list(dict.fromkeys(name for per_mode in values.values() for name in per_mode))
        lines = ["", f"## {title}", "", f"| {row_name} | " + " | ".join(values) + " |",
                 "| --- |" + " --- |" * len(values)]
        lines += [f"| {name} | " + " | ".join(str(per_mode.get(name, "-")) for per_mode in values.values()) + " |"
                  for name in names]
        return lines

    def block(self) -> str:
        """The docs' table: steps/s per mode, its speed-up and its resets."""
        rows = ["| mode (what renders) | steps/s | vs MetaDrive's passes | reset: same town / other town / new engine |",
                "| --- | --- | --- | --- |"]
        for m in self.by_mode().values():
            reset = m.reset_s
            rows.append(f"| {MODE_LABELS.get(m.mode, m.mode)} | {m.steps_per_s} | {self.speedup(m)} | "
                        f"{reset['same town']} s / {reset['other town']} s / {reset['new engine']} s |")
        return "\n".join(rows)

    def headline(self) -> str:
        """The README's simulator line: the evaluation mode's steps/s and its speed-up."""
        evaluation = self.by_mode()["evaluation"]
        return (f"- **Simulator speed**, MetaDrive on the CPU rendering what the benchmark reads (town_a, regular "
                f"traffic): {evaluation.steps_per_s} steps/s, {self.speedup(evaluation)} MetaDrive's own passes "
                "([simulator.md](docs/simulator.md#speed)).")
