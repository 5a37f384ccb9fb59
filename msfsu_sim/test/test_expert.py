import math

import numpy as np
import pytest

from msfsu_sim.environment import Obstacle, Odometry
from msfsu_sim.expert import (ExpertConfig, NoiseConfig, SteeringNoise, idm_acceleration, nearest_blocking,
                              pure_pursuit_steer)

CONFIG = ExpertConfig()
STRAIGHT = np.stack([np.arange(0.0, 40.0), np.zeros(40)], axis=1)
STRAIGHT_S = np.arange(0.0, 40.0)


def test_noise_is_active_one_second_every_five_seconds():
    noise = SteeringNoise(seed=3)
    times = np.round(np.arange(0, 30, 0.1), 1)
    active = np.array([noise.active(t) for t in times])
    assert not active[times < 5.0].any()
    starts = times[1:][active[1:] & ~active[:-1]]
    assert starts.tolist() == [5.0, 10.0, 15.0, 20.0, 25.0]
    assert active.sum() == 5 * 10  # 1 s at 10 Hz per burst


def test_noise_offset_is_zero_outside_bursts_and_bounded_inside():
    noise = SteeringNoise(seed=3, config=NoiseConfig(max_offset=0.3))
    assert noise.offset(4.9) == 0.0 and noise.offset(6.5) == 0.0
    inside = [noise.offset(t) for t in (5.0, 5.5, 10.2)]
    assert all(0.15 - 1e-9 <= abs(value) <= 0.3 for value in inside)


def test_noise_is_deterministic_per_seed():
    times = np.arange(0, 30, 0.1)
    first = [SteeringNoise(7).offset(t) for t in times]
    assert first == [SteeringNoise(7).offset(t) for t in times]


def test_pure_pursuit_steers_right_for_a_target_on_the_right():
    odometry = Odometry(0.0, 0.0, 0.0, 5.0, 0.0)
    assert pure_pursuit_steer(odometry, np.array([10.0, -2.0])) > 0  # CARLA: positive = right
    assert pure_pursuit_steer(odometry, np.array([10.0, 2.0])) < 0
    assert pure_pursuit_steer(odometry, np.array([10.0, 0.0])) == pytest.approx(0.0)


def test_idm_accelerates_on_free_road_and_brakes_behind_a_stopped_car():
    assert idm_acceleration(5.0, 8.0, None, 0.0, CONFIG) > 0
    assert idm_acceleration(8.0, 8.0, 8.0, 8.0, CONFIG) < -1.0


def test_obstacle_in_lane_blocks_and_obstacle_beside_the_road_does_not():
    in_lane = Obstacle(20.0, 0.5, 0.0, 0.0, 1.0)
    beside = Obstacle(20.0, 5.0, 0.0, 0.0, 1.0)
    gap, speed = nearest_blocking(STRAIGHT, STRAIGHT_S, [in_lane, beside], CONFIG)
    assert gap == pytest.approx(20.0 - 2.3 - 1.0) and speed == 0.0
    assert nearest_blocking(STRAIGHT, STRAIGHT_S, [beside], CONFIG) is None


def test_pedestrian_about_to_cross_blocks_the_path():
    crossing = Obstacle(15.0, 3.0, 0.0, -2.0, 0.5)  # 3 m beside the lane, walking into it at 2 m/s
    gap, _ = nearest_blocking(STRAIGHT, STRAIGHT_S, [crossing], CONFIG)
    assert gap == pytest.approx(15.0 - 2.3 - 0.5)


def test_lead_vehicle_speed_is_measured_along_the_path():
    lead = Obstacle(10.0, 0.0, 6.0 * math.cos(0.1), 6.0 * math.sin(0.1), 2.0)
    _, speed = nearest_blocking(STRAIGHT, STRAIGHT_S, [lead], CONFIG)
    assert speed == pytest.approx(6.0 * math.cos(0.1))
