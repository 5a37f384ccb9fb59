"""Teacher for data collection: pure-pursuit on the route + a target speed that yields to traffic, and
steering-noise injection (paper III-A). ROS-free; works on plain numbers from SimEnvironment.

Whom it yields to (msfsu_sim.scene decides who is in the way, with oriented boxes):
- the nearest participant in its corridor ahead (car following), and pedestrians predicted to walk
  into it within 3 s;
- before a junction, cross traffic: if a vehicle that is not a lead or follower in its lane would be in
  its path through the junction (constant velocity) while it is there itself (its time to each point,
  accelerating to junction speed, +- a safety margin), it stops short of the entry and waits for a gap;
  traffic that passes before it gets there, or after it has gone, does not stop it, nor a car still far
  enough from the meeting point to stop comfortably for it (traffic brakes for the ego in its path,
  msfsu_sim.traffic.YieldingIDMPolicy). Inside a junction it never stops for a prediction (stopping
  there is what gets a car hit); it is committed once it cannot stop before the entry anyway.

Its target speed (the label, and what it asks the control node's speed PID for, as the network's will
be) is the speed the *scene* allows, never a function of its own speed: the desired speed on a free road
(cruise, or junction speed while a turn command is active), else the highest speed from which it can still
stop `min_gap_m` behind what is ahead with `comfort_decel` after `reaction_s`, given the lead may brake as
hard (`scene_speed`, Gipps' safe speed). So one image has one label: the old label, current speed + IDM
acceleration x 1 s, was 1.5 m/s at rest and 8 m/s cruising on the same free road.

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
from msfsu_sim.scene import (EGO_HALF_LENGTH_M, PEDESTRIAN, VEHICLE, Encounter, Obstacle, first_in_corridor,
                             moving_with, occupancy, path_ahead, time_to_travel)

MAX_STEER_RAD = math.radians(40.0)  # MetaDrive DefaultVehicle max steering angle at |steer| = 1
WHEELBASE_M = 2.5


@dataclass(frozen=True)
class ExpertConfig:
    cruise_speed: float = 8.0  # m/s (~29 km/h, town driving)
    junction_speed: float = 5.0  # m/s while a turn command is active
    lookahead_min_m: float = 4.0
    lookahead_gain_s: float = 0.6  # pure-pursuit look-ahead grows with speed
    corridor_margin_m: float = 0.7  # beyond the ego's half width and the participant's half extent (pure pursuit
    # cuts the inside of a turn by a few decimetres: a car standing 2.5 m off the route was hit turning left)
    scan_m: float = 40.0
    # constant-velocity look-ahead per kind: pedestrians stepping into the lane, vehicles cutting in
    predict_s: tuple[tuple[str, tuple[float, ...]], ...] = (
        (PEDESTRIAN, (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0)), (VEHICLE, (0.0, 0.5)))
    # junctions: look for cross traffic from this far before the entry, over the time to clear the junction
    junction_approach_m: float = 25.0
    junction_stop_m: float = 5.0  # wait this far before the entry: turning traffic cuts the corners
    junction_exit_margin_m: float = 6.0  # the junction counts as cleared this far past its end
    junction_margin_s: float = 1.5  # gap kept, in time, to cross traffic at the point where the paths meet
    junction_horizon_s: float = 10.0
    start_accel: float = 2.0  # m/s^2: what it assumes for itself when it estimates its time through the junction
    # a crossing car farther from the meeting point than speed * reaction + speed^2 / (2 decel) + margin will stop
    traffic_decel: float = 2.0
    traffic_reaction_s: float = 1.0
    traffic_stop_margin_m: float = 5.0
    hard_decel: float = 4.0  # m/s^2: closer to the entry than this stopping distance, it commits
    # scene_speed
    comfort_decel: float = 2.5  # m/s^2
    min_gap_m: float = 3.0  # bumper to what is ahead, standing
    reaction_s: float = 1.0


@dataclass(frozen=True)
class ExpertAction:
    steer: float  # [-1, 1], positive right (CARLA)
    target_speed: float  # m/s
    command: RoadOption
    limited_by: str = "free"  # what holds target_speed below the desired speed (bag_io.EXPERT_LIMITS)


def scene_speed(desired: float, gap: float | None, lead_speed: float, config: ExpertConfig) -> float:
    """The speed the scene allows (m/s): `desired` on a free road (gap None), else the largest v with
    v * reaction_s + v^2 / (2 b) <= gap - min_gap + lead_speed^2 / (2 b), i.e. the car can stop behind the
    lead even if the lead brakes as hard (b = comfort_decel); 0 within min_gap. Independent of the car's speed."""
    if gap is None:
        return desired
    room = gap - config.min_gap_m
    if room <= 0.0:
        return 0.0
    b, tau = config.comfort_decel, config.reaction_s
    safe = -b * tau + math.sqrt((b * tau) ** 2 + max(lead_speed, 0.0) ** 2 + 2 * b * room)
    return float(min(desired, max(safe, 0.0)))


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
    around = path_ahead(tracker, progress - 20.0, end + config.junction_exit_margin_m)
    for obstacle in obstacles:
        if obstacle.kind != VEHICLE or moving_with(around, obstacle):
            continue
        reach = math.hypot(obstacle.x - through.points[0, 0], obstacle.y - through.points[0, 1])
        if reach > obstacle.speed * config.junction_horizon_s + config.scan_m:
            continue  # too far away to matter within the horizon
        occupied = occupancy(through, obstacle, config.junction_horizon_s, config.corridor_margin_m)
        if occupied is None:
            continue
        first_in, last_in, near_s, far_s = occupied
        v = obstacle.speed
        if first_in > 0.0 and v * first_in > (v * config.traffic_reaction_s + v * v / (2 * config.traffic_decel)
                                               + config.traffic_stop_margin_m):
            continue  # far enough from where the paths meet to stop for the ego, as traffic does
        ego_in = time_to_travel(near_s - 2 * EGO_HALF_LENGTH_M, speed, config.junction_speed, config.start_accel)
        ego_out = time_to_travel(far_s + 2 * EGO_HALF_LENGTH_M, speed, config.junction_speed, config.start_accel)
        if first_in - config.junction_margin_s < ego_out and ego_in < last_in + config.junction_margin_s:
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
        gap, lead_speed, cause = self.limit_ahead(odometry, tracker, obstacles)
        desired = self.desired_speed(command)
        target = scene_speed(desired, gap, lead_speed, config)
        return ExpertAction(steer, target, command, cause if target < desired else "free")

    def desired_speed(self, command: RoadOption) -> float:
        """Cruise speed while following the lane, junction speed while a turn or crossing command is active."""
        return self.config.cruise_speed if command is RoadOption.LANE_FOLLOW else self.config.junction_speed

    def limit_ahead(self, odometry: Odometry, tracker: RouteTracker,
                    obstacles: Sequence[Obstacle]) -> tuple[float | None, float, str]:
        """(gap in m, speed along the route, what it is) of what the car must stop behind: the nearest participant
        in the corridor ahead (its kind, "vehicle" or "pedestrian") or the waiting point before a junction with
        cross traffic ("junction"); (None, 0, "free") on a free road."""
        config = self.config
        path = path_ahead(tracker, tracker.progress_m, tracker.progress_m + config.scan_m)
        encounter = nearest_blocking(path, obstacles, config)
        gap, lead_speed, cause = ((encounter.gap_m, encounter.speed_along, encounter.obstacle.kind) if encounter
                                  else (None, 0.0, "free"))
        entry = junction_stop_gap(tracker, odometry.speed, obstacles, config)
        if entry is not None and (gap is None or entry < gap):
            gap, lead_speed, cause = entry, 0.0, "junction"
        return gap, lead_speed, cause

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
