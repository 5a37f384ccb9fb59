"""Teacher for data collection: pure-pursuit on the route + IDM speed that yields to traffic, and
steering-noise injection (paper III-A). ROS-free; works on plain numbers from SimEnvironment.

Whom it yields to (msfsu_sim.scene decides who is in the way, with oriented boxes):
- the nearest participant in its corridor ahead (IDM car following), and pedestrians predicted to walk
  into it within 3 s;
- before a junction, cross traffic: if a vehicle that does not drive its way (not a lead, not a
  follower) would come into its path through the junction before it could clear the junction, it stops
  at the entry and waits for the gap. Inside a junction it never stops for a prediction (stopping there
  is what gets a car hit); it is committed once it cannot stop before the entry anyway.

The label is always the expert's own steer/target speed; during noise only the *applied* steering is
perturbed, so the car drifts and the recorded labels show the correction (the noise flag marks
those frames so training can drop them).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_control.pid import Longitudinal, SpeedController
from msfsu_control.route_tracker import RouteTracker
from msfsu_sim.environment import STEP_S, Observation, Odometry, SimEnvironment
from msfsu_sim.scene import (EGO_HALF_LENGTH_M, PEDESTRIAN, VEHICLE, Encounter, Obstacle, crosses_within,
                             first_in_corridor, moving_with, path_ahead)

MAX_STEER_RAD = math.radians(40.0)  # MetaDrive DefaultVehicle max steering angle at |steer| = 1
WHEELBASE_M = 2.5


@dataclass(frozen=True)
class ExpertConfig:
    cruise_speed: float = 8.0  # m/s (~29 km/h, town driving)
    junction_speed: float = 5.0  # m/s while a turn command is active
    lookahead_min_m: float = 4.0
    lookahead_gain_s: float = 0.6  # pure-pursuit look-ahead grows with speed
    corridor_margin_m: float = 0.4  # beyond the ego's half width and the participant's half extent
    scan_m: float = 40.0
    # constant-velocity look-ahead per kind: pedestrians stepping into the lane, vehicles cutting in
    predict_s: tuple[tuple[str, tuple[float, ...]], ...] = (
        (PEDESTRIAN, (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0)), (VEHICLE, (0.0, 0.5)))
    # junctions: look for cross traffic from this far before the entry, over the time to clear the junction
    junction_approach_m: float = 25.0
    junction_stop_m: float = 3.0  # wait this far before the entry: turning traffic cuts the corners
    junction_exit_margin_m: float = 6.0  # the junction counts as cleared this far past its end
    junction_margin_s: float = 1.5  # added to the time to clear it
    max_junction_horizon_s: float = 8.0
    hard_decel: float = 4.0  # m/s^2: closer to the entry than this stopping distance, it commits
    # IDM
    max_accel: float = 1.5
    comfort_decel: float = 2.5
    min_gap_m: float = 3.0
    time_headway_s: float = 1.2


@dataclass(frozen=True)
class ExpertAction:
    steer: float  # [-1, 1], positive right (CARLA)
    target_speed: float  # m/s
    command: RoadOption


def idm_acceleration(speed: float, desired: float, gap: float | None, closing_speed: float,
                     config: ExpertConfig) -> float:
    """Intelligent Driver Model acceleration (m/s^2); gap None = free road."""
    free = 1.0 - (speed / max(desired, 0.1)) ** 4
    if gap is None:
        return config.max_accel * free
    desired_gap = config.min_gap_m + speed * config.time_headway_s + \
        speed * closing_speed / (2 * math.sqrt(config.max_accel * config.comfort_decel))
    return config.max_accel * (free - (max(desired_gap, 0.0) / max(gap, 0.1)) ** 2)


def pure_pursuit_steer(odometry: Odometry, target: np.ndarray) -> float:
    """Steer in CARLA convention (positive right) that drives the rear axle arc through `target`."""
    dx, dy = target[0] - odometry.x, target[1] - odometry.y
    alpha = math.atan2(dy, dx) - odometry.yaw
    distance = max(math.hypot(dx, dy), 1e-3)
    angle = math.atan(2 * WHEELBASE_M * math.sin(alpha) / distance)  # counter-clockwise positive
    return float(np.clip(-angle / MAX_STEER_RAD, -1.0, 1.0))


def nearest_blocking(path: PathAhead, obstacles: Sequence[Obstacle], config: ExpertConfig) -> Encounter | None:
    """The participant to follow or to stop for in the corridor ahead (look-ahead per kind), or None."""
    return first_in_corridor(path, obstacles, dict(config.predict_s), config.corridor_margin_m)


def junction_stop_gap(tracker: RouteTracker, speed: float, obstacles: Sequence[Obstacle],
                      config: ExpertConfig) -> float | None:
    """Gap (m) to the entry of the junction ahead if cross traffic means waiting there, else None.

    None too inside a junction, when no junction is near, or when the entry is closer than the car can stop.
    """
    progress = tracker.progress_m
    upcoming = [(start, end) for start, end in tracker.junction_spans() if end > progress]
    if not upcoming:
        return None
    start, end = upcoming[0]
    gap = start - progress - EGO_HALF_LENGTH_M - config.junction_stop_m  # front bumper to the waiting point
    if progress >= start or gap > config.junction_approach_m or \
            speed ** 2 / (2 * config.hard_decel) > gap + config.junction_stop_m:
        return None
    through = path_ahead(tracker, start - 2.0, end + config.junction_exit_margin_m)
    leaving = end + config.junction_exit_margin_m - progress
    horizon = min(leaving / max(speed, 0.6 * config.junction_speed) + config.junction_margin_s,
                  config.max_junction_horizon_s)
    around = path_ahead(tracker, progress - 20.0, end + config.junction_exit_margin_m)
    for obstacle in obstacles:
        if obstacle.kind != VEHICLE or moving_with(around, obstacle):
            continue
        reach = math.hypot(obstacle.x - through.points[0, 0], obstacle.y - through.points[0, 1])
        if reach > obstacle.speed * horizon + config.scan_m:
            continue  # too far away to matter within the horizon
        if crosses_within(through, obstacle, horizon, config.corridor_margin_m):
            return max(gap, 0.0)
    return None


class Expert:
    """One instance per episode (call `reset`)."""

    def __init__(self, config: ExpertConfig = ExpertConfig()) -> None:
        self.config = config
        self.speed_controller = SpeedController()

    def reset(self) -> None:
        self.speed_controller.reset()

    def act(self, odometry: Odometry, tracker: RouteTracker, command: RoadOption,
            obstacles: Sequence[Obstacle], dt: float) -> ExpertAction:
        config = self.config
        lookahead = config.lookahead_min_m + config.lookahead_gain_s * odometry.speed
        steer = pure_pursuit_steer(odometry, tracker.point_at(tracker.progress_m + lookahead))
        path = path_ahead(tracker, tracker.progress_m, tracker.progress_m + config.scan_m)
        desired = config.cruise_speed if command is RoadOption.LANE_FOLLOW else config.junction_speed
        encounter = nearest_blocking(path, obstacles, config)
        gap, lead_speed = (encounter.gap_m, encounter.speed_along) if encounter else (None, 0.0)
        entry = junction_stop_gap(tracker, odometry.speed, obstacles, config)
        if entry is not None and (gap is None or entry < gap):
            gap, lead_speed = entry, 0.0
        acceleration = idm_acceleration(odometry.speed, desired, gap, odometry.speed - lead_speed, config)
        target_speed = float(np.clip(odometry.speed + acceleration * 1.0, 0.0, desired))
        if gap is not None and gap < config.min_gap_m:
            target_speed = 0.0
        return ExpertAction(steer, target_speed, command)

    def act_on(self, obs: Observation, env: SimEnvironment) -> ExpertAction:
        """The label of a simulator frame: `act` on its odometry and command and the scene around it."""
        return self.act(obs.odometry, env.tracker, obs.command, env.obstacles(), STEP_S)

    def drive(self, obs: Observation, env: SimEnvironment) -> tuple[ExpertAction, Longitudinal]:
        """The label and the throttle/brake that track its target speed (the control node's speed PID)."""
        action = self.act_on(obs, env)
        return action, self.speed_controller.step(action.target_speed, obs.odometry.speed)


@dataclass(frozen=True)
class NoiseConfig:
    period_s: float = 5.0  # a noise burst starts every period
    duration_s: float = 1.0
    max_offset: float = 0.15  # largest steering offset of a burst (normalised steer)
    first_burst_s: float = 5.0  # let the car settle before the first burst


class SteeringNoise:
    """Deterministic (seeded) bursts: a steering offset of random sign and size held for 1 s, every 5 s."""

    def __init__(self, seed: int, config: NoiseConfig = NoiseConfig()) -> None:
        self.config = config
        self._rng = np.random.default_rng(seed)
        self._burst = -1
        self._amplitude = 0.0

    def active(self, time_s: float) -> bool:
        config = self.config
        if time_s < config.first_burst_s:
            return False
        return (time_s - config.first_burst_s) % config.period_s < config.duration_s - 1e-9

    def offset(self, time_s: float) -> float:
        """Steering offset to add to the applied command at `time_s` (0 outside bursts)."""
        if not self.active(time_s):
            return 0.0
        config = self.config
        burst = int((time_s - config.first_burst_s) // config.period_s)
        if burst != self._burst:
            self._burst = burst
            self._amplitude = float(self._rng.uniform(0.5, 1.0) * self._rng.choice([-1.0, 1.0])) * config.max_offset
        return self._amplitude
