"""Benchmark suites, tasks and their fixed routes (ROS-free).

Modelled on the paper's benchmarks (III-C): CoRL2017 (straight / one_turn / navigation on empty roads,
navigation_dynamic with traffic) and NoCrash (navigation with empty / regular / dense traffic, any
collision fails), each in training conditions (training towns + weathers) and held-out conditions.
Routes live in `routes.json` next to this module, generated once from the maps with

    python -m msfsu_evaluation.closed_loop.make_routes

and committed; its `version` is recorded with every result so numbers from different route sets are
never mixed. A task's routes are distinct start/destination pairs spread round-robin over the condition's
towns (every task has more than 25 pairs in both conditions, so spawn lane and position stay fixed); each
route has its own traffic seed.

- Version 3 (`routes.json`, the one runs use): every town of a condition meets every weather of it (town
  i of the round-robin takes the weathers in turn; v2 tied each held-out town to one held-out weather),
  and what happens on the routes changed: strikes of the kerb or a building fail the episode like other
  collisions, solid-line crossings are recorded (rules.py), and an episode is the same whatever ran before
  it in the simulator (msfsu_sim.environment: no reused vehicles, animation on simulated time).
- Version 2 (`routes_v2.json`, kept so that its committed results stay reportable; never run again):
  traffic drives from the first step (msfsu_sim.traffic), nothing spawns in the spawn clearance recorded
  in the file (msfsu_sim.clearance), pedestrians cross once when the ego comes, the timeouts are the
  original benchmarks' and only a wait without a reason counts as blocked (rules.py); weathers cycled with
  the route index, locked to the towns where their counts are equal.
"""

from __future__ import annotations

import json
import random
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from msfsu_common.road_option import RoadOption
from msfsu_sim.clearance import DEFAULT_CLEARANCE
from msfsu_sim.route_catalog import MAX_ROUTE_M, SPAWN_LONGITUDE_M
from msfsu_sim.scenario_spec import ScenarioSpec

ROUTES_FILE = Path(__file__).with_name("routes.json")
ROUTES_VERSION = 3  # what msfsu-benchmark runs
ROUTE_FILES = {2: Path(__file__).with_name("routes_v2.json"), ROUTES_VERSION: ROUTES_FILE}  # what reports read
SPAWN_CLEARANCE = DEFAULT_CLEARANCE  # no traffic inside it at an episode's start (recorded in the file)
ROUTES_PER_TASK = 25
SPAWN_LANE = 0
CONDITIONS = ("train", "heldout")


@dataclass(frozen=True)
class Task:
    suite: str
    name: str
    traffic: str  # msfsu_sim.scenarios.TRAFFIC
    timeout_speed_kmh: float  # timeout: the time to drive the route at this speed ...
    timeout_margin_s: float  # ... plus this margin

    def accepts(self, junctions: Sequence[RoadOption]) -> bool:
        """Does a route crossing these junctions (options in order) belong to this task?"""
        turns = sum(option in (RoadOption.LEFT, RoadOption.RIGHT) for option in junctions)
        if self.name == "straight":
            return turns == 0 and len(junctions) <= 1
        if self.name == "one_turn":
            return turns == 1 and len(junctions) == 1
        return turns >= 1 and len(junctions) >= 2  # navigation: several junctions


# Timeouts of the original benchmarks: route_km / 10 km/h + 10 s (CARLA's CoRL2017 suite) and route_km / 5 km/h
# + 20 s (NoCrash, which expects waiting in traffic). A collision fails the episode in every task (rules.py:
# MetaDrive ends an episode at any collision), as NoCrash requires and stricter than CoRL2017.
TASKS: dict[str, Task] = {task.name if task.suite == "corl2017" else f"nocrash_{task.name}": task for task in (
    Task("corl2017", "straight", "empty", 10.0, 10.0),
    Task("corl2017", "one_turn", "empty", 10.0, 10.0),
    Task("corl2017", "navigation", "empty", 10.0, 10.0),
    Task("corl2017", "navigation_dynamic", "regular", 10.0, 10.0),
    Task("nocrash", "empty", "empty", 5.0, 20.0),
    Task("nocrash", "regular", "regular", 5.0, 20.0),
    Task("nocrash", "dense", "dense", 5.0, 20.0),
)}
NAVIGATION = "navigation"  # the route class of navigation_dynamic and the NoCrash tasks
SUITES = ("smoke", "corl2017", "nocrash")


def route_class(task_key: str) -> str:
    """Which route filter a task uses: its own, or navigation for the traffic variants."""
    task = TASKS[task_key]
    return task.name if task.suite == "corl2017" and task.name != "navigation_dynamic" else NAVIGATION


@dataclass(frozen=True)
class BenchmarkRoute:
    suite: str
    task: str  # key of TASKS
    condition: str  # train / heldout
    index: int
    town: str
    weather: str
    seed: int  # traffic and pedestrians
    start: tuple[str, str]  # start road (MetaDrive nodes)
    lane: int
    longitude_m: float
    destination: str
    length_m: float  # from the spawn position to the destination, along the route
    junctions: tuple[str, ...]  # RoadOption names of the junction crossings
    scenario: ScenarioSpec | None = None  # a per-ability scenario (closed_loop.abilities): its actor and its goal

    @property
    def key(self) -> str:
        """Stable identity within a route-file version (results and resume are keyed by it)."""
        return f"{self.suite}/{self.task}/{self.condition}/{self.index:02d}"

    def to_dict(self) -> dict:
        """The route file's entry: every field, the scenario only where there is one."""
        data = asdict(self)
        data.pop("scenario")
        if self.scenario is not None:
            data["scenario"] = self.scenario.to_dict()
        return data

    @classmethod
    def from_dict(cls, item: dict) -> BenchmarkRoute:
        item = dict(item, start=tuple(item["start"]), junctions=tuple(item["junctions"]))
        if item.get("scenario") is not None:
            item["scenario"] = ScenarioSpec.from_dict(item["scenario"])
        return cls(**item)


@dataclass(frozen=True)
class Candidate:
    """A start/destination pair of a town (from msfsu_sim.route_catalog)."""

    start: tuple[str, str]
    destination: str
    junctions: tuple[RoadOption, ...]
    length_m: float  # from the start road's start
    start_road_m: float


def _seed(*parts: object) -> int:
    return zlib.crc32("/".join(map(str, parts)).encode()) % 2**31


def select_routes(suite: str, task_key: str, condition: str, towns: Sequence[str], weathers: Sequence[str],
                  candidates: Mapping[str, Sequence[Candidate]], count: int,
                  shortest: bool = False) -> list[BenchmarkRoute]:
    """`count` distinct routes of a task, round-robin over `towns` (seeded shuffle, or shortest first); each
    town takes the `weathers` in turn (route i: town i mod T, weather (i div T) mod W), so every town meets
    every weather.

    ValueError when the towns do not hold enough routes of the task's class.
    """
    task = TASKS[task_key]
    check = TASKS[NAVIGATION] if route_class(task_key) == NAVIGATION else task
    pools = []
    for town in towns:
        pool = [c for c in candidates[town] if check.accepts(c.junctions) and c.start_road_m > SPAWN_LONGITUDE_M + 5
                and c.length_m - SPAWN_LONGITUDE_M <= MAX_ROUTE_M]
        if shortest:
            # by the length as the file records it (0.1 m), ties in catalog order (sorted node names): raw lengths
            # are sums of MetaDrive's lane lengths, whose last bits differ between CPUs (AVX2 / AVX-512 numerics),
            # and two mirror routes of one length swapped places on an AVX2 EPYC
            pool.sort(key=lambda c: round(c.length_m, 1))
        else:
            random.Random(_seed(suite, task_key, condition, town)).shuffle(pool)
        pools.append((town, pool))
    chosen: list[tuple[str, Candidate]] = []
    while len(chosen) < count and any(pool for _, pool in pools):
        for town, pool in pools:
            if pool and len(chosen) < count:
                chosen.append((town, pool.pop(0)))
    if len(chosen) < count:
        raise ValueError(f"{suite}/{task_key}/{condition}: only {len(chosen)} routes in {', '.join(towns)}, "
                         f"{count} wanted")
    return [BenchmarkRoute(
        suite=suite, task=task_key, condition=condition, index=index, town=town,
        weather=weathers[(index // len(towns)) % len(weathers)], seed=_seed(suite, task_key, condition, index),
        start=candidate.start, lane=SPAWN_LANE, longitude_m=SPAWN_LONGITUDE_M, destination=candidate.destination,
        length_m=round(candidate.length_m - SPAWN_LONGITUDE_M, 1),
        junctions=tuple(option.name for option in candidate.junctions),
    ) for index, (town, candidate) in enumerate(chosen)]


def build_route_file(candidates: Mapping[str, Sequence[Candidate]], conditions: Mapping[str, tuple[list, list]],
                     generator: str) -> dict:
    """The whole route file: every task x condition (25 routes) plus the smoke suite (shortest routes)."""
    routes: list[BenchmarkRoute] = []
    for condition, (towns, weathers) in conditions.items():
        for key, task in TASKS.items():
            routes += select_routes(task.suite, key, condition, towns, weathers, candidates, ROUTES_PER_TASK)
    train_towns, train_weathers = conditions["train"]
    for key in ("straight", "one_turn"):  # CI: one short route each, first training town, first weather
        routes += select_routes("smoke", key, "train", train_towns[:1], train_weathers[:1], candidates, 1,
                                shortest=True)
    return {"version": ROUTES_VERSION, "generator": generator, "routes_per_task": ROUTES_PER_TASK,
            "spawn": {"lane": SPAWN_LANE, "longitude_m": SPAWN_LONGITUDE_M},
            "spawn_clearance": asdict(SPAWN_CLEARANCE),
            "routes": [route.to_dict() for route in routes]}


def load_routes(path: Path = ROUTES_FILE) -> tuple[int, list[BenchmarkRoute]]:
    """(version, routes); ValueError if the file is not a route file of a version this package knows
    (ROUTE_FILES: reports read older versions, msfsu-benchmark runs only ROUTES_VERSION)."""
    data = json.loads(Path(path).read_text())
    if data.get("version") not in ROUTE_FILES:
        raise ValueError(f"{path}: route file version {data.get('version')!r}, this benchmark knows "
                         f"{sorted(ROUTE_FILES)} (regenerate: python -m msfsu_evaluation.closed_loop.make_routes)")
    if data.get("spawn_clearance") != asdict(SPAWN_CLEARANCE):
        raise ValueError(f"{path}: spawn clearance {data.get('spawn_clearance')} is not this simulator's "
                         f"{asdict(SPAWN_CLEARANCE)} (regenerate the file and bump its version)")
    routes = []
    for item in data["routes"]:
        if item["task"] not in TASKS:
            raise ValueError(f"{path}: unknown task {item['task']!r}")
        routes.append(BenchmarkRoute.from_dict(item))
    return data["version"], routes


def choose(routes: Iterable[BenchmarkRoute], suites: Sequence[str], conditions: Sequence[str],
           tasks: Sequence[str] | None = None, per_task: int | None = None,
           towns: Sequence[str] | None = None) -> list[BenchmarkRoute]:
    """The routes of the given suites/conditions (and tasks, and towns), the first `per_task` of each task x condition
    (in index order, among those of the towns)."""
    chosen = [r for r in routes if r.suite in suites and r.condition in conditions and (not tasks or r.task in tasks)
              and (not towns or r.town in towns)]
    return first_per_task(chosen, per_task)


def first_per_task(routes: Sequence[BenchmarkRoute], per_task: int | None) -> list[BenchmarkRoute]:
    """The first `per_task` routes (by index) of each suite x task x condition, all where None; order kept."""
    if per_task is None:
        return list(routes)
    ranks: dict[tuple[str, str, str], list[int]] = {}
    for route in routes:
        ranks.setdefault((route.suite, route.task, route.condition), []).append(route.index)
    kept = {cell: set(sorted(indices)[:per_task]) for cell, indices in ranks.items()}
    return [route for route in routes if route.index in kept[(route.suite, route.task, route.condition)]]


def full_suite_routes(path: Path = ROUTES_FILE) -> int:
    """How many routes a full suite is: every route of the benchmark suites (SUITES but the smoke test), both
    conditions (350 on routes v3)."""
    _, routes = load_routes(path)
    return len(choose(routes, [suite for suite in SUITES if suite != "smoke"], CONDITIONS))
