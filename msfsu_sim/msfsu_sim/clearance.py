"""Spawn clearance (ROS-free): where no traffic participant may appear at the start of an episode.

A vehicle or pedestrian spawned inside or just in front of the ego car makes an episode unwinnable for
every agent (a collision at step 6, before anyone could react). The clear zone is a disc around the ego
plus a corridor along the first metres of its route; traffic placed there at reset, or respawned there
later, is dropped or placed elsewhere (msfsu_sim.traffic, msfsu_sim.pedestrians).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SpawnClearance:
    radius_m: float = 12.0  # around the ego's centre
    route_m: float = 30.0  # the first metres of the route ahead of the ego ...
    corridor_half_width_m: float = 2.5  # ... and this far on either side of it (a lane is 3.5 m wide)


DEFAULT_CLEARANCE = SpawnClearance()


class ClearZone:
    """The clear zone of one episode start: `blocks(xy, radius)` says whether a body there is too close."""

    def __init__(self, ego_xy: tuple[float, float], route_xy: np.ndarray, clearance: SpawnClearance) -> None:
        """`route_xy`: (N, 2) points of the ego's route from its position onwards, densely spaced (<= 2 m)."""
        self.ego = np.asarray(ego_xy, np.float64)
        self.clearance = clearance
        route = np.asarray(route_xy, np.float64).reshape(-1, 2)
        if len(route):
            arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=1))])
            route = route[arc <= clearance.route_m]
        self.route_ahead = route

    def blocks(self, xy: tuple[float, float] | np.ndarray, radius_m: float = 0.0) -> bool:
        """Is a body of `radius_m` at `xy` within the clearance of the ego or of its route's first metres?"""
        point = np.asarray(xy, np.float64)[:2]
        if np.linalg.norm(point - self.ego) < self.clearance.radius_m + radius_m:
            return True
        if not len(self.route_ahead):
            return False
        distance = float(np.min(np.linalg.norm(self.route_ahead - point, axis=1)))
        return distance < self.clearance.corridor_half_width_m + radius_m
