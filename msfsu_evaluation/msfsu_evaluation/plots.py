"""PNG figures of an evaluation (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
import numpy as np  # noqa: E402

from msfsu_common.road_option import RoadOption  # noqa: E402
from msfsu_evaluation.evaluation import FrameSeries, OverlayFrame  # noqa: E402
from msfsu_common.semantic_classes import colourise, overlay  # noqa: E402

DPI = 110
TURN_COLOURS = {RoadOption.LEFT: "tab:blue", RoadOption.RIGHT: "tab:red", RoadOption.STRAIGHT: "tab:green"}


def _save(figure: plt.Figure, path: Path, bottom_margin: float = 0.0) -> Path:
    figure.tight_layout(rect=(0.0, bottom_margin, 1.0, 1.0))
    figure.savefig(path, dpi=DPI)
    plt.close(figure)
    return path


def plot_actions(series: FrameSeries, path: Path) -> Path:
    """Predicted vs expert steer and target speed over time; turn commands shaded."""
    figure, (steer_axis, speed_axis) = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    panels = ((steer_axis, series.expert_steer, series.predicted_steer, "steer"),
              (speed_axis, series.expert_speed, series.predicted_speed, "target speed (m/s)"))
    for axis, expert, predicted, label in panels:
        for option, colour in TURN_COLOURS.items():
            active = series.command == option.value
            if active.any():
                axis.fill_between(series.time_s, 0, 1, where=active, transform=axis.get_xaxis_transform(),
                                  color=colour, alpha=0.12, step="mid", label=option.name)
        axis.plot(series.time_s, expert, color="black", linewidth=1.2, label="expert")
        axis.plot(series.time_s, predicted, color="tab:orange", marker=".", markersize=3, linewidth=0.8,
                  label="network")
        axis.set_ylabel(label)
        axis.grid(alpha=0.3)
    steer_axis.legend(loc="upper right", fontsize=8, ncol=5)
    speed_axis.set_xlabel("time since the first frame (s)")
    return _save(figure, path)


def plot_confusion(confusion: np.ndarray, class_names: tuple[str, ...], path: Path) -> Path:
    """Row-normalised (share of each true class), annotated with the share in percent."""
    totals = confusion.sum(axis=1, keepdims=True)
    shares = np.divide(confusion, totals, out=np.zeros(confusion.shape), where=totals > 0)
    figure, axis = plt.subplots(figsize=(6.5, 5.5))
    image = axis.imshow(shares, cmap="Blues", vmin=0.0, vmax=1.0)
    for (row, column), share in np.ndenumerate(shares):
        axis.text(column, row, f"{100 * share:.1f}", ha="center", va="center",
                  color="white" if share > 0.5 else "black", fontsize=8)
    axis.set_xticks(range(len(class_names)), class_names, rotation=30, ha="right")
    axis.set_yticks(range(len(class_names)), class_names)
    axis.set_xlabel("predicted")
    axis.set_ylabel("ground truth")
    axis.set_title("confusion matrix (% of each true class)")
    figure.colorbar(image, ax=axis)
    return _save(figure, path)


def plot_overlays(frames: list[OverlayFrame], class_names: tuple[str, ...], path: Path) -> Path:
    """One row per frame: the network's RGB | ground truth | prediction (colours over the RGB)."""
    figure, axes = plt.subplots(len(frames), 3, figsize=(9, 2.6 * len(frames) + 0.4), squeeze=False)
    colours = colourise(np.arange(len(class_names), dtype=np.uint8)) / 255.0
    figure.legend(handles=[Patch(color=colour, label=name) for colour, name in zip(colours, class_names)],
                  loc="lower center", ncol=len(class_names), fontsize=8)
    for row, frame in zip(axes, frames):
        panels = (frame.model_rgb, overlay(frame.model_rgb, frame.truth), overlay(frame.model_rgb, frame.prediction))
        for axis, panel, title in zip(row, panels, ("RGB (network input)", "ground truth", "prediction")):
            axis.imshow(panel, interpolation="nearest")
            axis.set_title(f"{title}\nstamp {frame.stamp_ns * 1e-9:.2f} s", fontsize=8)
            axis.axis("off")
    return _save(figure, path, bottom_margin=0.4 / (2.6 * len(frames) + 0.4))

