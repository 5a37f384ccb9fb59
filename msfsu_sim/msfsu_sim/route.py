"""Global route with CARLA RoadOptions, built from MetaDrive's road graph (ROS-free).

CARLA's global planner labels the waypoints inside a junction LEFT/RIGHT/STRAIGHT and everything else
LANE_FOLLOW. MetaDrive's `navigation_command` is angle-based (it says "left" on any left curve), so we
derive options from the map: a route edge that crosses an intersection block (X, T) gets the turn given by
the heading change between its entry and exit.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
import numpy as np

from msfsu_common.road_option import RoadOption

JUNCTION_BLOCKS = frozenset("XT")
TURN_THRESHOLD_RAD = math.radians(30.0)
_NODE = re.compile(r"^-?(\d+)([A-Za-z$])")


def wrap_angle(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def turn_option(heading_change: float) -> RoadOption:
    """Heading change through a junction (rad, counter-clockwise positive) -> LEFT/RIGHT/STRAIGHT."""
    if heading_change > TURN_THRESHOLD_RAD:
        return RoadOption.LEFT
    if heading_change < -TURN_THRESHOLD_RAD:
        return RoadOption.RIGHT
    return RoadOption.STRAIGHT


def _block_of(node: str) -> tuple[int, str] | None:
    """('2X0_0_' -> (2, 'X')); MetaDrive node names start with the block index and block type."""
    match = _NODE.match(node)
    return (int(match.group(1)), match.group(2)) if match else None


def is_junction_edge(start: str, end: str) -> bool:
    """The edge entering an intersection block from the previous block is the junction crossing."""
    start_block, end_block = _block_of(start), _block_of(end)
    return end_block is not None and end_block[1] in JUNCTION_BLOCKS and start_block != end_block


@dataclass(frozen=True)
class Route:
    """Poses along the route (x, y, yaw in the map frame, metres/rad), one RoadOption each.

    Progress and the command to drive now: msfsu_control.route_tracker.RouteTracker.
    """

    poses: np.ndarray  # (N, 3) float64
    options: np.ndarray  # (N,) uint8 RoadOption values


def route_from_checkpoints(road_graph: dict, checkpoints: list[str], lane_index: int,
                           spacing_m: float = 2.0) -> Route:
    """Sample the route every `spacing_m` on lane `lane_index` (clamped per road) of each edge."""
    poses, options = [], []
    for start, end in zip(checkpoints[:-1], checkpoints[1:]):
        road_lanes = road_graph[start][end]
        lane = road_lanes[min(lane_index, len(road_lanes) - 1)]
        option = RoadOption.LANE_FOLLOW
        if is_junction_edge(start, end):
            option = turn_option(wrap_angle(lane.heading_theta_at(lane.length) - lane.heading_theta_at(0.0)))
        for s in np.arange(0.0, lane.length, spacing_m):
            x, y = lane.position(s, 0.0)
            poses.append((x, y, lane.heading_theta_at(s)))
            options.append(option)
    return Route(np.asarray(poses, np.float64), np.asarray(options, np.uint8))
