"""The default-model recipe's records (make default-model): the collected data set (docs/results/data/data.json,
msfsu-dataset-report) and each training run (docs/results/training/<run>/metrics.csv and args.json, msfsu-train).

Rules:
- A run's training time is the sum of its epochs' `epoch_time_s`; its rate the samples/s of its epochs weighted by
  their time.
- The best epoch is the one of the lowest validation loss; a loss part a run did not train ("", "nan") is left out.
- One hour of data is 36,000 frames (one frame per simulator step at 10 Hz).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

FRAMES_PER_HOUR = 36000
VARIANT_NAMES = {"msfsu": "MSFSU (`models/msfsu_default.pt`)", "msf": "MSF (`models/msf.pt`)", "su": "SU (`models/su.pt`)"}


@dataclass(frozen=True)
class CollectedBag:
    """One bag of data.json: what the collection table counts of it."""

    split: str
    round: int
    driver: str
    frames: int
    slow_frames: int
    network_frames: int


@dataclass(frozen=True)
class DataSet:
    """data.json: the kept bags and the dropped episodes (split and round of each)."""

    bags: list[CollectedBag]
    dropped: list[tuple[str, int]]  # (split, round)

    @classmethod
    def from_json(cls, text: str) -> DataSet:
        record = json.loads(text)
        bags = [CollectedBag(split=b["split"], round=b["round"], driver=b["driver"], frames=b["frames"],
                             slow_frames=b["slow_frames"], network_frames=b["network_frames"]) for b in record["bags"]]
        return cls(bags, [(d["split"], d["round"]) for d in record["dropped"]])

    def rows(self) -> list[str]:
        """A table row per split and round: episodes kept, who drove, frames, hours, stopping and network shares."""
        rows = []
        for split, round_index in sorted({(b.split, b.round) for b in self.bags}):
            bags = [b for b in self.bags if (b.split, b.round) == (split, round_index)]
            dropped = [d for d in self.dropped if d == (split, round_index)]
            frames = sum(b.frames for b in bags)
            slow = sum(b.slow_frames for b in bags)
            network = sum(b.network_frames for b in bags)
            drivers = sorted({b.driver for b in bags})
            who = "expert" if drivers == ["expert"] else f"network ({', '.join(drivers)}) and expert"
            rows.append(f"| collect {split}, round {round_index} | {len(bags)} of {len(bags) + len(dropped)} episodes "
                        f"kept, driven by the {who} | {frames:,} frames ({frames / FRAMES_PER_HOUR:.2f} h), "
                        f"{100 * slow / frames:.1f} % labelled < 1 m/s"
                        f"{f', {100 * network / frames:.0f} % driven by the network' if network else ''} |")
        return rows


@dataclass(frozen=True)
class TrainingLog:
    """A training run's metrics.csv (a row per epoch, as msfsu-train writes it) and, where kept, its args.json."""

    epochs: list[dict[str, str]]
    args: Mapping[str, Any]

    @classmethod
    def read(cls, directory: Path) -> TrainingLog | None:
        """The run in `directory`; None when it has no metrics.csv."""
        metrics = directory / "metrics.csv"
        if not metrics.exists():
            return None
        with metrics.open() as handle:
            epochs = list(csv.DictReader(handle))
        arguments = directory / "args.json"
        return cls(epochs, json.loads(arguments.read_text()) if arguments.exists() else {})

    def time_and_rate(self) -> tuple[float, float]:
        """Seconds of training steps and the mean samples/s, weighted by epoch time."""
        seconds = sum(float(row["epoch_time_s"]) for row in self.epochs)
        return seconds, sum(float(row["samples_per_s"]) * float(row["epoch_time_s"]) for row in self.epochs) / seconds

    def row(self, variant: str) -> str:
        """The recipe table's row of this run: epochs, rate, hours and its best validation loss."""
        best = min(self.epochs, key=lambda row: float(row["val_total"]))
        seconds, rate = self.time_and_rate()
        parts = ", ".join(f"{name} {float(best[f'val_{name}']):.4f}" for name in ("steer", "speed", "scene")
                          if best.get(f"val_{name}") not in (None, "", "nan"))
        return (f"| train {VARIANT_NAMES[variant]} | {len(self.epochs)} epochs, {rate:.0f} samples/s, "
                f"{seconds / 3600:.2f} h of training steps | best validation loss {float(best['val_total']):.4f} at "
                f"epoch {int(best['epoch'])} ({parts}) |")

    def paper_line(self) -> str:
        """The int8 gate's short run of the paper preset: its rate, precision and decoder."""
        seconds, rate = self.time_and_rate()
        args = self.args
        precision = " + ".join(name for name, on in (("bf16", args["bf16"]), ("channels-last", args["channels_last"]))
                               if on)
        return (f"Training on 2 cores, paper preset: {rate:.1f} samples/s ({precision or 'fp32'}, decoder "
                f"{args['decoder_layout']}; the int8 gate's short run, {args['max_steps']} steps in "
                f"{seconds / 60:.1f} min, `docs/results/training/paper_short/`).")


@dataclass(frozen=True)
class DefaultModelRecipe:
    """The recipe's data set and its three training runs (None: not collected / not trained on this data yet)."""

    data: DataSet | None
    runs: dict[str, TrainingLog | None]  # variant -> its run

    @classmethod
    def read(cls, data: Path, training: Path) -> DefaultModelRecipe:
        """data.json at `data`, the runs in `training`/<variant>/."""
        return cls(DataSet.from_json(data.read_text()) if data.exists() else None,
                   {variant: TrainingLog.read(training / variant) for variant in VARIANT_NAMES})

    def block(self) -> str:
        """The docs' table: each collection round, then each variant's training."""
        if self.data is None:
            return "Not collected yet: `make default-model` writes `docs/results/data/data.json`."
        rows = ["| step | what | result |", "| --- | --- | --- |", *self.data.rows()]
        for variant, run in self.runs.items():
            rows.append(run.row(variant) if run is not None else
                        f"| train {VARIANT_NAMES[variant]} | not trained on this data yet | the file shipped is the v1 model |")
        return "\n".join(rows)
