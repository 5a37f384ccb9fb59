"""Training artefacts: the per-epoch CSV log, loss curves and the balancing histograms (paper Fig. 3)."""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msfsu_perception.losses import LossTerms  # noqa: E402


def append_csv_row(path: Path, row: Mapping[str, float | int | str]) -> None:
    """Append one epoch; the header is written with the first row. A file written before a column existed (a run
    resumed by a newer version) is rewritten once with the new columns at the end, left empty in its old rows."""
    if path.exists():
        with path.open(newline="") as stream:
            header = next(csv.reader(stream), [])
        if new_columns := [key for key in row if key not in header]:
            rows = read_csv(path)
            temporary = path.with_name(f".{path.name}.partial")
            with temporary.open("w", newline="") as stream:
                writer = csv.DictWriter(stream, fieldnames=[*header, *new_columns])
                writer.writeheader()
                writer.writerows(rows)
            temporary.replace(path)
            header = [*header, *new_columns]
        with path.open("a", newline="") as stream:
            csv.DictWriter(stream, fieldnames=header).writerow(row)
        return
    with path.open("w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=list(row))
        writer.writeheader()
        writer.writerow(row)


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as stream:
        return list(csv.DictReader(stream))


def plot_loss_curves(csv_path: Path, png_path: Path) -> None:
    """One panel per loss part, train and validation against the epoch."""
    rows = read_csv(csv_path)
    epochs = [int(row["epoch"]) for row in rows]
    parts = [part for part in LossTerms._fields if rows and rows[0][f"train_{part}"] != "nan"]
    figure, axes = plt.subplots(1, len(parts), figsize=(4 * len(parts), 3.2), squeeze=False)
    for axis, part in zip(axes[0], parts):
        for split in ("train", "val"):
            axis.plot(epochs, [float(row[f"{split}_{part}"]) for row in rows], marker=".", label=split)
        axis.set_title(f"{part} loss")
        axis.set_xlabel("epoch")
        axis.set_yscale("log")
        axis.legend()
    figure.tight_layout()
    figure.savefig(png_path, dpi=100)
    plt.close(figure)


def plot_balancing_histograms(
    before: tuple[np.ndarray, np.ndarray], after: tuple[np.ndarray, np.ndarray], png_path: Path
) -> None:
    """Paper Fig. 3 for LANE_FOLLOW samples: (steering [deg], speed [m/s]) before and after balancing."""
    figure, axes = plt.subplots(2, 2, figsize=(9, 6))
    for row, (label, (steer_deg, speed)) in enumerate((("original", before), ("balanced", after))):
        axes[row, 0].hist(steer_deg, bins=np.arange(-70, 71, 2.5))
        axes[row, 0].set_title(f"{label} steering angle (deg), n={len(steer_deg)}")
        axes[row, 1].hist(speed, bins=40)
        axes[row, 1].set_title(f"{label} target speed (m/s), n={len(speed)}")
    figure.tight_layout()
    figure.savefig(png_path, dpi=100)
    plt.close(figure)
