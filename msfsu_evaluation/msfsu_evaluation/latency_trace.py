"""Per-frame latency through the graph from the stage marks its nodes publish (msfsu_common.stage_times).

ROS-free: a frame is a dict of marks (stage name -> wall-clock ns) keyed by the frame's stamp; its origin is
the mark `stamp` when present (the lockstep benchmark: the simulator's wall time at publishing), else the key
itself (the soak: the camera stamps each frame with the wall clock). The stages below are the intervals of a
frame's path from its source (the soak's camera, the simulator) through perception and control back to a
receiver (the soak's measurer, the simulator). benchmarks/soak.py and benchmarks/lockstep.py tabulate them.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from msfsu_common.benchmark_run import percentiles  # n, p50, p95, p99, max of a stage (re-exported: the soak's)

# Stage intervals on a frame's path, (name, start mark, end mark). Marks: `stamp` (the camera's), the camera's
# `<topic>_sent` (its DDS write: rmw source timestamp) and each node's marks (`<input>_dds` rmw reception,
# `<input>_taken` callback start, then its own stages); `<input>_sent` of a received message is its writer's.
# "input ready" is the later of rgb_taken and depth_taken: the pair exists only once both are taken. A stage whose marks
# a run lacks (the brake's, without it) is left out.
STAGES: tuple[tuple[str, str, str], ...] = (
    ("camera: rgb message to DDS", "stamp", "rgb_sent"),
    ("DDS: rgb to perception", "rgb_sent", "rgb_dds"),
    ("perception: rgb waits for its executor", "rgb_dds", "rgb_taken"),
    ("camera: depth message to DDS", "rgb_sent", "depth_sent"),
    ("DDS: depth to perception", "depth_sent", "depth_dds"),
    ("perception: depth waits for its executor", "depth_dds", "depth_taken"),
    ("perception: decode and pair", "input_ready", "paired"),
    ("perception: waits for inference", "paired", "inference_start"),
    ("perception: preprocessing", "inference_start", "preprocessed"),
    ("perception: network", "preprocessed", "inferred"),
    ("perception: action to DDS", "inferred", "action_published"),
    # with the emergency brake between them (its marks: `network_action_*` as it receives perception's action)
    ("DDS: action to the brake", "network_action_sent", "network_action_dds"),
    ("aeb: waits for its executor", "network_action_dds", "network_action_taken"),
    ("aeb: waits for the segmentation and depth", "network_action_taken", "aeb_inputs_ready"),
    ("aeb: judges, action to DDS", "aeb_inputs_ready", "action_sent"),
    ("DDS: action to control", "action_sent", "action_dds"),
    ("control: waits for its executor", "action_dds", "action_taken"),
    ("control: PID, control to DDS", "action_taken", "control_sent"),
    ("DDS: control to measurer", "control_sent", "control_dds"),
)
CHECKPOINTS: tuple[tuple[str, str], ...] = (  # cumulative, since the camera stamp
    ("input ready (rgb and depth taken)", "input_ready"),
    ("network done", "inferred"),
    ("DrivingAction at control", "action_dds"),
    ("VehicleControl at the measurer (end to end)", "control_dds"),
)
# the stages of each stream's way into perception; a frame's critical path takes the stream taken last
BRANCHES = {"rgb": {"camera: rgb message to DDS", "DDS: rgb to perception", "perception: rgb waits for its executor"},
            "depth": {"camera: rgb message to DDS", "camera: depth message to DDS", "DDS: depth to perception",
                      "perception: depth waits for its executor"}}


@dataclass
class FrameTimes:
    """Per published frame: its stamp and, where it was answered, every mark in ms since the stamp (NaN if absent)."""

    stamps_ns: np.ndarray  # (N,)
    marks_ms: dict[str, np.ndarray]  # mark -> (N,)

    def interval(self, start: str, end: str) -> np.ndarray:
        return self.marks_ms[end] - self.marks_ms[start]


def frame_times(stamps_ns: Sequence[int], marks: dict[int, dict[str, int]]) -> FrameTimes:
    """The marks of the frames `stamps_ns` (in that order), in ms since each frame's origin; NaN where absent."""
    names = sorted({mark for frame in marks.values() for mark in frame if mark != "control_brake"} | {"stamp"})
    stamps = np.asarray(stamps_ns, np.int64)
    table = {name: np.full(stamps.size, np.nan) for name in names}
    for index, stamp in enumerate(stamps):
        frame = marks.get(int(stamp), {})
        origin = frame.get("stamp", int(stamp))
        for name, t in frame.items():
            if name != "control_brake":
                table[name][index] = (t - origin) / 1e6
    table["stamp"][:] = 0.0
    if "rgb_taken" in table and "depth_taken" in table:
        table["input_ready"] = np.fmax(table["rgb_taken"], table["depth_taken"])
        table["input_ready"][np.isnan(table["rgb_taken"]) | np.isnan(table["depth_taken"])] = np.nan
    return FrameTimes(stamps, table)


def stage_rows(times: FrameTimes, answered: np.ndarray) -> list[dict]:
    rows = []
    for name, start, end in STAGES:
        if start in times.marks_ms and end in times.marks_ms:
            values = times.interval(start, end)[answered]
            rows.append({"stage": name, "from": start, "to": end, **percentiles(values[~np.isnan(values)])})
    for name, mark in CHECKPOINTS:
        if mark in times.marks_ms:
            values = times.marks_ms[mark][answered]
            rows.append({"stage": f"since the camera stamp: {name}", "from": "stamp", "to": mark,
                         **percentiles(values[~np.isnan(values)])})
    return rows


def slow_frame_causes(times: FrameTimes, answered: np.ndarray, slow_ms: float) -> tuple[Counter, list[dict]]:
    """For every answered frame slower than `slow_ms` end to end: the stage that took longest on its critical path."""
    end_to_end = times.marks_ms["control_dds"]
    causes: Counter[str] = Counter()
    examples = []
    depth = times.marks_ms.get("depth_taken")
    for index in np.flatnonzero(answered & (end_to_end > slow_ms)):
        later = "depth" if depth is not None and depth[index] > times.marks_ms["rgb_taken"][index] else "rgb"
        off_path = BRANCHES["rgb" if later == "depth" else "depth"] - BRANCHES[later]  # the stream ready first waited
        durations = {name: times.interval(start, end)[index] for name, start, end in STAGES
                     if name not in off_path and start in times.marks_ms and end in times.marks_ms}
        cause = max((name for name in durations if not np.isnan(durations[name])), key=durations.get)
        causes[cause] += 1
        if len(examples) < 20:
            examples.append({"frame": int(index), "end_to_end_ms": round(float(end_to_end[index]), 1), "cause": cause,
                             "cause_ms": round(float(durations[cause]), 1)})
    return causes, examples


