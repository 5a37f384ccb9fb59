"""Navigation commands from a recorded CARLA route that carries no RoadOption (ROS-free).

carla_waypoint_publisher publishes the global planner's route as a nav_msgs/Path: poses only, the planner's
RoadOptions dropped. The turns are taken back from the route's shape: a stretch that bends tighter than
`TURN_RADIUS_M` (measured over `BEND_WINDOW_M` of route) is a turn, LEFT or RIGHT by `msfsu_sim.route.turn_option`
of its whole heading change (the rule the simulator's routes use at junctions); a stretch whose heading change
stays under that rule's threshold (a lane change, a kink) and every gentler curve is LANE_FOLLOW. A straight
crossing of a junction leaves no mark in the poses, so these commands never say STRAIGHT: a recording that needs
it carries a RoadOption topic. The command of each frame is then what the route tracker
(`msfsu_control.route_tracker.RouteTracker`, the route node's core) says at the vehicle's position: the first turn
within its look-ahead.
"""

from __future__ import annotations

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_control.route_tracker import RouteTracker, RouteTrackerConfig
from msfsu_sim.route import turn_option

TURN_RADIUS_M = 30.0  # junction turns in CARLA's towns are far tighter; road curves are gentler
BEND_WINDOW_M = 10.0  # route length over which a bend is measured
MIN_SEGMENT_M = 1e-3  # consecutive poses closer than this are one point


def route_polyline(points: np.ndarray) -> np.ndarray:
    """(N, 2) route positions without repeated points; ValueError for a route shorter than two distinct points."""
    points = np.asarray(points, np.float64)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) >= MIN_SEGMENT_M])
    points = points[keep]
    if len(points) < 2:
        raise ValueError(f"a route needs at least 2 distinct poses, got {len(points)}")
    return points


def turn_options(points: np.ndarray) -> np.ndarray:
    """(N, 2) distinct route positions -> (N,) uint8 RoadOption of the segment starting at each (last: LANE_FOLLOW)."""
    vectors = np.diff(points, axis=0)
    lengths = np.linalg.norm(vectors, axis=1)
    headings = np.unwrap(np.arctan2(vectors[:, 1], vectors[:, 0]))  # counter-clockwise positive, as turn_option
    starts = np.concatenate([[0.0], np.cumsum(lengths)])
    middles = starts[:-1] + lengths / 2

    def heading_at(arc: np.ndarray) -> np.ndarray:
        return headings[np.clip(np.searchsorted(starts, arc, side="right") - 1, 0, len(headings) - 1)]

    bend = heading_at(middles + BEND_WINDOW_M / 2) - heading_at(middles - BEND_WINDOW_M / 2)
    turning = np.abs(bend) > BEND_WINDOW_M / TURN_RADIUS_M
    options = np.full(len(points), RoadOption.LANE_FOLLOW, np.uint8)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], turning.astype(np.int8), [0]])))
    for first, end in zip(edges[::2], edges[1::2]):  # runs of turning segments [first, end)
        option = turn_option(float(headings[end - 1] - headings[first]))
        if option is not RoadOption.STRAIGHT:
            options[first:end] = option
    return options


def route_commands(points: np.ndarray, positions: np.ndarray,
                   config: RouteTrackerConfig = RouteTrackerConfig()) -> list[RoadOption]:
    """The command at each (x, y) of `positions` (in driving order) along the route through `points` (N, 2)."""
    polyline = route_polyline(points)
    tracker = RouteTracker(polyline, turn_options(polyline), config)
    return [tracker.update(float(x), float(y)) for x, y in np.asarray(positions, np.float64).reshape(-1, 2)]
