"""The last seconds before each collision, from the episodes' telemetry (closed_loop.telemetry): what the driver asked
for, what the expert would have asked for in the same state, and where the nearest pedestrian and vehicle were.

The report's `collisions.md` (msfsu-benchmark, msfsu-benchmark-report): per collision with a vehicle or pedestrian,
the steps WINDOW_S seconds before the last one the driver acted on, every STEP_EVERY_S. Episodes recorded before
telemetry was kept are counted, not shown.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from msfsu_evaluation.closed_loop.runs import Record
from msfsu_evaluation.closed_loop.telemetry import Telemetry

WINDOW_S = 3.0
STEP_EVERY_S = 0.5
KINDS = ("pedestrian", "vehicle")
WHERE_BEFORE_S = 1.0  # the summary says where the nearest participant of the kind hit was this long before
SLOW_MPS = 0.5  # the summary counts the collisions after the car had slowed below this within the window


@dataclass(frozen=True)
class Participant:
    name: str
    distance_m: float
    bearing_deg: float
    in_view: bool
    in_crop: bool
    height_px: float  # in the network's input
    visible: float  # share of its crop box the depth image shows (NaN: blind episode)

    def text(self) -> str:
        if not self.name:
            return "-"
        where = "in crop" if self.in_crop else "in view" if self.in_view else "out of view"
        size = f", {self.height_px:.0f} px high" if self.in_crop else ""
        seen = f", {self.visible:.0%} visible" if self.in_crop and math.isfinite(self.visible) else ""
        return f"{self.name}: {self.distance_m:.1f} m at {self.bearing_deg:+.0f} deg, {where}{size}{seen}"


@dataclass(frozen=True)
class CollisionStep:
    before_s: float  # seconds before the last step
    speed_mps: float
    target_speed_mps: float  # the driver's
    expert_target_speed_mps: float  # the expert's in the same state (NaN: not labelled)
    throttle: float
    brake: float
    pedestrian: Participant
    vehicle: Participant


@dataclass(frozen=True)
class CollisionWindow:
    agent: str
    route: str
    collision_type: str
    actor: str  # who was hit ("" when the record does not say)
    steps: tuple[CollisionStep, ...]

    def to_json(self) -> dict:
        return asdict(self)


def _participant(telemetry: Telemetry, kind: str, row: int) -> Participant:
    value = lambda name: float(telemetry.column(f"{kind}_{name}")[row])  # noqa: E731
    return Participant(telemetry.name_at(kind, row), value("distance_m"), value("bearing_deg"),
                       value("in_view") == 1.0, value("in_crop") == 1.0, value("height_px"), value("visible"))


def window(record: Record, telemetry: Telemetry) -> CollisionWindow:
    """The steps of the last WINDOW_S seconds of a collision episode, every STEP_EVERY_S, the last one included."""
    times = telemetry.column("time_s")
    end = times[-1]
    steps = []
    for before in np.arange(WINDOW_S, -1e-9, -STEP_EVERY_S):
        row = int(np.argmin(np.abs(times - (end - before))))
        if abs(times[row] - (end - before)) > 0.051:
            continue  # the episode is shorter than the window
        column = lambda name: float(telemetry.column(name)[row])  # noqa: E731
        steps.append(CollisionStep(round(float(before), 1), column("speed_mps"), column("action_target_speed_mps"),
                                   column("expert_target_speed_mps"), column("control_throttle"),
                                   column("control_brake"), _participant(telemetry, "pedestrian", row),
                                   _participant(telemetry, "vehicle", row)))
    episode = record.episode
    return CollisionWindow(episode.agent, episode.route, episode.collision_type, episode.collision_actor or "",
                           tuple(steps))


def collision_windows(records: Mapping[tuple[str, str], Record], agents: Sequence[str]) -> tuple[list[CollisionWindow], int]:
    """(windows of every vehicle or pedestrian collision of `agents` with telemetry, collisions without telemetry)."""
    windows, missing = [], 0
    for key, record in sorted(records.items()):
        episode = record.episode
        if key[0] not in agents or episode.status != "collision" or episode.collision_type not in KINDS:
            continue
        telemetry = record.telemetry()
        if telemetry is None or not len(telemetry):
            missing += 1
            continue
        windows.append(window(record, telemetry))
    return windows, missing


def number_text(value: float, digits: int = 1) -> str:
    """A figure of a table, "-" where it is not known (NaN)."""
    return "-" if not math.isfinite(value) else f"{value:.{digits}f}"


def where_before(item: CollisionWindow) -> str:
    """Where the nearest participant of the kind hit was WHERE_BEFORE_S before the last step: "out of view", "in
    view" (outside the network's crop), "in crop", or "-" (none of that kind near, or the episode is shorter)."""
    step = next((step for step in item.steps if step.before_s == WHERE_BEFORE_S), None)
    seen = None if step is None else getattr(step, item.collision_type)
    if seen is None or not seen.name:
        return "-"
    return "in crop" if seen.in_crop else "in view" if seen.in_view else "out of view"


def summary_markdown(windows: Sequence[CollisionWindow]) -> list[str]:
    """Per agent and kind hit: how many collisions, where the nearest participant of that kind was WHERE_BEFORE_S
    before (the camera's view, the network's crop), and how many came after the car had slowed below SLOW_MPS within
    the window."""
    places = ("out of view", "in view", "in crop", "-")
    lines = [f"Per agent and kind: where the nearest participant of the kind hit was {WHERE_BEFORE_S:g} s before ("
             "out of the camera's view, in view but outside the network's crop, in the crop; - none near or the "
             f"episode shorter), and the collisions after the car had slowed below {SLOW_MPS:g} m/s in the window.",
             "", "| agent | hit | collisions | " + " | ".join(places) + " | after slowing |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for agent in sorted({item.agent for item in windows}):
        for kind in KINDS:
            items = [item for item in windows if item.agent == agent and item.collision_type == kind]
            if not items:
                continue
            counts = [sum(where_before(item) == place for item in items) for place in places]
            slowed = sum(any(step.speed_mps < SLOW_MPS for step in item.steps) for item in items)
            lines.append(f"| {agent} | {kind} | {len(items)} | " + " | ".join(map(str, counts)) + f" | {slowed} |")
    return lines + [""]


def collisions_markdown(windows: Sequence[CollisionWindow], missing: int) -> str:
    """collisions.md: one table per collision."""
    lines = ["# The last seconds before each collision", "",
             f"Every collision with a vehicle or a pedestrian, the last {WINDOW_S:.0f} s before the last step the "
             f"driver acted on, every {STEP_EVERY_S} s, from the episodes' telemetry (closed_loop/telemetry.py): the "
             "car's speed, the target speed its driver asked for beside the expert's in the same state, the control, "
             "and the nearest pedestrian and vehicle ahead (distance and bearing from the car's centre, bearing "
             "positive right; in the camera's view, in the network's crop, its height in network input pixels, the "
             "share of its box the depth image shows).", ""]
    if missing:
        lines += [f"{missing} collisions of these runs have no telemetry (recorded before it was kept).", ""]
    if not windows:
        lines.append("No collision with telemetry.")
    else:
        lines += summary_markdown(windows)
    for item in windows:
        hit = f": {item.actor}" if item.actor else ""
        lines += [f"## {item.agent} on {item.route}, {item.collision_type}{hit}", "",
                  "| s before | speed m/s | target m/s (driver / expert) | throttle / brake | nearest pedestrian | "
                  "nearest vehicle |", "| --- | --- | --- | --- | --- | --- |"]
        for step in item.steps:
            lines.append(f"| {step.before_s:.1f} | {number_text(step.speed_mps)} | {number_text(step.target_speed_mps)} / "
                         f"{number_text(step.expert_target_speed_mps)} | {number_text(step.throttle, 2)} / "
                         f"{number_text(step.brake, 2)} | {step.pedestrian.text()} | {step.vehicle.text()} |")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"
