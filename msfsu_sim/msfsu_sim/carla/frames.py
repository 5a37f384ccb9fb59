"""Which recorded messages make each camera frame's sample, and its steer, target speed and command (ROS-free).

The rules are the importer's (`msfsu_sim.carla.importer`): pairing by the nearest time within the tolerance,
commands as recorded or derived from the route, every left-out frame counted once, by its first reason.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_control.route_tracker import RouteTrackerConfig
from msfsu_sim.carla.recording import STATUS_TYPE, CarlaImportError, Series, Sources
from msfsu_sim.carla.route import route_commands

# CARLA's RoadOption values the stack has no branch for but drives as LANE_FOLLOW (agents/navigation/local_planner.py)
LANE_CHANGES = {5: "CHANGELANELEFT", 6: "CHANGELANERIGHT"}


@dataclass(frozen=True)
class ImportSettings:
    split: str = "train"  # bag_io.SPLITS: how msfsu-train --bags uses the output
    tolerance_s: float = 0.05  # nearest-in-time matches further apart are no match (one bridge tick at 20 Hz)
    raw_tags: str | None = None  # labels.TAG_SETS numbering of a raw-tag semantic camera; None: palette colours
    labels: bool = True  # the semantic camera's labels are wanted: a recording without one is refused
    route: RouteTrackerConfig = RouteTrackerConfig()

    @property
    def tolerance_ns(self) -> int:
        return round(self.tolerance_s * 1e9)


def nearest(times: np.ndarray, queries: np.ndarray, tolerance_ns: int) -> np.ndarray:
    """Index into `times` (any order) of the time nearest to each query; -1 where none is within the tolerance."""
    if not len(times):
        return np.full(len(queries), -1, np.int64)
    order = np.argsort(times, kind="stable")
    ordered = times[order]
    right = np.clip(np.searchsorted(ordered, queries), 0, len(ordered) - 1)
    left = np.clip(right - 1, 0, len(ordered) - 1)
    pick = np.where(np.abs(ordered[left] - queries) <= np.abs(ordered[right] - queries), left, right)
    return np.where(np.abs(ordered[pick] - queries) <= tolerance_ns, order[pick], -1)


def latest_at_or_before(times: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Index into `times` (any order) of the latest time at or before each query; -1 before the first."""
    if not len(times):
        return np.full(len(queries), -1, np.int64)
    order = np.argsort(times, kind="stable")
    position = np.searchsorted(times[order], queries, side="right") - 1
    return np.where(position >= 0, order[np.clip(position, 0, None)], -1)


@dataclass(frozen=True)
class Frame:
    """One output sample: the messages it is made of (indices into their topic's series) and its labels."""

    stamp_ns: int
    rgb: int
    depth: int | None
    semantic: int | None
    steer: float
    target_speed: float
    command: int


@dataclass(frozen=True)
class Plan:
    frames: list[Frame]
    camera_frames: int
    dropped: Counter[str]
    sources: dict[str, str]  # what each output field came from, in words


def _frame_times(series: Series, rgb: Series, frames: np.ndarray) -> np.ndarray:
    """The frames' times on `series`' clock: their stamps, or their log times for a topic placed by log time."""
    return np.array(rgb.logs if series.by_log_time else rgb.stamps, np.int64)[frames]


def _increasing_frames(rgb: Series, dropped: Counter[str]) -> np.ndarray:
    """Indices of the RGB messages whose stamp is after every earlier message's (log order)."""
    stamps = np.array(rgb.stamps, np.int64)
    earlier_max = np.maximum.accumulate(np.concatenate([[np.iinfo(np.int64).min], stamps[:-1]]))
    keep = stamps > earlier_max
    dropped["stamp_not_increasing"] += int((~keep).sum())
    return np.flatnonzero(keep)


def _command_of(value: int) -> int | None:
    """A recorded RoadOption value -> the stack's command; None for VOID and values CARLA does not define."""
    if value in LANE_CHANGES:
        return int(RoadOption.LANE_FOLLOW)
    return value if value in {option.value for option in RoadOption} else None


def _recorded_commands(series: dict[str, Series], frames: np.ndarray) -> list[int | str]:
    """Per frame: the latest recorded command at or before it, or why there is none."""
    recorded = series["command"]
    found = latest_at_or_before(recorded.times(), _frame_times(recorded, series["rgb"], frames))
    commands: list[int | str] = []
    for index in found:
        command = None if index < 0 else _command_of(recorded.values[index])
        commands.append("no_command" if index < 0 else "unknown_command" if command is None else command)
    return commands


def _route_commands(series: dict[str, Series], frames: np.ndarray, tolerance_ns: int,
                    config: RouteTrackerConfig) -> list[int | str]:
    """Per frame: the command the route in force says at the frame's odometry position, or why there is none."""
    rgb, route, odometry = series["rgb"], series["route"], series["odometry"]
    if not route.values:  # the topic is there, its message is not (a recording cut short before it)
        return ["no_route"] * len(frames)
    at = nearest(odometry.times(), _frame_times(odometry, rgb, frames), tolerance_ns)
    # the route in force: the latest one logged before the frame (the latched route may be logged after the first)
    in_force = np.maximum(latest_at_or_before(np.array(route.logs, np.int64), np.array(rgb.logs)[frames]), 0)
    commands: list[int | str] = ["no_position"] * len(frames)
    for index in np.unique(in_force):
        rows = np.flatnonzero((in_force == index) & (at >= 0))
        if not len(rows):
            continue
        positions = np.array([odometry.values[i] for i in at[rows]], np.float64)
        try:
            options = route_commands(route.values[index], positions, config)
        except ValueError as error:
            raise CarlaImportError(f"the route logged at {route.logs[index] * 1e-9:.3f} s: {error}") from None
        for row, option in zip(rows, options):
            commands[row] = int(option)
    return commands


def plan_frames(series: dict[str, Series], sources: Sources, settings: ImportSettings) -> Plan:
    """The frames that make samples, each with its messages, steer, target speed and command; the rest counted."""
    dropped: Counter[str] = Counter()
    rgb = series["rgb"]
    frames = _increasing_frames(rgb, dropped)
    stamps = np.array(rgb.stamps, np.int64)[frames]
    tolerance = settings.tolerance_ns
    matched: dict[str, np.ndarray] = {}
    for role in ("depth", "semantic", "control", "speed"):
        if sources.connections[role] is not None:
            matched[role] = nearest(series[role].times(), _frame_times(series[role], rgb, frames), tolerance)
    if sources.connections["command"] is not None:
        commands = _recorded_commands(series, frames)
    else:
        commands = _route_commands(series, frames, tolerance, settings.route)
    kept = []
    for row, (index, stamp) in enumerate(zip(frames, stamps)):
        missing = next((role for role, found in matched.items() if found[row] < 0), None)
        steer, reverse = (0.0, False) if missing else series["control"].values[matched["control"][row]]
        reason = f"no_{missing}" if missing else "reverse" if reverse else commands[row]
        if isinstance(reason, str):  # each left-out frame counted once, by the first reason in this order
            dropped[reason] += 1
            continue
        kept.append(Frame(
            stamp_ns=int(stamp), rgb=int(index),
            depth=int(matched["depth"][row]) if "depth" in matched else None,
            semantic=int(matched["semantic"][row]) if "semantic" in matched else None,
            steer=float(np.clip(steer, -1.0, 1.0)), target_speed=series["speed"].values[matched["speed"][row]],
            command=reason))
    return Plan(kept, len(rgb.stamps), dropped, _describe_sources(series, sources, settings))


def _describe_sources(series: dict[str, Series], sources: Sources, settings: ImportSettings) -> dict[str, str]:
    """What each output field was made from, in words (the report's lines and the output's metadata)."""
    def placed(role: str) -> str:
        return " (no header stamps: placed by log time)" if series[role].values and series[role].by_log_time else ""

    control, speed, command = (sources.connections[role] for role in ("control", "speed", "command"))
    steer_field = "control.steer" if control.msgtype == STATUS_TYPE else "steer"
    speed_field = "velocity" if speed.msgtype == STATUS_TYPE else "|twist.linear|"
    if command is not None:
        command_source = f"recorded: {command.topic} ({command.msgtype}){placed('command')}"
    else:
        command_source = (f"derived from the route {sources.topic('route')} (turns from its shape, never STRAIGHT; "
                          f"look-ahead {settings.route.lookahead_m:g} m at the {sources.topic('odometry')} position)")
    semantic = sources.topic("semantic")
    encoding = f"raw tags, CARLA {settings.raw_tags}" if settings.raw_tags else "CityScapes palette"
    missing = {role: f"none: no {role} camera on {sources.looked_for[role]} (topics: {sources.present}; name it "
                     f"with --{role}-topic)" for role in ("semantic", "depth")}
    if not settings.labels:
        missing["semantic"] = "none: --no-labels"
    return {
        "labels": missing["semantic"] if semantic is None else f"{semantic} ({encoding})",
        "depth": sources.topic("depth") or missing["depth"],
        "steer": f"{control.topic} {steer_field}{placed('control')}",
        "target_speed": f"{speed.topic} {speed_field}{placed('speed')}",
        "command": command_source,
    }


