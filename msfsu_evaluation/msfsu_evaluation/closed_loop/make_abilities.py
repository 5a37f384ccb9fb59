"""Generate the committed scenario file of the per-ability suite from the towns' maps (run once; bump
abilities.ABILITIES_VERSION on change):

    python -m msfsu_evaluation.closed_loop.make_abilities [--out PATH] [--per-ability N]

Needs MetaDrive without rendering (a few seconds per town). Where each ability happens:
- mid-block abilities (pedestrians, lead braking, cut-in) and the clear road: a stretch of a catalog route with no
  junction from the spawn to past the goal, bending less than MAX_BEND_DEG, spawn on the route's start road;
- crossing traffic: the first junction of a catalog route, 25-31 m after the spawn, and a lane of another road
  through the same junction that crosses the ego's path (45-135 degrees) from the left or the right.
Each scenario draws its place and its actor's parameters from its own seed (suite, ability, condition, index).
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_evaluation.closed_loop.abilities import (ABILITIES, ABILITIES_FILE, ABILITIES_VERSION, ROUTES_PER_ABILITY,
                                                    SUITE, Ability)
from msfsu_evaluation.closed_loop.suites import SPAWN_LANE, BenchmarkRoute, _seed
from msfsu_sim.scenario_spec import (CLEAR_ROAD, CROSSING_TRAFFIC, CUT_IN, LEAD_BRAKING, PEDESTRIAN_BEHIND_PARKED_CAR,
                                     PEDESTRIAN_CROSSING, ScenarioSpec)
from msfsu_sim.scenarios import HELDOUT_TOWNS, HELDOUT_WEATHERS, TRAIN_TOWNS, TRAIN_WEATHERS

COMMAND = "python -m msfsu_evaluation.closed_loop.make_abilities"
INITIAL_SPEED_MPS = 7.0  # the ego starts moving, near the expert's cruise: the scenario begins at once
CONFLICT_M = (30.0, 38.0)  # from the spawn: the conflict of the mid-block abilities but the pedestrians'
CUE_AFTER_S = 1.0  # a pedestrian is cued about this long after the start (at INITIAL_SPEED_MPS): its conflict
# lies INITIAL_SPEED_MPS x (its time to the ego's lane + timing + CUE_AFTER_S) after the spawn
CUT_IN_M = (40.0, 46.0)  # cut_in: a nominal conflict (where it has cut in, at the expert's speeds): the goal's place
MIN_CLEAR_M = CONFLICT_M[0] + 25.0
GOAL_AFTER_M = 20.0  # the goal lies this far past the conflict (mid-block) ...
JUNCTION_GOAL_AFTER_M = 15.0  # ... or past the junction's end (crossing traffic)
JUNCTION_AHEAD_M = (25.0, 31.0)  # crossing traffic: from the spawn to the junction's entry
MAX_BEND_DEG = 25.0  # heading change over a mid-block stretch
END_MARGIN_M = 10.0  # the goal stays this far from the route's end (MetaDrive would end the episode there)
VEHICLES = ("s", "m", "l")  # MetaDrive's sedan-sized traffic classes (vehicle_type keys)
CONDITIONS = {"train": (list(TRAIN_TOWNS), list(TRAIN_WEATHERS)), "heldout": (list(HELDOUT_TOWNS), list(HELDOUT_WEATHERS))}


@dataclass(frozen=True)
class Place:
    """Where a scenario happens: a catalog route, the spawn on its start road, the conflict and the goal."""

    checkpoints: tuple[str, ...]
    spawn_m: float  # arc length of the spawn on the route (= the longitude on its start road)
    conflict_m: float
    goal_m: float
    junctions: tuple[str, ...]  # RoadOption names of the junctions from the spawn to the goal
    actor_lanes: tuple[tuple[str, str], ...] = ()
    side: str = ""
    clear_m: float = 0.0  # mid-block: junction-free and straight this far from the spawn


class TownMap:
    """A town's road graph (render-free MetaDrive) and the places its catalog routes offer."""

    def __init__(self, town: str) -> None:
        from metadrive.envs.metadrive_env import MetaDriveEnv

        from msfsu_sim.route_catalog import map_config, road_routes
        from msfsu_sim.scenarios import TOWNS

        spec = TOWNS[town]
        self.env = MetaDriveEnv(dict(map_config=map_config(spec), start_seed=spec.map_seed, num_scenarios=1,
                                     use_render=False, log_level=40, traffic_density=0.0,
                                     random_spawn_lane_index=False))
        self.env.reset(seed=spec.map_seed)
        network = self.env.engine.current_map.road_network
        self.graph = network.graph
        self.routes = list(road_routes(self.graph, network.shortest_path))

    def close(self) -> None:
        self.env.close()

    def _geometry(self, checkpoints: tuple[str, ...]):
        from msfsu_sim.route import edge_lane_option
        from msfsu_sim.scripted import PathFrame

        edges = list(zip(checkpoints[:-1], checkpoints[1:]))
        lanes_options = [edge_lane_option(self.graph, a, b, SPAWN_LANE) for a, b in edges]
        frame = PathFrame([lane for lane, _ in lanes_options])
        spans = [(float(frame.starts[i]), float(frame.starts[i + 1]), option, edges[i])
                 for i, (_, option) in enumerate(lanes_options) if option is not RoadOption.LANE_FOLLOW]
        return frame, spans

    def mid_block_places(self) -> list[Place]:
        """Every (route, spawn) whose stretch from the spawn on is junction-free and straight enough for at least
        MIN_CLEAR_M (Place.clear_m: how far it is); one per distinct stretch."""
        places, seen = [], set()
        for route in self.routes:
            frame, spans = self._geometry(route.checkpoints)
            limit = min([s for s, _, _, _ in spans] + [frame.length_m - END_MARGIN_M])
            for spawn in np.arange(5.0, route.start_road_m - 3.0 + 1e-9, 5.0):
                if any(s < spawn + 1.0 and e > spawn - 5.0 for s, e, _, _ in spans):
                    continue
                arcs = np.arange(spawn, limit, 2.0)
                if len(arcs) < 2:
                    continue
                headings = np.unwrap([frame.heading(a) for a in arcs])
                bent = np.flatnonzero(np.abs(headings - headings[0]) > math.radians(MAX_BEND_DEG))
                clear = float((arcs[bent[0]] if len(bent) else limit) - spawn)
                if clear < MIN_CLEAR_M:
                    continue
                key = (route.checkpoints[:2], float(spawn), round(clear))
                if key in seen:
                    continue
                seen.add(key)
                places.append(Place(route.checkpoints, float(spawn), 0.0, 0.0, (), clear_m=clear))
        return places

    def junction_places(self) -> list[Place]:
        """Every (route, crossing lane) where the route's first junction is JUNCTION_AHEAD_M after a spawn on its start
        road and another road's lane crosses the ego's path through it."""
        from msfsu_sim.scripted import PathFrame, crossing_roads

        places, seen = [], set()
        for route in self.routes:
            frame, spans = self._geometry(route.checkpoints)
            if not spans:
                continue
            start, end, option, edge = spans[0]
            spawn = start - JUNCTION_AHEAD_M[1]
            if spawn < 5.0:
                spawn = 5.0
            if not JUNCTION_AHEAD_M[0] <= start - spawn <= JUNCTION_AHEAD_M[1] or spawn > route.start_road_m - 1.0:
                continue
            goal = end + JUNCTION_GOAL_AFTER_M
            if goal > frame.length_m - END_MARGIN_M or any(s < goal and s > start for s, _, _, _ in spans[1:]):
                continue
            roads = tuple(zip(route.checkpoints[:-1], route.checkpoints[1:]))
            for path in crossing_roads(self.graph, list(roads), edge):
                key = (route.checkpoints[:2], edge, tuple(path))
                if key in seen:
                    continue
                seen.add(key)
                other = PathFrame([self.graph[a][b][0] for a, b in path])
                junction_lane = self.graph[edge[0]][edge[1]][SPAWN_LANE]
                ours = np.array([junction_lane.position(s, 0.0) for s in np.linspace(0, junction_lane.length, 40)])
                arcs = np.arange(0.0, other.length_m, 0.25)
                theirs = np.array([other.position(a) for a in arcs])
                distances = np.linalg.norm(ours[:, None] - theirs[None], axis=2)
                i, j = np.unravel_index(int(np.argmin(distances)), distances.shape)
                conflict = start + junction_lane.length * i / 39
                heading = frame.heading(conflict)
                before = other.position(arcs[j] - 20.0) - frame.position(conflict)
                side = "left" if math.cos(heading) * before[1] - math.sin(heading) * before[0] > 0 else "right"
                places.append(Place(route.checkpoints, float(spawn), float(conflict), float(goal), (option.name,),
                                    tuple(path), side))
        return places


def _needed_m(conflict_m: float) -> float:
    """How far a mid-block stretch must be clear for a conflict this far from the spawn."""
    return conflict_m + GOAL_AFTER_M + 5.0


def _scenario(ability: Ability, pool: list[Place], rng: random.Random) -> tuple[ScenarioSpec, Place]:
    """The ability's actor parameters and a place of `pool` that fits them (conflict and goal set)."""
    uniform = lambda low, high: round(rng.uniform(low, high), 2)  # noqa: E731
    vehicle = rng.choice(VEHICLES)
    params: dict = {}
    distance = uniform(*CONFLICT_M)  # spawn to conflict
    if ability.kind == PEDESTRIAN_CROSSING:
        from msfsu_sim.scripted import LANE_WIDTH_M, kerb_offsets

        left, right = kerb_offsets(2)
        speed = uniform(1.3, 1.7)
        timing = uniform(0.8, 1.8)
        enter = abs(left if ability.side == "left" else right) - (LANE_WIDTH_M / 2 + 0.4)
        distance = round(INITIAL_SPEED_MPS * (enter / speed + timing + CUE_AFTER_S), 1)
        params = dict(side=ability.side, actor_speed_mps=speed, timing_s=timing)
    elif ability.kind == PEDESTRIAN_BEHIND_PARKED_CAR:
        params = dict(actor_speed_mps=uniform(1.2, 1.6), timing_s=uniform(0.6, 1.2), vehicle=vehicle)
    elif ability.kind == LEAD_BRAKING:
        params = dict(actor_speed_mps=uniform(6.5, 8.0), gap_m=uniform(10.0, 16.0), decel_mps2=uniform(5.0, 7.0),
                      hold_s=uniform(2.0, 4.0), vehicle=vehicle)
    elif ability.kind == CUT_IN:  # it overtakes at 2.5-4 m/s more than the expert's cruise, cuts in, brakes
        distance = uniform(*CUT_IN_M)
        params = dict(actor_speed_mps=uniform(10.5, 12.0), gap_m=uniform(3.0, 6.0), decel_mps2=uniform(4.0, 6.0),
                      slow_speed_mps=uniform(2.0, 3.5), hold_s=uniform(1.5, 3.0), vehicle=vehicle)
    elif ability.kind == CROSSING_TRAFFIC:
        params = dict(actor_speed_mps=uniform(6.0, 8.0), gap_m=uniform(25.0, 35.0), timing_s=uniform(-0.4, 0.4),
                      vehicle=vehicle)
    if ability.kind == CROSSING_TRAFFIC:
        place = pool[rng.randrange(len(pool))]
        params.update(side=place.side, actor_lanes=place.actor_lanes)
    else:
        fitting = [place for place in pool if place.clear_m >= _needed_m(distance)]
        if not fitting:
            raise ValueError(f"no mid-block stretch of {_needed_m(distance):.0f} m for {ability.name}")
        place = fitting[rng.randrange(len(fitting))]
        conflict = round(place.spawn_m + distance, 1)
        place = Place(place.checkpoints, place.spawn_m, conflict, round(conflict + GOAL_AFTER_M, 1), ())
    spec = ScenarioSpec(kind=ability.kind, conflict_m=place.conflict_m, goal_m=place.goal_m,
                        initial_speed_mps=INITIAL_SPEED_MPS, **params)
    return spec, place


def build_abilities(per_ability: int, conditions: dict[str, tuple[list[str], list[str]]] | None = None,
                    suite: str = SUITE, seed: int | None = None) -> list[BenchmarkRoute]:
    """`per_ability` scenarios of every ability per condition ({name: (towns, weathers)}; the committed suite's by
    default), keyed under `suite`; `seed` (None: the committed suite's) varies every scenario's placement and actor."""
    routes: list[BenchmarkRoute] = []
    for condition, (towns, weathers) in (conditions or CONDITIONS).items():
        maps = {}
        for town in towns:
            town_map = TownMap(town)
            try:
                maps[town] = (town_map.mid_block_places(), town_map.junction_places())
            finally:
                town_map.close()
            print(f"{town}: {len(maps[town][0])} mid-block places, {len(maps[town][1])} junction crossings",
                  file=sys.stderr)
        for ability in ABILITIES.values():
            for index in range(per_ability):
                town = towns[index % len(towns)]
                weather = weathers[(index // len(towns)) % len(weathers)]
                seed_of = _seed(SUITE, ability.name, condition, index, *(() if seed is None else (seed,)))
                rng = random.Random(seed_of)
                mid_block, junctions = maps[town]
                pool = junctions if ability.kind == CROSSING_TRAFFIC else mid_block
                if ability.kind == CROSSING_TRAFFIC:  # alternate the side the car comes from
                    wanted = "left" if index % 2 == 0 else "right"
                    pool = [place for place in pool if place.side == wanted] or pool
                spec, place = _scenario(ability, pool, rng)
                graph_route = place.checkpoints
                routes.append(BenchmarkRoute(
                    suite=suite, task=ability.name, condition=condition, index=index, town=town, weather=weather,
                    seed=seed_of, start=(graph_route[0], graph_route[1]), lane=SPAWN_LANE, longitude_m=place.spawn_m,
                    destination=graph_route[-1], length_m=round(place.goal_m - place.spawn_m, 1),
                    junctions=place.junctions, scenario=spec))
    return routes


def _condition(text: str) -> tuple[str, tuple[list[str], list[str]]]:
    """NAME=TOWN[,TOWN...]:WEATHER[,WEATHER...] -> (NAME, (towns, weathers)); ValueError naming what is unknown."""
    from msfsu_sim.scenarios import TOWNS, WEATHERS

    name, _, rest = text.partition("=")
    towns, _, weathers = rest.partition(":")
    towns, weathers = [t for t in towns.split(",") if t], [w for w in weathers.split(",") if w]
    if not (name and towns and weathers):
        raise ValueError(f"--condition {text}: give NAME=TOWN[,TOWN...]:WEATHER[,WEATHER...]")
    if unknown := [town for town in towns if town not in TOWNS] + [w for w in weathers if w not in WEATHERS]:
        raise ValueError(f"--condition {text}: unknown {', '.join(unknown)} (towns {', '.join(TOWNS)}; weathers "
                         f"{', '.join(WEATHERS)})")
    return name, (towns, weathers)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=COMMAND, description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ABILITIES_FILE)
    parser.add_argument("--per-ability", type=int, default=ROUTES_PER_ABILITY, help="scenarios per ability and condition")
    parser.add_argument("--condition", action="append", default=[], metavar="NAME=TOWN[,TOWN...]:WEATHER[,WEATHER...]",
                        help="a condition of your own: its towns and weathers (msfsu_sim.scenarios; repeatable); default "
                             "the committed suite's train and heldout")
    parser.add_argument("--seed", type=int, help="vary every scenario's placement and actor (default: the committed suite's)")
    parser.add_argument("--suite", default=SUITE, help=f"the name its scenarios' keys start with (default {SUITE})")
    options = parser.parse_args(argv)
    try:
        conditions = dict(_condition(text) for text in options.condition) or None
    except ValueError as error:
        print(f"{COMMAND}: {error}", file=sys.stderr)
        return 2
    routes = build_abilities(options.per_ability, conditions, options.suite, options.seed)
    header = {"suite": SUITE, "version": ABILITIES_VERSION, "generator": COMMAND, "per_ability": options.per_ability}
    lines = ",\n  ".join(json.dumps(route.to_dict()) for route in routes)  # one scenario per line: readable diffs
    options.out.write_text(json.dumps(header)[:-1] + f', "routes": [\n  {lines}\n]}}\n')
    print(f"{len(routes)} scenarios -> {options.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
