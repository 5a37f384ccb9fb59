"""Pedestrians for procedural maps (MetaDrive spawns none): walkers on sidewalks and crossers at junctions.

Walkers follow the kerb of the route's roads (curves included) and turn round at a road's end. A crosser
waits on the kerb where the ego's route enters a junction until the ego comes within its trigger distance
(seeded, 20-35 m), then crosses the whole road once at walking speed and stays on the far kerb: a
crossing the ego meets, like CARLA's pedestrian-crossing scenarios, not a pedestrian pacing the road for
ever. Nobody is placed inside the episode's clear zone (msfsu_sim.clearance).

MetaDrive's IDM traffic asks every object near it for its `lane`, which its pedestrians lack: the
AttributeError sends the policy to a fallback that sees no object at all, so with a pedestrian within
50 m a traffic car drove into whatever was ahead of it, the ego included. Our pedestrians have a lane:
the driving lane a crosser is on while crossing (traffic stops for it), else a footpath that is no
driving lane's neighbour (traffic ignores people on the sidewalk).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from metadrive.component.traffic_participants.pedestrian import Pedestrian
from metadrive.constants import PGDrivableAreaProperty
from metadrive.manager.base_manager import BaseManager

from msfsu_sim.clearance import DEFAULT_CLEARANCE, SpawnClearance
from msfsu_sim.route import is_junction_edge
from msfsu_sim.traffic import ego_clear_zone

WALK_SPEED_MPS = 1.2
TRIGGER_M = (20.0, 35.0)  # a crosser starts when the ego is this close (uniform, seeded per crosser)
KERB_GAIN = 0.5  # 1/s: how fast a walker steers back to its kerb line
SPAWN_TRIES = 10
CROSSER_SPACING_M = 2.5  # between crossers of one junction (people standing in one spot push each other)
BODY_RADIUS_M = 0.5


class _Footpath:
    """The `lane` of a pedestrian off the carriageway: no driving lane is it, or leads to or from it."""

    start = end = (math.nan, math.nan)
    index = ("footpath", "footpath", 0)

    def is_previous_lane_of(self, lane: Any) -> bool:
        return False


FOOTPATH = _Footpath()


class Person(Pedestrian):
    """MetaDrive's pedestrian with the `lane` its traffic policy reads (see the module docstring)."""

    lane: Any = FOOTPATH


@dataclass
class _Walker:
    """Walks the kerb line of `lane` (lateral offset `kerb_m`), forwards or backwards along it."""

    agent: Any
    lane: Any
    kerb_m: float
    forward: bool

    def velocity(self) -> tuple[float, float]:
        lane = self.lane
        s, lateral = lane.local_coordinates(np.asarray(self.agent.position))
        if self.forward and s > lane.length - 2.0 or not self.forward and s < 2.0:
            self.forward = not self.forward
        s = min(max(s, 0.0), lane.length)
        heading = lane.heading_theta_at(s) + (0.0 if self.forward else math.pi)
        normal = np.asarray(lane.position(s, 1.0)) - np.asarray(lane.position(s, 0.0))
        direction = np.array([math.cos(heading), math.sin(heading)]) + KERB_GAIN * (self.kerb_m - lateral) * normal
        return tuple(direction / max(np.linalg.norm(direction), 1e-6))


@dataclass
class _Crosser:
    """Waits at `start` until the ego is within `trigger_m`, crosses to `end`, then stands there."""

    agent: Any
    start: np.ndarray
    end: np.ndarray
    trigger_m: float
    state: str = "waiting"  # waiting -> crossing -> crossed

    def velocity(self, ego_xy: np.ndarray) -> tuple[float, float] | None:
        if self.state == "waiting" and np.linalg.norm(ego_xy - self.start) < self.trigger_m:
            self.state = "crossing"
        if self.state == "crossing":
            to_go = self.end - np.asarray(self.agent.position)
            if float(np.dot(to_go, self.end - self.start)) <= 0.0:
                self.state = "crossed"
            else:
                return tuple((self.end - self.start) / np.linalg.norm(self.end - self.start))
        return None


class PedestrianManager(BaseManager):
    """Spawns `walkers` along the ego route's sidewalk and `crossers` at its junction entries each reset.

    Counts are set by `configure()` before the env reset; placement uses this manager's seeded RNG.
    """

    def __init__(self) -> None:
        super().__init__()
        self.walkers_count = 0
        self.crossers_count = 0
        self.clearance = DEFAULT_CLEARANCE
        self._walkers: list[_Walker] = []
        self._crossers: list[_Crosser] = []

    def configure(self, walkers: int, crossers: int, clearance: SpawnClearance = DEFAULT_CLEARANCE) -> None:
        self.walkers_count, self.crossers_count, self.clearance = walkers, crossers, clearance

    def seed(self, random_seed: int) -> None:
        """Ignored, as MetaDrive's traffic manager ignores it with random traffic: every env reset gives every
        manager the map's seed, which placed the same pedestrians for every episode seed of a route (until
        simulator revision 2). SimEnvironment.reset seeds this manager with the episode's seed
        (`BaseManager.seed(manager, seed)`) before the env reset."""

    def reset(self) -> None:
        super().reset()
        self._walkers, self._crossers = [], []

    def after_reset(self) -> None:
        """Spawn once the ego car exists (its route decides where)."""
        super().after_reset()
        agent = next(iter(self.engine.agents.values()))
        checkpoints = agent.navigation.checkpoints
        graph = self.engine.current_map.road_network.graph
        edges = list(zip(checkpoints[:-1], checkpoints[1:]))
        roads = [graph[a][b] for a, b in edges if not is_junction_edge(a, b) and graph[a][b][-1].length > 20]
        junctions = [graph[a][b] for a, b in edges if is_junction_edge(a, b)]
        zone = ego_clear_zone(self.engine, self.clearance)
        for _ in range(self.walkers_count if roads else 0):
            for _ in range(SPAWN_TRIES):
                if self._spawn_walker(roads[self.np_random.randint(len(roads))], zone):
                    break
        for index in range(self.crossers_count if junctions else 0):
            self._spawn_crosser(junctions[index % len(junctions)], zone, index // len(junctions))

    def _kerb_offset(self, lane: Any) -> float:
        return lane.width / 2 + PGDrivableAreaProperty.SIDEWALK_LINE_DIST + PGDrivableAreaProperty.SIDEWALK_WIDTH / 2

    def _spawn(self, position: tuple[float, float], heading: float) -> Any:
        return self.spawn_object(Person, position=position, heading_theta=heading, random_seed=0)

    def _spawn_walker(self, road_lanes: list, zone) -> bool:
        outer = road_lanes[-1]  # lanes are numbered from the centre line outwards
        s = float(self.np_random.uniform(5.0, outer.length - 5.0))
        forward = bool(self.np_random.rand() < 0.5)
        kerb = self._kerb_offset(outer)
        position = tuple(outer.position(s, kerb))
        if zone.blocks(position, BODY_RADIUS_M):
            return False
        heading = outer.heading_theta_at(s) + (0.0 if forward else math.pi)
        body = self._spawn(position, heading)
        body.msfsu_role = f"walker {len(self._walkers)}"  # environment.actor_name
        self._walkers.append(_Walker(body, outer, kerb, forward))
        return True

    def _spawn_crosser(self, junction_lanes: list, zone, nth: int = 0) -> None:
        """On the kerb where the route enters the junction, to cross to the kerb opposite. The `nth` crosser of
        the same junction starts CROSSER_SPACING_M further back along the road, from the other kerb if odd."""
        entry, outer = junction_lanes[0], junction_lanes[-1]
        back = -CROSSER_SPACING_M * nth * np.array([math.cos(entry.heading_theta_at(0.0)),
                                                    math.sin(entry.heading_theta_at(0.0))])
        start = np.asarray(outer.position(0.0, self._kerb_offset(outer)), np.float64) + back
        centre = np.asarray(entry.position(0.0, -entry.width / 2), np.float64) + back  # the two-way road's centre
        end = 2 * centre - start
        if nth % 2:
            start, end = end, start
        if zone.blocks(start, BODY_RADIUS_M):
            return
        heading = math.atan2(*(end - start)[::-1])
        trigger = float(self.np_random.uniform(*TRIGGER_M))
        body = self._spawn(tuple(start), heading)
        body.msfsu_role = f"crosser {len(self._crossers)}"  # environment.actor_name
        self._crossers.append(_Crosser(body, start, end, trigger))

    def after_step(self, *args: Any, **kwargs: Any) -> dict:
        ego = np.asarray(next(iter(self.engine.agents.values())).position, np.float64)
        for walker in self._walkers:
            direction = walker.velocity()
            walker.agent.set_heading_theta(math.atan2(direction[1], direction[0]))
            walker.agent.set_velocity(list(direction), WALK_SPEED_MPS)
        network = self.engine.current_map.road_network
        for crosser in self._crossers:
            direction = crosser.velocity(ego)
            crosser.agent.set_velocity([1.0, 0.0] if direction is None else list(direction),
                                       0.0 if direction is None else WALK_SPEED_MPS)
            crosser.agent.lane = FOOTPATH if crosser.state != "crossing" else network.get_lane(
                network.get_closest_lane_index(crosser.agent.position)[0])
        return {}
