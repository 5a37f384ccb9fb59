"""The routes collected episodes drive: drawn (by the episode's seed) from its town's start/destination pairs
(`msfsu_sim.route_catalog`, the catalog the benchmark's routes come from) that cross at least one junction, leave
room for the spawn on the start road and are at most MAX_ROUTE_M long. The bag's metadata names the route."""

from __future__ import annotations

import json
import random
from collections.abc import Sequence

from msfsu_common import bag_io
from msfsu_sim.collection_plan import Episode
from msfsu_sim.environment import SimEnvironment
from msfsu_sim.route_catalog import MAX_ROUTE_M, SPAWN_LONGITUDE_M, RoadRoute

SPAWN_ROOM_M = 5.0  # the start road must reach this far beyond the spawn position

_catalog: dict[str, list[RoadRoute]] = {}  # town -> collection_routes of its map (fixed by the town)


def collection_routes(routes: Sequence[RoadRoute]) -> list[RoadRoute]:
    """The catalog routes an episode may drive: at least one junction, room for the spawn on the start road,
    at most MAX_ROUTE_M from the spawn to the destination."""
    return [route for route in routes if route.junctions and route.start_road_m >= SPAWN_LONGITUDE_M + SPAWN_ROOM_M
            and route.length_m - SPAWN_LONGITUDE_M <= MAX_ROUTE_M]


def draw_route(routes: Sequence[RoadRoute], seed: int) -> RoadRoute:
    """The route of the episode with `seed` (uniform over `routes`, deterministic)."""
    if not routes:
        raise ValueError("no route to draw from")
    return routes[random.Random(seed).randrange(len(routes))]


def episode_route(env: SimEnvironment, episode: Episode) -> RoadRoute:
    """The route `episode` drives (its town's map is loaded by a blind reset the first time)."""
    if episode.town not in _catalog:
        env.reset(episode.town, episode.weather, "empty", episode.seed, render=False)
        _catalog[episode.town] = collection_routes(env.road_routes())
    return draw_route(_catalog[episode.town], episode.seed)


def route_metadata(route: RoadRoute) -> dict[str, str]:
    """The bag metadata naming the route: start road, destination, junction options, length from the spawn."""
    return {bag_io.ROUTE_START: json.dumps(list(route.checkpoints[:2])),
            bag_io.ROUTE_DESTINATION: route.checkpoints[-1],
            bag_io.ROUTE_JUNCTIONS: ",".join(option.name for option in route.junctions),
            bag_io.ROUTE_LENGTH_M: f"{route.length_m - SPAWN_LONGITUDE_M:.1f}"}
