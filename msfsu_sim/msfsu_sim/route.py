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
from msfsu_control.path_options import turn_option

JUNCTION_BLOCKS = frozenset("XT")
_NODE = re.compile(r"^-?(\d+)([A-Za-z$])")
_NEGATIVE_JUNCTION_ENTRY = re.compile(r"^-\d+[XT]\d+_0_$")  # inner end of an exit road, inbound


def wrap_angle(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def block_of(node: str) -> tuple[int, str] | None:
    """('2X0_0_' -> (2, 'X')); MetaDrive node names start with the block index and block type."""
    match = _NODE.match(node)
    return (int(match.group(1)), match.group(2)) if match else None


def is_junction_edge(start: str, end: str) -> bool:
    """Is this edge a crossing of an intersection block?

    Driving forwards, the edge entering the block from the previous block crosses it ('1S0_0_' ->
    '2X0_0_'). A route that comes back in along one of the block's exit roads (a negative road) crosses
    it from that road's inner end, '-2X1_0_', to another exit ('2X2_0_') or to the previous block
    ('-1S0_0_').
    """
    start_block, end_block = block_of(start), block_of(end)
    entering = end_block is not None and end_block[1] in JUNCTION_BLOCKS and start_block != end_block
    if entering and not end.startswith("-"):  # a negative road from the next block ends on an exit road
        return True
    return _NEGATIVE_JUNCTION_ENTRY.match(start) is not None


@dataclass(frozen=True)
class Route:
    """Poses along the route (x, y, yaw in the map frame, metres/rad), one RoadOption each.

    Progress and the command to drive now: msfsu_control.route_tracker.RouteTracker.
    """

    poses: np.ndarray  # (N, 3) float64
    options: np.ndarray  # (N,) uint8 RoadOption values


def edge_lane_option(road_graph: dict, start: str, end: str, lane_index: int) -> tuple[object, RoadOption]:
    """The lane `lane_index` (clamped) of a road and its option: the turn if it crosses a junction."""
    road_lanes = road_graph[start][end]
    lane = road_lanes[min(lane_index, len(road_lanes) - 1)]
    if not is_junction_edge(start, end):
        return lane, RoadOption.LANE_FOLLOW
    return lane, turn_option(wrap_angle(lane.heading_theta_at(lane.length) - lane.heading_theta_at(0.0)))


def route_from_checkpoints(road_graph: dict, checkpoints: list[str], lane_index: int,
                           spacing_m: float = 2.0) -> Route:
    """Sample the route every `spacing_m` on lane `lane_index` (clamped per road) of each edge."""
    poses, options = [], []
    for start, end in zip(checkpoints[:-1], checkpoints[1:]):
        lane, option = edge_lane_option(road_graph, start, end, lane_index)
        for s in np.arange(0.0, lane.length, spacing_m):
            x, y = lane.position(s, 0.0)
            poses.append((x, y, lane.heading_theta_at(s)))
            options.append(option)
    return Route(np.asarray(poses, np.float64), np.asarray(options, np.uint8))
