"""Teacher for data collection: pure-pursuit on the route + IDM speed that yields to traffic, and
steering-noise injection (paper III-A). ROS-free; works on plain numbers from SimEnvironment.

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
from msfsu_sim.environment import STEP_S, Observation, Obstacle, Odometry, SimEnvironment

MAX_STEER_RAD = math.radians(40.0)  # MetaDrive DefaultVehicle max steering angle at |steer| = 1
WHEELBASE_M = 2.5
EGO_HALF_LENGTH_M = 2.3


@dataclass(frozen=True)
class ExpertConfig:
    cruise_speed: float = 8.0  # m/s (~29 km/h, town driving)
    junction_speed: float = 5.0  # m/s while a turn command is active
    lookahead_min_m: float = 4.0
    lookahead_gain_s: float = 0.6  # pure-pursuit look-ahead grows with speed
    corridor_half_width_m: float = 1.6  # obstacles closer than this (+ their radius) to the path block it
    scan_m: float = 40.0
    predict_s: tuple[float, ...] = (0.0, 0.5, 1.0, 1.5)  # constant-velocity look-ahead for crossing agents
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


def nearest_blocking(path: np.ndarray, path_s: np.ndarray, obstacles: Sequence[Obstacle],
                     config: ExpertConfig) -> tuple[float, float] | None:
    """(gap m, obstacle speed along the path m/s) of the closest obstacle in the corridor ahead, or None."""
    best: tuple[float, float] | None = None
    headings = np.arctan2(np.gradient(path[:, 1]), np.gradient(path[:, 0]))
    for obstacle in obstacles:
        for t in config.predict_s:
            point = np.array([obstacle.x + obstacle.vx * t, obstacle.y + obstacle.vy * t])
            distances = np.linalg.norm(path - point, axis=1)
            index = int(np.argmin(distances))
            if distances[index] > config.corridor_half_width_m + obstacle.radius or index == 0:
                continue
            gap = path_s[index] - EGO_HALF_LENGTH_M - obstacle.radius
            along = obstacle.vx * math.cos(headings[index]) + obstacle.vy * math.sin(headings[index])
            # A predicted position means the agent will be in the way: treat it as standing there.
            speed = max(along, 0.0) if t == 0.0 else 0.0
            if best is None or gap < best[0]:
                best = (gap, speed)
            break
    return best


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
        path_s = np.arange(0.0, config.scan_m, 1.0)
        path = np.array([tracker.point_at(tracker.progress_m + s) for s in path_s])
        desired = config.cruise_speed if command is RoadOption.LANE_FOLLOW else config.junction_speed
        blocking = nearest_blocking(path, path_s, obstacles, config)
        gap, lead_speed = blocking if blocking else (None, 0.0)
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
