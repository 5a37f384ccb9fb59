import numpy as np
import pytest

from msfsu_common.road_option import RoadOption
from msfsu_control.route_tracker import RouteTracker, RouteTrackerConfig

LF, LEFT = RoadOption.LANE_FOLLOW, RoadOption.LEFT


def l_shaped_route():
    """50 m east, a left turn through a junction at (50, 0), 50 m north; one pose per metre."""
    east = [(x, 0.0) for x in range(0, 46)]
    turn = [(45.0 + 5.0 * np.sin(a), 5.0 - 5.0 * np.cos(a)) for a in np.linspace(0.2, np.pi / 2, 8)]
    north = [(50.0, y) for y in range(6, 56)]
    points = np.array(east + turn + north, dtype=float)
    options = [LF] * len(east) + [LEFT] * len(turn) + [LF] * len(north)
    options[len(east) - 1] = LEFT  # the segment entering the junction
    return points, np.array(options)


def test_commands_along_an_l_shaped_route():
    points, options = l_shaped_route()
    tracker = RouteTracker(points, options, RouteTrackerConfig(lookahead_m=10.0))
    assert tracker.update(0.0, 0.0) is LF
    assert tracker.update(30.0, 0.5) is LF
    assert tracker.update(37.0, -0.5) is LEFT  # within 10 m of the junction
    assert tracker.update(48.0, 2.0) is LEFT  # inside it
    assert tracker.update(50.5, 12.0) is LF  # after it
    assert tracker.update(50.0, 40.0) is LF


def test_progress_never_jumps_backwards_and_survives_lateral_deviation():
    points, options = l_shaped_route()
    tracker = RouteTracker(points, options)
    tracker.update(30.0, 0.0)
    assert tracker.progress_m == pytest.approx(30.0)
    tracker.update(10.0, 0.0)  # a bad fix behind the car
    assert tracker.progress_m == pytest.approx(30.0)
    tracker.update(33.0, 4.0)  # 4 m off the lane
    assert tracker.progress_m == pytest.approx(33.0)


def test_route_coming_back_near_itself_is_not_short_cut():
    """An out-and-back route: the return leg passes the start; progress must follow the car, not jump."""
    points = np.array([(x, 0.0) for x in range(0, 41)] + [(x, 3.0) for x in range(40, -1, -1)], dtype=float)
    tracker = RouteTracker(points, np.full(len(points), int(LF)), RouteTrackerConfig(search_window_m=20.0))
    tracker.update(2.0, 0.2)
    assert tracker.progress_m < 5.0  # the return leg at y=3 is 80 m of route away


def test_rejects_malformed_routes():
    with pytest.raises(ValueError, match="at least 2 points"):
        RouteTracker(np.zeros((1, 2)), np.array([4]))
    with pytest.raises(ValueError, match="options"):
        RouteTracker(np.zeros((3, 2)), np.array([4, 4]))
    with pytest.raises(ValueError, match="unknown navigation command 9"):
        RouteTracker(np.array([[0, 0], [1, 0]]), np.array([4, 9]))


def test_point_at_interpolates_along_the_route_and_clamps():
    tracker = RouteTracker(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]), np.array([4, 4, 4]))
    np.testing.assert_allclose(tracker.point_at(4.0), [4.0, 0.0])
    np.testing.assert_allclose(tracker.point_at(15.0), [10.0, 5.0])
    np.testing.assert_allclose(tracker.point_at(99.0), [10.0, 10.0])
    np.testing.assert_allclose(tracker.point_at(-1.0), [0.0, 0.0])
