"""Navigation commands of a recorded CARLA route that carries no RoadOption (ROS-free).

carla_waypoint_publisher publishes the global planner's route as a nav_msgs/Path: poses only, the planner's
RoadOptions dropped. The turns are taken back from the route's shape (`msfsu_control.path_options`, the rule the
route node applies to the bridge's live waypoints), and the command of each frame is what the route tracker says at
the vehicle's position: the first turn within its look-ahead.
"""

from __future__ import annotations

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_control.path_options import path_tracker
from msfsu_control.route_tracker import RouteTrackerConfig


def route_commands(points: np.ndarray, positions: np.ndarray,
                   config: RouteTrackerConfig = RouteTrackerConfig()) -> list[RoadOption]:
    """The command at each (x, y) of `positions` (in driving order) along the route through `points` (N, 2)."""
    tracker = path_tracker(points, config)
    return [tracker.update(float(x), float(y)) for x, y in np.asarray(positions, np.float64).reshape(-1, 2)]
