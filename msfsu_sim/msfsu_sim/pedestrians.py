"""Pedestrians for procedural maps (MetaDrive spawns none): walkers on sidewalks and crossers at junctions."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from metadrive.component.traffic_participants.pedestrian import Pedestrian
from metadrive.constants import PGDrivableAreaProperty
from metadrive.manager.base_manager import BaseManager

from msfsu_sim.route import is_junction_edge

WALK_SPEED_MPS = 1.2


@dataclass
class _Walker:
    agent: Any
    direction: tuple[float, float]
    # Crossers turn back when they are this far from the crossing's centre line (road half width + kerb).
    turn_distance_m: float | None = None
    centre: tuple[float, float] = (0.0, 0.0)


class PedestrianManager(BaseManager):
    """Spawns `walkers` along the ego route's sidewalk and `crossers` at its junction entries each reset.

    Counts are set by `configure()` before the env reset; placement uses this manager's seeded RNG.
    """

    def __init__(self) -> None:
        super().__init__()
        self.walkers_count = 0
        self.crossers_count = 0
        self._walkers: list[_Walker] = []

    def configure(self, walkers: int, crossers: int) -> None:
        self.walkers_count, self.crossers_count = walkers, crossers

    def reset(self) -> None:
        super().reset()
        self._walkers = []

    def after_reset(self) -> None:
        """Spawn once the ego car exists (its route decides where)."""
        super().after_reset()
        agent = next(iter(self.engine.agents.values()))
        checkpoints = agent.navigation.checkpoints
        graph = self.engine.current_map.road_network.graph
        edges = list(zip(checkpoints[:-1], checkpoints[1:]))
        roads = [graph[a][b] for a, b in edges if not is_junction_edge(a, b) and graph[a][b][-1].length > 20]
        junctions = [graph[a][b] for a, b in edges if is_junction_edge(a, b)]
        for _ in range(self.walkers_count if roads else 0):
            self._spawn_walker(roads[self.np_random.randint(len(roads))])
        for index in range(self.crossers_count if junctions else 0):
            self._spawn_crosser(junctions[index % len(junctions)])

    def _kerb_offset(self, lane: Any) -> float:
        return lane.width / 2 + PGDrivableAreaProperty.SIDEWALK_LINE_DIST + PGDrivableAreaProperty.SIDEWALK_WIDTH / 2

    def _spawn(self, position: tuple[float, float], heading: float) -> Any:
        return self.spawn_object(Pedestrian, position=position, heading_theta=heading, random_seed=0)

    def _spawn_walker(self, road_lanes: list) -> None:
        outer = road_lanes[-1]  # lanes are numbered from the centre line outwards
        s = float(self.np_random.uniform(5.0, outer.length - 5.0))
        forward = self.np_random.rand() < 0.5
        heading = outer.heading_theta_at(s) + (0.0 if forward else math.pi)
        agent = self._spawn(tuple(outer.position(s, self._kerb_offset(outer))), heading)
        self._walkers.append(_Walker(agent, (math.cos(heading), math.sin(heading))))

    def _spawn_crosser(self, junction_lanes: list) -> None:
        """Start on the kerb where the route enters the junction and walk across the road and back."""
        entry, outer = junction_lanes[0], junction_lanes[-1]
        start = outer.position(0.0, self._kerb_offset(outer))
        centre = entry.position(0.0, -entry.width / 2)  # the centre line of a two-way road
        dx, dy = centre[0] - start[0], centre[1] - start[1]
        half_width = math.hypot(dx, dy)
        direction = (dx / half_width, dy / half_width)
        agent = self._spawn(tuple(start), math.atan2(dy, dx))
        self._walkers.append(_Walker(agent, direction, half_width, tuple(centre)))

    def after_step(self, *args: Any, **kwargs: Any) -> dict:
        for walker in self._walkers:
            if walker.turn_distance_m is not None:
                x, y = walker.agent.position
                beyond = (x - walker.centre[0]) * walker.direction[0] + (y - walker.centre[1]) * walker.direction[1]
                if beyond > walker.turn_distance_m:
                    walker.direction = (-walker.direction[0], -walker.direction[1])
            walker.agent.set_velocity(list(walker.direction), WALK_SPEED_MPS)
        return {}
