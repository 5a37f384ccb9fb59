"""Every start/destination pair a town offers, with the junction turns of its route (benchmark routes).

A start is a road that is not a junction crossing and whose start node has a single successor road
(so MetaDrive's breadth-first planner, which starts from that node, plans through the start road);
a destination is the end node of another such road. The route between them is MetaDrive's own
shortest path, so what is listed here is what the navigation drives. Loading a town needs MetaDrive
but no rendering.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

from msfsu_common.road_option import RoadOption
from msfsu_sim.route import edge_lane_option, is_junction_edge
from msfsu_sim.scenarios import TOWNS, Town

SPAWN_LONGITUDE_M = 5.0  # MetaDrive's default spawn position along the start lane (routes spawn there too)
MAX_ROUTE_M = 350.0  # from the spawn to the destination: a few minutes of driving (benchmark and collection)


@dataclass(frozen=True)
class RoadRoute:
    """Checkpoints (MetaDrive node names) from a start road to a destination node."""

    checkpoints: tuple[str, ...]
    junctions: tuple[RoadOption, ...]  # option of every junction crossing, in driving order
    length_m: float  # along lane 0, from the start road's start
    start_road_m: float  # length of the start road (room for the spawn position)


def map_config(town: Town) -> dict:
    """MetaDrive map configuration of a town (the same map for the simulator and the route catalog)."""
    return {"type": "block_sequence", "config": town.blocks, "lane_num": town.lanes, "lane_width": 3.5}


ShortestPath = Callable[[tuple[str, str, int], str], list[str]]


def road_routes(graph: dict, shortest_path: ShortestPath) -> Iterator[RoadRoute]:
    """All (start road, destination) routes of a road graph {from: {to: [lanes]}} in a stable order."""
    roads = [(a, b) for a in sorted(graph) for b in sorted(graph[a]) if not is_junction_edge(a, b)]
    starts = [road for road in roads if len(graph[road[0]]) == 1]
    for start in starts:
        for _, destination in roads:
            if destination == start[1]:
                continue
            checkpoints = shortest_path((*start, 0), destination)
            if len(checkpoints) < 3 or checkpoints[1] != start[1]:
                continue  # unreachable, or planned around the start road
            edges = list(zip(checkpoints[:-1], checkpoints[1:]))
            lanes_options = [edge_lane_option(graph, a, b, 0) for a, b in edges]
            junctions = tuple(option for _, option in lanes_options if option is not RoadOption.LANE_FOLLOW)
            yield RoadRoute(tuple(checkpoints), junctions, float(sum(lane.length for lane, _ in lanes_options)),
                            float(lanes_options[0][0].length))


def town_routes(town: str) -> list[RoadRoute]:
    """Load the town's map in a render-free MetaDrive and list its routes (one engine per process)."""
    from metadrive.envs.metadrive_env import MetaDriveEnv

    spec = TOWNS[town]
    env = MetaDriveEnv(dict(map_config=map_config(spec), start_seed=spec.map_seed, num_scenarios=1,
                            use_render=False, log_level=40, traffic_density=0.0, random_spawn_lane_index=False))
    try:
        env.reset(seed=spec.map_seed)
        network = env.engine.current_map.road_network
        return list(road_routes(network.graph, network.shortest_path))
    finally:
        env.close()
