"""The global route of an episode as CARLA's planner gives it: poses with a RoadOption each.

MetaDrive's navigation is a list of road nodes. Roads inside an intersection block (X, T) are the
junction connectors; the turn they make (heading change from entry to exit) labels them LEFT, RIGHT
or STRAIGHT, everything else is LANE_FOLLOW. (MetaDrive's own `navigation_command` is an angle
heuristic on the next lanes and is not a junction decision.)
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from msfsu_common.road_option import RoadOption

JUNCTION_BLOCKS = ("X", "T")
TURN_THRESHOLD_RAD = math.radians(30.0)
SPACING_M = 1.0
_NODE = re.compile(r"^(\d+)([A-Za-z])(\d+)_(\d+)_$")


@dataclass(frozen=True)
class GlobalRoute:
    points: np.ndarray  # (N, 2) metres, world frame
    headings: np.ndarray  # (N,) rad
    options: np.ndarray  # (N,) RoadOption values, option of the segment starting at each point

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


def is_junction_road(start_node: str, end_node: str) -> bool:
    """A connector through an intersection: it ends at an X/T block node without being that block's exit road."""
    end = _NODE.match(end_node)
    if end is None or end.group(2) not in JUNCTION_BLOCKS:
        return False
    start = _NODE.match(start_node)
    is_exit_road = start is not None and start.group(1, 2, 3) == end.group(1, 2, 3)
    return not is_exit_road


def turn_option(heading_change_rad: float) -> RoadOption:
    """Heading change through a junction (counter-clockwise positive) -> LEFT / RIGHT / STRAIGHT."""
    change = math.atan2(math.sin(heading_change_rad), math.cos(heading_change_rad))
    if change > TURN_THRESHOLD_RAD:
        return RoadOption.LEFT
    if change < -TURN_THRESHOLD_RAD:
        return RoadOption.RIGHT
    return RoadOption.STRAIGHT


def build_route(road_network, checkpoints: list[str], lane_index: int) -> GlobalRoute:
    """Sample the lane centre lines of the route's roads every SPACING_M metres and label junctions.

    Keeps `lane_index` where a road has that many lanes (turn connectors have fewer: the nearest is used).
    """
    points, headings, options = [], [], []
    roads = list(zip(checkpoints[:-1], checkpoints[1:]))
    index = 0
    while index < len(roads):
        start_node, end_node = roads[index]
        if is_junction_road(start_node, end_node):
            group = [roads[index]]
            while index + 1 < len(roads) and is_junction_road(*roads[index + 1]):
                index += 1
                group.append(roads[index])
            lanes = [_lane(road_network, road, lane_index) for road in group]
            option = turn_option(lanes[-1].heading_theta_at(lanes[-1].length) - lanes[0].heading_theta_at(0.0))
        else:
            lanes, option = [_lane(road_network, roads[index], lane_index)], RoadOption.LANE_FOLLOW
        for lane in lanes:
            for longitudinal in np.arange(0.0, lane.length, SPACING_M):
                points.append(lane.position(longitudinal, 0.0))
                headings.append(lane.heading_theta_at(longitudinal))
                options.append(int(option))
        index += 1
    return GlobalRoute(np.asarray(points, np.float64)[:, :2], np.asarray(headings, np.float64),
                       np.asarray(options, np.uint8))


def _lane(road_network, road: tuple[str, str], lane_index: int):
    lanes = road_network.graph[road[0]][road[1]]
    return lanes[min(lane_index, len(lanes) - 1)]
