"""A soak's records made into its result (benchmarks/soak.py): the camera's stamps and the measurer's marks, stage
times and diagnostics into a SoakRecord (msfsu_evaluation.records.soak: per-stage percentiles, totals, windows, the
causes of slow frames), and its plot (latency over time and the stage means per window).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msfsu_evaluation.latency_trace import STAGES, frame_times, percentiles, slow_frame_causes, stage_rows
from msfsu_evaluation.records.soak import SoakRecord, SoakTotals


def watchdog_timeout_ns() -> int:
    """The control node's default watchdog timeout, ns: a brake after the stream's end is the watchdog's."""
    from msfsu_control.control_node import ControlSettings

    return round(ControlSettings().watchdog_timeout * 1e9)


def last_values(diagnostics: list[dict], name: str, before_ns: int | None = None) -> dict[str, str]:
    chosen = [d for d in diagnostics if d["name"] == name and (before_ns is None or d["t_ns"] <= before_ns)]
    return chosen[-1]["values"] if chosen else {}


def analyse(result: SoakRecord, camera: dict, measurer: dict, window_s: float,
            rss: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """Fill `result` from the camera's and the measurer's records (and the parent's RSS samples); returns each
    frame's time since the first frame (s) and end-to-end latency (ms, NaN where unanswered), for the plot."""
    marks = {int(k): v for k, v in measurer["marks"].items()}
    stamps = np.asarray(camera["stamps_ns"], np.int64)
    times = frame_times(stamps, marks)
    answered = ~np.isnan(times.marks_ms.get("control_dds", np.full(stamps.size, np.nan)))
    end_to_end = times.marks_ms.get("control_dds", np.full(stamps.size, np.nan))
    result.stages = stage_rows(times, answered)
    causes, examples = slow_frame_causes(times, answered, result.slow_ms) if answered.any() else ({}, [])
    result.slow_causes, result.slow_examples = dict(sorted(causes.items(), key=lambda item: -item[1])), examples
    diagnostics = measurer["diagnostics"]
    perception, control = last_values(diagnostics, "msfsu/perception"), last_values(diagnostics, "msfsu/control")
    result.diagnostics = {"msfsu/perception": perception, "msfsu/control": control}
    dropped = {key.removeprefix("dropped_"): int(value) for key, value in perception.items() if key.startswith("dropped_")}
    published, skipped = int(stamps.size), int(perception.get("skipped_newer_frame", 0))
    first_action = np.flatnonzero(answered)
    frame_stamps = set(stamps.tolist())
    # brakes while the graph drives: after the first answer, before the stream's end could trip the watchdog
    first_answer_ns = (stamps[first_action[0]] + end_to_end[first_action[0]] * 1e6) if first_action.size else np.inf
    end_ns = stamps[-1] + watchdog_timeout_ns() if stamps.size else 0
    brakes = sum(frame.get("control_brake", 0) for stamp, frame in marks.items()
                 if stamp not in frame_stamps and first_answer_ns < frame.get("control_dds", 0) < end_ns)
    result.totals = SoakTotals(
        published=published, answered=int(answered.sum()), processed=int(perception.get("processed", 0)),
        skipped=skipped, unpaired=sum(v for k, v in dropped.items() if k.startswith("unpaired")),
        dropped=dropped, answered_or_skipped_share=round((int(answered.sum()) + skipped) / max(published, 1), 4),
        end_to_end_ms=percentiles(end_to_end[answered]),
        camera_late_ms=percentiles(camera["late_ms"]), camera_send_ms=percentiles(camera["send_ms"]),
        watchdog_brakes_driving=brakes,
        watchdog_brakes_total=int(control.get("watchdog_brakes", -1)),  # the control node's: start and end too
        first_answered_frame=int(first_action[0]) if first_action.size else None,
        rss_mb=rss,
    )
    start = stamps[0] if stamps.size else 0
    for window_start in np.arange(0.0, (stamps[-1] - start) / 1e9 + 1e-9 if stamps.size else 0.0, window_s):
        in_window = ((stamps - start) / 1e9 >= window_start) & ((stamps - start) / 1e9 < window_start + window_s)
        window = {"start_s": round(float(window_start), 1), "published": int(in_window.sum()),
                  "answered": int((in_window & answered).sum()),
                  "end_to_end_ms": percentiles(end_to_end[in_window & answered])}
        for name, start_mark, end_mark in STAGES:
            if start_mark in times.marks_ms and end_mark in times.marks_ms:
                values = times.interval(start_mark, end_mark)[in_window & answered]
                window.setdefault("stage_mean_ms", {})[name] = round(float(np.nanmean(values)), 2) if (
                    values.size and not np.isnan(values).all()) else None
        result.windows.append(window)
    return (stamps - start) / 1e9, end_to_end


def plot(result: SoakRecord, frames_s: np.ndarray, end_to_end_ms: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (latency_axes, stage_axes) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    answered = ~np.isnan(end_to_end_ms)
    latency_axes.plot(frames_s[answered], end_to_end_ms[answered], ".", markersize=1.5,
                      label="each answered frame")
    window_s = result.windows[1]["start_s"] - result.windows[0]["start_s"] if len(result.windows) > 1 else 1.0
    middles = [w["start_s"] + window_s / 2 for w in result.windows]
    latency_axes.plot(middles, [w["end_to_end_ms"].get("p95", np.nan) for w in result.windows], "-o", markersize=3,
                      label="p95 per window", color="C3")
    latency_axes.axhline(result.slow_ms, color="grey", linewidth=0.8, linestyle="--", label=f"{result.slow_ms:g} ms")
    latency_axes.set_yscale("log")
    latency_axes.set_ylabel("camera -> VehicleControl, ms")
    latency_axes.legend(loc="upper right")
    latency_axes.grid(alpha=0.3)
    for name, _, _ in STAGES:  # the stages that matter: a mean of at least 0.5 ms in some window
        means = [w.get("stage_mean_ms", {}).get(name) for w in result.windows]
        if any(m is not None and m >= 0.5 for m in means):
            stage_axes.plot(middles, [np.nan if m is None else m for m in means], "-o", markersize=2, label=name)
    stage_axes.set_ylabel("stage mean per window, ms")
    stage_axes.set_xlabel("seconds since the first frame")
    stage_axes.legend(fontsize=6, loc="upper left", ncol=2)
    stage_axes.grid(alpha=0.3)
    figure.suptitle(f"Soak: {result.camera} at {result.rate_hz:g} Hz, perception on {result.inference}")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
