"""Navigation commands from a path's shape (msfsu_control.path_options): what the route node makes of the bridge's
nav_msgs/Path waypoints and msfsu-import-carla of a recorded route."""

import math

import numpy as np
import pytest

from msfsu_common.road_option import RoadOption
from msfsu_control.path_options import (BEND_WINDOW_M, TURN_THRESHOLD_RAD, path_tracker, route_polyline,
                                        turn_option, turn_options)
from msfsu_control.route_tracker import RouteTrackerConfig

LOOKAHEAD_M = RouteTrackerConfig().lookahead_m
ANNOUNCED_M = LOOKAHEAD_M + BEND_WINDOW_M / 2  # the earliest a turn is announced before its bend


def quarter_turn(sign: int, radius: float = 10.0) -> np.ndarray:
    """40 m east, a quarter circle to the left (sign 1) or right (-1), 40 m on: a point every metre."""
    angles = np.arange(1.0, radius * np.pi / 2) / radius
    arc = np.c_[40 + radius * np.sin(angles), sign * radius * (1 - np.cos(angles))]
    after = np.c_[np.full(40, 40 + radius), sign * (radius + np.arange(40.0))]
    return np.vstack([np.c_[np.arange(40.0), np.zeros(40)], arc, after])


def commands_along(route: np.ndarray, arcs: np.ndarray, config: RouteTrackerConfig = RouteTrackerConfig()):
    tracker = path_tracker(route, config)
    return np.array([tracker.update(*route[min(int(arc), len(route) - 1)]) for arc in arcs])


def test_a_heading_change_beyond_the_threshold_is_a_turn_each_way():
    assert turn_option(math.radians(90)) is RoadOption.LEFT
    assert turn_option(math.radians(-90)) is RoadOption.RIGHT
    assert turn_option(TURN_THRESHOLD_RAD * 0.9) is RoadOption.STRAIGHT
    assert turn_option(-TURN_THRESHOLD_RAD * 0.9) is RoadOption.STRAIGHT


@pytest.mark.parametrize("sign, option", [(1, RoadOption.LEFT), (-1, RoadOption.RIGHT)])
def test_a_tight_bend_of_the_path_is_a_turn_announced_the_lookahead_ahead(sign, option):
    route = quarter_turn(sign)
    assert set(turn_options(route)) == {RoadOption.LANE_FOLLOW, option}
    arcs = np.arange(0.0, 95.0, 1.0)
    commands = commands_along(route, arcs)
    assert (commands[(arcs >= 40 - LOOKAHEAD_M) & (arcs < 40 + 15)] == option).all()
    assert (commands[(arcs < 40 - ANNOUNCED_M - 2) | (arcs > 40 + 15.7 + 5 + 2)] == RoadOption.LANE_FOLLOW).all()


def test_the_lookahead_is_the_trackers_own():
    route, arcs = quarter_turn(1), np.arange(0.0, 40.0, 1.0)
    near = commands_along(route, arcs, RouteTrackerConfig(lookahead_m=5.0))
    assert (near[arcs < 40 - 5.0 - BEND_WINDOW_M / 2 - 2] == RoadOption.LANE_FOLLOW).all()
    assert (commands_along(route, arcs)[arcs >= 40 - LOOKAHEAD_M] == RoadOption.LEFT).all()


def test_gentle_curves_and_lane_changes_are_lane_follow():
    angles = np.linspace(0, np.pi / 2, 160)
    gentle = np.c_[100 * np.sin(angles), 100 * (1 - np.cos(angles))]  # radius 100 m
    x = np.arange(0.0, 80.0)
    lane_change = np.c_[x, 3.5 / (1 + np.exp(-(x - 40) / 3))]  # one lane over in ~20 m
    for route in (gentle, lane_change):
        assert set(turn_options(route)) == {RoadOption.LANE_FOLLOW}


def test_two_junctions_get_their_own_turns_in_order():
    """Left, then right: a path the bridge's planner would send through two junctions (waypoints 2 m apart)."""
    first = quarter_turn(1)[::2]
    second = quarter_turn(-1)[::2]
    # the second turn starts where the first path ends, rotated to its heading (north)
    rotated = np.c_[-second[:, 1], second[:, 0]] + first[-1] + [0.0, 2.0]
    route = np.vstack([first, rotated])
    options = [RoadOption(value) for value in turn_options(route_polyline(route))]
    runs = [option for index, option in enumerate(options) if index == 0 or option != options[index - 1]]
    assert runs == [RoadOption.LANE_FOLLOW, RoadOption.LEFT, RoadOption.LANE_FOLLOW, RoadOption.RIGHT,
                    RoadOption.LANE_FOLLOW]  # never STRAIGHT: a straight crossing leaves no mark in the poses


def test_repeated_poses_are_one_point_and_a_path_that_is_none_is_refused():
    route = quarter_turn(1)
    doubled = np.repeat(route, 2, axis=0)
    assert np.array_equal(route_polyline(doubled), route)
    assert np.array_equal(turn_options(route_polyline(doubled)), turn_options(route))
    for bad, reason in [(np.zeros((0, 2)), "at least 2 distinct poses, got 0"),
                        (np.zeros((5, 2)), "at least 2 distinct poses, got 1"),
                        (np.array([[0.0, 0.0], [np.nan, 1.0]]), "non-finite")]:
        with pytest.raises(ValueError, match=reason):
            path_tracker(bad)
