"""Pedestrians on the sidewalks and crossings of the route (MetaDrive's procedural maps have none).

Half of them walk along the sidewalk next to the route, the others cross the road in front of the ego
car once it comes within `TRIGGER_M`, as a careless pedestrian would; all are real physics bodies, so
hitting one is a `crash_human` event.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from msfsu_sim.route import GlobalRoute

WALK_SPEED_MPS = 1.2
TRIGGER_M = 25.0
SIDEWALK_OFFSET_M = 5.5  # from the centre of the route lane to the sidewalk (two 3.5 m lanes + kerb)
MIN_START_M = 40.0  # no pedestrian right in front of the start position


class Pedestrians:
    def __init__(self, engine: Any, route: GlobalRoute, count: int, rng: np.random.Generator) -> None:
        from metadrive.component.traffic_participants.pedestrian import Pedestrian

        self.engine = engine
        self.objects: list[Any] = []
        self._walks: list[tuple[np.ndarray, bool]] = []  # (unit direction, crossing?)
        usable = np.flatnonzero(np.cumsum(np.r_[0.0, np.linalg.norm(np.diff(route.points, axis=0), axis=1)]) > MIN_START_M)
        if count == 0 or usable.size == 0:
            return
        for index in rng.choice(usable, size=min(count, usable.size), replace=False):
            heading = route.headings[index]
            right = np.array([math.sin(heading), -math.cos(heading)])
            side = 1.0 if rng.random() < 0.5 else -1.0
            position = route.points[index] + side * SIDEWALK_OFFSET_M * right
            crossing = bool(rng.random() < 0.5)
            direction = -side * right if crossing else np.array([math.cos(heading), math.sin(heading)]) * side
            walker = engine.spawn_object(Pedestrian, position=position, heading_theta=math.atan2(direction[1], direction[0]),
                                         random_seed=int(rng.integers(1 << 30)))
            self.objects.append(walker)
            self._walks.append((direction, crossing))

    def step(self, ego_position: np.ndarray) -> None:
        for walker, (direction, crossing) in zip(self.objects, self._walks):
            near = np.linalg.norm(np.asarray(walker.position[:2]) - ego_position[:2]) < TRIGGER_M
            walker.set_velocity(direction, WALK_SPEED_MPS if (near or not crossing) else 0.0)

    def clear(self) -> None:
        if self.objects:
            self.engine.clear_objects([walker.id for walker in self.objects])
        self.objects, self._walks = [], []
