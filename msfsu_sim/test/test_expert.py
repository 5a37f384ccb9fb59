import math

import numpy as np
import pytest

from msfsu_common.road_option import RoadOption
from msfsu_control.route_tracker import RouteTracker
from msfsu_sim.environment import Odometry
from msfsu_sim.expert import (Expert, ExpertConfig, NoiseConfig, SteeringNoise, junction_stop_gap, nearest_blocking,
                              pure_pursuit_steer, scene_speed)
from msfsu_sim.scene import PEDESTRIAN, VEHICLE, Obstacle, path_ahead

CONFIG = ExpertConfig()


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


def test_scene_speed_is_the_desired_speed_on_a_free_road_and_falls_to_zero_at_the_minimum_gap():
    assert scene_speed(8.0, None, 0.0, CONFIG) == 8.0
    assert scene_speed(8.0, CONFIG.min_gap_m, 0.0, CONFIG) == 0.0
    speeds = [scene_speed(8.0, gap, 0.0, CONFIG) for gap in (4.0, 8.0, 15.0, 30.0)]
    assert speeds == sorted(speeds) and 0.0 < speeds[0] < 2.0 and speeds[-1] == 8.0
    # the car can stop behind a standing obstacle from that speed: reaction + braking distance fit the room
    for gap, v in zip((4.0, 8.0, 15.0), speeds):
        assert v * CONFIG.reaction_s + v ** 2 / (2 * CONFIG.comfort_decel) == pytest.approx(gap - CONFIG.min_gap_m)


def test_scene_speed_follows_a_moving_lead_and_does_not_depend_on_the_own_speed():
    behind_lead = scene_speed(8.0, 12.0, 8.0, CONFIG)
    assert 7.0 < behind_lead <= 8.0  # a lead at 8 m/s 12 m ahead: about its speed
    assert scene_speed(8.0, 5.0, 8.0, CONFIG) < behind_lead  # too close: drop back
    tracker = _tracker(0.0)
    labels = {Expert().act(Odometry(0.0, 0.0, 0.0, speed, 0.0), tracker, RoadOption.LANE_FOLLOW, [], 0.1).target_speed
              for speed in (0.0, 1.5, 5.0, 8.0)}
    assert labels == {8.0}  # one free road, one label, at rest or cruising


def _tracker(progress_m: float) -> RouteTracker:
    """A straight 100 m route along x with a junction from 50 to 70 m (STRAIGHT), driven up to `progress_m`."""
    points = np.stack([np.arange(0.0, 101.0, 2.0), np.zeros(51)], axis=1)
    options = np.where((points[:, 0] >= 50) & (points[:, 0] < 70), int(RoadOption.STRAIGHT),
                       int(RoadOption.LANE_FOLLOW))
    tracker = RouteTracker(points, options.astype(np.uint8))
    for x in (*np.arange(0.0, progress_m, 10.0), progress_m):  # drive there: progress only searches 30 m ahead
        tracker.update(float(x), 0.0)
    return tracker


def _car(x: float, y: float, heading: float, speed: float) -> Obstacle:
    return Obstacle(x, y, speed * math.cos(heading), speed * math.sin(heading), 4.5, 1.9, heading, VEHICLE)


def test_the_expert_follows_a_lead_and_ignores_a_car_in_the_next_lane():
    path = path_ahead(_tracker(0.0), 0.0, 40.0)
    lead = _car(20.0, 0.0, 0.0, 3.0)
    assert nearest_blocking(path, [lead, _car(10.0, 3.5, 0.0, 0.0)], CONFIG).obstacle is lead
    assert nearest_blocking(path, [_car(10.0, 3.5, 0.0, 0.0), _car(30.0, -3.5, math.pi, 8.0)], CONFIG) is None


def test_the_label_says_what_holds_it_below_the_desired_speed():
    tracker, odometry = _tracker(0.0), Odometry(0.0, 0.0, 0.0, 8.0, 0.0)

    def held_by(obstacles):
        return Expert().act(odometry, tracker, RoadOption.LANE_FOLLOW, obstacles, 0.1).limited_by

    walker = Obstacle(15.0, 0.0, 0.0, 0.0, 0.5, 0.5, 0.0, PEDESTRIAN)
    assert held_by([]) == "free"
    assert held_by([_car(12.0, 0.0, 0.0, 2.0)]) == "vehicle"
    assert held_by([walker, _car(30.0, 0.0, 0.0, 2.0)]) == "pedestrian"  # the nearer of the two
    assert held_by([_car(10.0, 3.5, 0.0, 0.0)]) == "free"  # in the next lane: not in the way
    assert held_by([_car(39.0, 0.0, 0.0, 8.0)]) == "free"  # a lead at cruise speed far ahead does not slow it


def test_cross_traffic_makes_the_expert_wait_at_the_junction_entry():
    tracker = _tracker(40.0)  # 10 m before the entry, standing: at the crossing point (x = 60) in ~4-6 s
    crossing = _car(60.0, 26.0, -math.pi / 2, 8.0)  # there in ~3 s: too close to stop for the ego
    gap = junction_stop_gap(tracker, 0.0, [crossing], CONFIG)
    assert gap == pytest.approx(50.0 - 40.0 - 2.3 - CONFIG.junction_stop_m, abs=0.5)
    assert junction_stop_gap(tracker, 0.0, [_car(60.0, 60.0, -math.pi / 2, 8.0)], CONFIG) is None  # can stop for it
    action = Expert().act(Odometry(40.0, 0.0, 0.0, 0.0, 0.0), tracker, RoadOption.STRAIGHT, [crossing], 0.1)
    assert action.target_speed == pytest.approx(scene_speed(CONFIG.junction_speed, gap, 0.0, CONFIG))
    assert action.target_speed < CONFIG.junction_speed  # slowing towards the waiting point
    assert action.limited_by == "junction"
    at_the_point = _tracker(50.0 - 2.3 - CONFIG.junction_stop_m - CONFIG.min_gap_m)
    assert Expert().act(Odometry(at_the_point.progress_m, 0.0, 0.0, 0.0, 0.0), at_the_point, RoadOption.STRAIGHT,
                        [crossing], 0.1).target_speed == 0.0


def test_no_wait_for_oncoming_or_following_cars_or_cross_traffic_that_passes_before_or_after():
    crossing = _car(60.0, 26.0, -math.pi / 2, 8.0)
    tracker = _tracker(40.0)
    assert junction_stop_gap(tracker, 0.0, [_car(80.0, 3.5, math.pi, 8.0), _car(25.0, 0.0, 0.0, 8.0)], CONFIG) is None
    assert junction_stop_gap(tracker, 0.0, [_car(60.0, 8.0, -math.pi / 2, 8.0)], CONFIG) is None  # gone in ~1 s
    assert junction_stop_gap(tracker, 0.0, [_car(60.0, 120.0, -math.pi / 2, 8.0)], CONFIG) is None  # ~15 s away
    assert junction_stop_gap(_tracker(55.0), 5.0, [crossing], CONFIG) is None  # inside: clear it, never stop
    assert junction_stop_gap(_tracker(44.0), 8.0, [crossing], CONFIG) is None  # cannot stop before the entry


def test_a_car_in_the_next_lane_behind_is_yielded_to_when_the_turn_crosses_its_lane():
    """Ego in the inner lane turning right (the route bends right at the junction), a car coming up the outer
    lane on the right at 8 m/s: it would meet the turning ego, so the expert waits at the entry."""
    points = np.array([[x, 0.0] for x in range(0, 52, 2)] + [[50 + 10 * math.sin(a), -10 + 10 * math.cos(a)]
                                                             for a in np.linspace(0.2, math.pi / 2, 8)] +
                      [[60.0, -10.0 - d] for d in range(2, 40, 2)])
    options = np.full(len(points), int(RoadOption.LANE_FOLLOW), np.uint8)
    options[25:34] = int(RoadOption.RIGHT)
    tracker = RouteTracker(points, options)
    for x in (0.0, 10.0, 20.0, 30.0, 35.0):
        tracker.update(x, 0.0)
    beside = _car(38.0, -3.5, 0.0, 8.0)  # at the turn (x ~ 57) in ~2.5 s, as the ego: too close to stop
    assert junction_stop_gap(tracker, 0.0, [beside], CONFIG) is not None


def test_junction_spans_of_the_route():
    assert _tracker(0.0).junction_spans() == [(50.0, 70.0)]
