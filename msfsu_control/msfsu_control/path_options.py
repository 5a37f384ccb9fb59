"""Navigation commands from a route that carries poses but no RoadOption: a nav_msgs/Path (ROS-free).

carla-ros-bridge's carla_waypoint_publisher sends the global planner's route as a nav_msgs/Path: poses only, the
planner's RoadOptions dropped. CARLA's own local planner, given bare waypoints, takes the option back from their
geometry (`_compute_connection`: the heading change from one waypoint to the next); here the same is done over a
stretch of the path, so that the junction's whole turn counts, not one step of it:

- a stretch of the path that bends tighter than `TURN_RADIUS_M` (measured over `BEND_WINDOW_M` of path) is a turn,
  LEFT or RIGHT by `turn_option` of its whole heading change (the rule the simulator's routes use at junctions);
- a stretch whose heading change stays under that rule's threshold (a lane change, a kink) and every gentler curve
  is LANE_FOLLOW. A straight crossing of a junction leaves no mark in the poses, so these options never say STRAIGHT.

`path_tracker` gives the route tracker (msfsu_control.route_tracker, the route node's core) of such a path: the
command at the vehicle's position is the first turn within its look-ahead. Headings are counter-clockwise positive in
the path's frame (ROS's right-handed map frame, as the bridge publishes it).
"""

from __future__ import annotations

import math

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_control.route_tracker import RouteTracker, RouteTrackerConfig

TURN_THRESHOLD_RAD = math.radians(30.0)  # a junction turns LEFT or RIGHT beyond this heading change, else STRAIGHT
TURN_RADIUS_M = 30.0  # junction turns in CARLA's towns are far tighter; road curves are gentler
BEND_WINDOW_M = 10.0  # path length over which a bend is measured
MIN_SEGMENT_M = 1e-3  # consecutive poses closer than this are one point


def turn_option(heading_change: float) -> RoadOption:
    """Heading change through a junction (rad, counter-clockwise positive) -> LEFT/RIGHT/STRAIGHT."""
    if heading_change > TURN_THRESHOLD_RAD:
        return RoadOption.LEFT
    if heading_change < -TURN_THRESHOLD_RAD:
        return RoadOption.RIGHT
    return RoadOption.STRAIGHT


def route_polyline(points: np.ndarray) -> np.ndarray:
    """(N, 2) path positions without repeated points; ValueError for a path shorter than two distinct points."""
    points = np.asarray(points, np.float64).reshape(-1, 2)
    if not np.isfinite(points).all():
        raise ValueError("a path with non-finite positions")
    if len(points) == 0:
        raise ValueError("a path needs at least 2 distinct poses, got 0")
    keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) >= MIN_SEGMENT_M])
    points = points[keep]
    if len(points) < 2:
        raise ValueError(f"a path needs at least 2 distinct poses, got {len(points)}")
    return points


def turn_options(points: np.ndarray) -> np.ndarray:
    """(N, 2) distinct path positions -> (N,) uint8 RoadOption of the segment starting at each (last: LANE_FOLLOW)."""
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


def path_tracker(points: np.ndarray, config: RouteTrackerConfig = RouteTrackerConfig()) -> RouteTracker:
    """The route tracker of a path's (x, y) positions, its options from the path's shape; ValueError for a path that
    is none (fewer than two distinct finite positions)."""
    polyline = route_polyline(points)
    return RouteTracker(polyline, turn_options(polyline), config)
