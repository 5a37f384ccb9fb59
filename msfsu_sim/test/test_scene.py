"""Who is in the ego's way: oriented boxes against the path ahead, look-ahead, cross traffic, waiting."""

import math

import numpy as np
import pytest

from msfsu_sim.scene import (EGO_HALF_LENGTH_M, PEDESTRIAN, VEHICLE, Obstacle, PathAhead, first_in_corridor,
                             moving_with, occupancy, time_to_travel, waiting_for)

STRAIGHT = PathAhead.of(np.stack([np.arange(0.0, 40.0), np.zeros(40)], axis=1), np.arange(0.0, 40.0))
NOW = {VEHICLE: (0.0,), PEDESTRIAN: (0.0,)}


def car(x: float, y: float, heading: float = 0.0, speed: float = 0.0) -> Obstacle:
    return Obstacle(x, y, speed * math.cos(heading), speed * math.sin(heading), 4.5, 1.9, heading, VEHICLE)


def walker(x: float, y: float, vx: float = 0.0, vy: float = 0.0) -> Obstacle:
    return Obstacle(x, y, vx, vy, 0.8, 0.8, math.atan2(vy, vx), PEDESTRIAN)


def test_a_car_in_the_lane_is_in_the_way_at_its_rear_bumper():
    encounter = first_in_corridor(STRAIGHT, [car(20.0, 0.5)], NOW, 0.4)
    assert encounter.gap_m == pytest.approx(20.0 - EGO_HALF_LENGTH_M - 4.5 / 2)
    assert encounter.obstacle.kind == VEHICLE and not encounter.predicted


def test_a_car_in_the_next_lane_is_not_in_the_way_but_one_across_the_path_is():
    """Lanes are 3.5 m apart: a disc of the car's length (the old model) reached into the ego's lane."""
    assert first_in_corridor(STRAIGHT, [car(20.0, 3.5), car(20.0, -3.5, math.pi)], NOW, 0.4) is None
    across = car(20.0, 3.2, heading=-math.pi / 2)  # its nose 1 m into the lane: length across the path
    assert first_in_corridor(STRAIGHT, [across], NOW, 0.4) is not None


def test_a_pedestrian_about_to_step_in_is_in_the_way_only_with_look_ahead():
    crossing = walker(15.0, 3.0, vy=-2.0)  # 3 m beside the path, walking into it
    assert first_in_corridor(STRAIGHT, [crossing], NOW, 0.4) is None
    encounter = first_in_corridor(STRAIGHT, [crossing], {PEDESTRIAN: (0.0, 0.5, 1.0)}, 0.4)
    assert encounter.predicted and encounter.speed_along == 0.0
    assert encounter.gap_m == pytest.approx(15.0 - EGO_HALF_LENGTH_M - 0.4)


def test_the_lead_speed_is_measured_along_the_path():
    encounter = first_in_corridor(STRAIGHT, [car(10.0, 0.0, heading=0.1, speed=6.0)], NOW, 0.4)
    assert encounter.speed_along == pytest.approx(6.0 * math.cos(0.1))


def test_nothing_behind_the_ego_or_beyond_the_path_counts():
    assert first_in_corridor(STRAIGHT, [car(-6.0, 0.0), car(45.0, 0.0)], NOW, 0.4) is None


def test_cross_traffic_occupies_the_path_when_and_where_it_crosses():
    from_the_side = car(10.0, 30.0, heading=-math.pi / 2, speed=8.0)  # its nose reaches the corridor at ~3.2 s
    first, last, near, far = occupancy(STRAIGHT, from_the_side, 6.0, 0.4)
    assert 3.0 <= first <= 3.5 and 4.0 <= last <= 4.75 and near == far == 10.0
    assert occupancy(STRAIGHT, from_the_side, 2.0, 0.4) is None  # not within 2 s
    oncoming = car(35.0, 3.5, heading=math.pi, speed=8.0)  # the other lane, straight on: never in the way
    assert occupancy(STRAIGHT, oncoming, 6.0, 0.4) is None


def test_time_to_travel_accelerates_then_cruises():
    assert time_to_travel(0.0, 0.0, 5.0, 2.0) == 0.0
    assert time_to_travel(4.0, 0.0, 5.0, 2.0) == pytest.approx(2.0)  # s = a t^2 / 2
    assert time_to_travel(6.25 + 10.0, 0.0, 5.0, 2.0) == pytest.approx(2.5 + 2.0)  # ramp to 5 m/s, then 10 m at 5
    assert time_to_travel(10.0, 5.0, 5.0, 2.0) == pytest.approx(2.0)


def test_leads_and_followers_drive_the_ego_way_and_cross_traffic_does_not():
    assert moving_with(STRAIGHT, car(15.0, 0.0, heading=0.0, speed=5.0))
    assert moving_with(STRAIGHT, car(0.0, 0.0, heading=0.2))  # standing: its heading counts
    assert not moving_with(STRAIGHT, car(15.0, 10.0, heading=-math.pi / 2, speed=5.0))
    assert not moving_with(STRAIGHT, car(15.0, 3.5, heading=math.pi, speed=5.0))
    assert not moving_with(STRAIGHT, car(2.0, -3.5, heading=0.0, speed=8.0))  # the next lane, the same way


class _Route:
    progress_m = 5.0

    @staticmethod
    def point_at(arc: float) -> np.ndarray:
        return np.array([arc, 0.0])


def test_waiting_for_names_what_stands_in_the_route_ahead():
    assert waiting_for(_Route(), [car(18.0, 0.0)]) == VEHICLE
    assert waiting_for(_Route(), [walker(12.0, 4.0, vy=-1.2)]) == PEDESTRIAN  # on the path within 3 s
    assert waiting_for(_Route(), [walker(12.0, 6.0, vx=1.2)]) == ""  # on the sidewalk, walking along
    assert waiting_for(_Route(), [car(60.0, 0.0)]) == ""  # far beyond the scan
