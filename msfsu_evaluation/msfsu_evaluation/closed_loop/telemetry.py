"""Per-step telemetry of a closed-loop episode: what the driver asked for, what the control did, who was ahead.

One row per simulator step (10 Hz), written beside the episode's trajectory as `telemetry/<agent>/<route>.npz`
(numpy's compressed archive: each column an int16 array at its COLUMNS scale, NaN stored as INT16_NAN, plus the
names of the participants the rows refer to): a few kB per episode. `load(path)` gives the columns back as float
arrays with NaN where nothing was recorded.

Columns, per step:
- the car: time, speed, the command in force (the simulator's route, RoadOption value);
- the driver's action for this frame (a network's DrivingAction as its perception node published it, the expert's
  own): steer, target speed, the command of the branch that produced it, and its age in steps (free-running: the
  newest action that had arrived; 0 in lockstep); with the emergency brake, its decision (AEB_DECISIONS) and the
  target speed it sent on to the control;
- the control applied: steer, throttle, brake;
- the expert's action in the same state (labels computed beside a network, as the on-policy rounds label frames;
  the expert's own where it drives): steer, target speed, and what limits its speed (EXPERT_LIMITS);
- from the simulator's ground truth, the nearest pedestrian and the nearest vehicle ahead of the car (in front of its
  centre, within AHEAD_M): distance and bearing from the car's centre (bearing positive right, as steer), whether its
  box is in the camera's field of view and in the network's crop (msfsu_common.camera_geometry), its size in network
  input pixels, the share of its box's crop pixels that the depth image shows (occlusion; NaN in a blind episode),
  and which participant it is (an index into the archive's names).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_common.camera_geometry import HEIGHTS_M, CameraView, appearance, visible_fraction
from msfsu_sim.scene import PEDESTRIAN, VEHICLE, Obstacle

INT16_NAN = -32768
AHEAD_M = 60.0
EXPERT_LIMITS = ("free", "vehicle", "pedestrian", "junction")  # msfsu_sim.expert.ExpertAction.limited_by
AEB_DECISIONS = ("none", "cap", "brake")  # msfsu_control.aeb


@dataclass(frozen=True)
class Column:
    name: str
    scale: float  # stored value = round(value / scale)
    unit: str


def _participant_columns(prefix: str) -> tuple[Column, ...]:
    return (Column(f"{prefix}_distance_m", 0.01, "m"), Column(f"{prefix}_bearing_deg", 0.01, "deg"),
            Column(f"{prefix}_in_view", 1, "0/1"), Column(f"{prefix}_in_crop", 1, "0/1"),
            Column(f"{prefix}_width_px", 0.01, "px"), Column(f"{prefix}_height_px", 0.01, "px"),
            Column(f"{prefix}_visible", 0.001, "share"), Column(f"{prefix}_id", 1, "index"))


COLUMNS: tuple[Column, ...] = (
    Column("time_s", 0.1, "s"), Column("speed_mps", 0.01, "m/s"), Column("command", 1, "RoadOption"),
    Column("action_steer", 0.0001, ""), Column("action_target_speed_mps", 0.01, "m/s"),
    Column("action_command", 1, "RoadOption"), Column("action_age_steps", 1, "steps"),
    Column("aeb_decision", 1, "AEB_DECISIONS index"), Column("aeb_target_speed_mps", 0.01, "m/s"),
    Column("control_steer", 0.0001, ""), Column("control_throttle", 0.0001, ""), Column("control_brake", 0.0001, ""),
    Column("expert_steer", 0.0001, ""), Column("expert_target_speed_mps", 0.01, "m/s"),
    Column("expert_limit", 1, "EXPERT_LIMITS index"),
    *_participant_columns("pedestrian"), *_participant_columns("vehicle"),
)
NAMES = tuple(column.name for column in COLUMNS)
_SCALES = np.array([column.scale for column in COLUMNS], np.float64)


@dataclass(frozen=True)
class DriverStep:
    """The driver's action of one frame, as telemetry records it (NaN: none had arrived)."""

    steer: float
    target_speed_mps: float
    command: int | None
    age_steps: int | None
    aeb_decision: str | None = None  # the emergency brake's on this frame (None: the driver has none)
    aeb_target_speed_mps: float = math.nan  # the target speed it sent on to the control


@dataclass(frozen=True)
class ExpertLabel:
    steer: float
    target_speed_mps: float
    limited_by: str


@dataclass(frozen=True)
class Nearest:
    """The nearest participant of a kind ahead, as the row records it."""

    obstacle: Obstacle
    distance_m: float
    bearing_deg: float
    forward_m: float
    right_m: float


def nearest_ahead(participants: Sequence[Obstacle], x: float, y: float, yaw: float, kind: str) -> Nearest | None:
    """The nearest participant of `kind` in front of the car's centre and within AHEAD_M (map frame x, y, yaw)."""
    best = None
    cos, sin = math.cos(yaw), math.sin(yaw)
    for obstacle in participants:
        if obstacle.kind != kind:
            continue
        dx, dy = obstacle.x - x, obstacle.y - y
        forward, left = dx * cos + dy * sin, -dx * sin + dy * cos
        distance = math.hypot(dx, dy)
        if forward <= 0.0 or distance > AHEAD_M or (best is not None and distance >= best.distance_m):
            continue
        best = Nearest(obstacle, distance, math.degrees(math.atan2(-left, forward)), forward, -left)
    return best


class TelemetryRecorder:
    """Collects one episode's rows; `arrays()` / `save(path)` at the end."""

    def __init__(self, view: CameraView) -> None:
        self.view = view
        self.rows: list[list[float]] = []
        self.names: list[str] = []

    def _name_index(self, name: str) -> int:
        if name not in self.names:
            self.names.append(name)
        return self.names.index(name)

    def _participant(self, nearest: Nearest | None, yaw: float, depth: np.ndarray | None) -> list[float]:
        if nearest is None:
            return [math.nan] * 8
        obstacle = nearest.obstacle
        relative_heading = obstacle.heading - yaw  # counter-clockwise, as camera_geometry.appearance takes it
        seen = appearance(self.view, nearest.forward_m, nearest.right_m, relative_heading, obstacle.length,
                          obstacle.width, HEIGHTS_M.get(obstacle.kind, 1.5))
        visible = math.nan
        if depth is not None and seen.box is not None:
            reach = obstacle.half_extent_along(obstacle.heading) + obstacle.width / 2
            visible = visible_fraction(depth, seen.box, nearest.forward_m - self.view.forward_m - reach,
                                       nearest.forward_m - self.view.forward_m + reach)
        return [nearest.distance_m, nearest.bearing_deg, float(seen.in_view), float(seen.in_crop), seen.width_px,
                seen.height_px, visible, float(self._name_index(obstacle.name or obstacle.kind))]

    def add(self, time_s: float, speed_mps: float, command: int, action: DriverStep,
            control: tuple[float, float, float], expert: ExpertLabel | None, participants: Sequence[Obstacle],
            pose: tuple[float, float, float], depth: np.ndarray | None) -> None:
        """One step: the car's time, speed, command and pose (x, y, yaw), the driver's action, the control applied
        (steer, throttle, brake), the expert's label, the scene's participants and the frame's depth image."""
        x, y, yaw = pose
        row = [time_s, speed_mps, float(command), action.steer, action.target_speed_mps,
               math.nan if action.command is None else float(action.command),
               math.nan if action.age_steps is None else float(action.age_steps),
               float(AEB_DECISIONS.index(action.aeb_decision)) if action.aeb_decision in AEB_DECISIONS else math.nan,
               action.aeb_target_speed_mps, *control]
        row += ([math.nan] * 3 if expert is None else
                [expert.steer, expert.target_speed_mps, float(EXPERT_LIMITS.index(expert.limited_by))
                 if expert.limited_by in EXPERT_LIMITS else math.nan])
        for kind in (PEDESTRIAN, VEHICLE):
            row += self._participant(nearest_ahead(participants, x, y, yaw, kind), yaw, depth)
        self.rows.append(row)

    def arrays(self) -> np.ndarray:
        """(T, len(COLUMNS)) float64."""
        return np.asarray(self.rows, np.float64).reshape(-1, len(COLUMNS))

    def save(self, path: Path) -> None:
        save(path, self.arrays(), self.names)


def save(path: Path, rows: np.ndarray, names: Sequence[str]) -> None:
    """Write rows (T, len(COLUMNS)) and participant names as the compact archive."""
    stored = np.round(rows / _SCALES)
    stored = np.where(np.isfinite(stored), np.clip(stored, INT16_NAN + 1, 32767), INT16_NAN).astype(np.int16)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, columns=np.array(NAMES), rows=stored, names=np.array(list(names), dtype=str))


@dataclass(frozen=True)
class Telemetry:
    """An episode's telemetry read back: `column(name)` as float64 with NaN where nothing was recorded."""

    rows: np.ndarray  # (T, C) float64
    columns: tuple[str, ...]
    names: tuple[str, ...]  # participants, by the *_id columns

    def column(self, name: str) -> np.ndarray:
        return self.rows[:, self.columns.index(name)]

    def name_at(self, prefix: str, step: int) -> str:
        """The participant the row's `prefix` (pedestrian / vehicle) columns describe, "" for none."""
        index = self.column(f"{prefix}_id")[step]
        return "" if not np.isfinite(index) else self.names[int(index)]

    def __len__(self) -> int:
        return len(self.rows)


def load(path: Path) -> Telemetry:
    """ValueError when the archive is not a telemetry file (columns missing)."""
    with np.load(path) as archive:
        if "columns" not in archive or "rows" not in archive:
            raise ValueError(f"{path} is not a telemetry archive")
        columns = tuple(str(name) for name in archive["columns"])
        stored = archive["rows"]
        names = tuple(str(name) for name in archive["names"])
    scales = np.array([dict((c.name, c.scale) for c in COLUMNS).get(name, 1.0) for name in columns])
    rows = np.where(stored == INT16_NAN, np.nan, stored.astype(np.float64) * scales)
    return Telemetry(rows, columns, names)
